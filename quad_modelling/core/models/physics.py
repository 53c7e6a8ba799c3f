r"""The nonlinear physics model (``physics`` spec, DESIGN 6.1b): rigid body, rotor map, motor lag, rotor drag.

Frames and units: N = NED, B = FRD (:mod:`quad_modelling.core.frames`), SI. Per batch member the state is

.. math:: x = (p_N, v_N, R, \omega_B, \Omega)

position [m] and velocity [m/s] in N, attitude :math:`R = R_{N \leftarrow B}`, body rates
:math:`\omega = (p, q, r)` [rad/s], rotor speeds :math:`\Omega_i` [rad/s] (command order).
Constants: :class:`~quad_modelling.core.models.physics_params.PhysicsParameters` (symbols as the code's fields).

Motor map, command delay and first-order lag: the rotors answer the command logged :math:`\delta` earlier,
:math:`\tilde u_k = u_j` with j the last row with :math:`t_j \le t_k - \delta` (:func:`delayed_commands`; the
first command before the log starts), held over each sample interval :math:`\Delta t_k` (exact solution of
:math:`\dot\Omega = (\Omega_{ss} - \Omega)/\tau_m`, :func:`rotor_step`):

.. math::

    \Omega_{ss,i} = \max(k_u \tilde u_i + \Omega_{off}, 0), \qquad
    \Omega_{k+1} = \Omega_{ss}(\tilde u_k) + (\Omega_k - \Omega_{ss}(\tilde u_k))\, e^{-\Delta t_k / \tau_m}

The delay is the main lever of a short horizon: the first :math:`\delta / \Delta t` steps of a prediction
run on commands already logged at the anchor.

Wrench in B (:func:`accelerations`), rotor i at :math:`(x_i, y_i)` with spin :math:`s_i` (+1 = counter-clockwise
seen from above), :math:`T_i = k_f \Omega_i^2`, linear rotor drag with
:math:`D = \mathrm{diag}(d_{xy}, d_{xy}, d_z)`:

.. math::

    F_B = (0, 0, -\textstyle\sum_i T_i) - (\sum_i \Omega_i)\, D\, R^T v_N

    \tau_B = \big(-\textstyle\sum_i y_i T_i - h_d F_{d,y},\ \sum_i x_i T_i + h_d F_{d,x},\
             k_m \sum_i s_i \Omega_i^2 + I_p \sum_i s_i \dot\Omega_i\big)

where :math:`F_d = -(\sum_i \Omega_i) D R^T v_N` is the rotor drag, acting at the height :math:`h_d` (FRD z from the
CG, negative above it): :math:`(0, 0, h_d) \times F_d`. Rotor drag and blade flapping tilt the rotor forces
against the airspeed; on the NanoBench Crazyflie this moment is what the controller's slow differential commands
balance in forward flight (R² 0.95 at 1 Hz, h_d ≈ -3 cm), without it the model reads those commands as
torques of ~15 rad/s² that are not there.

Motion, with the constant disturbances :math:`\hat d_v` (N) and :math:`\hat d_\omega` (B) of the anchor
(:func:`disturbance_estimate`):

.. math::

    \dot v_N = R F_B / m + g e_z + \hat d_v, \qquad
    \dot\omega = I^{-1}(\tau_B - \omega \times I \omega) + \hat d_\omega, \qquad
    \dot R = R [\omega]_\times

:math:`\dot v_N` is the acceleration output (``acc_x..z``): the measurement's convention,
:math:`a_N = R f_B + g e_z` from the accelerometer (:func:`~quad_modelling.core.preprocess.measured_variables`),
zero in hover. :math:`\dot\omega` is ``roll_acc..yaw_acc``.

Integration (:func:`step`): semi-implicit (symplectic) Euler over the real sample intervals
:math:`\Delta t_k = t_{k+1} - t_k` (jitter and dropped samples are simply longer steps), vectorised over a batch:

.. math::

    \omega_{k+1} = \omega_k + \Delta t_k \dot\omega_k,\quad R_{k+1} = R_k \mathrm{Exp}(\omega_{k+1} \Delta t_k),\quad
    v_{k+1} = v_k + \Delta t_k \dot v_k,\quad p_{k+1} = p_k + \Delta t_k v_{k+1}

with the rotor speeds stepped exactly (above), |ω| limited to the gyro full scale and |v| to :data:`MAX_SPEED_MPS`
(an open-loop 10 s window stays finite). Why: the rotor lag, the only fast mode, is integrated
exactly, leaving the rigid body, whose open-loop modes are integrators (no stiffness); semi-implicit
Euler keeps the attitude on SO(3) (the exponential map) and costs one wrench evaluation per sample,
a quarter of RK4's, which matters for 2048 starts x 50 steps and for the 400 Hz live node. Its local
error is :math:`O(\Delta t^2)` per step (test: jitter).

Causal anchoring (:func:`anchor_state`, :func:`disturbance_estimate`): a prediction from anchor row a uses
rows <= a only: the start state is the raw measured row a (motion-capture position, velocity,
attitude; gyro rates), the rotor speeds come from the lag filter run over the delayed commands up to a
(:func:`rotor_speeds`), and a constant disturbance (:class:`Observer`) is held over the horizon:

* linear: the mean (measured - modelled) acceleration over the last ``linear_s`` before a. The measured mean
  is exact and needs no differentiation, :math:`(v_a - v_j)/(t_a - t_j)`; the modelled mean integrates the
  model's accelerations at the measured rows j..a-1. It absorbs what changes slowly and the model lacks
  (battery sag of the thrust, wind, a mass error).
* angular (``angular_trim``, the default): minus the model's mean angular acceleration over the last
  ``angular_s``, a causal trim of the commands: the model predicts the rate changes that the command changes
  against their recent mean cause (CG offset, motor imbalance and any constant moment the controller
  balances cancel), and the measured mean angular acceleration is not extrapolated. Extrapolating it
  (``angular_trim`` off: measured - modelled, as the linear part) follows the closed loop's oscillation the
  wrong way: on held-out NanoBench shapes it scored an AV SimErr ratio of 1.15 against 0.83 with the trim.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.flight_log import GYRO_FULL_SCALE, FlightLog
from quad_modelling.core.models.physics_params import PhysicsParameters
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.preprocess import TrimConfig, state_measurement, trim_prediction
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.vehicle import GRAVITY, VehicleConfig
from quad_modelling.errors import DataError

HISTORY_S = 0.5
"""Default history of the linear disturbance observer [s]: long enough to average motion-capture noise (50 rows
at 100 Hz), short against battery sag and manoeuvre changes (the NanoBench manoeuvres last seconds)."""

ANGULAR_HISTORY_S = 0.5
"""Default history of the angular disturbance observer [s] (see :class:`Observer`)."""


MAX_SPEED_MPS = 50.0
"""Largest speed the open-loop state may reach [m/s] (racing multirotors reach ~40 m/s): with the rates limited to
the gyro full scale (:data:`~quad_modelling.core.flight_log.GYRO_FULL_SCALE`), it keeps a long open-loop window
(the thesis's 10 s) finite, where an uncontrolled rigid body tumbles and ω × Iω grows without bound."""


def _limit_norm(vectors: np.ndarray, limit: float) -> np.ndarray:
    """Rows of ``vectors`` scaled down to norm ``limit`` where longer."""
    norm = np.linalg.norm(vectors, axis=1, keepdims=True)
    return np.where(norm > limit, vectors * (limit / np.maximum(norm, 1e-300)), vectors)


@dataclass(frozen=True)
class Observer:
    """The constant-disturbance observer (module docstring): histories [s] ``linear_s`` for the linear acceleration
    (N frame) and ``angular_s`` for the angular acceleration (B frame), 0 switching that part off; ``angular_trim``:
    the angular part is minus the model's mean only (the measured mean is not extrapolated)."""

    linear_s: float = HISTORY_S
    angular_s: float = ANGULAR_HISTORY_S
    angular_trim: bool = True

    def __post_init__(self) -> None:
        for name in ("linear_s", "angular_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.0 <= value < 1e3):
                raise ValueError(f"observer history {name} must be 0 (off) or a positive number of seconds, got {value}")


@dataclass
class PhysicsState:
    """A batch of B model states (module docstring), SI, N = NED, B = FRD.

    pos_n, vel_n (B, 3); rot (B, 3, 3) R_N<-B; rates (B, 3) body rates; rotor (B, 4) rotor speeds [rad/s];
    yaw (B,) continuous (unwrapped) yaw [rad] that the Euler output follows.
    """

    pos_n: np.ndarray
    vel_n: np.ndarray
    rot: np.ndarray
    rates: np.ndarray
    rotor: np.ndarray
    yaw: np.ndarray

    def take(self, index) -> PhysicsState:
        """The members ``index`` of the batch."""
        return PhysicsState(self.pos_n[index], self.vel_n[index], self.rot[index], self.rates[index], self.rotor[index], self.yaw[index])


@dataclass
class Disturbance:
    """Constant disturbance accelerations held over a horizon: linear (B, 3) in N [m/s²], angular (B, 3) in B [rad/s²]."""

    linear_n: np.ndarray
    angular_b: np.ndarray

    @classmethod
    def zero(cls, batch: int) -> Disturbance:
        return cls(np.zeros((batch, 3)), np.zeros((batch, 3)))


STAMP_TOLERANCE_S = 1e-7
"""Stamps closer than this [s] count as equal when looking up the delayed command (float rounding of t - δ)."""


def delayed_commands(p: PhysicsParameters, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 4) commands the rotors answer at each row: ũ_k = u_j, j the last row with t_j <= t_k - δ (row 0 before
    the first); ``u`` (N, 4) logged commands, ``t`` (N,) [s]. Causal: ũ_k uses rows <= k."""
    u = np.asarray(u, dtype=float)
    if p.delay <= 0.0:
        return u
    t = np.asarray(t, dtype=float)
    rows = np.searchsorted(t, t - p.delay + STAMP_TOLERANCE_S, side="right") - 1
    return u[np.maximum(rows, 0)]


def steady_rotor_speed(p: PhysicsParameters, u: np.ndarray) -> np.ndarray:
    """Ω_ss = max(k_u u + Ω_off, 0) [rad/s] of commands ``u`` (..., 4)."""
    return np.maximum(p.speed_gain * np.asarray(u, dtype=float) + p.speed_offset, 0.0)


def rotor_step(p: PhysicsParameters, rotor: np.ndarray, u: np.ndarray, dt) -> np.ndarray:
    """Ω_{k+1} from Ω_k = ``rotor`` under command ``u`` held for ``dt`` [s] (exact first-order lag; τ_m = 0: at once)."""
    target = steady_rotor_speed(p, u)
    if p.time_constant <= 0.0:
        return target
    decay = np.exp(-np.asarray(dt, dtype=float) / p.time_constant)
    if np.ndim(decay) and np.ndim(decay) < np.ndim(target):
        decay = np.reshape(decay, np.shape(decay) + (1,) * (np.ndim(target) - np.ndim(decay)))
    return target + (rotor - target) * decay


def rotor_speeds(p: PhysicsParameters, u: np.ndarray, t: np.ndarray, initial: np.ndarray | None = None) -> np.ndarray:
    """(N, ..., 4) rotor speeds Ω_k at each row of commands ``u`` (N, ..., 4) stamped ``t`` (N, ...) [s].

    Row k depends on u_0..u_{k-1} only (causal); Ω_0 = ``initial`` or the steady speed of u_0 (the motor
    settled before the data starts). Time runs along axis 0; other leading axes are independent series.
    """
    u = np.asarray(u, dtype=float)
    target = steady_rotor_speed(p, u)
    out = np.empty_like(target)
    out[0] = target[0] if initial is None else initial
    if p.time_constant <= 0.0:
        out[1:] = target[:-1]
        return out
    decay = np.exp(-np.diff(np.asarray(t, dtype=float), axis=0) / p.time_constant)
    decay = decay.reshape(decay.shape + (1,) * (target.ndim - decay.ndim)) * np.ones_like(target[:-1])
    gain, offset = first_order_scan(decay, (1.0 - decay) * target[:-1])
    out[1:] = gain * out[0] + offset
    return out


def first_order_scan(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, Q) with x_{k+1} = P_k x_0 + Q_k for the recurrence x_{k+1} = a_k x_k + b_k along axis 0.

    A Hillis-Steele prefix scan of the affine maps f_k(x) = a_k x + b_k (composition
    (P, Q)_k ∘ (P, Q)_{k-s} = (P_k P_{k-s}, P_k Q_{k-s} + Q_k)): log2(N) vectorised passes instead of N
    Python steps, exact up to rounding, stable for |a_k| <= 1 (products only shrink).
    """
    p, q = np.array(a, dtype=float), np.array(b, dtype=float)
    shift = 1
    while shift < len(p):
        q[shift:] = p[shift:] * q[:-shift] + q[shift:]
        p[shift:] = p[shift:] * p[:-shift]
        shift *= 2
    return p, q


def rotor_acceleration(p: PhysicsParameters, rotor: np.ndarray, u: np.ndarray) -> np.ndarray:
    """dΩ/dt = (Ω_ss(u) - Ω)/τ_m [rad/s²] (0 without lag)."""
    if p.time_constant <= 0.0:
        return np.zeros_like(rotor)
    return (steady_rotor_speed(p, u) - rotor) / p.time_constant


def accelerations(p: PhysicsParameters, vel_n: np.ndarray, rot: np.ndarray, rates: np.ndarray, rotor: np.ndarray,
                  rotor_dot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model accelerations without disturbance: (dv_N/dt (B, 3) [m/s², N], dω/dt (B, 3) [rad/s², B]).

    Inputs (B, ...) as :class:`PhysicsState` plus ``rotor_dot`` dΩ/dt (B, 4) (module docstring equations).
    """
    w2 = rotor * rotor
    thrust = p.thrust_constant * w2
    vel_b = np.einsum("bji,bj->bi", rot, vel_n)
    drag_b = -(rotor.sum(axis=1)[:, None] * np.asarray(p.drag)) * vel_b
    force_b = drag_b.copy()
    force_b[:, 2] -= thrust.sum(axis=1)
    acc_n = np.einsum("bij,bj->bi", rot, force_b) / p.mass
    acc_n[:, 2] += GRAVITY
    inertia = np.asarray(p.inertia)
    torque = np.column_stack([
        -thrust @ p.positions[:, 1] - p.drag_arm * drag_b[:, 1],
        thrust @ p.positions[:, 0] + p.drag_arm * drag_b[:, 0],
        p.torque_constant * (w2 @ p.spins) + p.prop_inertia * (rotor_dot @ p.spins),
    ])
    torque -= np.cross(rates, rates * inertia)
    return acc_n, torque / inertia


def outputs(p: PhysicsParameters, state: PhysicsState, u: np.ndarray, disturbance: Disturbance) -> np.ndarray:
    """(B, 18) VARIABLES of ``state`` under commands ``u`` (B, 4): absolute, internal convention."""
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, state.rotor, rotor_acceleration(p, state.rotor, u))
    out = np.empty((len(state.pos_n), len(VARIABLES)))
    out[:, 0:3] = state.pos_n
    out[:, 3:6] = state.vel_n
    out[:, 6:9] = acc_n + disturbance.linear_n
    out[:, 9:12] = frames.matrix_to_euler_ned(state.rot)
    out[:, 11] = state.yaw
    out[:, 12:15] = state.rates
    out[:, 15:18] = ang_acc + disturbance.angular_b
    return out


def _continue_yaw(previous: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """The yaw of ``rot`` unwrapped next to ``previous`` [rad]."""
    psi = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
    return previous + (psi - previous + np.pi) % (2.0 * np.pi) - np.pi


def step(p: PhysicsParameters, state: PhysicsState, u: np.ndarray, dt, disturbance: Disturbance) -> PhysicsState:
    """One semi-implicit Euler step (module docstring) of every batch member under ``u`` (B, 4) held for ``dt``
    (scalar or (B,)) [s]."""
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (len(state.pos_n),))
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, state.rotor, rotor_acceleration(p, state.rotor, u))
    rates = _limit_norm(state.rates + dt[:, None] * (ang_acc + disturbance.angular_b), GYRO_FULL_SCALE)
    rot = frames.rotation_increment(state.rot, rates, dt)
    vel = _limit_norm(state.vel_n + dt[:, None] * (acc_n + disturbance.linear_n), MAX_SPEED_MPS)
    pos = state.pos_n + dt[:, None] * vel
    return PhysicsState(pos, vel, rot, rates, rotor_step(p, state.rotor, u, dt), _continue_yaw(state.yaw, rot))


def rollout(p: PhysicsParameters, state: PhysicsState, disturbance: Disturbance, u: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(B, H + 1, 18) open-loop outputs from ``state`` (row 0) under commands ``u`` (B, H + 1, 4) with sample
    intervals ``dt`` (B, H) [s]: row h is the state after h steps, output with command u[:, h]."""
    horizon = dt.shape[1]
    out = np.empty((len(state.pos_n), horizon + 1, len(VARIABLES)))
    for h in range(horizon + 1):
        out[:, h] = outputs(p, state, u[:, h], disturbance)
        if h < horizon:
            state = step(p, state, u[:, h], dt[:, h], disturbance)
    return out


def measured_states(p: PhysicsParameters, measured: np.ndarray, rotor: np.ndarray, rows) -> PhysicsState:
    """The model state at ``rows`` from an (N, 18) measurement (VARIABLES order, raw rows, yaw unwrapped) and the
    lag-filtered rotor speeds (N, 4) (:func:`rotor_speeds`)."""
    m = measured[rows]
    return PhysicsState(m[:, 0:3].copy(), m[:, 3:6].copy(), frames.euler_ned_to_matrix(m[:, 9:12]), m[:, 12:15].copy(),
                        rotor[rows].copy(), m[:, 11].copy())


def disturbance_estimate(p: PhysicsParameters, t: np.ndarray, u: np.ndarray, measured: np.ndarray, rotor: np.ndarray,
                         anchors: np.ndarray, observer: Observer = Observer()) -> Disturbance:
    """Constant-disturbance observer (module docstring) at each anchor row: mean over the rows j..a-1 with
    t_a - t_j <= the observer's history (linear and angular: their own) of (measured - modelled) acceleration.
    Uses rows <= a only.

    ``t`` (N,) [s], ``u`` (N, 4) delayed commands (:func:`delayed_commands`), ``measured`` (N, 18) raw rows (VARIABLES order), ``rotor`` (N, 4); an anchor with
    no earlier row (or a history of 0) gets a zero disturbance.
    """
    anchors = np.asarray(anchors, dtype=int)
    all_rows = np.arange(len(t))
    state = measured_states(p, measured, rotor, all_rows)
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, state.rotor, rotor_acceleration(p, rotor, u))
    return observed_disturbance(t, measured, np.concatenate([acc_n, ang_acc], axis=1), anchors, observer)


def observed_disturbance(t: np.ndarray, measured: np.ndarray, modelled: np.ndarray, anchors: np.ndarray,
                         observer: Observer = Observer()) -> Disturbance:
    """The observer's means (module docstring, :func:`disturbance_estimate`) from a model's accelerations at the
    measured rows: ``modelled`` (N, 6) = (dv_N/dt [m/s², N], dω/dt [rad/s², B]) at each row of ``measured``
    (N, 18, raw rows, VARIABLES order) stamped ``t`` (N,) [s]. Any model's anchoring can call it (the ``truth``
    model does, :mod:`quad_modelling.core.sim.truth_model`). Uses rows <= each anchor only."""
    anchors = np.asarray(anchors, dtype=int)
    dt = np.diff(t)
    modelled = modelled[:-1] * dt[:, None]
    integral = np.concatenate([np.zeros((1, 6)), np.cumsum(modelled, axis=0)])  # ∫ modelled from t_0 to t_k
    parts = []
    for history, cols in ((observer.linear_s, slice(0, 3)), (observer.angular_s, slice(3, 6))):
        first = np.minimum(np.searchsorted(t, t[anchors] - history - 1e-9, side="left"), anchors)
        span = t[anchors] - t[first]
        ok = (span > 0) & (history > 0)
        safe = np.where(ok, span, 1.0)[:, None]
        state_cols = slice(3, 6) if cols.start == 0 else slice(12, 15)
        measured_mean = (measured[anchors, state_cols] - measured[first, state_cols]) / safe
        if cols.start == 3 and observer.angular_trim:
            measured_mean = np.zeros_like(measured_mean)
        modelled_mean = (integral[anchors, cols] - integral[first, cols]) / safe
        parts.append(np.where(ok[:, None], measured_mean - modelled_mean, 0.0))
    return Disturbance(parts[0], parts[1])


def anchor_state(p: PhysicsParameters, log: FlightLog, anchors: np.ndarray, observer: Observer = Observer(),
                 measured: np.ndarray | None = None) -> tuple[PhysicsState, Disturbance, np.ndarray]:
    """(start states, disturbances, rotor speeds (N, 4)) at ``anchors`` rows of ``log``, causally (module docstring).

    ``measured``: the log's :func:`~quad_modelling.core.preprocess.state_measurement` if already computed (only
    its raw columns are used: positions, velocities, angles, rates).
    """
    if measured is None:
        measured = state_measurement(log)
    commands = delayed_commands(p, log.u, log.t)
    rotor = rotor_speeds(p, commands, log.t)
    return (measured_states(p, measured, rotor, anchors),
            disturbance_estimate(p, log.t, commands, measured, rotor, anchors, observer), rotor)


class PhysicsStream:
    """Live stream of one window (:class:`~quad_modelling.core.models.streaming.WindowStream`).

    ``push(command)`` steps by the warm rows' median sample interval; ``push_at(command, t_s)`` by the real
    interval since the previous sample (what :func:`~quad_modelling.core.models.streaming.push_sample` calls
    when the stamp is known). The logged commands of the last δ are kept for the delay.
    """

    def __init__(self, params: PhysicsParameters, state: PhysicsState, disturbance: Disturbance, times: np.ndarray,
                 commands: np.ndarray, period_s: float):
        self.params = params
        self.state = state
        self.disturbance = disturbance
        self.times = [float(x) for x in times]
        self.commands = [np.asarray(c, dtype=float).reshape(1, 4) for c in commands]
        self.period_s = period_s

    def _command_at(self, t_s: float) -> np.ndarray:
        """The command the rotors answer at ``t_s``: the last logged at or before t_s - δ (the first one before it)."""
        limit = t_s - self.params.delay + STAMP_TOLERANCE_S
        for i in range(len(self.times) - 1, -1, -1):
            if self.times[i] <= limit:
                return self.commands[i]
        return self.commands[0]

    def _forget(self) -> None:
        """Drop commands no later sample can need (keep the last one at or before t - δ)."""
        limit = self.times[-1] - self.params.delay + STAMP_TOLERANCE_S
        drop = 0
        while drop + 1 < len(self.times) and self.times[drop + 1] <= limit:
            drop += 1
        if drop:
            del self.times[:drop], self.commands[:drop]

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        previous = self.times[-1]
        dt = t_s - previous
        if not dt > 0:
            raise DataError(f"physics stream: sample time {t_s:.6f} s is not after the previous {previous:.6f} s")
        self.state = step(self.params, self.state, self._command_at(previous), dt, self.disturbance)
        self.times.append(float(t_s))
        self.commands.append(np.asarray(command, dtype=float).reshape(1, 4))
        self._forget()
        return outputs(self.params, self.state, self._command_at(t_s), self.disturbance)[0]

    def push(self, command: np.ndarray) -> np.ndarray:
        return self.push_at(command, self.times[-1] + self.period_s)


class PhysicsPredictor:
    """The ``physics`` model: window (:meth:`predict_window`), multi-step (:meth:`predict_horizons`) and live
    (:meth:`start_window`) forms, all causal (module docstring).

    ``observer``: the disturbance observer's histories (:class:`Observer`). In a window the history is limited
    to the warm rows.
    """

    def __init__(self, vehicle: VehicleConfig, observer: Observer = Observer(), trim: TrimConfig | None = None,
                 name: str = "physics"):
        self.vehicle = vehicle
        self.params = PhysicsParameters.from_vehicle(vehicle)
        self.observer = observer
        self.trim = trim or TrimConfig()
        self.name = name

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, PhysicsStream]:
        """Warm rows -> (their measurement (W, 18) as predictions, stream anchored on the last warm row)."""
        if len(warm) < 2:
            raise DataError(f"{warm.meta.source}: the physics model needs at least 2 warm-start samples, got {len(warm)}")
        measured = state_measurement(warm, self.vehicle)
        last = np.array([len(warm) - 1])
        state, disturbance, _ = anchor_state(self.params, warm, last, self.observer, measured)
        period = float(np.median(np.diff(warm.t)))
        return measured, PhysicsStream(self.params, state, disturbance, warm.t, warm.u, period)

    def predict_absolute(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) absolute prediction: the live calls with each sample's real stamp."""
        return predict_window_by_stream(self, window, warm_samples)

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) prediction in the evaluation's trimmed convention."""
        return trim_prediction(window, self.predict_absolute(window, warm_samples), self.trim)

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute open-loop predictions from each start row (IDSIA multi-step), causal."""
        starts = np.asarray(starts, dtype=int)
        if starts.size and (starts.min() < 0 or starts.max() + horizon >= len(segment)):
            raise DataError(f"{segment.meta.source}: multi-step starts + horizon {horizon} leave the segment")
        if segment.gyro_b is None:
            raise DataError(f"{segment.meta.source}: the physics model's multi-step form needs the gyro (body rates at each anchor)")
        state, disturbance, _ = anchor_state(self.params, segment, starts, self.observer)
        rows = starts[:, None] + np.arange(horizon + 1)[None, :]
        dt = np.diff(segment.t)[rows[:, :-1]]
        return rollout(self.params, state, disturbance, delayed_commands(self.params, segment.u, segment.t)[rows], dt)
