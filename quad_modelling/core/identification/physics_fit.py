r"""Identification of the nonlinear physics model's constants (:mod:`quad_modelling.core.models.physics`) from flight data.

Data: the training span of each flight (``config.train`` after the take-off/landing drops, split at marked
measurement gaps), raw rows; anchors every :data:`ANCHOR_STRIDE_S` from :data:`SETTLE_S` into each segment
(the rotor filter starts from the first command's steady speed) that stay off the ground over their history and
horizon (:func:`~quad_modelling.core.preprocess.ground_contact`, the test the scores and the window drop use).

What is fitted is the model's own multi-step error, with its constant-disturbance observer, along the measured
trajectory. For a channel with state y (velocity in N, a body rate) whose model acceleration is linear in the
constants θ, :math:`\dot y = X(t) \theta + k(t) + d`, the observer-corrected prediction from anchor a over h rows,
with the history rows j..a (the :class:`~quad_modelling.core.models.physics.Observer`'s history of that channel;
without one, the bracket is 0), is

.. math::

    \hat y_{a+h} = y_a + (C_{a+h} - C_a)\theta + K_{a+h} - K_a
        + (t_{a+h} - t_a)\Big[\frac{y_a - y_j}{t_a - t_j} - \frac{(C_a - C_j)\theta + K_a - K_j}{t_a - t_j}\Big]

with :math:`C_k = \sum_{i<k} X_i \Delta t_i` (the model's integration rule), K the same for the known part k. Its
error is linear in θ, so each channel is a linear least squares over all anchors and the horizons
:data:`FIT_HORIZONS_S`, no differentiated signal needed. The rows are never stacked: each channel's normal equations
:math:`X^T X, X^T y, y^T y` (and those of the thinned rows, for the uncertainty) are summed segment by segment
(:class:`NormalEquations`), so the memory of the fit does not grow with the number of flights; SSR =
:math:`y^T y − 2θ^T X^T y + θ^T X^T X θ`. The regressors use the measured attitude and
velocity along the horizon (the equation error of the whole step, not of one row), rotor speeds
:math:`\Omega_i` from the lag filter over the delayed commands
(:func:`~quad_modelling.core.physics.rotors.rotor_speeds`), each interval's rotor terms with its mean speed
(:func:`~quad_modelling.core.physics.rotors.interval_rotor_speeds`, as the model's step), :math:`S = \sum_i \Omega_i`, :math:`v_B = R^T v_N`:

* velocity (3 axes in N, jointly): :math:`\dot v_N = R\big(-\tfrac{k_f}{m}\sum_i\Omega_i^2 e_z
  - \tfrac{d_{xy}}{m} S (v_{B,x}, v_{B,y}, 0) - \tfrac{d_z}{m} S (0, 0, v_{B,z})\big) + g e_z`, θ = (k_f, d_xy, d_z);
* roll: :math:`\dot p = \alpha_x(-\sum_i y_i \Omega_i^2) + b_x S v_{B,y} - \tfrac{I_{zz} - I_{yy}}{I_{xx}} q r`,
  θ = (α_x = k_f / I_xx, b_x = h_d d_xy / I_xx);
* pitch: :math:`\dot q = \alpha_y \sum_i x_i \Omega_i^2 - b_y S v_{B,x} - \tfrac{I_{xx} - I_{zz}}{I_{yy}} p r`,
  θ = (α_y = k_f / I_yy, b_y = h_d d_xy / I_yy), the drag arm :math:`h_d` the inverse-variance mean of
  :math:`b_x I_{xx} / d_{xy}` and :math:`b_y I_{yy} / d_{xy}`;
* yaw: :math:`\dot r = \beta \sum_i s_i \Omega_i^2 + \tfrac{I_p}{I_{zz}} \sum_i s_i \dot\Omega_i - \tfrac{I_{yy} - I_{xx}}{I_{zz}} p q`,
  θ = β = k_m / I_zz

(gyroscopic terms with the starting inertias; the known part k of velocity is gravity :math:`g e_z`, which
cancels in an observer's slope and pins :math:`k_f` to the hover without one). Identifiable without
rotor-speed measurements are :math:`k_f k_u^2`, so the speed map :math:`k_u, \Omega_{off}` is held (literature)
and :math:`k_f, k_m, d_{xy}, d_z, h_d, I_{xx} = k_f/\alpha_x, I_{yy} = k_f/\alpha_y` are fitted, :math:`I_{zz}` held.
:math:`\tau_m` and the command delay :math:`\delta` minimise :math:`J = \sum_c \mathrm{SSR}_c / \mathrm{SSR}_c^{0}`,
each channel's SSR relative to its SSR with θ = 0 (the observer alone): a coordinate search over the delays of
:func:`delay_grid` (whole sample periods; the best at the starting τ first, then neighbours while they improve),
each with a bounded scalar search of τ in :data:`TIME_CONSTANT_RANGE_S`, then δ between samples (:func:`subsample_delay`);
a later pass of the same fit (the imbalance's Gauss-Newton passes) starts at the previous pass's δ and τ
(:data:`SEARCH_NEAR_LOG`).

Uncertainty (1 sigma, from the Jacobian): the linear parameters from :math:`s^2 (X^T X)^{-1}` with anchors
thinned to one per longest horizon (overlapping horizons share their errors, so neighbouring anchors are
not independent); ratios by first-order propagation; :math:`\tau_m` from the curvature of the profile
:math:`\chi^2(\tau) = \sum_c \mathrm{SSR}_c / s_c^2` on the same thinning, :math:`\sigma_\tau^2 = 2 / \chi^{2\prime\prime}`;
δ's from the curvature of :math:`\chi^2(\delta)` over whole samples, with a delay between them the vertex's error
(one sample period / sqrt(12), alone where that profile is flat) in quadrature. A value outside its bounds (:data:`BOUNDS_FACTOR`
around the starting value; drag from 0) is clipped there and flagged ``at_bound``. A channel whose normal matrix is
singular (:data:`~quad_modelling.core.identification.normal_equations.MAX_CONDITION`; the flights do not excite it) leaves its constants at the file's values, flagged
``identifiable: false``.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.identification.physics_result import (FIT_OBSERVERS, FITTED, OBSERVERS, PhysicsFit, prediction_errors,
                                                                 training_score)
from quad_modelling.core.models.physics import Observer
from quad_modelling.core.identification.normal_equations import NormalEquations, solve_channels
from quad_modelling.core.identification.uncertainty import profile_sigma, subsample_delay
from quad_modelling.core.identification.physics_terms import (
    GROUND_OFFSETS, IMBALANCE_AXES, IMBALANCE_ITERATIONS, IMBALANCE_LEVEL_CHANNELS, VANISHED_HELD,
    VANISHING_AT_BOUND, TermDesign, cg_offset_columns, channel_columns, imbalance_columns, imbalance_separated,
    rate_columns, term_estimates, updated_gains, velocity_columns
)
from quad_modelling.core.physics.effects import BASE_SWITCHES, EffectTerm, switched_off
from quad_modelling.core.physics.rigid_body import gyroscopic_torque, rotor_momentum, rotor_wrench
from quad_modelling.core.physics.rotors import delayed_commands, effective_commands, interval_rotor_speeds, rotor_speeds
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.preprocess import ground_contact
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import EvaluationConfig, SpanSpec, span_segments
from quad_modelling.errors import DataError

FIT_HORIZONS_S = (0.1, 0.25, 0.5)
"""Horizons of the fitted multi-step error [s]: 10, 25 and 50 samples at 100 Hz, spread over the SimErr horizon."""

ANCHOR_STRIDE_S = 0.1
"""Spacing of the fit's anchors [s]; closer anchors share nearly all their horizon and add cost, not information."""

SETTLE_S = 0.3
"""First anchor after a segment start [s] beyond the observer history: the rotor filter starts from the first command's steady speed."""

TIME_CONSTANT_RANGE_S = (0.002, 0.3)
"""Bounds of the rotor time constant [s]: from a brushless ESC's few ms to a large slow rotor's 300 ms."""

TAU_LOG_TOLERANCE = 0.1
"""Tolerance of the τ search in log τ (10 %): finer than its uncertainty on real flights (sigma above 50 % of τ on the
bundled bag and the NanoBench flights). A τ this close to a bound is at it (2.13 ms: 0.065 from 2 ms)."""

SEARCH_NEAR_LOG = 0.5
"""Half-width in log τ of the τ search of a later pass of one fit (the imbalance's Gauss-Newton passes), around the
previous pass's τ: a factor 1.65 either way, 5-6 objective evaluations instead of 8 over the whole range."""

DELAY_MAX_S = 0.15
"""Largest command delay searched [s]: 15 samples at 100 Hz. The NanoBench Crazyflie's logged commands lead its
response by about 40 ms; at the earlier 60 ms limit a 20 ms delay added to those flights sat on the bound."""

BOUNDS_FACTOR = 10.0
"""k_f, k_m and the roll/pitch inertias are bounded to [start / 10, start * 10]: an order of magnitude either side
of the literature value; beyond it the data, not the constant, is wrong (e.g. a motor-order error)."""

DRAG_MAX_FACTOR = 100.0
"""The rotor drag is bounded to [0, 100 x start]; its arm to ±10 x max(|start|, arm_length / 10)."""


CHANNELS = ("velocity", "roll", "pitch", "yaw")

BATTERY_FIT_LINEAR_S = 5.0
"""History of the linear disturbance observer the constants are *fitted* with when the battery term is among the
fitted terms [s] (what the model predicts with is chosen as always). κ rests on the pack's sag over the flight,
which a 0.5 s observer takes out of the regression as a slow force. On simulated LinkQuad flights with the battery
on (development seeds 5101-5102: V 12.35 -> 11.71 V over 60 s; the simulator's rotor speed is proportional to V,
so κ = 1/V = 0.084 1/V at the mean voltage) κ came out 0.066 +- 0.029 with the 0.5 s observer (not resolved),
0.077 +- 0.015 with 2 s and 0.081 +- 0.009 with 5 s, the thrust constant within 0.2 % across the three."""

def delay_grid(sample_rate: float) -> np.ndarray:
    """Delays searched [s]: whole sample periods from 0 to :data:`DELAY_MAX_S` (then between two: :func:`subsample_delay`)."""
    return np.arange(0, int(round(DELAY_MAX_S * sample_rate)) + 1) / sample_rate


@dataclass
class _Segment:
    """One training segment's fixed data (everything but the rotor speeds, which depend on τ_m and δ)."""

    t: np.ndarray
    u: np.ndarray
    rot: np.ndarray  # (N, 3, 3) measured R_N<-B
    vel_n: np.ndarray  # (N, 3) [m/s]
    v_b: np.ndarray  # (N, 3) body velocity [m/s]
    rates: np.ndarray  # (N, 3) gyro [rad/s]
    anchors: np.ndarray  # (A,) anchor rows
    history: dict  # "linear"/"angular" -> (A,) first observer row of each anchor (= the anchor: no observer)
    horizons: np.ndarray  # (H,) horizon lengths [rows]
    height: np.ndarray  # (N,) height above the ground plane z_N = 0 [m]
    voltage: np.ndarray | None  # (N,) battery voltage [V]


def _cumulative(values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """C_k = sum_{i<k} values_i (t_{i+1} - t_i) along axis 0 (C_0 = 0): the model's rectangle rule."""
    dt = np.diff(t).reshape((-1,) + (1,) * (values.ndim - 1))
    return np.concatenate([np.zeros((1,) + values.shape[1:]), np.cumsum(values[:-1] * dt, axis=0)])


def training_segments(flights: Sequence[FlightLog], config: EvaluationConfig, observer: Observer = Observer(),
                      min_history_s: float = 0.0) -> list[_Segment]:
    """The fixed data of every training segment (module docstring); DataError when no anchor is usable."""
    span = SpanSpec.parse("train", config.train)
    history_s = max(observer.linear_s, observer.angular_s, min_history_s)  # the same anchors for every observer compared
    segments = []
    for log in flights:
        log.require(("gyro_b",), "the physics identification (it fits the body-rate predictions)")
        contact = ground_contact(log)
        for start, stop in span_segments(log, span, config):
            seg = log.slice(start, stop)
            rate = seg.sample_rate
            horizons = np.array([max(1, int(round(h * rate))) for h in FIT_HORIZONS_S])
            first = int(np.searchsorted(seg.t, seg.t[0] + SETTLE_S + history_s))
            candidates = np.arange(first, len(seg) - horizons.max(), max(1, int(round(ANCHOR_STRIDE_S * rate))))
            if not candidates.size:
                continue
            history = np.minimum(np.searchsorted(seg.t, seg.t[candidates] - history_s - 1e-9, side="left"), candidates - 1)
            histories = {name: np.minimum(np.searchsorted(seg.t, seg.t[candidates] - h - 1e-9, side="left"), candidates)
                         for name, h in (("linear", observer.linear_s), ("angular", observer.angular_s))}
            grounded = np.concatenate([[0], np.cumsum(contact[start:stop])])
            ok = grounded[candidates + horizons.max() + 1] == grounded[history]  # airborne from history to horizon
            if not ok.any():
                continue
            rot = frames.euler_ned_to_matrix(seg.euler)
            segments.append(_Segment(seg.t, seg.u, rot, seg.vel_n, np.einsum("nji,nj->ni", rot, seg.vel_n), seg.gyro_b,
                                     candidates[ok], {k: h[ok] for k, h in histories.items()}, horizons, -seg.pos_n[:, 2], seg.vbat))
    if not segments or sum(len(s.anchors) for s in segments) < 20:
        raise DataError(f"no usable training anchors for the physics identification in span {config.train} "
                        f"of the flights ({', '.join(f'{log.meta.source} {log.duration:.1f} s' for log in flights)}) after the "
                        f"drops {config.drop_start:g}/{config.drop_end:g} s, ground contact, {SETTLE_S} s settling and the "
                        f"{history_s:g} s observer history")
    return segments


def _wrench_per_unit(p: PhysicsParameters, rotor: np.ndarray, v_b: np.ndarray, height: np.ndarray | None,
                     **unit) -> tuple[np.ndarray, np.ndarray]:
    """(F_B, τ_B) (N, 3) of the one physics' rotor wrench (:func:`~quad_modelling.core.physics.rigid_body.rotor_wrench`)
    with every constant it is linear in set to 0 except ``unit`` (e.g. ``thrust_constant=1``): the regressor column of
    that constant."""
    zero = {"thrust_constant": 0.0, "torque_constant": 0.0, "drag": (0.0, 0.0, 0.0), "drag_arm": 0.0, "prop_inertia": 0.0}
    return rotor_wrench(p.with_values(**{**zero, **unit}), rotor, np.zeros_like(rotor), v_b, height)


def _rows(p: PhysicsParameters, seg: _Segment, time_constant: float, delay: float, design: TermDesign = TermDesign()) -> dict[str, tuple]:
    """Per channel (state y (N, k_y), regressors X (N, k_y, k_θ), known part (N, k_y)) of one segment: the columns are
    the one physics' wrench per unit constant (module docstring), then the fitted terms'
    (:mod:`~quad_modelling.core.identification.physics_terms`), named by
    :func:`~quad_modelling.core.identification.physics_terms.channel_columns`; the known part its gyroscopic torque.
    Terms the vehicle switches on and ``design`` does not fit act with their values."""
    q = p.with_values(time_constant=time_constant, delay=delay)
    for name in design.names:  # fitted terms: off in the known part (the imbalance at the iteration's gains, no CG offset)
        q = q.with_term(name, (*design.motor_gains, 0.0, 0.0) if name == "motor_imbalance" else None)
    if q.battery is not None and seg.voltage is None:
        raise DataError("the vehicle's battery term needs the battery voltage, and a training flight has none")
    commands = effective_commands(q, delayed_commands(q, seg.u, seg.t), seg.voltage if q.battery is not None else None)
    rotor = rotor_speeds(q, commands, seg.t)
    mean_rotor = interval_rotor_speeds(q, rotor, commands, seg.t)  # each interval's, as the model's step integrates
    m = p.mass
    inertia = np.asarray(p.inertia, dtype=float)
    thrust_force, thrust_torque = _wrench_per_unit(q, mean_rotor, seg.v_b, seg.height, thrust_constant=1.0)
    drag_xy_force, drag_xy_torque = _wrench_per_unit(q, mean_rotor, seg.v_b, None, drag=(1.0, 1.0, 0.0), drag_arm=1.0)
    drag_z_force, _ = _wrench_per_unit(q, mean_rotor, seg.v_b, None, drag=(0.0, 0.0, 1.0))
    _, yaw_torque = _wrench_per_unit(q, mean_rotor, seg.v_b, None, torque_constant=1.0)
    body = np.stack([thrust_force, drag_xy_force, drag_z_force] if design.drag else [thrust_force], axis=2) / m
    gyro = np.zeros_like(seg.rates)
    if q.gyroscopic is not None:  # the vehicle's gyroscopic torques, known (not fitted here)
        body_scale, rotor_scale = q.gyroscopic
        momentum = rotor_scale * rotor_momentum(q.prop_inertia, q.spins, mean_rotor) if rotor_scale else None
        gyro = gyroscopic_torque(seg.rates, inertia, momentum, body_scale) / inertia
    velocity = np.matmul(seg.rot, body)  # R B per row (matmul: 5x faster than einsum on (N, 3, 3) stacks)
    extra = velocity_columns(design, velocity[:, :, 0], seg.height, seg.voltage)
    if extra:
        velocity = np.concatenate([velocity, np.stack(extra, axis=2)], axis=2)
    rate_extra = rate_columns(design, q.prop_inertia, q.spins, seg.rates, mean_rotor, inertia)
    imbalance = (imbalance_columns(design, q.positions, q.spins, q.speed_offset, mean_rotor)
                 if "motor_imbalance" in design.names else None)
    cg = cg_offset_columns(thrust_force) if imbalance is not None and design.cg_offset else None
    patterns = [imbalance if name in design.imbalance_axes else None for name in ("roll", "pitch", "yaw")]
    torques = [_torque_columns(thrust_torque, drag_xy_torque if design.drag else None, rate_extra, patterns[axis], axis, cg)
               for axis in range(2)]
    # yaw's rotor reaction I_p/I_zz Σ s_i dΩ_i/dt integrates to I_p/I_zz Σ s_i (Ω(t) - Ω(t_0)): the known part below, exact
    return {
        "velocity": (seg.vel_n, velocity, np.tile([0.0, 0.0, GRAVITY], (len(seg.t), 1))),  # g e_z (cancels in an observer)
        "roll": (seg.rates[:, :1], torques[0], gyro[:, :1]),
        "pitch": (seg.rates[:, 1:2], torques[1], gyro[:, 1:2]),
        "yaw": (seg.rates[:, 2:], _torque_columns(yaw_torque, None, rate_extra, patterns[2], 2), gyro[:, 2:],
                -rotor_momentum(p.prop_inertia, p.spins, rotor)[:, 2:] / inertia[2]),  # I_p Σ s_i Ω_i / I_zz
    }


def _torque_columns(gain: np.ndarray, drag: np.ndarray | None, gyro: np.ndarray | None, imbalance: np.ndarray | None,
                    axis: int, cg: np.ndarray | None = None) -> np.ndarray:
    """(N, 1, k) regressors of the roll (``axis`` 0), pitch (1) or yaw (2) rate in the order of
    :func:`~quad_modelling.core.identification.physics_terms.channel_columns`: the thrust (yaw: torque) gain[, drag
    moment][, body and rotors' gyroscopic (yaw: the body's)][, imbalance][, CG offset (roll, pitch: ``cg`` (N, 2))]."""
    parts = [gain[:, axis]] + ([] if drag is None else [drag[:, axis]])
    if gyro is not None:
        parts += [gyro[:, axis, 0]] + ([gyro[:, axis, 1]] if axis < 2 else [])
    if imbalance is not None:
        parts.append(imbalance[:, axis])
    if cg is not None and axis < 2:
        parts.append(cg[:, axis])
    return np.stack(parts, axis=1)[:, None, :]


def _design_blocks(p: PhysicsParameters, segments: list[_Segment], time_constant: float, delay: float,
                   observer: Observer = Observer(), design: TermDesign = TermDesign()) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """The rows of the observer-corrected multi-step error (module docstring), one block at a time: (channel,
    regressors (rows, k_θ), target (rows,)) per segment, channel and horizon, in the order of the stacked design
    (segments, then channels, then horizons; within a block anchors, then state components). Only one segment's
    rows exist at a time."""
    for seg in segments:
        a = seg.anchors
        for name, entry in _rows(p, seg, time_constant, delay, design).items():
            j = seg.history["linear" if name == "velocity" else "angular"]
            if name in IMBALANCE_LEVEL_CHANNELS and "motor_imbalance" in design.names and design.cg_offset:
                j = a  # no observer: the CG offset rests on the level of the moment (IMBALANCE_LEVEL_CHANNELS)
            span = np.maximum(seg.t[a] - seg.t[j], 1e-12)[:, None]  # j = a: no observer, every slope difference is 0
            y, x, known = entry[:3]
            cx, ck = _cumulative(x, seg.t), _cumulative(known, seg.t)
            if len(entry) == 4:  # an exact integral (yaw rotor reaction), already in integrated form
                ck = ck + entry[3]
            slope_y = (y[a] - y[j]) / span
            if name != "velocity" and observer.angular_trim:
                slope_y = np.zeros_like(slope_y)
            slope_x = (cx[a] - cx[j]) / span[:, :, None]
            slope_k = (ck[a] - ck[j]) / span
            for h in seg.horizons:
                lead = (seg.t[a + h] - seg.t[a])[:, None]
                target = y[a + h] - y[a] - (ck[a + h] - ck[a]) - lead * (slope_y - slope_k)
                regressor = cx[a + h] - cx[a] - lead[:, :, None] * slope_x
                yield name, regressor.reshape(-1, regressor.shape[-1]), target.reshape(-1)


def _normal_equations(p: PhysicsParameters, segments: list[_Segment], time_constant: float, delay: float,
                      observer: Observer = Observer(), thin: int = 1, design: TermDesign = TermDesign()) -> dict[str, NormalEquations]:
    """Per channel the :class:`NormalEquations` of all segments' rows (:func:`_design_blocks`), streamed."""
    sums: dict[str, NormalEquations] = {}
    for name, x, y in _design_blocks(p, segments, time_constant, delay, observer, design):
        if name not in sums:
            sums[name] = NormalEquations.empty(x.shape[1], thin)
        sums[name].add(x, y)
    return sums


def identify_physics(flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig,
                     observer: Observer | None = None, terms: Sequence[str] = (), drag: bool | None = None,
                     dynamics: tuple[float | None, float | None, float, *tuple[float, ...]] | None = None,
                     imbalance_axes: tuple[str, ...] = IMBALANCE_AXES) -> PhysicsFit:
    """Fit the physics constants :data:`FITTED` on ``config``'s training span of ``flights`` (module docstring), with
    the optional ``terms`` (:mod:`~quad_modelling.core.identification.physics_terms`; ``imbalance_axes``: the motor
    imbalance's gain patterns fitted, :attr:`~quad_modelling.core.identification.physics_terms.TermDesign.imbalance_axes`).

    Without an ``observer``, the observer is chosen by the data among
    :data:`~quad_modelling.core.identification.physics_result.OBSERVERS`: the fit runs with each and keeps the one
    whose open-loop multi-step error on the training span is least
    (:func:`~quad_modelling.core.identification.physics_result.training_score`, the protocol the model is scored
    with; the fit's own error predicts along the *measured* attitude, and chose the linear observer on simulated
    flights where none predicted velocity 18 % better, bench/results/truth_floor.md);
    then the observer the model *predicts* with is chosen the same way with those constants (an observer fitted with
    may still be dropped for predicting).
    The default's angular trim stands for a constant moment the model lacks (a CG offset the
    controller balances) and its linear part for a force it lacks (battery sag, a mass error); where the model has
    no such gap (the simulator's flights), they throw away what it predicts right (roll rate error 0.14 -> 0.016 of
    the observer alone's, yaw 0.74 -> 0.004, on simulated LinkQuad flights with the true constants)."""
    if observer is not None:
        return _identify_with(flights, vehicle, config, observer, terms, drag, dynamics, imbalance_axes)
    fits = {name: _identify_with(flights, vehicle, config, OBSERVERS[name], terms, drag, dynamics, imbalance_axes)
            for name in FIT_OBSERVERS}
    scores = {name: training_score(f, flights, vehicle, config) for name, f in fits.items()}
    chosen = min(scores, key=scores.get)
    best = fits[chosen]
    predicting = prediction_errors(best, flights, vehicle, config, {chosen: scores[chosen]})
    predict_with = min(predicting, key=predicting.get)
    best.observer = OBSERVERS[predict_with]
    best.diagnostics["observer_choice"] = {"chosen": predict_with, "fitted_with": chosen, "errors": scores,
                                           "predicting_errors": predicting}
    return best


def _identify_with(flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig,
                   observer: Observer, terms: Sequence[str], drag: bool | None = None,
                   dynamics: tuple[float | None, float | None, float, *tuple[float, ...]] | None = None,
                   imbalance_axes: tuple[str, ...] = IMBALANCE_AXES) -> PhysicsFit:
    """:func:`_fit_once`; a term whose unconstrained estimate lies beyond the bound it vanishes at
    (:data:`VANISHING_AT_BOUND`: a negative ground-effect coefficient) is held there and every other constant fitted
    again without it. Clipping it alone left the others at the values that made up for the term's impossible sign:
    on real flights such a model was worse on its own training flights than the fit without the term (error 0.886
    against 0.803), and the diagnosis credited the term at 0 with a -12 % "shrink"."""
    fit = _fit_once(flights, vehicle, config, observer, terms, drag, dynamics, imbalance_axes)
    vanished = {name: key for name, key in VANISHING_AT_BOUND.items() if name in fit.terms
                and fit.terms[name][key]["identifiable"] and fit.terms[name][key]["value"] <= fit.terms[name][key]["bounds"][0]}
    if not vanished:
        return fit
    off = replace(vehicle, effects={**vehicle.effects, **{name: EffectTerm(name, False, {}) for name in vanished}})  # not in the
    refit = _fit_once(flights, off, config, observer, [t for t in terms if t not in vanished], drag, dynamics, imbalance_axes)  # known part
    for name, key in vanished.items():
        refit.terms[name] = {**fit.terms[name], key: {**fit.terms[name][key], "sigma": float("nan"), "held": VANISHED_HELD}}
    refit.diagnostics["vanished_terms"] = {name: f"{key} estimated beyond its bound {fit.terms[name][key]['bounds'][0]:g} "
                                                 "before it was held there" for name, key in vanished.items()}
    return refit


def _fit_once(flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig,
              observer: Observer, terms: Sequence[str], drag: bool | None = None,
              dynamics: tuple[float | None, float | None, float, *tuple[float, ...]] | None = None,
              imbalance_axes: tuple[str, ...] = IMBALANCE_AXES) -> PhysicsFit:
    """:func:`identify_physics` with one ``observer``; with motor_imbalance among the ``terms``, the whole fit is
    repeated :data:`~quad_modelling.core.identification.physics_terms.IMBALANCE_ITERATIONS` times from the gains of
    the previous pass (Gauss-Newton). A switch of :data:`~quad_modelling.core.physics.effects.BASE_SWITCHES` the
    vehicle turns off and ``terms`` does not name holds its constants at 0; ``drag`` (not None) overrides the rotor
    drag's, ``dynamics`` (τ_m, δ, σ_δ[, σ_τ]; None: searched) holds the rotor lag and delay (the sigmas those of the
    fit they were taken from). With the battery term among the
    ``terms`` the regression's linear observer history is at least :data:`BATTERY_FIT_LINEAR_S` (the fit keeps
    ``observer``; its diagnostics name the regression's)."""
    began = time.perf_counter()
    p = PhysicsParameters.from_vehicle(vehicle)
    predicting_observer = observer  # the fit's; the regression's is longer with the battery term
    if "battery" in terms and observer.linear_s > 0:
        observer = replace(observer, linear_s=max(observer.linear_s, BATTERY_FIT_LINEAR_S))
    unmeasured = next((log for log in flights if "battery" in terms and log.vbat is None), None)
    if unmeasured is not None:  # named here: a segment does not know its flight
        why = unmeasured.meta.notes.get("battery")
        raise DataError(f"{unmeasured.meta.source}: identify --effects battery needs the battery voltage, and this flight "
                        f"has none{f' ({why})' if why else ''}")
    segments = training_segments(flights, config, observer, min_history_s=max(o.linear_s for o in OBSERVERS.values()))
    rate = float(np.median([1.0 / np.median(np.diff(s.t)) for s in segments]))
    off = [name for name in BASE_SWITCHES if switched_off(vehicle.effects, name) and name not in terms]
    drag = "rotor_drag" not in off if drag is None else drag
    tau_held, delay_held, delay_held_sd = dynamics[:3] if dynamics is not None else (None, None, float("nan"))
    tau_held_sd = dynamics[3] if dynamics is not None and len(dynamics) > 3 and "motor_lag" not in off else float("nan")
    tau_held = 0.0 if "motor_lag" in off else tau_held
    delay_held, delay_held_sd = (0.0, float("nan")) if "input_delay" in off else (delay_held, delay_held_sd)
    held = {key: f"held at 0: effects.{name} is switched off in the vehicle file" for name in off
            for key in BASE_SWITCHES[name] if name != "rotor_drag" or not drag}
    dynamics = None if tau_held is None and delay_held is None else (tau_held, delay_held, delay_held_sd)
    switches = {name: (drag if name == "rotor_drag" else name not in off) for name in BASE_SWITCHES
                if name in terms or name in vehicle.effects}
    design = replace(_term_design(tuple(t for t in terms if t not in BASE_SWITCHES), segments, vehicle), drag=drag,
                     imbalance_axes=imbalance_axes)
    imbalance = "motor_imbalance" in design.names
    start = design
    near = None  # the previous pass's (τ, δ): the next pass's search starts there (SEARCH_NEAR_LOG)
    levels = (True, False) if "roll" in imbalance_axes else (False,)  # the CG offset held at 0 without roll and pitch
    for cg_offset in (levels if imbalance else (True,)):  # ... and where the flights do not separate it
        design = replace(start, cg_offset=cg_offset)
        for _ in range(IMBALANCE_ITERATIONS if imbalance else 1):
            tau, delay, delay_sd, profile, design, fit, thin = _search_dynamics(p, segments, observer, design, rate, vehicle,
                                                                                dynamics, near)
            near = (tau, delay)
            gains = updated_gains(design, fit, p.positions, p.spins) if imbalance else None
            if gains is not None:
                design = replace(design, motor_gains=tuple(float(g) for g in gains[0]))
        if not imbalance or not cg_offset or imbalance_separated(design, fit, gains, vehicle.value("arm_length")):
            break
    columns = channel_columns(design)

    def coef(channel: str, name: str) -> tuple[float, float]:
        if name not in columns[channel]:
            return 0.0, float("nan")  # held at 0 (rotor drag off)
        i = columns[channel].index(name)
        return float(fit[channel]["coef"][i]), float(np.sqrt(fit[channel]["cov"][i, i]))

    kf, kf_sd = coef("velocity", "thrust")
    (d_xy, d_xy_sd), (d_z, d_z_sd) = coef("velocity", "drag_xy"), coef("velocity", "drag_z")
    values = {"rotor_time_constant": tau, "rotor_delay": delay, "rotor_thrust_constant": kf, "rotor_drag_xy": d_xy, "rotor_drag_z": d_z}
    sigma = {"rotor_thrust_constant": kf_sd, "rotor_drag_xy": d_xy_sd, "rotor_drag_z": d_z_sd}
    arms = []
    for key, channel in (("effective_ixx", "roll"), ("effective_iyy", "pitch")):
        (alpha, alpha_sd), (b, b_sd) = coef(channel, "thrust"), coef(channel, "drag_moment")
        values[key] = kf / alpha if alpha != 0 else float("nan")
        sigma[key] = abs(values[key]) * np.hypot(kf_sd / kf, alpha_sd / alpha) if alpha != 0 and kf != 0 else float("nan")
        arm = b * values[key] / d_xy if d_xy != 0 and np.isfinite(values[key]) else float("nan")
        arm_sd = abs(arm) * np.sqrt((b_sd / b) ** 2 + (sigma[key] / values[key]) ** 2 + (d_xy_sd / d_xy) ** 2) if np.isfinite(arm) and b != 0 else float("nan")
        arms.append((arm, arm_sd))
    finite = [(a, sd) for a, sd in arms if np.isfinite(a) and np.isfinite(sd) and sd > 0]
    if finite:
        weights = np.array([1.0 / sd**2 for _, sd in finite])
        values["rotor_drag_arm"] = float(np.sum(weights * np.array([a for a, _ in finite])) / weights.sum())
        sigma["rotor_drag_arm"] = float(1.0 / np.sqrt(weights.sum()))
    elif not drag:
        values["rotor_drag_arm"], sigma["rotor_drag_arm"] = 0.0, float("nan")
    else:
        values["rotor_drag_arm"], sigma["rotor_drag_arm"] = float("nan"), float("nan")
    torque, torque_sd = coef("yaw", "torque")
    values["rotor_torque_constant"], sigma["rotor_torque_constant"] = torque * p.inertia[2], torque_sd * p.inertia[2]
    sigma["rotor_time_constant"] = tau_held_sd if tau_held is not None else profile_sigma(
        lambda value: _chi2(p, segments, value, delay, observer, thin, fit, design), tau, 0.05 * tau)
    sigma["rotor_delay"] = delay_sd

    start = {key: float(vehicle.effective_value(key)) for key in FITTED}
    bounds = {key: (start[key] / BOUNDS_FACTOR, start[key] * BOUNDS_FACTOR) for key in FITTED}
    bounds["rotor_time_constant"] = TIME_CONSTANT_RANGE_S
    bounds["rotor_delay"] = (0.0, DELAY_MAX_S)
    for key in ("rotor_drag_xy", "rotor_drag_z"):
        bounds[key] = (0.0, DRAG_MAX_FACTOR * start[key] if start[key] > 0 else np.inf)
    reach = BOUNDS_FACTOR * max(abs(start["rotor_drag_arm"]), 0.1 * vehicle.value("arm_length"))
    bounds["rotor_drag_arm"] = (-reach, reach)
    if not any(np.isfinite(fit[c]["coef"]).any() for c in CHANNELS):  # nothing excited: the lag and delay neither
        values["rotor_time_constant"] = values["rotor_delay"] = float("nan")
    at_bound, identifiable = {}, {}
    for key in FITTED:
        low, high = bounds[key]
        value = values[key]
        identifiable[key] = bool(np.isfinite(value))
        if key in held:
            values[key], sigma[key], at_bound[key] = 0.0, float("nan"), False
            continue
        if not identifiable[key]:
            values[key], sigma[key], at_bound[key] = start[key], float("nan"), False
            continue
        if key == "rotor_time_constant":
            at_bound[key] = bool(min(abs(np.log(value / low)), abs(np.log(value / high))) < TAU_LOG_TOLERANCE)
        elif key == "rotor_delay":  # 0: the grid's first delay was the best (no vertex below it); near 150 ms: on it
            at_bound[key] = bool(value <= low or value >= high - 0.5 / rate)
        elif not drag and key.startswith("rotor_drag"):
            at_bound[key] = False  # held at 0: rotor drag off
        else:
            at_bound[key] = bool(value <= low or value >= high)
            values[key] = float(np.clip(value, low, high))
        values[key] = float(values[key])
        sigma[key] = float(sigma[key])
    diagnostics = {
        "anchors": int(sum(len(s.anchors) for s in segments)), "segments": len(segments),
        "error_ratio": {c: fit[c]["ssr"] / fit[c]["ssr0"] if fit[c]["ssr0"] > 0 else float("nan") for c in CHANNELS},
        "ssr": {c: fit[c]["ssr"] for c in CHANNELS}, "ssr0": {c: fit[c]["ssr0"] for c in CHANNELS},
        "horizons_s": list(FIT_HORIZONS_S), "observer": {"linear_s": observer.linear_s, "angular_s": observer.angular_s, "angular_trim": observer.angular_trim}, "anchor_thinning": thin,
        "delay_profile": [{"delay_s": d, "time_constant_s": t, "objective": f} for f, t, d in profile],
        "held": {"rotor_speed_gain": p.speed_gain, "rotor_speed_offset": p.speed_offset, "izz": p.inertia[2]},
        "rotor_drag": "fitted" if drag else "held at 0 (off)", "sample_rate_hz": rate,
        "seconds": time.perf_counter() - began,
    }
    terms_fitted = term_estimates(design, fit, (values["rotor_thrust_constant"], sigma["rotor_thrust_constant"]),
                                  vehicle.value("arm_length"), gains)
    return PhysicsFit(values, sigma, bounds, at_bound, start, diagnostics, identifiable, terms_fitted, predicting_observer, held, switches)


def _search_dynamics(p: PhysicsParameters, segments: list[_Segment], observer: Observer, design: TermDesign, rate: float,
                     vehicle: VehicleConfig, held: tuple[float | None, float | None, float] | None = None,
                     near: tuple[float, float] | None = None) -> tuple:
    """τ_m and δ of least :math:`J` (module docstring): a coordinate search over whole-sample delays (the best of
    every other delay at the starting τ first, then neighbours while they improve, each with τ's bounded search),
    then δ between samples (:func:`subsample_delay`); h_off of ground effect on its grid. ``held`` (τ, δ, σ_δ): those
    not None are not searched. ``near`` (τ, δ) of a previous pass of the same fit: the walk starts at δ's sample and
    τ's search within :data:`SEARCH_NEAR_LOG` of it (all of its range when it ends at that window's edge). Returns
    (τ, δ, σ_δ, profile, design, channel fits, thinning)."""

    def objective(tau: float, delay: float) -> float:
        fit = solve_channels(_normal_equations(p, segments, tau, delay, observer, 1, design))
        return sum(fit[c]["ssr"] / fit[c]["ssr0"] for c in CHANNELS if fit[c]["ssr0"] > 0)

    lo, hi = TIME_CONSTANT_RANGE_S
    tau_held, delay_held, delay_held_sd = held if held is not None else (None, None, float("nan"))
    grid = delay_grid(rate) if delay_held is None else np.array([delay_held])
    start_tau = float(np.clip(p.time_constant, lo, hi)) if tau_held is None else tau_held
    searched: dict[int, tuple[float, float]] = {}

    def tau_at(delay: float) -> tuple[float, float]:
        if tau_held is not None:
            return objective(tau_held, delay), tau_held
        window = (np.log(lo), np.log(hi)) if near is None else (max(np.log(lo), np.log(near[0]) - SEARCH_NEAR_LOG),
                                                                 min(np.log(hi), np.log(near[0]) + SEARCH_NEAR_LOG))
        while True:
            search = optimize.minimize_scalar(lambda log_tau: objective(float(np.exp(log_tau)), delay), bounds=window,
                                              method="bounded", options={"xatol": TAU_LOG_TOLERANCE})
            edge = min(search.x - window[0] if window[0] > np.log(lo) else np.inf,
                       window[1] - search.x if window[1] < np.log(hi) else np.inf)
            if edge > 2 * TAU_LOG_TOLERANCE:
                return float(search.fun), float(np.exp(search.x))
            window = (np.log(lo), np.log(hi))  # the minimum may lie beyond the window: the whole range

    period = 1.0 / rate
    thin = max(1, int(round(max(FIT_HORIZONS_S) / ANCHOR_STRIDE_S)))
    if tau_held is not None and delay_held is not None:
        tau, delay, sigma = held
        design = _ground_offset(p, segments, tau, delay, observer, design, vehicle)
        return tau, delay, sigma, [], design, solve_channels(_normal_equations(p, segments, tau, delay, observer, thin, design)), thin
    if near is not None:
        i = int(np.argmin(np.abs(grid - near[1])))
    else:
        coarse = np.arange(0, len(grid), 2)  # every other delay: the neighbours of the best are searched next
        i = int(coarse[np.argmin([objective(start_tau, float(grid[k])) for k in coarse])])
    while True:
        for j in (i - 1, i, i + 1):
            if 0 <= j < len(grid) and j not in searched:
                searched[j] = tau_at(float(grid[j]))
        j = min(searched, key=lambda k: searched[k][0])
        if j == i:
            break
        i = j
    tau, delay = searched[i][1], float(grid[i])
    if 0 < i < len(grid) - 1:  # between samples: the vertex of the parabola through the three profile values
        low, mid, high = (searched[k][0] for k in (i - 1, i, i + 1))
        curvature = low - 2.0 * mid + high
        if curvature > 0:  # not checked against J at the vertex itself: see subsample_delay
            delay = subsample_delay(float(grid[i]), low, mid, high, period)
    profile = [(searched[k][0], searched[k][1], float(grid[k])) for k in sorted(searched)]
    design = _ground_offset(p, segments, tau, delay, observer, design, vehicle)
    fit = solve_channels(_normal_equations(p, segments, tau, delay, observer, thin, design))
    if delay_held is not None:
        return tau, delay, delay_held_sd, profile, design, fit, thin
    sigma = profile_sigma(lambda d: _chi2(p, segments, tau, d, observer, thin, fit, design), float(grid[i]), period)
    if not np.isfinite(sigma) or delay != float(grid[i]):  # flat or kinked there / the vertex's own error (subsample_delay)
        sigma = float(np.hypot(sigma, period / np.sqrt(12.0))) if np.isfinite(sigma) else period / np.sqrt(12.0)
    return tau, delay, sigma, profile, design, fit, thin


def _ground_offset(p: PhysicsParameters, segments: list[_Segment], tau: float, delay: float, observer: Observer,
                   design: TermDesign, vehicle: VehicleConfig) -> TermDesign:
    """``design`` with ground effect's h_off the grid value of least velocity error at τ, δ (unchanged without it)."""
    if "ground_effect" not in design.names:
        return design
    offsets = [g * vehicle.value("arm_length") for g in GROUND_OFFSETS]
    errors = [solve_channels(_normal_equations(p, segments, tau, delay, observer, 1, replace(design, ground_offset=h)))
              ["velocity"]["ssr"] for h in offsets]
    return replace(design, ground_offset=offsets[int(np.argmin(errors))])


def _chi2(p: PhysicsParameters, segments: list[_Segment], tau: float, delay: float, observer: Observer, thin: int, fit: dict,
          design: TermDesign) -> float:
    """χ²(τ, δ) = Σ_c SSR_c / (thin s_c²) with the channel variances s_c² of ``fit`` (module docstring)."""
    trial = solve_channels(_normal_equations(p, segments, tau, delay, observer, 1, design))
    s2 = {c: fit[c]["s2"] for c in CHANNELS}
    return sum(trial[c]["ssr"] / (thin * s2[c]) for c in CHANNELS if np.isfinite(s2[c]) and s2[c] > 0)


def _term_design(terms: tuple[str, ...], segments: list[_Segment], vehicle: VehicleConfig) -> TermDesign:
    """The :class:`TermDesign` of ``terms``: V_ref the mean training voltage (DataError without one), h_off the middle
    of its grid until the search."""
    reference = float("nan")
    if "battery" in terms:
        if any(s.voltage is None for s in segments):
            raise DataError("identify --effects battery needs the battery voltage, and a training flight has none")
        reference = float(np.mean(np.concatenate([s.voltage for s in segments])))
    return TermDesign(terms, GROUND_OFFSETS[len(GROUND_OFFSETS) // 2] * vehicle.value("arm_length"), reference)
