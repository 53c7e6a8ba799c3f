r"""Carried-state forecasts: the receding-horizon mode's anchor advanced by one row per input, then rolled out h steps;
and the compiled one physics step of the live window streams.

The live receding-horizon mode (:class:`~quad_modelling.core.models.streaming.RecedingHorizon`) predicts from every
anchor s, h steps ahead. A model's offline multi-step form (``predict_horizons``) derives its anchor from all the
rows up to s: rotor speeds and the disturbance observer's means (physics, hybrid), the 1 s trims and the motor
filter (greybox), the delayed outputs and commands (NARX). Re-running it at every input over a history costs the
whole history per input. A *carried forecast* holds exactly that anchor and advances it by the rows that came in
since the previous anchor (one per input), then rolls the model out from it:

* :meth:`CarriedForecast.add` ``(rows, first)``: the rows ``first ..`` of the FlightLog ``rows`` are new, in time
  order after every row added before (rows before ``first`` were added already: context for the yaw unwrap);
* :meth:`CarriedForecast.predict` ``(t_after, u_after, rows=None)``: (h + 1, 18) absolute prediction from the last
  row added (row 0) over the h rows after it stamped ``t_after`` (h,) [s] with the commands ``u_after`` (h, 4), as
  the offline multi-step form gives it; ``rows``: only these rows of it (a forecast publishes row h, and checks it
  against row 0: the physics models then output 2 states instead of h + 1).

Per model (:func:`~quad_modelling.core.live.forms.carried_forecast` picks the form; a model without one is predicted
by the history re-run; the direct model's: :mod:`~quad_modelling.core.live.direct`):

* **physics, hybrid** (:class:`PhysicsForecast`): carried are the logged commands of the last δ (the command delay),
  the rotor speeds (the exact lag stepped row by row: :func:`~quad_modelling.core.physics.rotors.rotor_step`), the
  unwrapped yaw and the observer's rows of the last ``max(linear_s, angular_s)`` (time, velocity, rates and the
  integral of the model's acceleration, with the hybrid's net correction: its observer subtracts the net's mean, which
  is the mean of the sum; :func:`~quad_modelling.core.models.physics.modelled_integral` one term per row), whose means
  are :func:`~quad_modelling.core.models.physics.disturbance_means` itself, and the hybrid's command filters' states.
  The h-step rollout is the one physics step (:func:`~quad_modelling.core.physics.rigid_body.step`, with the hybrid's
  correction) built once as a CasADi Function by the export (:func:`~quad_modelling.core.export.casadi_model.casadi_functions`:
  ``F_disturbed``; with command filters their states beside x, :func:`~quad_modelling.core.export.casadi_model.filtered_step`) and chained h times
  (:meth:`~quad_modelling.core.export.casadi_model.Step.chained`, compiled to C where a C compiler is found:
  :func:`~quad_modelling.core.export.casadi_model.compile_step`): one call instead of h numpy steps of a batch of
  one (12 ms for h = 50 here). The accelerations of the states output (and of each row added to the observer) are
  the export's continuous dynamics ``f_disturbed`` compiled the same way (:func:`~quad_modelling.core.live.compiled.model_derivative`), the same
  equations as :func:`~quad_modelling.core.models.physics.outputs` and
  :meth:`~quad_modelling.core.models.hybrid.HybridModel.outputs` (~10 us a state against ~150 us in numpy).
* **greybox** (:class:`GreyboxForecast`): carried are the running sums of the commands and of the measured
  roll/pitch (the 1 s trailing means, :func:`~quad_modelling.core.preprocess.trailing_means`' own arithmetic), the
  motor filter's state (:func:`~quad_modelling.core.discretise.motor_thrusts`, its recursion) and the unwrapped
  yaw; the rollout is :func:`~quad_modelling.core.models.greybox.linear_horizons` unrolled into two matrix products
  (:func:`~quad_modelling.core.models.greybox.lifted_horizons`, built once per h) evaluated for the rows asked only:
  the outputs to rounding, 2 products per row instead of 2 (h + 1) for every row. The sample period is the
  receding horizon's dt (the offline form takes the segment's median step: the same on a regular timer).
* **NARX** (:class:`NarxForecast`): its memory is finite: the last max(max(D_u) + 1, n_y) rows of commands and
  measured outputs; the h closed-loop steps are the model's own step built as a CasADi Function and chained
  (:func:`~quad_modelling.core.export.casadi_model.narx_step`), the expansion to 18 variables :func:`~quad_modelling.core.models.narx.expand_horizons`.

Equality with the offline multi-step form on all the rows of the time base (test:
``test/core/live/test_forecast.py``): to rounding, 1e-9 and tighter. What differs is the order of float
operations only: the rotor lag stepped row by row instead of the prefix scan, the observer's integral summed over
its rows instead of the segment, the CasADi step instead of numpy's (3e-15 over 50 steps), the yaw unwrapped by
differences. The physics forms need the gyro (as their multi-step forms); the greybox's carried form does too (a
flight without one gets its rates from differentiated attitudes over past rows: the history re-run does that).

The compiled steps themselves (built once per model, with the window mode's) are
:mod:`~quad_modelling.core.live.compiled`'s.
"""

from __future__ import annotations

from collections import deque
from typing import Protocol

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.export.casadi_model import Step, output_row, state_vector
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.live.compiled import CompiledDerivative
from quad_modelling.core.models import physics
from quad_modelling.core.models.greybox import MEASURED_STATE_COLUMNS, GreyboxPredictor, lifted_horizons
from quad_modelling.core.models.hybrid import HybridModel, filter_inputs, filtered_commands
from quad_modelling.core.models.narx import OUTPUT_COLUMNS, OUTPUTS, NarxPredictor, expand_horizons
from quad_modelling.core.models.physics import Disturbance, Observer
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import continued_yaw
from quad_modelling.core.physics.rotors import (
    STAMP_TOLERANCE_S,
    delayed_command_at,
    delayed_commands,
    effective_commands,
    rotor_step,
    steady_rotor_speed,
)
from quad_modelling.core.variables import VARIABLES
from quad_modelling.errors import DataError

OBSERVER_MARGIN_S = 1e-9
"""The observer's rows start at the first row with t >= t_a - history - this [s] (its ``searchsorted``)."""


class CarriedForecast(Protocol):
    """A model's anchor carried from row to row (module docstring)."""

    def add(self, rows: FlightLog, first: int) -> None:
        ...

    def predict(self, t_after: np.ndarray, u_after: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        ...


class UnwrappedYaw:
    """The continuous yaw of rows added in order: the first rows' as their log unwraps it, then each later row the
    previous one's plus the step between them in its log (logs unwrap their rows: ``measurement_log``)."""

    def __init__(self) -> None:
        self.last = None  # continuous yaw of the last row added [rad]

    def add(self, rows: FlightLog, first: int) -> np.ndarray:
        """(n,) continuous yaw [rad] of rows ``first ..`` of ``rows`` (``first`` > 0 once a row was added: the row
        before them is the context)."""
        yaw = frames.unwrap_angles(rows.euler[:, 2])
        out = np.empty(len(rows) - first)
        for i in range(first, len(rows)):
            self.last = float(yaw[i]) if self.last is None else self.last + float(yaw[i] - yaw[i - 1])
            out[i - first] = self.last
        return out


def _require_gyro(rows: FlightLog, what: str) -> None:
    if rows.gyro_b is None:
        raise DataError(f"{rows.meta.source}: the carried forecast of {what} needs the gyro (body rates at each anchor)")


class _Rows:
    """Rows of fixed width kept in one growing numpy array; :meth:`drop_before` forgets the oldest."""

    def __init__(self, width: int, capacity: int = 256):
        self.data = np.empty((capacity, width))
        self.start = self.stop = 0

    def append(self, values: np.ndarray) -> None:
        if self.stop == len(self.data):
            kept = self.stop - self.start
            if kept * 2 > len(self.data):
                self.data = np.concatenate([self.data, np.empty_like(self.data)])
            self.data[:kept] = self.data[self.start:self.stop]
            self.start, self.stop = 0, kept
        self.data[self.stop] = values
        self.stop += 1

    def view(self) -> np.ndarray:
        return self.data[self.start:self.stop]

    def last(self) -> np.ndarray | None:
        """The last row appended (None before the first, or once every row was dropped)."""
        return self.data[self.stop - 1] if self.stop > self.start else None

    def drop_before(self, count: int) -> None:
        self.start += count


def newest_first(history: np.ndarray | None, added: np.ndarray, length: int) -> np.ndarray:
    """The last ``length`` rows newest first: ``added`` (n, ...) in time order after ``history`` (newest first; None
    before any row: the first added row stands for the rows before it, as row 0 does in the models' batch inputs)."""
    if history is None:
        history = np.repeat(added[:1], length, axis=0)
    return np.concatenate([added[::-1], history])[:length]


class PhysicsForecast:
    """Physics or hybrid model (``hybrid`` given), carried (module docstring)."""

    def __init__(self, step: Step, derivative: Step, params: PhysicsParameters, observer: Observer, steps: int,
                 hybrid: HybridModel | None = None):
        self.params, self.observer, self.hybrid, self.steps = params, observer, hybrid, steps
        self.derivative, self.history_s = CompiledDerivative(derivative), max(observer.linear_s, observer.angular_s)
        rollout = step.chained(steps)  # x_{k+1} = F(x_k, u_k, dt_k, d), k < h: (22 [+ 4 M filters' states], h)
        # evaluated in place on these arrays (CasADi is column-major: an (n, h) argument is an (h, n) C array)
        width = step.function.size1_in(0)
        self._x0, self._u = np.zeros(width), np.zeros((steps, step.function.size1_in(1)))
        self._dt, self._d, self._after = np.zeros(steps), np.zeros((steps, 6)), np.zeros((steps, width))
        self._buffer, self._evaluate = rollout.buffer()
        for i, array in enumerate((self._x0, self._u, self._dt, self._d)):
            self._buffer.set_arg(i, memoryview(array))
        self._buffer.set_res(0, memoryview(self._after))
        self.reset()

    def reset(self) -> None:
        """A new time base: forget every row."""
        self.times: list[float] = []  # logged commands of the last δ (and the one before): the delay's table
        self.commands = _Rows(4)
        self.observer_rows = _Rows(1 + 3 + 3 + 6)  # t, v_N, ω, the integral of the modelled (dv_N/dt, dω/dt) incl. the net's correction
        self.modelled = None  # the modelled accelerations (6,) at the last row: the integral's next term
        self.yaw = UnwrappedYaw()
        self.rotor = None  # rotor speeds at the last row [rad/s]
        self.rotor_command = None  # the effective command the rotors answered at the last row
        self.last_t = None  # time of the last row [s]
        self.anchor = None  # (t, pos, vel, euler with continuous yaw, R, rates, rotor, logged u, voltage) of the last row
        self.filtered = None  # the hybrid's command filters' states (M, 4) at the last row
        self._disturbance = None  # disturbance() of the last row, once asked

    def add(self, rows: FlightLog, first: int) -> None:
        _require_gyro(rows, "the physics model")
        p, n = self.params, len(rows) - first
        self.times += rows.t[first:].tolist()
        for u in rows.u[first:]:
            self.commands.append(u)
        commands = self.commands.view()
        delayed = np.array([delayed_command_at(p, self.times, commands, t) for t in rows.t[first:].tolist()])
        voltage = physics.battery_voltage(p, rows)
        voltage = None if voltage is None else voltage[first:]
        effective = effective_commands(p, delayed, voltage)
        yaw = self.yaw.add(rows, first)
        rotor = np.empty((n, 4))
        for i in range(n):  # rotor_speeds' recursion: Ω_0 steady at the first command, then the exact lag per interval
            t_i = float(rows.t[first + i])
            if self.rotor is None:
                rotor[i] = steady_rotor_speed(p, effective[i])
            else:
                rotor[i] = rotor_step(p, self.rotor, self.rotor_command, t_i - self.last_t)
            self.rotor, self.rotor_command, self.last_t = rotor[i], effective[i], t_i
        euler = rows.euler[first:].copy()
        euler[:, 2] = yaw
        rot = frames.euler_ned_to_matrix(euler)
        pos, vel, rates = rows.pos_n[first:], rows.vel_n[first:], rows.gyro_b[first:]
        filtered = self._filters_at(rows, first)
        no_disturbance = np.zeros(6)
        for i in range(n):  # the modelled accelerations (the hybrid's with its correction): the compiled f at each row
            u = self._inputs(delayed[i], rows.u[first + i], None if voltage is None else voltage[i], None if filtered is None else filtered[i])
            xdot = self.derivative(state_vector(pos[i], vel[i], rot[i], rates[i], rotor[i]), u, no_disturbance)
            t_i = float(rows.t[first + i])
            last = self.observer_rows.last()
            # physics.modelled_integral's next term: I_k = I_{k-1} + a_{k-1} (t_k - t_{k-1})
            integral = np.zeros(6) if last is None else last[7:13] + self.modelled * (t_i - last[0])
            self.modelled = np.concatenate([xdot[3:6], xdot[15:18]])
            self.observer_rows.append(np.concatenate([[t_i], vel[i], rates[i], integral]))
        t_last = float(rows.t[-1])
        self.anchor = (t_last, pos[-1].copy(), vel[-1].copy(), euler[-1], rot[-1], rates[-1].copy(), rotor[-1].copy(),
                       rows.u[-1].copy(), None if voltage is None else float(voltage[-1]))
        self._forget(t_last)
        self._disturbance = None

    def _filters_at(self, rows: FlightLog, first: int) -> np.ndarray | None:
        """The hybrid's command filters' states (n, M, 4) at rows ``first ..`` of ``rows``, from the last row added (the
        context row; a time base's first row: settled on its command); None without filters."""
        if not (self.hybrid and self.hybrid.filters):
            return None
        begin = first if self.filtered is None else first - 1
        filtered = filtered_commands(rows.u[begin:], rows.t[begin:], self.hybrid.filters, self.filtered)[first - begin:]
        self.filtered = filtered[-1]
        return filtered

    def _forget(self, t_last: float) -> None:
        """Drop the commands no later delay can need (keep the last at or before t - δ) and the observer's rows no
        later anchor's history reaches."""
        limit = t_last - self.params.delay + STAMP_TOLERANCE_S
        drop = 0
        while drop + 1 < len(self.times) and self.times[drop + 1] <= limit:
            drop += 1
        if drop:
            del self.times[:drop]
            self.commands.drop_before(drop)
        t = self.observer_rows.view()[:, 0]
        self.observer_rows.drop_before(int(np.searchsorted(t, t_last - self.history_s - OBSERVER_MARGIN_S, side="left")))

    def disturbance(self) -> Disturbance:
        """The observer's constant disturbance at the last row (:func:`~quad_modelling.core.models.physics.disturbance_means`)."""
        if self._disturbance is None:  # every forecast from one row holds it (held inputs re-forecast without a row)
            rows = self.observer_rows.view()
            self._disturbance = physics.disturbance_means(rows[:, 0], rows[:, 1:4], rows[:, 4:7], rows[:, 7:13],
                                                          np.array([len(rows) - 1]), self.observer)
        return self._disturbance

    def predict(self, t_after: np.ndarray, u_after: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        p, h = self.params, len(t_after)
        if h != self.steps:
            raise ValueError(f"carried physics forecast built for {self.steps} steps, asked for {h}")
        t_s, pos, vel, euler, rot_s, rates, rotor, u_s, voltage = self.anchor
        t = np.concatenate([[t_s], t_after])
        logged = np.concatenate([u_s[None, :], u_after])
        delayed = delayed_commands(p, np.concatenate([self.commands.view(), u_after]), np.concatenate([self.times, t_after]))[-(h + 1):]
        disturbance = self.disturbance()
        self._u[:, 0:4] = delayed[:h]  # the step's input layout: delayed commands, logged ones (hybrid), voltage
        if self.hybrid is not None:
            self._u[:, 4:8] = logged[:h]
        if p.battery is not None:
            self._u[:, -1] = voltage
        x0 = self._x0
        x0[0:3], x0[3:6], x0[6:15], x0[15:18], x0[18:22] = pos, vel, rot_s.ravel(), rates, rotor
        if self.filtered is not None:  # the filters' states chained beside x (filtered_step)
            x0[22:] = self.filtered.ravel()
        self._dt[:], self._d[:, 0:3], self._d[:, 3:6] = np.diff(t), disturbance.linear_n, disturbance.angular_b
        self._evaluate()
        x = np.concatenate([x0[None, :], self._after])  # (h + 1, 22 [+ 4 M])
        filtered = None if self.filtered is None else x[:, 22:].reshape(h + 1, -1, 4)
        yaw = continued_yaw(float(euler[2]), x[:, 6:15].reshape(-1, 3, 3))
        rows = np.arange(h + 1) if rows is None else np.asarray(rows)
        d = np.concatenate([disturbance.linear_n[0], disturbance.angular_b[0]])
        return np.array([output_row(x[r], self.derivative(x[r, :22], self._inputs(delayed[r], logged[r], voltage,
                                                                             None if filtered is None else filtered[r]), d), yaw[r])
                         for r in rows.tolist()])

    def _inputs(self, delayed: np.ndarray, logged: np.ndarray, voltage: float | None, filtered: np.ndarray | None = None) -> np.ndarray:
        """The export's input layout of one sample: the delayed command, the logged one (hybrid), the inputs of the
        command filters at their states ``filtered`` (M, 4) (hybrid), the voltage (battery)."""
        parts = [delayed] if self.hybrid is None else [delayed, logged] if filtered is None else [delayed, logged, filter_inputs(filtered, logged)]
        return np.concatenate([*parts, [voltage]] if self.params.battery is not None else parts)


class GreyboxForecast:
    """The linear greybox, carried (module docstring; the anchor of :meth:`GreyboxPredictor.predict_horizons`)."""

    def __init__(self, predictor: GreyboxPredictor, period_s: float):
        self.model = predictor.model.discretise(period_s, predictor.discretisation)
        self.trim_rows = max(1, int(round(predictor.trim.trim_s * (1.0 / period_s))))
        self.pole, self.gain = float(self.model.ad[12, 12]), float(self.model.bd[12, 0])
        self._lifts: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.reset()

    def reset(self) -> None:
        self.u_ref = self.attitude_ref = None  # the first row's command and roll/pitch (trailing_means' offset)
        self.u_totals: deque[np.ndarray] = deque(maxlen=self.trim_rows + 1)
        self.attitude_totals: deque[np.ndarray] = deque(maxlen=self.trim_rows + 1)
        self.motor = None  # the motor filter's state (lfilter's z)
        self.thrust = None  # filtered thrust of the last row, before the trim
        self.yaw = UnwrappedYaw()
        self.anchor = None  # the measured state (12) of the last row and its command

    def add(self, rows: FlightLog, first: int) -> None:
        _require_gyro(rows, "the greybox")
        yaw = self.yaw.add(rows, first)
        for i in range(first, len(rows)):
            u, attitude = rows.u[i], rows.euler[i, 0:2]
            if self.u_ref is None:
                self.u_ref, self.attitude_ref = u.copy(), attitude.copy()
                self.u_totals.append(np.zeros(4))
                self.attitude_totals.append(np.zeros(2))
                self.motor = np.zeros(4)  # steady state of the first (reference-removed) command: zero
            self.u_totals.append(self.u_totals[-1] + (u - self.u_ref))
            self.attitude_totals.append(self.attitude_totals[-1] + (attitude - self.attitude_ref))
            x = u - self.u_ref  # lfilter([0, g], [1, -p]) of the commands minus the reference, one row
            self.thrust = 0.0 * x + self.motor
            self.motor = self.gain * x - (-self.pole) * self.thrust
        measured = np.empty(len(VARIABLES))
        measured[0:3], measured[3:6], measured[9:12], measured[12:15] = rows.pos_n[-1], rows.vel_n[-1], rows.euler[-1], rows.gyro_b[-1]
        measured[11] = yaw[-1]
        self.anchor = (measured[MEASURED_STATE_COLUMNS], rows.u[-1].copy())

    def predict(self, t_after: np.ndarray, u_after: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        count = len(self.u_totals) - 1
        input_trim = self.u_ref + (self.u_totals[-1] - self.u_totals[0]) / count
        attitude_trim = self.attitude_ref + (self.attitude_totals[-1] - self.attitude_totals[0]) / count
        thrusts = self.thrust - (input_trim - self.u_ref) * (self.gain / (1.0 - self.pole))
        state, u_s = self.anchor
        x = np.concatenate([state, thrusts])
        x[6:8] -= attitude_trim
        u = np.concatenate([u_s[None, :], u_after]) - input_trim
        g_x, g_u = self._lifted(len(u) - 1)
        rows = range(len(u)) if rows is None else np.asarray(rows).tolist()
        u_stacked = u.ravel()
        out = np.array([g_x[r] @ x + g_u[r] @ u_stacked for r in rows])  # row by row: a row's numbers whatever is asked
        out[:, 9:11] += attitude_trim
        return out

    def _lifted(self, steps: int) -> tuple[np.ndarray, np.ndarray]:
        """:func:`~quad_modelling.core.models.greybox.lifted_horizons` for ``steps``, built once per ``steps``."""
        if steps not in self._lifts:
            self._lifts[steps] = lifted_horizons(self.model, steps)
        return self._lifts[steps]


class NarxForecast:
    """NARX, carried: its last rows (module docstring). The h closed-loop steps of
    :meth:`~quad_modelling.core.models.narx.NarxModel.simulate_from_starts` (the nets fed back their own outputs)
    run as one CasADi Function built by the model's own step (:meth:`~quad_modelling.core.models.narx.NarxModel.net_output`
    of :func:`~quad_modelling.core.models.narx.sigmoid`, fed symbolic arrays) chained h times; the input part of the
    nets, ``W_u`` times the lagged commands, and the expansion to 18 variables are the model's numpy code."""

    def __init__(self, predictor: NarxPredictor, period_s: float, steps: int, step: Step):
        model = predictor.model
        if abs(period_s - model.dt) > 0.01 * model.dt:
            raise DataError(f"receding horizon: sampled every {period_s * 1e3:.3f} ms but the {model.kind} model was trained "
                            f"at {model.dt * 1e3:.3f} ms")
        self.model, self.steps = model, steps
        self.keep = max(max(model.config.input_delays) + 1, model.config.output_delays, 2)
        n_y, hidden = model.config.output_delays, model.config.hidden
        self._feedback, self._z_u = np.zeros((len(OUTPUTS), n_y)), np.zeros((steps, len(OUTPUTS), hidden))
        self._outputs = np.zeros((steps, len(OUTPUTS)))
        self._buffer, self._evaluate = step.chained(steps).buffer()
        self._buffer.set_arg(0, memoryview(self._feedback))
        self._buffer.set_arg(1, memoryview(self._z_u))
        self._buffer.set_res(1, memoryview(self._outputs))
        self._states = np.zeros((steps, len(OUTPUTS) * n_y))
        self._buffer.set_res(0, memoryview(self._states))
        self.reset()

    def reset(self) -> None:
        self.rows: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=self.keep)  # (command, measured (18)) per row
        self.yaw = UnwrappedYaw()

    def add(self, rows: FlightLog, first: int) -> None:
        _require_gyro(rows, "NARX")
        yaw = self.yaw.add(rows, first)
        for i in range(first, len(rows)):
            measured = np.zeros(len(VARIABLES))  # positions, velocities, angles, rates: what the rollout reads
            measured[0:3], measured[3:6], measured[9:12], measured[12:15] = rows.pos_n[i], rows.vel_n[i], rows.euler[i], rows.gyro_b[i]
            measured[11] = yaw[i - first]
            self.rows.append((rows.u[i].copy(), measured))

    def predict(self, t_after: np.ndarray, u_after: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        model, h, n_y = self.model, len(t_after), self.model.config.output_delays
        if h != self.steps:
            raise ValueError(f"carried NARX forecast built for {self.steps} steps, asked for {h}")
        s = len(self.rows) - 1
        u = np.concatenate([np.array([row[0] for row in self.rows]), u_after])
        measured = np.array([row[1] for row in self.rows])
        y = model.normalise_outputs(measured[:, OUTPUT_COLUMNS])
        padded = np.concatenate([np.repeat(y[:1], n_y - 1, axis=0), y])  # rows before the first repeat it (as offline)
        self._feedback[:] = padded[-n_y:].T  # y(s - n_y + 1 .. s), oldest first
        self._z_u[:] = model.input_part(u, s + 1)  # the h rows after the anchor
        self._evaluate()
        v = np.concatenate([measured[-1:, OUTPUT_COLUMNS], model.denormalise_outputs(self._outputs)])
        out = expand_horizons(model, measured, np.array([s]), v[None])[0]
        return out if rows is None else out[rows]
