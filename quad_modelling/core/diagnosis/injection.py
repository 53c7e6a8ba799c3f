"""Known answers on the user's own flights (``diagnose --inject SPEC``): change the command channel of every flight in
a way whose right answer is known, diagnose again, and compare with the un-injected run.

=================  ==========================================================  ===========================================
spec               change of the logged commands u (N, 4)                       right answer
=================  ==========================================================  ===========================================
``delay:MS``       advanced by MS: :math:`u'(t) = u(t + MS)` (linear            the delay rises by MS (+-
                   interpolation; the last MS of the flight is dropped)          :data:`DELAY_TOLERANCE_S`)
``gain:M:K``       motor M's command divided by K: :math:`u'_M = u_M / K`       motor M's gain relative to the others'
                                                                                 changes by the factor K (+- :data:`GAIN_TOLERANCE`)
``swap:A:B``       the columns of motors A and B exchanged                      the motor-order check names the swap
``none``           unchanged                                                    nothing changes
=================  ==========================================================  ===========================================

In every case no effect may newly be found (but the motor imbalance for ``gain``, the input delay for ``delay``), the motor-order check's verdict
stays (but for ``swap``), and but for ``delay:MS`` the delay stays (+- :data:`DELAY_TOLERANCE_S`). The delay's rise
is not judged (the verdict NOT JUDGED, exit code 0) when the un-injected delay sits on its search's lower bound, 0 ms
(:func:`injection_checks`). What the
identification cannot measure is refused: a delay of :data:`~quad_modelling.core.identification.physics_fit.DELAY_MAX_S`
or more (the delay's whole search range), a factor K outside the motor gains' search range :data:`GAIN_RANGE`; a
delay that puts the identified one on its search bound fails its check saying so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.identification.physics_fit import DELAY_MAX_S
from quad_modelling.core.identification.physics_terms import TERM_BOUNDS
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import ConfigError, DataError

DELAY_TOLERANCE_S = 0.005
"""Allowed error of the delay's rise [s] (issue #26: MS +- 5 ms)."""

GAIN_TOLERANCE = 0.05
"""Allowed relative error of the gain ratio (issue #26: K +- 5 %)."""

GAIN_RANGE = TERM_BOUNDS[("motor_imbalance", "gain_1")]
"""The motor gains' search range (the identification's bounds): an injected factor K must lie inside it."""

AT_BOUND_S = 5e-4
"""A delay within this of the search's upper bound [s] is on it (the stored delay may be a float32: 149.99986 ms)."""

MIN_FLIGHT_S = 1.0
"""Least flight left after a delay injection [s]."""


@dataclass(frozen=True)
class Injection:
    """A parsed ``--inject`` spec: kind ('delay', 'gain', 'swap', 'none') and its numbers (delay [s]; motor, factor;
    motors A, B; 1-based)."""

    kind: str
    delay_s: float = 0.0
    motor: int = 0
    factor: float = 1.0
    swap: tuple[int, int] = (0, 0)
    spec: str = "none"

    def apply(self, log: FlightLog) -> FlightLog:
        """``log`` with its commands changed (module docstring); DataError when a delay leaves no commands."""
        if self.kind == "none":
            return log
        u = np.array(log.u, dtype=float)
        if self.kind == "gain":
            u[:, self.motor - 1] /= self.factor
            return replace(log, u=u)
        if self.kind == "swap":
            a, b = self.swap[0] - 1, self.swap[1] - 1
            u[:, [a, b]] = u[:, [b, a]]
            return replace(log, u=u)
        keep = int(np.searchsorted(log.t, log.t[-1] - self.delay_s, side="right"))
        if log.t[max(keep - 1, 0)] - log.t[0] < MIN_FLIGHT_S:
            raise DataError(f"{log.meta.source}: --inject {self.spec} leaves no commands (the flight lasts "
                            f"{log.t[-1] - log.t[0]:.2f} s)")
        shifted = np.column_stack([np.interp(log.t[:keep] + self.delay_s, log.t, u[:, i]) for i in range(u.shape[1])])
        cut = log.slice(0, keep)
        return replace(cut, u=shifted)


def parse_injection(spec: str, motors: int = 4) -> Injection:
    """An :class:`Injection` from ``delay:MS``, ``gain:M:K``, ``swap:A:B`` or ``none``; ConfigError in one line naming
    the spec and what is wrong."""
    text = spec.strip()
    parts = text.split(":")
    kind = parts[0]
    usage = "expected delay:MS, gain:MOTOR:K, swap:A:B or none"
    shapes = {"none": 1, "delay": 2, "gain": 3, "swap": 3}
    if shapes.get(kind) != len(parts):
        raise ConfigError(f"--inject {text}: {usage}")
    try:
        numbers = [float(x) for x in parts[1:]]
    except ValueError as err:
        raise ConfigError(f"--inject {text}: {usage} (numbers where MS, MOTOR, K, A, B stand)") from err
    if kind == "none":
        return Injection("none", spec=text)
    if kind == "delay":
        if not (np.isfinite(numbers[0]) and numbers[0] > 0):
            raise ConfigError(f"--inject {text}: the delay must be a positive number of milliseconds")
        if numbers[0] <= DELAY_TOLERANCE_S * 1e3:
            raise ConfigError(f"--inject {text}: the check tells a delay from none only beyond its {DELAY_TOLERANCE_S * 1e3:g} ms "
                              "tolerance; inject more (e.g. 10-40 ms)")
        if numbers[0] >= DELAY_MAX_S * 1e3:
            raise ConfigError(f"--inject {text}: the identification searches delays up to {DELAY_MAX_S * 1e3:g} ms (the "
                              f"vehicle's own delay included); inject less (e.g. 10-40 ms)")
        return Injection("delay", delay_s=numbers[0] / 1000.0, spec=text)
    first = _check_motor(text, numbers[0], motors)
    if kind == "gain":
        if not (np.isfinite(numbers[1]) and numbers[1] > 0):
            raise ConfigError(f"--inject {text}: the gain factor K must be a positive number")
        if abs(1.0 / numbers[1] - 1.0) <= GAIN_TOLERANCE + 1e-9:  # a measured ratio of 1 (no change seen) would pass
            raise ConfigError(f"--inject {text}: the check tells a gain from none only beyond its {GAIN_TOLERANCE:.0%} tolerance "
                              f"(K outside {1 / (1 + GAIN_TOLERANCE):.4f}..{1 / (1 - GAIN_TOLERANCE):.4f}); inject more "
                              "(e.g. 1.1-1.3, or 0.8)")
        if not GAIN_RANGE[0] < numbers[1] < GAIN_RANGE[1]:
            raise ConfigError(f"--inject {text}: the identification searches motor gains in {GAIN_RANGE[0]:g}..{GAIN_RANGE[1]:g}; "
                              "K must lie strictly inside")
        return Injection("gain", motor=first, factor=numbers[1], spec=text)
    second = _check_motor(text, numbers[1], motors)
    if first == second:
        raise ConfigError(f"--inject {text}: swap needs two different motors")
    return Injection("swap", swap=(first, second), spec=text)


def _check_motor(text: str, motor: float, motors: int) -> int:
    """The 1-based motor number ``motor``; ConfigError unless a whole number in 1..``motors``."""
    if not (float(motor).is_integer() and 1 <= motor <= motors):
        raise ConfigError(f"--inject {text}: motor {motor:g}: the vehicle has motors 1..{motors}")
    return int(motor)


def relative_gain(gains, motor: int) -> float:
    """Motor ``motor``'s (1-based) gain over the mean of the others'."""
    g = np.asarray(gains, dtype=float)
    others = np.delete(g, motor - 1)
    return float(g[motor - 1] / others.mean())


def injection_checks(injection: Injection, plain: dict, injected: dict) -> dict:
    """The comparison of the injected run's summary with the un-injected one (module docstring): per check the
    expected and measured values and whether it holds (None: not judged); a swap is expected relative to the flights
    as logged (their own exchange of the same motors and the injected one cancel: no swap; another one makes two
    exchanges, which the order check, naming one, cannot: not judged); ``passed`` True when all hold, False when
    one does not, else None. The delay's rise is not judged when the un-injected delay sits on the search's lower
    bound, 0 ms (``reference_at_zero``): what is known is that bound -- the flights' commands act at or before their
    stamps, or the command path's lag was fitted as rotor lag -- and the rise from it is less than the injected delay
    by the unknown amount the un-injected optimum lies below it (simulated flights without ``input_delay``: a profile
    whose minimum lies 10 ms below 0 with a 10 ms lag, a 20 ms injection rose 9.3 ms, a 40 ms one 30 ms; simulated
    Crazyflie flights with an 8 ms input delay and no motor lag, seeds 21-23: the delay at 0 and a rotor lag of 8.7 ms);
    comparing two injections (``delay:20`` and ``delay:40``) measures it."""
    checks = []
    new = sorted(set(injected["found"]) - set(plain["found"]))
    allowed = {"gain": {"motor_imbalance"}, "delay": {"input_delay"}}.get(injection.kind, set())  # the injected change
    checks.append({"check": "nothing else newly found", "newly_found": new, "expected_new": sorted(allowed),
                   "holds": not [n for n in new if n not in allowed]})
    if injection.kind != "swap":
        before, after = ((run.get("motor_order") or {}).get("swap") for run in (plain, injected))
        checks.append({"check": "the motor-order check's verdict stays", "expected": before, "named": after,
                       "holds": after == before})
    if injection.kind == "delay":
        rise = injected["delay_s"]["value"] - plain["delay_s"]["value"]
        at_bound = injected["delay_s"]["value"] >= DELAY_MAX_S - AT_BOUND_S
        # the un-injected delay searched and on its lower bound (a delay held at 0, not searched, has no sigma)
        from_floor = plain["delay_s"]["value"] <= 0.0 and np.isfinite(plain["delay_s"].get("sigma", 0.0))
        checks.append({"check": "delay rises by the injected delay", "expected_s": injection.delay_s, "measured_s": rise,
                       "tolerance_s": DELAY_TOLERANCE_S, "at_search_bound": at_bound, "reference_at_zero": from_floor,
                       "holds": None if from_floor and not at_bound
                       else abs(rise - injection.delay_s) <= DELAY_TOLERANCE_S and not at_bound})
    else:
        shift = injected["delay_s"]["value"] - plain["delay_s"]["value"]
        checks.append({"check": "the delay stays (its change)", "expected_s": 0.0, "measured_s": shift, "tolerance_s": DELAY_TOLERANCE_S,
                       "holds": abs(shift) <= DELAY_TOLERANCE_S})
    if injection.kind == "gain":
        ratio = (relative_gain(injected["motor_command_gains"]["value"], injection.motor)
                 / relative_gain(plain["motor_command_gains"]["value"], injection.motor))
        checks.append({"check": f"motor {injection.motor}'s relative gain changes by K", "expected": injection.factor,
                       "measured": ratio, "tolerance": GAIN_TOLERANCE,
                       "holds": abs(ratio / injection.factor - 1.0) <= GAIN_TOLERANCE})
    if injection.kind == "swap":  # relative to the flights as logged: a swap there and the same injected cancel
        fix = (injected.get("motor_order") or {}).get("swap")
        logged = (plain.get("motor_order") or {}).get("swap")
        expected = sorted(injection.swap) if logged is None else None if sorted(logged) == sorted(injection.swap) else "two"
        checks.append({"check": "the motor-order check names the swap", "expected": None if expected == "two" else expected,
                       "named": fix, "logged_swap": logged, "holds": None if expected == "two" else fix == expected})
    verdicts = [c["holds"] for c in checks]
    return {"spec": injection.spec, "checks": checks,
            "passed": False if False in verdicts else None if None in verdicts else True}


def swapped(log: FlightLog, swap) -> FlightLog:
    """``log`` with the command columns of motors ``swap`` = [A, B] (1-based) exchanged: the motor-order check's
    fix, with which the diagnosis then runs (a wrong motor order leaves a base no effect can mend, and one of
    them took 5 % of its error on NanoBench flights with motors 3 and 4 exchanged: battery, newly found)."""
    return Injection("swap", swap=(int(swap[0]), int(swap[1]))).apply(log)


def swapped_motors(document: dict, swap) -> dict:
    """A vehicle ``document`` whose motors A and B of ``swap`` (1-based; name, position, spin) and their
    ``motor_imbalance`` gains are exchanged: a vehicle diagnosed on commands :func:`swapped` back, written in the order
    the logged commands hold the motors, predicts the flights as logged as the diagnosis did (changed in place)."""
    a, b = (int(i) - 1 for i in swap)
    motors = document["motors"]
    motors[a], motors[b] = motors[b], motors[a]
    terms = document.get("effects", {}).get("motor_imbalance", {})
    if f"gain_{a + 1}" in terms and f"gain_{b + 1}" in terms:
        terms[f"gain_{a + 1}"], terms[f"gain_{b + 1}"] = terms[f"gain_{b + 1}"], terms[f"gain_{a + 1}"]
    document["description"] += f" (motors {a + 1} and {b + 1} listed in the order the logged commands hold them)"
    return document


def motor_order_check(train: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig) -> dict:
    """``identify``'s motor order and spin check (:mod:`~quad_modelling.core.identification.motor_check`) on the
    training flights, with ``swap`` [A, B] (1-based) when the likely fix is exactly one exchange of two columns."""
    from quad_modelling.core.identification.greybox_fit import identify_base
    from quad_modelling.core.identification.identify import modelled_thrusts, training_batch
    from quad_modelling.core.identification.motor_check import check_motor_layout

    batch = training_batch(train, vehicle, config)
    check = check_motor_layout(batch, modelled_thrusts(batch, identify_base(batch, vehicle)), vehicle)
    names = [m.name for m in vehicle.motors]
    swap = None
    fix = check.get("fix")
    if fix and fix["moved"] == 2:
        moved = [i + 1 for i, name in enumerate(fix["order"]) if name != names[i]]
        swap = sorted(moved)
    return {"verdict": check["verdict"], "wrong": check["wrong"], "actions": fix["actions"] if fix else [], "swap": swap}
