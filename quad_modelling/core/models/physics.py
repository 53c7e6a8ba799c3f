r"""The nonlinear physics model (``physics`` spec, DESIGN 6.1b): rigid body, rotor map, motor lag, rotor drag.

Frames and units: N = NED, B = FRD (:mod:`quad_modelling.core.frames`), SI. Per batch member the state is

.. math:: x = (p_N, v_N, R, \omega_B, \Omega)

position [m] and velocity [m/s] in N, attitude :math:`R = R_{N \leftarrow B}`, body rates
:math:`\omega = (p, q, r)` [rad/s], rotor speeds :math:`\Omega_i` [rad/s] (command order).
Constants: :class:`~quad_modelling.core.physics.parameters.PhysicsParameters` (symbols as the code's fields).

The physics itself -- command map, command delay, rotor lag, thrust and yaw torque, rotor drag, rigid body and
the semi-implicit Euler step -- is defined once in :mod:`quad_modelling.core.physics` (equations there, same
symbols); this module anchors it on measurements and runs it in the three forms every model has (window,
multi-step, live). The delay is the main lever of a short horizon: the first :math:`\delta / \Delta t` steps of
a prediction run on commands already logged at the anchor. Rotor drag acts at the height :math:`h_d` (FRD z from
the CG, negative above it); on the NanoBench Crazyflie its moment is what the controller's slow differential
commands balance in forward flight (R² 0.95 at 1 Hz, h_d ≈ -3 cm), without it the model reads those commands as
torques of ~15 rad/s² that are not there.

Motion, with the constant disturbances :math:`\hat d_v` (N) and :math:`\hat d_\omega` (B) of the anchor
(:func:`disturbance_estimate`) added to the rigid body's accelerations:
:math:`\dot v_N = R F_B / m + g e_z + \hat d_v`, :math:`\dot\omega = I^{-1}(\tau_B - \omega \times I \omega) + \hat d_\omega`.
:math:`\dot v_N` is the acceleration output (``acc_x..z``): the measurement's convention,
:math:`a_N = R f_B + g e_z` from the accelerometer (:func:`~quad_modelling.core.preprocess.measured_variables`),
zero in hover. :math:`\dot\omega` is ``roll_acc..yaw_acc``. Steps run over the real sample intervals
:math:`\Delta t_k = t_{k+1} - t_k` (jitter and dropped samples are simply longer steps).

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

from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.streaming import WindowByStream
from quad_modelling.core.physics import rigid_body
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import PhysicsState, accelerations
from quad_modelling.core.physics.rotors import (
    STAMP_TOLERANCE_S,
    delayed_command_at,
    delayed_commands,
    effective_commands,
    rotor_acceleration,
    rotor_speeds,
)
from quad_modelling.core.preprocess import TrimConfig, state_measurement
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import DataError

HISTORY_S = 0.5
"""Default history of the linear disturbance observer [s]: long enough to average motion-capture noise (50 rows
at 100 Hz), short against battery sag and manoeuvre changes (the NanoBench manoeuvres last seconds)."""

ANGULAR_HISTORY_S = 0.5
"""Default history of the angular disturbance observer [s] (see :class:`Observer`)."""


@dataclass(frozen=True)
class Observer:
    """The constant-disturbance observer (module docstring): histories [s] ``linear_s`` for the linear acceleration
    (N frame) and ``angular_s`` for the angular acceleration (B frame), 0 switching that part off; ``angular_trim``:
    the angular part is minus the model's mean only (the measured mean is not extrapolated)."""

    linear_s: float = HISTORY_S
    angular_s: float = ANGULAR_HISTORY_S
    angular_trim: bool = True

    @classmethod
    def from_vehicle(cls, vehicle: VehicleConfig) -> Observer:
        """The observer the vehicle file asks for: its ``disturbance_observer`` term
        (:mod:`quad_modelling.core.physics.effects`) switched on (its histories and trim flag) or off (no observer);
        without one, the default."""
        term = vehicle.effects.get("disturbance_observer")
        if term is None:
            return cls()
        if not term.on:
            return cls(0.0, 0.0)
        linear_s, angular_s, trim = term.values()
        return cls(linear_s, angular_s, trim >= 0.5)

    def __post_init__(self) -> None:
        for name in ("linear_s", "angular_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.0 <= value < 1e3):
                raise ValueError(f"observer history {name} must be 0 (off) or a positive number of seconds, got {value}")


@dataclass
class Disturbance:
    """Constant disturbance accelerations held over a horizon: linear (B, 3) in N [m/s²], angular (B, 3) in B [rad/s²]."""

    linear_n: np.ndarray
    angular_b: np.ndarray

    @classmethod
    def zero(cls, batch: int) -> Disturbance:
        return cls(np.zeros((batch, 3)), np.zeros((batch, 3)))


def outputs(p: PhysicsParameters, state: PhysicsState, u: np.ndarray, disturbance: Disturbance) -> np.ndarray:
    """(B, 18) VARIABLES of ``state`` under commands ``u`` (B, 4): absolute, internal convention."""
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, state.rotor, rotor_acceleration(p, state.rotor, u),
                                   state.pos_n)
    out = state_outputs(state)
    out[:, 6:9] = acc_n + disturbance.linear_n
    out[:, 15:18] = ang_acc + disturbance.angular_b
    return out


def state_outputs(state: PhysicsState) -> np.ndarray:
    """(B, 18) VARIABLES of ``state`` that the state holds (position, velocity, attitude, body rates), the two
    acceleration groups NaN: :func:`outputs` without the wrench, what a multi-step score needs."""
    out = np.full((len(state.pos_n), len(VARIABLES)), np.nan)
    out[:, 0:3] = state.pos_n
    out[:, 3:6] = state.vel_n
    out[:, 9:12] = frames.matrix_to_euler_ned(state.rot)
    out[:, 11] = state.yaw
    out[:, 12:15] = state.rates
    return out


def step(p: PhysicsParameters, state: PhysicsState, u: np.ndarray, dt, disturbance: Disturbance,
         rates_next: np.ndarray | None = None, down_velocity_next: np.ndarray | None = None) -> PhysicsState:
    """One step of :func:`quad_modelling.core.physics.rigid_body.step` of every batch member under ``u`` (B, 4) held
    for ``dt`` (scalar or (B,)) [s], with the anchor's constant ``disturbance`` (and given end-of-step body rates
    ``rates_next`` (B, 3) [rad/s] and down velocity ``down_velocity_next`` (B,) [m/s], if any)."""
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (len(state.pos_n),))
    return rigid_body.step(p, state, u, dt, disturbance.linear_n, disturbance.angular_b, rates_next, down_velocity_next)


def rollout(p: PhysicsParameters, state: PhysicsState, disturbance: Disturbance, u: np.ndarray, dt: np.ndarray,
            with_accelerations: bool = True, rates: np.ndarray | None = None,
            down_velocity: np.ndarray | None = None) -> np.ndarray:
    """(B, H + 1, 18) open-loop outputs from ``state`` (row 0) under commands ``u`` (B, H + 1, 4) with sample
    intervals ``dt`` (B, H) [s]: row h is the state after h steps, output with command u[:, h]. Without
    ``with_accelerations`` the acceleration columns are NaN (:func:`state_outputs`; a quarter less work per step).
    ``rates`` (B, G + 1, 3) [rad/s]: body rates given for rows 1..G (G <= H; row 0 unused), each step's
    ``rates_next`` (:func:`step`); after row G the rates are integrated again. ``down_velocity`` (B, G' + 1) [m/s]:
    the same for the velocity's down component (``down_velocity_next``)."""
    horizon = dt.shape[1]
    given = 0 if rates is None else rates.shape[1] - 1
    given_down = 0 if down_velocity is None else down_velocity.shape[1] - 1
    out = np.empty((len(state.pos_n), horizon + 1, len(VARIABLES)))
    for h in range(horizon + 1):
        out[:, h] = outputs(p, state, u[:, h], disturbance) if with_accelerations else state_outputs(state)
        if h < horizon:
            state = step(p, state, u[:, h], dt[:, h], disturbance, rates[:, h + 1] if h < given else None,
                         down_velocity[:, h + 1] if h < given_down else None)
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
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, state.rotor, rotor_acceleration(p, rotor, u), state.pos_n)
    return observed_disturbance(t, measured, np.concatenate([acc_n, ang_acc], axis=1), anchors, observer)


def observed_disturbance(t: np.ndarray, measured: np.ndarray, modelled: np.ndarray, anchors: np.ndarray,
                         observer: Observer = Observer()) -> Disturbance:
    """The observer's means (module docstring, :func:`disturbance_estimate`) from a model's accelerations at the
    measured rows: ``modelled`` (N, 6) = (dv_N/dt [m/s², N], dω/dt [rad/s², B]) at each row of ``measured``
    (N, 18, raw rows, VARIABLES order) stamped ``t`` (N,) [s]. Any model's anchoring can call it (the ``truth``
    model does, :mod:`quad_modelling.core.sim.truth_model`). Uses rows <= each anchor only."""
    return disturbance_means(t, measured[:, 3:6], measured[:, 12:15], modelled_integral(t, modelled), anchors, observer)


def modelled_integral(t: np.ndarray, modelled: np.ndarray) -> np.ndarray:
    r"""(N, 6) the integral of the modelled accelerations ``modelled`` (N, 6) from t_0 to each row, left rectangles:
    :math:`I_k = \sum_{j<k} a_j (t_{j+1} - t_j)` (a carried form adds one term per row)."""
    dt = np.diff(t)
    return np.concatenate([np.zeros((1, 6)), np.cumsum(modelled[:-1] * dt[:, None], axis=0)])


def disturbance_means(t: np.ndarray, vel_n: np.ndarray, rates: np.ndarray, integral: np.ndarray, anchors: np.ndarray,
                      observer: Observer = Observer()) -> Disturbance:
    """The observer's means at ``anchors`` from the measured velocities ``vel_n`` (N, 3) [m/s, N] and body rates
    ``rates`` (N, 3) [rad/s, B] and the modelled accelerations' integral ``integral`` (N, 6)
    (:func:`modelled_integral`): over the rows j..a with t_a - t_j <= the history (linear and angular: their own),
    d = (x_a - x_j) / (t_a - t_j) - (I_a - I_j) / (t_a - t_j), the mean measured minus the mean modelled
    acceleration (0 without an earlier row or with a history of 0; the angular measured part 0 with ``angular_trim``)."""
    anchors = np.asarray(anchors, dtype=int)
    parts = []
    if anchors.size == 1:  # the carried forecast's case, one anchor per input: the same operations on floats
        a = int(anchors.reshape(-1)[0])
        for history, measured, cols in ((observer.linear_s, vel_n, slice(0, 3)), (observer.angular_s, rates, slice(3, 6))):
            first = min(int(np.searchsorted(t, t[a] - history - 1e-9, side="left")), a)
            span = float(t[a] - t[first])
            if not (span > 0 and history > 0):
                parts.append(np.zeros((1, 3)))
                continue
            trimmed = cols.start == 3 and observer.angular_trim
            measured_mean = [0.0] * 3 if trimmed else [(x - y) / span for x, y in zip(measured[a].tolist(), measured[first].tolist())]
            modelled_mean = [(x - y) / span for x, y in zip(integral[a, cols].tolist(), integral[first, cols].tolist())]
            parts.append(np.array([[m - d for m, d in zip(measured_mean, modelled_mean)]]))
        return Disturbance(parts[0], parts[1])
    for history, measured, cols in ((observer.linear_s, vel_n, slice(0, 3)), (observer.angular_s, rates, slice(3, 6))):
        first = np.minimum(np.searchsorted(t, t[anchors] - history - 1e-9, side="left"), anchors)
        span = t[anchors] - t[first]
        ok = (span > 0) & (history > 0)
        safe = np.where(ok, span, 1.0)[:, None]
        measured_mean = (measured[anchors] - measured[first]) / safe
        if cols.start == 3 and observer.angular_trim:
            measured_mean = np.zeros_like(measured_mean)
        modelled_mean = (integral[anchors, cols] - integral[first, cols]) / safe
        parts.append(np.where(ok[:, None], measured_mean - modelled_mean, 0.0))
    return Disturbance(parts[0], parts[1])


def battery_voltage(p: PhysicsParameters, log: FlightLog) -> np.ndarray | None:
    """The log's battery voltage (N,) [V] when the battery term is on (DataError naming the file without one)."""
    if p.battery is None:
        return None
    if log.vbat is None:
        raise DataError(f"{log.meta.source}: the vehicle's battery term needs the battery voltage, and this flight has none "
                        f"(switch effects.battery off in the vehicle file)")
    return log.vbat


def rotor_commands(p: PhysicsParameters, log: FlightLog) -> np.ndarray:
    """(N, 4) the commands the rotors answer at each row of ``log``: delayed (:func:`delayed_commands`), then through
    the command path's terms with each row's measured voltage (:func:`~quad_modelling.core.physics.rotors.effective_commands`)."""
    return effective_commands(p, delayed_commands(p, log.u, log.t), battery_voltage(p, log))


def horizon_commands(p: PhysicsParameters, log: FlightLog, starts: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(S, H + 1, 4) the commands the rotors answer over each horizon ``rows`` (S, H + 1) from ``starts`` (S,): delayed,
    through the command path's terms with the anchor's battery voltage held (causal: no later voltage is used)."""
    voltage = battery_voltage(p, log)
    return effective_commands(p, delayed_commands(p, log.u, log.t)[rows], None if voltage is None else voltage[starts][:, None])


def anchor_state(p: PhysicsParameters, log: FlightLog, anchors: np.ndarray, observer: Observer = Observer(),
                 measured: np.ndarray | None = None) -> tuple[PhysicsState, Disturbance, np.ndarray]:
    """(start states, disturbances, rotor speeds (N, 4)) at ``anchors`` rows of ``log``, causally (module docstring).

    ``measured``: the log's :func:`~quad_modelling.core.preprocess.state_measurement` if already computed (only
    its raw columns are used: positions, velocities, angles, rates).
    """
    if measured is None:
        measured = state_measurement(log)
    commands = rotor_commands(p, log)
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
                 commands: np.ndarray, period_s: float, voltage: float | None = None):
        self.params = params
        self.voltage = voltage  # the anchor's battery voltage [V], held over the window (battery term)
        self.state = state
        self.disturbance = disturbance
        self.times = [float(x) for x in times]
        self.commands = [np.asarray(c, dtype=float).reshape(1, 4) for c in commands]
        self.period_s = period_s

    def _command_at(self, t_s: float) -> np.ndarray:
        """The command the rotors answer at ``t_s`` (:func:`~quad_modelling.core.physics.rotors.delayed_command_at`)."""
        return effective_commands(self.params, delayed_command_at(self.params, self.times, self.commands, t_s), self.voltage)

    def _forget(self) -> None:
        """Drop commands no later sample can need (keep the last one at or before t - δ)."""
        limit = self.times[-1] - self.params.delay + STAMP_TOLERANCE_S
        drop = 0
        while drop + 1 < len(self.times) and self.times[drop + 1] <= limit:
            drop += 1
        if drop:
            del self.times[:drop], self.commands[:drop]

    def given_rates(self, command: np.ndarray) -> np.ndarray | None:
        """Body rates (1, 3) [rad/s] given for the sample of ``command`` (a rate predictor's; the direct model's
        stream), or None: the physics integrates them."""
        return None

    def given_down_velocity(self) -> np.ndarray | None:
        """The velocity's down component (1,) [m/s] given for the sample whose rates :meth:`given_rates` just gave (the
        direct model's vertical map), or None: the physics integrates it."""
        return None

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        previous = self.times[-1]
        dt = t_s - previous
        if not dt > 0:
            raise DataError(f"physics stream: sample time {t_s:.6f} s is not after the previous {previous:.6f} s")
        rates_next = self.given_rates(command)
        self.state = step(self.params, self.state, self._command_at(previous), dt, self.disturbance, rates_next,
                          self.given_down_velocity())
        self.times.append(float(t_s))
        self.commands.append(np.asarray(command, dtype=float).reshape(1, 4))
        self._forget()
        return outputs(self.params, self.state, self._command_at(t_s), self.disturbance)[0]

    def push(self, command: np.ndarray) -> np.ndarray:
        return self.push_at(command, self.times[-1] + self.period_s)


class PhysicsPredictor(WindowByStream):
    """The ``physics`` model: window (:meth:`predict_window`), multi-step (:meth:`predict_horizons`) and live
    (:meth:`start_window`) forms, all causal (module docstring).

    ``observer``: the disturbance observer's histories (:class:`Observer`). In a window the history is limited
    to the warm rows.
    """

    def __init__(self, vehicle: VehicleConfig, observer: Observer | None = None, trim: TrimConfig | None = None,
                 name: str = "physics"):
        self.vehicle = vehicle
        self.params = PhysicsParameters.from_vehicle(vehicle)
        self.observer = observer or Observer.from_vehicle(vehicle)
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
        voltage = battery_voltage(self.params, warm)
        return measured, PhysicsStream(self.params, state, disturbance, warm.t, warm.u, period,
                                       None if voltage is None else float(voltage[-1]))



    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute open-loop predictions from each start row (IDSIA multi-step), causal."""
        return rollout(self.params, *self.horizon_inputs(segment, starts, horizon))

    def predict_horizons_of(self, parts: Sequence[tuple[FlightLog, np.ndarray]], horizon: int) -> list[np.ndarray]:
        """:meth:`predict_horizons` of each (segment, starts) of ``parts`` for the multi-step scores, whose groups hold no
        acceleration: the starts of all parts stepped as one batch (one rollout instead of one per segment: the
        per-step cost of numpy's small arrays is paid once), the acceleration columns NaN (no wrench evaluated for
        the outputs). The other columns are :meth:`predict_horizons`'s numbers (test)."""
        inputs = [self.horizon_inputs(segment, np.asarray(starts, dtype=int), horizon) for segment, starts in parts]
        if not inputs:
            return []
        states, disturbances, commands, intervals = zip(*inputs)
        state = PhysicsState(*(np.concatenate([getattr(s, f.name) for s in states]) for f in fields(PhysicsState)))
        disturbance = Disturbance(np.concatenate([d.linear_n for d in disturbances]),
                                  np.concatenate([d.angular_b for d in disturbances]))
        out = rollout(self.params, state, disturbance, np.concatenate(commands), np.concatenate(intervals), with_accelerations=False)
        return np.split(out, np.cumsum([len(dt) for dt in intervals])[:-1])

    def horizon_inputs(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> tuple:
        """(start states, disturbances, commands (S, H + 1, 4), sample intervals (S, H)) of :meth:`predict_horizons`."""
        starts = np.asarray(starts, dtype=int)
        if starts.size and (starts.min() < 0 or starts.max() + horizon >= len(segment)):
            raise DataError(f"{segment.meta.source}: multi-step starts + horizon {horizon} leave the segment")
        if segment.gyro_b is None:
            raise DataError(f"{segment.meta.source}: the physics model's multi-step form needs the gyro (body rates at each anchor)")
        state, disturbance, _ = anchor_state(self.params, segment, starts, self.observer)
        rows = starts[:, None] + np.arange(horizon + 1)[None, :]
        return state, disturbance, horizon_commands(self.params, segment, starts, rows), np.diff(segment.t)[rows[:, :-1]]
