r"""The physics model's optional terms fitted with its base constants (``identify --effects``; DESIGN 6.1b).

:mod:`~quad_modelling.core.identification.physics_fit` fits each channel's constants by linear least squares of
the model's multi-step error. A term joins when the channel's acceleration is linear in one coefficient of it,
given the term's nonlinear parameters (held on a grid, or computed from the data); its regressor is the one
physics' wrench per unit of that coefficient (:mod:`quad_modelling.core.physics.rigid_body`), with
:math:`X_T` the thrust column (body force per unit :math:`k_f`, rotated to N, over m):

* ``ground_effect`` (velocity): :math:`X_T G(h)`, :math:`G = 1/(h + h_{off})^2` at the measured height
  :math:`h = -z_N`, coefficient :math:`\theta = k_f c_{ge}`; :math:`h_{off}` on the grid :data:`GROUND_OFFSETS`
  (times the arm length), the one of least velocity error kept;
* ``battery`` (velocity): :math:`X_T\, 2 (V - V_{ref})`, coefficient :math:`\theta = k_f \kappa`: the rotor
  speeds scale by :math:`f = 1 + \kappa (V - V_{ref})` (the lag is linear), the thrust by
  :math:`f^2 \approx 1 + 2 \kappa (V - V_{ref})`; :math:`V_{ref}` the mean training voltage;
* ``gyroscopic`` (roll, pitch, yaw): :math:`-(\omega \times I\omega)/I` (coefficient :math:`k_b`, all three
  axes) and :math:`-(\omega \times h_r)/I` of the rotors' momentum
  (:func:`~quad_modelling.core.physics.rigid_body.rotor_momentum`, coefficient :math:`k_p`, roll and pitch), each
  coefficient's axes combined by inverse variance;
* ``motor_imbalance``: not fitted here (it needs a per-motor joint fit of all channels); ``identify --effects
  motor_imbalance`` says so in one line.

The torques of roll and pitch keep the thrust without the ground-effect and battery factors (second order: a
common factor of the differential thrust). Sigmas by first-order propagation of the channel's; bounds
(:data:`TERM_BOUNDS`) clip with an at-bound flag, as the base constants.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quad_modelling.core.physics.aero import ground_effect_factor
from quad_modelling.core.physics.effects import TERMS
from quad_modelling.core.physics.rigid_body import gyroscopic_torque, rotor_momentum
from quad_modelling.errors import ConfigError

FITTABLE = ("ground_effect", "battery", "gyroscopic")
"""The terms ``identify --effects`` fits with the base constants (module docstring)."""

GROUND_OFFSETS = (0.25, 0.5, 1.0, 2.0)
"""Ground-effect offsets h_off searched, in arm lengths: the rotor-plane height at which the gain law would
diverge lies within a rotor radius (about half an arm) of the hubs' height above the CG's."""

TERM_BOUNDS = {
    ("ground_effect", "coefficient"): (0.0, 1.0),  # times arm_length²: c_ge = (R/4)² is ~1/64 of it for R = arm/2
    ("ground_effect", "offset"): (0.0, 4.0),  # times arm_length (GROUND_OFFSETS)
    ("battery", "kappa"): (-1.0, 1.0),  # 1/V: a rotor speed proportional to V has kappa = 1/V_ref (0.24 at 4.2 V)
    ("battery", "reference_voltage"): (0.0, 100.0),  # V
    ("gyroscopic", "body_scale"): (0.0, 10.0),
    ("gyroscopic", "rotor_scale"): (0.0, 10.0),
}
"""Bounds of each fitted term parameter (ground effect in units of the vehicle's arm length)."""


@dataclass(frozen=True)
class TermDesign:
    """The terms fitted and their held nonlinear parameters: ``names`` (of :data:`FITTABLE`), ``ground_offset``
    h_off [m], ``reference_voltage`` V_ref [V]."""

    names: tuple[str, ...] = ()
    ground_offset: float = float("nan")
    reference_voltage: float = float("nan")

    def __post_init__(self) -> None:
        refused = [n for n in self.names if n not in FITTABLE]
        if refused:
            raise ConfigError(f"--effects: identify cannot fit {', '.join(refused)} yet (it fits {', '.join(FITTABLE)}); "
                              f"set its parameters in the vehicle file's effects section (docs/formats.md)")


def velocity_columns(design: TermDesign, thrust_n: np.ndarray, height: np.ndarray, voltage: np.ndarray | None) -> list[np.ndarray]:
    """Extra velocity regressors (N, 3) per unit coefficient, in :attr:`TermDesign.names` order, from the thrust
    column ``thrust_n`` (N, 3) (module docstring)."""
    columns = []
    if "ground_effect" in design.names:
        per_coefficient = ground_effect_factor(np.maximum(height, 0.0), 1.0, design.ground_offset) - 1.0  # ∂k_GE/∂c_ge
        columns.append(thrust_n * per_coefficient[:, None])
    if "battery" in design.names:
        columns.append(thrust_n * 2.0 * (voltage - design.reference_voltage)[:, None])
    return columns


def rate_columns(design: TermDesign, prop_inertia: float, spins: np.ndarray, rates: np.ndarray, rotor: np.ndarray,
                 inertia: np.ndarray) -> np.ndarray | None:
    """The gyroscopic regressors (N, 3, 2) [rad/s² per unit k_b, k_p]: the body's -(ω × Iω)/I and the rotors'
    -(ω × h_r)/I; None when not fitted."""
    if "gyroscopic" not in design.names:
        return None
    momentum = rotor_momentum(prop_inertia, spins, rotor)
    body = gyroscopic_torque(rates, inertia) / inertia
    rotors = gyroscopic_torque(rates, inertia, momentum, body_scale=0.0) / inertia
    return np.stack([body, rotors], axis=2)


def term_estimates(design: TermDesign, fit: dict, thrust: tuple[float, float], arm_length: float) -> dict[str, dict]:
    """Per fitted term and parameter: value, sigma, bounds, at_bound, identifiable (from the channel fits ``fit``
    of :func:`~quad_modelling.core.identification.normal_equations.solve_channels`; ``thrust`` = (k_f, its sigma))."""
    kf, kf_sd = thrust
    out: dict[str, dict] = {}
    velocity = iter(range(3, 3 + sum(n in design.names for n in ("ground_effect", "battery"))))
    for name in design.names:
        if name in ("ground_effect", "battery"):
            i = next(velocity)
            theta, theta_sd = fit["velocity"]["coef"][i], np.sqrt(fit["velocity"]["cov"][i, i])
            value = theta / kf
            sd = abs(value) * np.hypot(theta_sd / theta, kf_sd / kf) if theta != 0 else theta_sd / kf
            key = "coefficient" if name == "ground_effect" else "kappa"
            fixed = ("offset", design.ground_offset) if name == "ground_effect" else ("reference_voltage", design.reference_voltage)
            out[name] = {key: _bounded(name, key, value, sd, arm_length), fixed[0]: _bounded(name, fixed[0], fixed[1], np.nan, arm_length)}
        else:  # body scale from roll, pitch and yaw (column 2, 2, 1); rotor scale from roll and pitch (column 3)
            body = _combined([(fit[c]["coef"][i], fit[c]["cov"][i, i]) for c, i in (("roll", 2), ("pitch", 2), ("yaw", 1))])
            rotor = _combined([(fit[c]["coef"][3], fit[c]["cov"][3, 3]) for c in ("roll", "pitch")])
            out[name] = {"body_scale": _bounded(name, "body_scale", *body, arm_length),
                         "rotor_scale": _bounded(name, "rotor_scale", *rotor, arm_length)}
    return out


def _combined(estimates: list[tuple[float, float]]) -> tuple[float, float]:
    """Inverse-variance mean and its sigma of (value, variance) estimates; NaN when none is finite."""
    finite = [(v, var) for v, var in estimates if np.isfinite(v) and np.isfinite(var) and var > 0]
    if not finite:
        return float("nan"), float("nan")
    w = np.array([1.0 / var for _, var in finite])
    return float(np.sum(w * np.array([v for v, _ in finite])) / w.sum()), float(1.0 / np.sqrt(w.sum()))


def _bounded(name: str, key: str, value: float, sigma: float, arm_length: float) -> dict:
    low, high = TERM_BOUNDS[(name, key)]
    if name == "ground_effect":
        low, high = low * arm_length ** (2 if key == "coefficient" else 1), high * arm_length ** (2 if key == "coefficient" else 1)
    unit = {p.name: p.unit for p in TERMS[name]}[key]
    if not np.isfinite(value):
        return {"value": float("nan"), "sigma": float("nan"), "unit": unit, "bounds": [low, high], "at_bound": False, "identifiable": False}
    return {"value": float(np.clip(value, low, high)), "sigma": float(sigma), "unit": unit, "bounds": [float(low), float(high)],
            "at_bound": bool(value <= low or value >= high), "identifiable": True}


def effects_section(estimates: dict[str, dict], source: str) -> dict:
    """The vehicle file's ``effects`` entries of the fitted terms: switched on when every parameter was identified,
    otherwise written off with status 'not identified' and the reason in the source."""
    section = {}
    for name, parameters in estimates.items():
        on = all(p["identifiable"] for p in parameters.values())
        entry: dict = {"enabled": on}
        for key, p in parameters.items():
            status = "identified" if p["identifiable"] else "not identified"
            note = "" if p["identifiable"] else "; the flights do not excite it"
            if p["at_bound"]:
                note += f"; AT BOUND {p['bounds']} {p['unit']}"
            value = p["value"] if p["identifiable"] else float(np.mean(p["bounds"]))
            entry[key] = {"value": value, "sigma": p["sigma"], "unit": p["unit"], "bounds": p["bounds"],
                          "source": source + note, "status": status}
        section[name] = entry
    return section
