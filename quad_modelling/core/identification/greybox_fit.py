"""The identification of the linear greybox model's constants on training windows (the one fit).

Used by ``quad-modelling identify`` (:func:`quad_modelling.core.identification.identify.identify`,
which adds the voltage dependence, the motor order/spin check and the vehicle file) and by the
diagnosis as its base model (:func:`quad_modelling.core.diagnosis.diagnose.diagnose`): the same
windows give the same constants, with the same bounds and units.

Model: the linear greybox (:mod:`quad_modelling.core.models.greybox`) run open loop over each window
of a :class:`~quad_modelling.core.identification.window_batch.WindowBatch` by
:func:`~quad_modelling.core.identification.base_model.predict_batch`, motor

.. math::

    \\dot T_i = A_m T_i + K u_i, \\qquad \\tau_m = -1/A_m, \\qquad K = 2 B_m \\sqrt{a m g / 4}.

Fitted (output error on the smoothed acc_z, roll_acc, pitch_acc and yaw_acc, each normalised by
its measured RMS -- the variables the thrusts drive without integration, so open-loop drift does
not enter), as the vector :math:`z`:

* :math:`z_0 = \\ln \\tau_m` [s], :math:`\\tau_m \\in` :data:`MOTOR_TIME_CONSTANT_RANGE`;
* :math:`z_1 = \\ln(G / G_{config})`, :math:`G = K \\tau_m` the steady thrust per command
  [N per command unit] (the static gain; :math:`K` itself would trade off against :math:`\\tau_m`),
  :math:`G / G_{config} \\in` :data:`STEADY_GAIN_RATIO_RANGE`;
* :math:`z_2 = d/a` [m], the yaw drag ratio, in :data:`YAW_DRAG_RATIO_RANGE`;
* :math:`z_3` a common scale of the motor arm lengths (torque per thrust / inertia for roll and
  pitch), in :data:`ARM_SCALE_RANGE`;
* :math:`z_4 = \\ln k_R`, a scale of the rotor-reaction yaw term
  :math:`I_{prop} \\sum_i s_i \\dot\\Omega_i / I_{zz}` (Eq 3-13...3-16), i.e. of
  :math:`I_{prop} / (2 a \\Omega_0)` and :math:`I_{prop} B_m`, in :data:`ROTOR_REACTION_SCALE_RANGE`.
  These products hold :math:`a` through :math:`\\Omega_0` and :math:`B_m = K / (2\\sqrt{a m g/4})`,
  and Table 3-1's :math:`a` is not consistent with its other constants (docs/simulator.md): held at
  the configured values the term is ~8x too strong for the LinkQuad, and the fit then inflated
  :math:`\\tau_m` (to 34 ms on flights with instant rotors) to shrink :math:`K` and with it the yaw
  feedthrough :math:`I_{prop} B_m u`.

:math:`a` is held (only :math:`B_m\\sqrt a` is identifiable): :math:`A_m = -1/\\tau_m`,
:math:`B_m = K / (2\\sqrt{a m g/4})`, :math:`d = a \\cdot (d/a)`.

The search is the one fitting engine's (:func:`~quad_modelling.core.identification.least_squares.fit_least_squares`:
trust-region reflective within the bounds, z_0, z_1, z_4 as logarithms, one start per :data:`GAIN_STARTS`).
Uncertainties (1 sigma) from the Jacobian at the optimum: the engine's HAC (Newey-West) sandwich
:math:`\\mathrm{cov}(z) = (J^T J)^{-1} S (J^T J)^{-1}` with windows as blocks
(:mod:`~quad_modelling.core.identification.uncertainty`), because the residuals are autocorrelated
(smoothed, 100 Hz, every 4th sample used): the textbook :math:`s^2 (J^T J)^{-1}` treated each kept
sample as independent and was optimistic. Propagated to the constants
(:math:`\\sigma_{A_m} = |A_m| \\sigma_{z_0}`, :math:`\\sigma_{\\ln K}^2 = \\mathrm{var}(z_1 - z_0)`,
:math:`\\sigma_d = a\\, \\sigma_{z_2}`, :math:`\\sigma_{k_R} = k_R \\sigma_{z_4}`). Every fitted
parameter that ends on its search bound (within the engine's
:data:`~quad_modelling.core.identification.least_squares.AT_BOUND_FRACTION` of its range in z) is flagged
(``fit['at_bound']``); its sigma is then the
unconstrained curvature's and the value is the bound's, not the data's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from quad_modelling.core.identification.base_model import BaseModel, predict_batch
from quad_modelling.core.identification.constants_report import ConstantEstimate
from quad_modelling.core.identification.least_squares import LeastSquaresFit, Parameter, fit_least_squares
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.models.greybox import GreyboxParameters
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import DataError

MIN_MOTOR_TIME_CONSTANT = 0.002
"""Lower bound of the motor time constant [s] (a fifth of a 100 Hz sample). The discrete model's thrust
state already answers a command one sample late; rotors that follow their command within a sample (the
effects-off simulator: instant rotors, IMU averaged over the sample before the log time) drove a 10 ms
bound to its limit, and the base then carried ~10 ms of lag that an input delay would have to explain."""

MAX_MOTOR_TIME_CONSTANT = 2.0
"""Upper bound of the motor time constant [s] (A_m >= -0.5 1/s): a motor slower than 2 s is not a
small-quadrotor motor (the LinkQuad's Table 3-1 pole gives 105 ms, the Crazyflie's configured 50 ms),
and within a 5-10 s window it could not be told apart from a drift of the trim."""

MOTOR_TIME_CONSTANT_RANGE = (MIN_MOTOR_TIME_CONSTANT, MAX_MOTOR_TIME_CONSTANT)
"""Search range of tau_m = -1/A_m [s]; a fit that ends on a bound says so (``fit['at_bound']['motor_time_constant']``)."""

MOTOR_POLE_RANGE = (1.0 / MAX_MOTOR_TIME_CONSTANT, 1.0 / MIN_MOTOR_TIME_CONSTANT)
"""The same search range as -A_m = 1/tau_m [1/s], as the vehicle files state A_m (reported in ``fit['motor_pole_range_per_s']``)."""

STEADY_GAIN_RATIO_RANGE = (0.05, 20.0)
"""Search range of the steady thrust per command G = K tau_m relative to the configured one [1]: the
configured constants are a starting guess that can be off by an order of magnitude (Table 3-1's units of
u are unstated), not by more."""

YAW_DRAG_RATIO_RANGE = (1.0e-4, 1.0)
"""Search range of d/a [m] (drag torque per thrust): physical values are a few mm to cm (LinkQuad
2.93e-9 / 1.59e-7 = 18 mm); 1 m is far beyond any propeller, 0.1 mm far below. Positive: the drag torque opposes
each rotor's spin, whose direction the vehicle file gives (a wrong one is the motor check's finding, not a negative
d). It was (-1, 1) until session 26: a flight with little yaw excitation (5 of the 18 NanoBench flights alone) then
fitted a negative d, which the vehicle file's range refused when the identified file was written."""

ARM_SCALE_RANGE = (0.3, 3.0)
"""Search range of the common scale of the motor arm lengths [1]: the configured geometry is measured, so
a factor of 3 either way only absorbs inertia and torque-map errors."""

ROTOR_REACTION_SCALE_RANGE = (1e-3, 1e3)
"""Search range of k_R [1], the scale of the rotor-reaction yaw term: Table 3-1's inconsistent a makes the
configured term ~8x off (module docstring), so three decades either way."""

ROTOR_REACTION_FLOOR = 0.01
"""Fraction of the measured yaw acceleration RMS below which the configured rotor-reaction term
:math:`I_{prop} \\sum_i s_i \\dot\\Omega_i / I_{zz}` (k_R = 1) is negligible and k_R is held at 1
(``fit['held']``). On the bundled Crazyflie bag (I_prop 3.4e-11 kg m², a guess) the term is 0.07 % of the
yaw acceleration (1.7e-4 of 0.26 rad/s² RMS, training span 10-25 s): the cost was flat in k_R, and the fit
ended on the lower bound 1e-3 with sigma 1.7e3, a bound's value, not the data's. The LinkQuad's term
(Table 3-1, ~8x too strong, module docstring) stays free."""

FITTED_VARIABLES = ("acc_z", "roll_acc", "pitch_acc", "yaw_acc")
"""The variables the fit compares (driven by the thrusts without integration)."""

EXCITATION_FLOOR = 1e-6
"""RMS [m/s², rad/s²] of a smoothed trimmed measured variable below which the windows do not excite it and
it is left out of the fit, with the constants only it shows (:data:`PARAMETER_VARIABLES`) held at their
starting values. Any real sensor's noise is orders above (an accelerometer's ~1e-3 m/s², the gyro
derivative's ~1e-2 rad/s²); below it is floating-point residue, as roll/pitch/yaw acceleration (~1e-16) on
collective-only flights of the linear model, which normalised by their RMS became unit noise and stalled
the fit at A_m = -20.4 1/s (truth -25)."""

FITTED_NAMES = ("motor_time_constant", "steady_gain_ratio", "yaw_drag_ratio", "arm_scale", "rotor_reaction_scale")
"""The fitted parameters (tau_m [s], G / G_config, d/a [m], arm scale, k_R), searched as z_0...z_4 (module docstring)."""

PARAMETER_VARIABLES = ((), (), ("yaw_acc",), ("roll_acc", "pitch_acc"), ("yaw_acc",))
"""Which fitted variables show z_2...z_4 (z_0, z_1, the motor, show in all): a parameter none of the excited
variables shows is held."""

RESIDUAL_STRIDE = 4
"""Every 4th sample of the smoothed residual is used (neighbours carry little new information at 100 Hz
after a 3-5 Hz low-pass; a quarter of the cost)."""

MAX_EVALUATIONS = 80
"""Model evaluations per start of the least-squares search (each one predicts every window)."""

GAIN_STARTS = (1.0, 3.0, 1.0 / 3.0)
"""Starts of the steady gain ratio G / G_config, one search each (the lowest cost wins): the configured gain can be
off by a lot."""


@dataclass
class BaseFit:
    """The identified linear model (the diagnosis base) and how it was obtained.

    ``values``: motor_a_m [1/s], motor_b_m, torque_constant d [N m s²], thrust_gain_K [N/s per command unit],
    arm_scale [1], rotor_reaction_scale [1], prop_inertia [kg m²], reference_voltage [V] (None without
    voltage); ``sigma``: 1-sigma of motor_a_m, motor_b_m, torque_constant, thrust_gain_K, arm_scale,
    rotor_reaction_scale (empty when not identified); ``fit``: cost, residual count, the held parameters and which
    ended on a search bound (:data:`FITTED_NAMES`).
    """

    model: BaseModel
    values: dict[str, float]
    identified: bool
    note: str
    sigma: dict[str, float] = field(default_factory=dict)
    fit: dict = field(default_factory=dict)


def fitted_parameters(p: GreyboxParameters, tau_m: float, gain: float, yaw_ratio: float, arm_scale: float,
                      rotor_reaction_scale: float = 1.0) -> GreyboxParameters:
    """``p`` with A_m = -1/tau_m, B_m from K = ``gain``, d = a (d/a), arms scaled, I_prop scaled by k_R."""
    return replace(
        p,
        motor_a_m=-1.0 / tau_m,
        motor_b_m=gain / p.thrust_slope,
        torque_constant=yaw_ratio * p.thrust_constant,
        motor_positions=tuple((arm_scale * x, arm_scale * y) for x, y in p.motor_positions),
        prop_inertia=rotor_reaction_scale * p.prop_inertia,
    )


def identify_base(batch: WindowBatch, vehicle: VehicleConfig, motor_time_constant: float | None = None) -> BaseFit:
    """Fit the linear model's identifiable constants on the windows of ``batch`` (module docstring) with the one
    fitting engine (:func:`~quad_modelling.core.identification.least_squares.fit_least_squares`).

    ``motor_time_constant``: hold :math:`\\tau_m` at this value [s] (inside :data:`MOTOR_TIME_CONSTANT_RANGE`)
    and fit the rest; None fits it. The diagnosis holds it at :data:`MIN_MOTOR_TIME_CONSTANT` when it assesses
    the effects that own the motor's dynamics (motor lag, input delay): a base that refits :math:`\\tau_m` on
    the same effect-on flights soaks them up (a simulated 105 ms motor lag became a 95 ms base constant and
    the lag was then named input delay). Held at the vehicle file's value instead, the LinkQuad base carried
    Table 3-1's 105 ms pole -- the simulator's whole motor lag -- and neither lag nor delay was found
    on flights with them on (seed 31337).
    """
    if motor_time_constant is not None and not MIN_MOTOR_TIME_CONSTANT <= motor_time_constant <= MAX_MOTOR_TIME_CONSTANT:
        raise ValueError(f"motor_time_constant {motor_time_constant:g} s outside {MOTOR_TIME_CONSTANT_RANGE} s")
    hold_motor_time_constant = motor_time_constant is not None
    p0 = GreyboxParameters.from_vehicle(vehicle)
    v_ref = float(batch.vbat.mean()) if batch.vbat is not None else None
    rows = slice(batch.warm, None, RESIDUAL_STRIDE)
    every = np.array([INDEX[v] for v in FITTED_VARIABLES])
    rms = np.sqrt(np.mean(batch.measured[:, rows][:, :, every] ** 2, axis=(0, 1)))
    excited = [v for v, r in zip(FITTED_VARIABLES, rms) if r >= EXCITATION_FLOOR]
    if "acc_z" not in excited:
        raise DataError(f"the training windows do not excite acc_z (RMS {rms[0]:.2g} m/s² < {EXCITATION_FLOOR:g}): "
                        f"no thrust change to identify the motor from")
    cols = np.array([INDEX[v] for v in excited])
    target = batch.measured[:, rows][:, :, cols]
    scale = rms[[FITTED_VARIABLES.index(v) for v in excited]]
    held = [name for name, shown in zip(FITTED_NAMES, PARAMETER_VARIABLES) if shown and not any(v in excited for v in shown)]
    if hold_motor_time_constant:
        held.append("motor_time_constant")
    if "rotor_reaction_scale" not in held and _rotor_reaction_negligible(p0, batch, rms[FITTED_VARIABLES.index("yaw_acc")]):
        held.append("rotor_reaction_scale")  # k_R held at 1: the data cannot tell the configured term from none (ROTOR_REACTION_FLOOR)
    tau_config = -1.0 / p0.motor_a_m
    steady_config = p0.input_gain * tau_config
    tau0 = motor_time_constant if hold_motor_time_constant else min(max(tau_config, 1.1 * MIN_MOTOR_TIME_CONSTANT), 0.95 * MAX_MOTOR_TIME_CONSTANT)
    searched = _searched_parameters(tau0, p0.torque_constant / p0.thrust_constant)

    def parameters(values: np.ndarray) -> GreyboxParameters:
        tau, ratio, yaw_ratio, arm_scale, reaction_scale = values
        return fitted_parameters(p0, tau, steady_config * ratio / tau, yaw_ratio, arm_scale, reaction_scale)

    def residuals(values: np.ndarray) -> np.ndarray:
        pred = predict_batch(BaseModel(parameters(values)), batch, columns=cols)
        return (target - pred[:, rows][:, :, cols]) / scale

    fit = fit_least_squares(residuals, searched, held=held, starts=[{"steady_gain_ratio": ratio} for ratio in GAIN_STARTS[1:]],
                            sample_period_s=batch.dt * RESIDUAL_STRIDE, max_evaluations=MAX_EVALUATIONS)
    p = parameters(fit.values)
    values = {"motor_a_m": float(p.motor_a_m), "motor_b_m": float(p.motor_b_m), "torque_constant": float(p.torque_constant),
              "thrust_gain_K": float(p.input_gain), "arm_scale": fit.value("arm_scale"),
              "rotor_reaction_scale": fit.value("rotor_reaction_scale"), "prop_inertia": float(p.prop_inertia), "reference_voltage": v_ref}
    note = f"tau_m held at {motor_time_constant * 1e3:g} ms; " if hold_motor_time_constant else "tau_m, "
    return BaseFit(BaseModel(p, v_ref), values, True,
                   "identified on the training windows (acc_z, roll/pitch/yaw acceleration): " + note
                   + "steady gain, d/a, arm scale, rotor-reaction scale",
                   sigma=_sigma(fit, p), fit={
                       "cost": fit.cost, "residuals": int(fit.residuals.size), "motor_time_constant_s": fit.value("motor_time_constant"),
                       "motor_time_constant_range_s": list(MOTOR_TIME_CONSTANT_RANGE),
                       "motor_pole_range_per_s": list(MOTOR_POLE_RANGE),
                       "fitted_on": ", ".join(excited) + " jointly (output error, open loop over each window)",
                       "not_excited": {v: float(r) for v, r in zip(FITTED_VARIABLES, rms) if v not in excited},
                       "held": [name for name in FITTED_NAMES if name in held],
                       "at_bound": {name: fit.at_bound(name) is not None for name in FITTED_NAMES},
                   })


def _searched_parameters(motor_time_constant: float, yaw_drag_ratio: float) -> tuple[Parameter, ...]:
    """z_0...z_4 of the module docstring as the engine's parameters (starts: ``motor_time_constant`` [s], the
    configured gain, ``yaw_drag_ratio`` [m], the configured arms and rotor reaction)."""
    return (
        Parameter("motor_time_constant", motor_time_constant, *MOTOR_TIME_CONSTANT_RANGE, transform="log"),
        Parameter("steady_gain_ratio", GAIN_STARTS[0], *STEADY_GAIN_RATIO_RANGE, transform="log"),
        Parameter("yaw_drag_ratio", yaw_drag_ratio, *YAW_DRAG_RATIO_RANGE, step=0.05),
        Parameter("arm_scale", 1.0, *ARM_SCALE_RANGE, step=0.3),
        Parameter("rotor_reaction_scale", 1.0, *ROTOR_REACTION_SCALE_RANGE, transform="log"),
    )


def _rotor_reaction_negligible(p0: GreyboxParameters, batch: WindowBatch, yaw_rms: float) -> bool:
    """Whether the configured rotor-reaction term (k_R = 1) moves the predicted yaw acceleration by less than
    :data:`ROTOR_REACTION_FLOOR` of the measured one (RMS over the windows)."""
    column = INDEX["yaw_acc"]
    yaw_ratio = p0.torque_constant / p0.thrust_constant
    tau = min(max(-1.0 / p0.motor_a_m, MIN_MOTOR_TIME_CONSTANT), MAX_MOTOR_TIME_CONSTANT)
    with_term, without = (predict_batch(BaseModel(fitted_parameters(p0, tau, p0.input_gain, yaw_ratio, 1.0, k)), batch,
                                        columns=[column])[:, batch.warm :, column] for k in (1.0, 0.0))
    return float(np.sqrt(np.mean((with_term - without) ** 2))) < ROTOR_REACTION_FLOOR * yaw_rms


def _sigma(fit: LeastSquaresFit, p: GreyboxParameters) -> dict[str, float]:
    """1-sigma of the identified constants at the optimum (module docstring): the engine's HAC covariance of the
    search coordinates (ln tau_m, ln G ratio, d/a, arm scale, ln k_R), propagated to the constants; a held
    constant's is NaN."""
    cov = fit.search_covariance
    motor = cov[0, :2] if fit.moving[0] else np.zeros(2)  # a held tau_m (z_0) adds no variance to ln K
    log_gain_var = cov[1, 1] + motor[0] - 2.0 * motor[1]  # ln K = ln G_config + z_1 - z_0
    sigma_log_gain = math.sqrt(log_gain_var) if log_gain_var >= 0 else float("nan")

    def root(v: float) -> float:
        return math.sqrt(v) if v >= 0 else float("nan")

    return {"motor_a_m": float(abs(p.motor_a_m) * root(cov[0, 0])),
            "motor_b_m": float(p.motor_b_m * sigma_log_gain),
            "thrust_gain_K": float(p.input_gain * sigma_log_gain),
            "torque_constant": float(p.thrust_constant * root(cov[2, 2])),
            "arm_scale": fit.sigma_of("arm_scale"),
            "rotor_reaction_scale": fit.sigma_of("rotor_reaction_scale")}


def constant_estimates(fit: BaseFit, vehicle: VehicleConfig) -> list[ConstantEstimate]:
    """The fit's constants with units, sigma, search bounds (in each constant's unit), at-bound flags and the
    vehicle file's values (:mod:`~quad_modelling.core.identification.constants_report`)."""
    p0 = GreyboxParameters.from_vehicle(vehicle)
    v, s, flags = fit.values, fit.sigma, fit.fit.get("at_bound", {})
    root = p0.thrust_slope  # ∂T/∂Ω at hover = 2 sqrt(a m g / 4): K = B_m root
    steady = p0.input_gain * (-1.0 / p0.motor_a_m)  # G_config = K tau_m [N per command unit]
    k_range = (steady * STEADY_GAIN_RATIO_RANGE[0] / MAX_MOTOR_TIME_CONSTANT, steady * STEADY_GAIN_RATIO_RANGE[1] / MIN_MOTOR_TIME_CONSTANT)
    motor_at_bound = bool(flags.get("motor_time_constant") or flags.get("steady_gain_ratio"))
    configured = vehicle.greybox_constants()  # the greybox section, or derived from the physical constants
    unit = {key: configured[key].unit for key in ("motor_a_m", "motor_b_m", "torque_constant")}
    excite = "more collective (throttle) steps"
    why = {"rotor_reaction_scale": f"its term is below {ROTOR_REACTION_FLOOR:.0%} of the yaw acceleration",
           "motor_time_constant": "the diagnosis judges motor lag and input delay against the configured value"}
    held = {name: why.get(name, "the flights do not excite it") for name in fit.fit.get("held", [])}
    return [
        ConstantEstimate("motor_a_m", v["motor_a_m"], unit["motor_a_m"], s.get("motor_a_m", math.nan),
                         (-MOTOR_POLE_RANGE[1], -MOTOR_POLE_RANGE[0]), configured["motor_a_m"].value,
                         bool(flags.get("motor_time_constant")), excite + " faster than the motor lag",
                         held.get("motor_time_constant", "")),
        ConstantEstimate("motor_b_m", v["motor_b_m"], unit["motor_b_m"], s.get("motor_b_m", math.nan),
                         (k_range[0] / root, k_range[1] / root), configured["motor_b_m"].value, motor_at_bound, excite),
        ConstantEstimate("thrust_gain_K", v["thrust_gain_K"], "N/s per command unit", s.get("thrust_gain_K", math.nan),
                         k_range, p0.input_gain, motor_at_bound, excite),
        ConstantEstimate("torque_constant", v["torque_constant"], unit["torque_constant"], s.get("torque_constant", math.nan),
                         tuple(p0.thrust_constant * b for b in YAW_DRAG_RATIO_RANGE), configured["torque_constant"].value,
                         bool(flags.get("yaw_drag_ratio")), "yaw manoeuvres", held.get("yaw_drag_ratio", "")),
        ConstantEstimate("arm_scale", v["arm_scale"], "1", s.get("arm_scale", math.nan), ARM_SCALE_RANGE, 1.0,
                         bool(flags.get("arm_scale")), "roll/pitch manoeuvres (closed loop hides the slow ones)",
                         held.get("arm_scale", "")),
        ConstantEstimate("rotor_reaction_scale", v["rotor_reaction_scale"], "1", s.get("rotor_reaction_scale", math.nan),
                         ROTOR_REACTION_SCALE_RANGE, 1.0, bool(flags.get("rotor_reaction_scale")),
                         "fast yaw command steps", held.get("rotor_reaction_scale", "")),
    ]
