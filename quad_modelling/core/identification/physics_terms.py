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
* ``motor_imbalance`` (roll, pitch, yaw): each motor's gain :math:`g_i` on its logged command, mean 1 (the common
  gain is :math:`k_f`'s). The gains move along three patterns :math:`P_c` (:func:`imbalance_patterns`: the rows
  :math:`-y_i, x_i, s_i` of the allocation, zero-mean), each seen first by its own channel c: around the current
  gains :math:`\hat g`, :math:`\partial \Omega_i / \partial g_i = (\Omega_i - \Omega_{off}) / \hat g_i` (the speed map
  and the lag are linear in the command), so the channel's acceleration gains the column
  :math:`\sum_i M_{c,i}\, 2 \Omega_i (\Omega_i - \Omega_{off}) / \hat g_i\, P_{c,i}` with coefficient
  :math:`\gamma_c = \alpha_c e_c` (:math:`\alpha_c` the channel's thrust or torque gain), and
  :math:`g \leftarrow \hat g + \sum_c e_c P_c`, renormalised to mean 1; repeated :data:`IMBALANCE_ITERATIONS`
  times (Gauss-Newton) by :func:`~quad_modelling.core.identification.physics_fit.identify_physics`. Its CG offset
  :math:`c` (roll, pitch) is linear: the rotor forces' moment about the CG gains :math:`-c \times F`
  (:func:`~quad_modelling.core.physics.rigid_body.cg_offset_moment`), so roll gains the column
  :math:`\sum_i \Omega_i^2` (the CG moment per unit :math:`k_f c_y`) with coefficient :math:`\alpha_x c_y` and pitch
  :math:`-\sum_i \Omega_i^2` with :math:`\alpha_y c_x` (:func:`cg_offset_columns`; the yaw part :math:`c \times`
  rotor drag is second order and left out of the fit, not of the model). Roll and pitch are then fitted without
  the observer (:data:`IMBALANCE_LEVEL_CHANNELS`), and where the flights do not separate the offset from the gains
  it is held at 0 (:func:`imbalance_separated`).

Rotor drag is a base constant of the physics (``rotor_drag_xy/_z/_arm``); ``TermDesign.drag`` False holds it at 0
(its columns left out): the diagnosis's base without rotor drag.

The torques of roll and pitch keep the thrust without the ground-effect and battery factors (second order: a
common factor of the differential thrust). Sigmas by first-order propagation of the channel's; bounds
(:data:`TERM_BOUNDS`) clip with an at-bound flag, as the base constants.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quad_modelling.core.physics.aero import ground_effect_factor
from quad_modelling.core.physics.effects import BASE_SWITCHES, TERMS, parse_term_names
from quad_modelling.core.physics.rigid_body import allocation_matrix, cg_offset_moment, gyroscopic_torque, rotor_momentum
from quad_modelling.errors import ConfigError

FITTABLE = ("ground_effect", "battery", "gyroscopic", "motor_imbalance")
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
    **{("motor_imbalance", f"gain_{i}"): (0.5, 2.0) for i in range(1, 5)},  # a motor at half or twice the others' answer
    ("motor_imbalance", "cg_offset_x"): (-0.25, 0.25),  # times arm_length: a CG a quarter arm off centre needs a rotor
    ("motor_imbalance", "cg_offset_y"): (-0.25, 0.25),  # ~1.7x the opposite one's thrust to hover (X frame)
}
"""Bounds of each fitted term parameter (ground effect and the CG offset in units of the vehicle's arm length,
:data:`ARM_POWERS`)."""

VANISHING_AT_BOUND = {"ground_effect": "coefficient"}
"""Terms that are no term at a bound of one parameter: a ground-effect coefficient at its lower bound 0 is no ground
effect (k_GE = 1)."""

VANISHED_HELD = "the term vanishes at this bound: the other constants fitted without it"
"""Why a vanished term's parameter is held (:func:`~quad_modelling.core.identification.physics_fit.identify_physics`)."""


ARM_POWERS = {("ground_effect", "coefficient"): 2, ("ground_effect", "offset"): 1,
              ("motor_imbalance", "cg_offset_x"): 1, ("motor_imbalance", "cg_offset_y"): 1}
"""The power of the arm length each :data:`TERM_BOUNDS` entry is written in (absent: absolute)."""


IMBALANCE_AXES = ("roll", "pitch", "yaw")
"""The imbalance's gain patterns (:func:`imbalance_patterns`), all fitted by default (:attr:`TermDesign.imbalance_axes`)."""


@dataclass(frozen=True)
class TermDesign:
    """The terms fitted and their held nonlinear parameters: ``names`` (of :data:`FITTABLE`), ``ground_offset``
    h_off [m], ``reference_voltage`` V_ref [V]."""

    names: tuple[str, ...] = ()
    ground_offset: float = float("nan")
    reference_voltage: float = float("nan")
    drag: bool = True
    """False: rotor drag held at 0, its columns left out (module docstring)."""
    motor_gains: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    """The current gains :math:`\\hat g` of the imbalance iteration (module docstring)."""
    cg_offset: bool = True
    """False: the imbalance's CG offset held at 0, its columns left out (:func:`imbalance_separated`)."""
    imbalance_axes: tuple[str, ...] = IMBALANCE_AXES
    """The gain patterns fitted (the others held, their channel's imbalance column left out; without roll and pitch
    the CG offset is held at 0 too): ``("yaw",)`` is the imbalance's yaw pattern alone, against which the diagnosis
    weighs the rest (:data:`~quad_modelling.core.diagnosis.physics_base.YAW_PATTERN_ONLY`)."""

    def __post_init__(self) -> None:
        refused = [n for n in self.names if n not in FITTABLE]
        if refused:
            why = ("identify chooses the observer by the data; set it in the vehicle file's effects section to hold one"
                   if refused == ["disturbance_observer"] else "set its parameters in the vehicle file's effects section")
            fits = (*FITTABLE, *BASE_SWITCHES)
            raise ConfigError(f"--effects: identify cannot fit {', '.join(refused)} yet (it fits {', '.join(fits)}); "
                              f"{why} (docs/formats.md)")


def identify_term_names(names) -> tuple[str, ...]:
    """The terms of an ``identify --effects`` list (ConfigError in one line otherwise): known, each named once, and
    fittable (:data:`FITTABLE`) or a switch of base constants (:data:`~quad_modelling.core.physics.effects.BASE_SWITCHES`),
    which ``identify`` then fits and switches on."""
    names = parse_term_names(names, listed=(*FITTABLE, *BASE_SWITCHES))
    TermDesign(tuple(n for n in names if n not in BASE_SWITCHES))  # refuses a term identify cannot fit
    return names


IMBALANCE_ITERATIONS = 3
"""Gauss-Newton passes of the motor gains (module docstring): a 25 % gain on one motor converges to 0.1 % in 3."""


IMBALANCE_LEVEL_CHANNELS = ("roll", "pitch")
"""Channels whose regression runs without the disturbance observer when the motor imbalance is fitted with its CG
offset (held at 0, :func:`imbalance_separated`, they keep it): the CG
offset (and the gains' roll and pitch patterns, nearly collinear with it on an X frame) is a moment proportional to
the thrust, nearly constant in a hover, which an angular observer takes out of the regression, leaving only its
variation with the thrust to fit it on; a level left wrong makes the model need the observer to predict.
Simulated LinkQuad, the simulator's CG offset alone (development seeds 5101-5103; its ESC gains held at 1 in a
bench script, not in the simulator), diagnosis's held-out J (truth 0.212, base 0.318): observer in every channel
0.286 (CG (6.01, -4.02) mm +- 0.09, truth (6, -4)); none in roll and pitch 0.263 ((6.05, -3.96) +- 0.045); none in
yaw too 0.213. Yaw keeps it: without, the gains' spin pattern takes an unmodelled yaw torque's level, and a bent
arm (a disturbance, to be found as nothing) was found as a motor imbalance on those seeds (7.5 %; with the
simulator's gains and CG the imbalance then shrank J by 32.9 % of a 34.1 % ceiling, 10.7 % with yaw's observer)."""


def channel_columns(design: TermDesign) -> dict[str, list[str]]:
    """The regressor names of each channel, in column order (the main gain first: columns are kept in order while
    the flights excite them, :func:`~quad_modelling.core.identification.normal_equations.excited_columns`)."""
    drag = ["drag_xy", "drag_z"] if design.drag else []
    gyro = ["gyro_body", "gyro_rotor"] if "gyroscopic" in design.names else []
    imbalance = ["imbalance"] if "motor_imbalance" in design.names else []
    velocity = ["thrust", *drag, *[n for n in ("ground_effect", "battery") if n in design.names]]
    cg = ["cg_offset"] if imbalance and design.cg_offset else []

    def pattern(axis: str) -> list[str]:
        return imbalance if axis in design.imbalance_axes else []

    torque = ["thrust", *(["drag_moment"] if design.drag else []), *gyro]
    return {"velocity": velocity, "roll": [*torque, *pattern("roll"), *cg], "pitch": [*torque, *pattern("pitch"), *cg],
            "yaw": ["torque", *gyro[:1], *pattern("yaw")]}


def imbalance_patterns(positions: np.ndarray, spins: np.ndarray) -> np.ndarray:
    """(3, 4) gain patterns P_c of roll, pitch and yaw: the allocation's rows -y_i, x_i, s_i
    (:func:`~quad_modelling.core.physics.rigid_body.allocation_matrix`), each made zero-mean and scaled to a largest
    entry of 1."""
    rows = allocation_matrix(positions, spins, 1.0)[1:]
    rows = rows - rows.mean(axis=1, keepdims=True)
    return rows / np.abs(rows).max(axis=1, keepdims=True)


def imbalance_columns(design: TermDesign, positions: np.ndarray, spins: np.ndarray, speed_offset: float,
                      rotor: np.ndarray) -> np.ndarray:
    """(N, 3) the imbalance regressors of roll, pitch and yaw (module docstring) of rotor speeds ``rotor`` (N, 4)."""
    rows = allocation_matrix(positions, spins, 1.0)[1:]
    slope = 2.0 * rotor * (rotor - speed_offset) / np.asarray(design.motor_gains)  # ∂Ω_i²/∂g_i
    return slope @ (rows * imbalance_patterns(positions, spins)).T


def cg_offset_columns(thrust_force: np.ndarray) -> np.ndarray:
    """(N, 2) the CG-offset regressors of roll and pitch (module docstring) from the body thrust per unit k_f
    ``thrust_force`` (N, 3): the roll moment of a CG offset (0, 1) and the pitch moment of (1, 0)
    (:func:`~quad_modelling.core.physics.rigid_body.cg_offset_moment`), coefficients α_x c_y and α_y c_x."""
    return np.column_stack([cg_offset_moment((0.0, 1.0), thrust_force)[:, 0], cg_offset_moment((1.0, 0.0), thrust_force)[:, 1]])


def cg_offset_estimate(design: TermDesign, fit: dict) -> dict[str, tuple[float, float]]:
    """{cg_offset_x, cg_offset_y: (value [m], sigma)} from the roll and pitch fits: c_y = γ_roll / α_x,
    c_x = γ_pitch / α_y (module docstring); NaN where the channel is not excited."""
    out = {}
    for key, channel in (("cg_offset_y", "roll"), ("cg_offset_x", "pitch")):
        i = channel_columns(design)[channel].index("cg_offset")
        alpha, gamma = fit[channel]["coef"][0], fit[channel]["coef"][i]
        ok = np.isfinite(alpha) and np.isfinite(gamma) and alpha != 0
        if not ok:
            out[key] = (float("nan"), float("nan"))
            continue
        value = gamma / alpha
        relative_alpha = np.sqrt(fit[channel]["cov"][0, 0]) / abs(alpha)
        out[key] = (float(value), float(np.hypot(np.sqrt(fit[channel]["cov"][i, i]) / abs(alpha), value * relative_alpha)))
    return {key: out[key] for key in ("cg_offset_x", "cg_offset_y")}


def imbalance_separated(design: TermDesign, fit: dict, gains: tuple[np.ndarray, np.ndarray], arm_length: float) -> bool:
    r"""Whether the flights separate the CG offset from the gains' roll and pitch patterns (module docstring): every
    gain and both offsets finite and inside their bounds (:data:`TERM_BOUNDS`). On an X frame the two are collinear
    but for the speed map's offset :math:`\Omega_{off}` (the gain's column :math:`2\Omega(\Omega - \Omega_{off})`,
    the offset's :math:`\Omega^2`); where the flights do not part them the Gauss-Newton passes run both to their
    bounds (the bundled NanoBench flight with motor 1's command divided by 1.25: gains 2 / 0.5 / 0.5 / 2, offsets
    ±11.5 mm), and :func:`~quad_modelling.core.identification.physics_fit.identify_physics` refits with the offset
    held at 0 (:attr:`TermDesign.cg_offset`)."""
    values = [("gain_%d" % (i + 1), g) for i, g in enumerate(gains[0])]
    values += [(key, value) for key, (value, _) in cg_offset_estimate(design, fit).items()]
    for key, value in values:
        low, high = TERM_BOUNDS[("motor_imbalance", key)]
        power = ARM_POWERS.get(("motor_imbalance", key), 0)
        if not (np.isfinite(value) and low * arm_length**power < value < high * arm_length**power):
            return False
    return True


def updated_gains(design: TermDesign, fit: dict, positions: np.ndarray, spins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gains (4,), sigma (4,)): :math:`\\hat g + \\sum_c e_c P_c` renormalised to mean 1, :math:`e_c = \\gamma_c / \\alpha_c`
    from the channel fits ``fit`` (module docstring); a channel the flights do not excite adds nothing (sigma NaN), a
    pattern held (:attr:`TermDesign.imbalance_axes`) nothing (sigma 0)."""
    patterns = imbalance_patterns(positions, spins)
    columns = channel_columns(design)
    step, variance = np.zeros(3), np.zeros(3)
    for c, channel in enumerate(("roll", "pitch", "yaw")):
        if "imbalance" not in columns[channel]:
            continue  # held: no step
        i = columns[channel].index("imbalance")
        alpha, gamma = fit[channel]["coef"][0], fit[channel]["coef"][i]
        if np.isfinite(alpha) and np.isfinite(gamma) and alpha != 0:
            step[c] = gamma / alpha
            variance[c] = fit[channel]["cov"][i, i] / alpha**2
        else:
            variance[c] = np.nan
    gains = np.asarray(design.motor_gains) + step @ patterns
    scale = gains.mean()
    return gains / scale, np.sqrt(variance @ patterns**2) / scale


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


def term_estimates(design: TermDesign, fit: dict, thrust: tuple[float, float], arm_length: float,
                   gains: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, dict]:
    """Per fitted term and parameter: value, sigma, bounds, at_bound, identifiable (from the channel fits ``fit``
    of :func:`~quad_modelling.core.identification.normal_equations.solve_channels`; ``thrust`` = (k_f, its sigma);
    ``gains`` the motor gains and their sigmas, :func:`updated_gains`)."""
    kf, kf_sd = thrust
    columns = channel_columns(design)
    out: dict[str, dict] = {}
    for name in design.names:
        if name in ("ground_effect", "battery"):
            i = columns["velocity"].index(name)
            theta, theta_sd = fit["velocity"]["coef"][i], np.sqrt(fit["velocity"]["cov"][i, i])
            value = theta / kf
            sd = abs(value) * np.hypot(theta_sd / theta, kf_sd / kf) if theta != 0 else theta_sd / kf
            key = "coefficient" if name == "ground_effect" else "kappa"
            fixed = ("offset", design.ground_offset) if name == "ground_effect" else ("reference_voltage", design.reference_voltage)
            out[name] = {key: _bounded(name, key, value, sd, arm_length),
                         fixed[0]: {**_bounded(name, fixed[0], fixed[1], np.nan, arm_length), "held": FIXED_HELD[name]}}
        elif name == "gyroscopic":  # body scale from roll, pitch and yaw; rotor scale from roll and pitch
            def estimate(channel: str, column: str) -> tuple[float, float]:
                i = columns[channel].index(column)
                return fit[channel]["coef"][i], fit[channel]["cov"][i, i]

            body = _combined([estimate(c, "gyro_body") for c in ("roll", "pitch", "yaw")])
            rotor = _combined([estimate(c, "gyro_rotor") for c in ("roll", "pitch")])
            out[name] = {"body_scale": _bounded(name, "body_scale", *body, arm_length),
                         "rotor_scale": _bounded(name, "rotor_scale", *rotor, arm_length)}
        elif name == "motor_imbalance" and gains is not None:
            out[name] = {f"gain_{i + 1}": _bounded(name, f"gain_{i + 1}", float(g), float(sd), arm_length)
                         for i, (g, sd) in enumerate(zip(*gains))}
            if design.cg_offset:
                out[name].update({key: _bounded(name, key, *estimate, arm_length) for key, estimate in cg_offset_estimate(design, fit).items()})
            else:  # held at 0 (imbalance_separated): reported as such, not as identified
                out[name].update({key: {**_bounded(name, key, 0.0, float("nan"), arm_length), "held": CG_HELD}
                                  for key in ("cg_offset_x", "cg_offset_y")})
    return out


CG_HELD = "held at 0: the flights do not separate the CG offset from the motor gains (motor_imbalance)"
"""Why a fit holds the CG offset at 0 (:func:`imbalance_separated`)."""

FIXED_HELD = {"ground_effect": "the best of a grid, not fitted",
              "battery": "the flights' mean voltage, not fitted; k_f and k_m are the rotors' at this voltage"}
"""Why the ground effect's offset and the battery's reference voltage carry no sigma (reported as held, not as poorly
determined: no amount of excitation would give them one). With the battery term on, the rotor speed map answers
f = 1 + kappa (V - V_ref), so the thrust and torque constants fitted are those at V_ref, not at another pack voltage (a
simulated Crazyflie whose ESC reference is 3.8 V, flown at 3.71 V on average: k_f (3.71 / 3.8)^2 = 0.953 of the
simulator's, review of session 34)."""


def _combined(estimates: list[tuple[float, float]]) -> tuple[float, float]:
    """Inverse-variance mean and its sigma of (value, variance) estimates; NaN when none is finite."""
    finite = [(v, var) for v, var in estimates if np.isfinite(v) and np.isfinite(var) and var > 0]
    if not finite:
        return float("nan"), float("nan")
    w = np.array([1.0 / var for _, var in finite])
    return float(np.sum(w * np.array([v for v, _ in finite])) / w.sum()), float(1.0 / np.sqrt(w.sum()))


def _bounded(name: str, key: str, value: float, sigma: float, arm_length: float) -> dict:
    low, high = TERM_BOUNDS[(name, key)]
    power = ARM_POWERS.get((name, key), 0)
    low, high = low * arm_length**power, high * arm_length**power
    unit = {p.name: p.unit for p in TERMS[name]}[key]
    if not np.isfinite(value):
        return {"value": float("nan"), "sigma": float("nan"), "unit": unit, "bounds": [low, high], "at_bound": False, "identifiable": False}
    return {"value": float(np.clip(value, low, high)), "sigma": float(sigma), "unit": unit, "bounds": [float(low), float(high)],
            "at_bound": bool(value <= low or value >= high), "identifiable": True}


def effects_section(estimates: dict[str, dict], source: str) -> dict:
    """The vehicle file's ``effects`` entries of the fitted terms: switched on when every parameter was identified,
    otherwise written off with status 'not identified' and the reason in the source."""
    section = {}
    for name, parameters in estimates.items():  # a vanished term (VANISHED_HELD) is no term: written off
        on = all(p["identifiable"] and p.get("held") != VANISHED_HELD for p in parameters.values())
        entry: dict = {"enabled": on}
        for key, p in parameters.items():
            status = "identified" if p["identifiable"] else "not identified"
            note = "" if p["identifiable"] else "; the flights do not excite it"
            if p.get("held"):
                note += f"; {p['held']}"
            if p["at_bound"]:
                note += f"; AT BOUND {p['bounds']} {p['unit']}"
            value = p["value"] if p["identifiable"] else float(np.mean(p["bounds"]))
            entry[key] = {"value": value, "sigma": p["sigma"], "unit": p["unit"], "bounds": p["bounds"],
                          "source": source + note, "status": status}
        section[name] = entry
    return section
