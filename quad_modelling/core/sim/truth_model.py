r"""The ``truth`` model: the truth simulator's own physics as a predictor, the perfect-model floor (DESIGN 9).

On a simulated log it predicts with what flew the flight: the simulator's rigid body, rotors and effect forms
(:class:`~quad_modelling.core.sim.dynamics.QuadDynamics` with the log's effects switched on), its true constants
and parameters (the log's notes, :func:`~quad_modelling.core.sim.params.sim_params_from_notes`), integrated as the
simulator integrates (classical RK4 at ``physics_rate``, 1 kHz, quaternion renormalised), fed the logged commands
through the simulator's command path:

* **delay** (``input_delay`` on): the ESCs answer at time :math:`\tau` the command logged last at or before
  :math:`\tau - \delta`, looked up at every physics step (:meth:`TruthDynamics.esc_commands`);
* **ESC speed map** with the per-motor gains (``motor_imbalance``) and the **battery** scaling
  (:meth:`QuadDynamics.omega_command <quad_modelling.core.sim.dynamics.QuadDynamics.omega_command>`):
  :math:`\Omega_{c,i} = g_i k_u \max(u_i - u_0, 0)\, V / V_{ref}`, with V the mean logged voltage over the last
  :data:`VOLTAGE_HISTORY_S` before the anchor (``battery`` on; V_ref off, as the simulator);
* **motor lag** (``motor_lag`` on): :math:`\dot\Omega = (\Omega_c - \Omega)/\tau_m` in the state; off: the rotors
  jump to :math:`\Omega_c` with the reaction impulse on r, as the simulator applies it;
* **wind** (``wind`` on): the seed's own wind series (:func:`~quad_modelling.core.sim.simulate.wind_series`),
  read at the log's time as the simulator's time (t = 0 at power-up, as ``simulate`` writes the log).

Anchored as the ``physics`` model anchors (:mod:`quad_modelling.core.models.physics`): a prediction from row a
starts from the raw measured row a (motion-capture position, velocity and attitude, gyro rates), the rotor speeds
are the command path run over the logged commands up to a (from the steady speed of the first command,
:meth:`TruthDynamics.rotor_history`). The physics model's constant-disturbance
:class:`~quad_modelling.core.models.physics.Observer` (its means:
:func:`~quad_modelling.core.models.physics.observed_disturbance`) is there with ``truth:L,A`` but off by default
(:data:`NO_OBSERVER`): the truth has no model error for it to absorb, only noise and the closed loop's recent
motion to take in. Three forms, as every model: window (:meth:`TruthPredictor.predict_window`, by the live form),
multi-step (:meth:`TruthPredictor.predict_horizons`, vectorised over the starts with
:attr:`~quad_modelling.core.sim.dynamics.QuadDynamics.batch_derivative`) and live
(:meth:`TruthPredictor.start_window` / :class:`TruthStream`, the scalar derivative the simulator runs); they give
the same numbers (the batch derivative is the scalar one on arrays, bit for bit).

Even the truth is not exact: the stabiliser commands at 250 Hz and the log keeps 100 Hz of them (held between
log rows here), the start state is measured (motion-capture noise, gyro bias), the voltage is the logged, noisy one.

Where it lives: here, with the simulator it runs. It imports the models' anchoring (core/models: the observer,
the live-window helper); core/models never imports core/sim: the registry knows the ``truth`` spec as a plug-in
module it imports by name on first use (:data:`~quad_modelling.core.models.registry.PLUGIN_MODULES`), and this
module registers its factory. Specs: ``truth`` (the notes of the log predicted), ``truth:L,A`` (with the
observer's histories [s]) and ``truth:NOTES.json[,L,A]`` (the notes from a JSON file, for the live node, whose
windows carry no notes; ``run-bag`` writes it from the bag). A flight without simulator notes is refused in one line
naming it (:meth:`TruthPredictor.check_flight`, which ``evaluate`` and ``run-bag`` call before any window).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from quad_modelling.core import frames
from quad_modelling.core.flight_log import GYRO_FULL_SCALE, FlightLog
from quad_modelling.core.models.physics import Disturbance, Observer, PhysicsStream, observed_disturbance
from quad_modelling.core.physics.rigid_body import MAX_SPEED_MPS
from quad_modelling.core.physics.rotors import STAMP_TOLERANCE_S, first_order_scan
from quad_modelling.core.models.registry import register_model
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.preprocess import TrimConfig, state_measurement, trim_prediction
from quad_modelling.core.sim.dynamics import QuadDynamics
from quad_modelling.core.sim.params import SimParams, sim_params_from_notes
from quad_modelling.core.sim.simulate import wind_series
from quad_modelling.core.variables import VARIABLES
from quad_modelling.errors import ConfigError, DataError

NO_OBSERVER = Observer(0.0, 0.0)
"""The truth model's default: no disturbance observer. The model has no error for it to take out, only the
measurement noise and the closed loop's motion over its history to take in: on the held-out effect-free LinkQuad
flights of ``bench/results/truth_floor.md`` (trial seeds 4711, 31337) the physics model's default observer (0.5 s
linear, 0.5 s angular trim) takes the truth's SimErr ratio to naive from 0.46 / 0.37 to 0.65 / 0.55 on velocity and
from 0.13 / 0.12 to 0.97 / 1.00 on angular velocity."""

VOLTAGE_HISTORY_S = 0.5
"""History of the logged battery voltage averaged at an anchor [s]: 50 rows at 100 Hz take the ADC noise (10 mV)
down to ~1.4 mV; the pack changes over minutes."""


def _limit(vx, vy, vz, limit: float):
    """(vx, vy, vz) scaled down to norm ``limit`` where longer (floats or arrays)."""
    norm = np.sqrt(vx * vx + vy * vy + vz * vz)
    scale = np.where(norm > limit, limit / np.maximum(norm, 1e-300), 1.0)
    if np.ndim(scale) == 0:
        scale = float(scale)
    return vx * scale, vy * scale, vz * scale


class TruthDynamics:
    """The simulator of one log (module docstring): ``params`` and ``effects`` as the log's notes say."""

    def __init__(self, params: SimParams, effects, seed: int = 0, duration: float = 0.0):
        self.params = params
        self.dynamics = QuadDynamics(params, effects)
        self.effects = self.dynamics.effects
        self.delay = params.input_delay if "input_delay" in self.effects else 0.0
        self.lag = "motor_lag" in self.effects
        self.battery = "battery" in self.effects
        self.reference_voltage = params.battery.reference_voltage
        self.rate = params.physics_rate
        self.wind = wind_series(params, self.effects, seed, duration) if "wind" in self.effects else None
        self.impulse = self.dynamics.prop_inertia / float(self.dynamics.inertia[2])
        self.yaw_signs = [float(v) for v in self.dynamics.yaw_signs]

    @classmethod
    def from_notes(cls, notes: dict, where: str) -> TruthDynamics:
        """The simulator that wrote a log with ``notes`` (DataError naming ``where`` for a log without them)."""
        params = sim_params_from_notes(notes, where)
        try:
            return cls(params, tuple(notes["effects"]), int(notes["seed"]), float(notes["pilot"]["duration"]))
        except (KeyError, TypeError, ValueError) as err:
            raise DataError(f"{where}: simulator notes lack the effects, seed or pilot duration ({err})") from err

    # ---------------------------------------------------------------- command path
    def esc_commands(self, times: np.ndarray, log_t: np.ndarray, log_u: np.ndarray) -> np.ndarray:
        """(B, 4) commands the ESCs answer at ``times`` (B,) [s]: the last logged (``log_t``, ``log_u``) at or before
        t - δ (the first before the log starts)."""
        rows = np.searchsorted(log_t, np.asarray(times) - self.delay + STAMP_TOLERANCE_S, side="right") - 1
        return log_u[np.maximum(rows, 0)]

    def voltages(self, log: FlightLog) -> np.ndarray:
        """(N,) battery voltage the ESC map uses at each row [V]: the mean logged voltage over the last
        :data:`VOLTAGE_HISTORY_S` up to the row (``battery`` on), else V_ref. Causal."""
        if not self.battery:
            return np.full(len(log), self.reference_voltage)
        if log.vbat is None:
            raise DataError(f"{log.meta.source}: the truth model needs the battery voltage (the simulated flight has "
                            f"the battery effect on) and this log has none")
        first = np.searchsorted(log.t, log.t - VOLTAGE_HISTORY_S - 1e-9, side="left")
        total = np.concatenate([[0.0], np.cumsum(log.vbat)])
        rows = np.arange(len(log))
        return (total[rows + 1] - total[first]) / (rows + 1 - first)

    def substeps(self, dt) -> int:
        """Physics steps in a sample interval of ``dt`` [s] (the largest of a batch): the simulator's rate."""
        return max(1, int(math.ceil(float(np.max(dt)) * self.rate - 1e-6)))

    def rotor_history(self, log: FlightLog) -> np.ndarray:
        """(N, 4) rotor speeds [rad/s] at each row at the reference voltage (scale by V / V_ref: the map is linear in
        V), the command path run over the logged commands from the steady speed of the first one; row k reads
        commands of rows <= k only. Exact first-order lag per physics step (the simulator's RK4 of it agrees to
        ~1e-12)."""
        t, u = log.t, log.u
        steady = self.dynamics.omega_commands(self.esc_commands(t, t, u), self.reference_voltage)
        if not self.lag or len(log) < 2:
            return steady
        dt = np.diff(t)
        counts = np.maximum(1, np.ceil(dt * self.rate - 1e-6).astype(int))
        interval = np.repeat(np.arange(len(dt)), counts)
        first_of = np.concatenate([[0], np.cumsum(counts)[:-1]])
        h = (dt / counts)[interval]
        tau = t[interval] + (np.arange(len(interval)) - first_of[interval]) * h
        target = self.dynamics.omega_commands(self.esc_commands(tau, t, u), self.reference_voltage)
        decay = np.exp(-h / self.params.motor_time_constant)[:, None] * np.ones((1, 4))
        gain, offset = first_order_scan(decay, (1.0 - decay) * target)
        after = gain * steady[0] + offset
        out = np.empty_like(steady)
        out[0] = steady[0]
        out[1:] = after[np.cumsum(counts) - 1]
        return out

    # ---------------------------------------------------------------- the rollout
    def wind_at(self, times):
        """Air velocity in N at ``times`` [s] (simulator time): three scalars (zeros) or three (B,) arrays."""
        if self.wind is None:
            return (0.0, 0.0, 0.0)
        ticks = np.clip((np.asarray(times) * self.params.control.rate + 1e-6).astype(int), 0, len(self.wind) - 1)
        w = self.wind[ticks]
        return tuple(w[..., i] for i in range(3))

    def derivative(self, disturbance: Disturbance, batch: bool):
        """The simulator's derivative plus the held disturbance accelerations (linear in N, angular in B)."""
        base = self.dynamics.batch_derivative if batch else self.dynamics.derivative
        lin, ang = disturbance.linear_n, disturbance.angular_b
        if not batch:
            lin, ang = [float(x) for x in lin[0]], [float(x) for x in ang[0]]
        else:
            lin, ang = lin.T, ang.T

        def with_disturbance(s, wc, wind):
            d = base(s, wc, wind)
            d[3], d[4], d[5] = d[3] + lin[0], d[4] + lin[1], d[5] + lin[2]
            d[10], d[11], d[12] = d[10] + ang[0], d[11] + ang[1], d[12] + ang[2]
            return d

        return with_disturbance

    def targets(self, times, commands_at, voltage, batch: bool):
        """Ω_c at ``times`` through the command path: four (B,) arrays (batch) or four floats."""
        target = self.dynamics.omega_commands(commands_at(np.atleast_1d(times)), voltage)
        return [target[:, i] for i in range(4)] if batch else target[0].tolist()

    def advance(self, s: list, t0, dt, commands_at, voltage, derivative, batch: bool) -> list:
        """The state ``s`` (17 entries: floats, or (B,) arrays with ``batch``) from time ``t0`` over ``dt`` [s],
        RK4 at the physics rate under the commands ``commands_at(times) -> (B, 4)`` answers; speed and rates limited
        as the physics model's (an open-loop window stays finite)."""
        n = self.substeps(dt)
        h = dt / n
        step = self.dynamics.step
        for i in range(n):
            tau = t0 + i * h
            target = self.targets(tau, commands_at, voltage, batch)
            if not self.lag:  # the simulator's apply_commands: the rotors jump, the body takes the reaction
                s = list(s)
                s[12] = s[12] + self.impulse * sum(g * (new - old) for g, new, old in zip(self.yaw_signs, target, s[13:17]))
                s[13:17] = target
            s, _ = step(s, target, self.wind_at(tau), h, derivative)
        s = list(s)
        s[3:6] = _limit(s[3], s[4], s[5], MAX_SPEED_MPS)
        s[10:13] = _limit(s[10], s[11], s[12], GYRO_FULL_SCALE)
        return s

    def outputs(self, s: list, t, commands_at, voltage, disturbance: Disturbance, yaw: np.ndarray,
                batch: bool) -> tuple[np.ndarray, np.ndarray]:
        """((B, 18) VARIABLES of state ``s`` at time ``t``, continuous yaw (B,)): the accelerations are the
        derivative's with the disturbance, the attitude from the quaternion, the yaw unwrapped next to ``yaw``."""
        d = self.derivative(disturbance, batch)(s, self.targets(t, commands_at, voltage, batch), self.wind_at(t))
        state = np.column_stack([np.broadcast_to(np.asarray(x, dtype=float), np.shape(yaw)) for x in s])
        deriv = np.column_stack([np.broadcast_to(np.asarray(x, dtype=float), np.shape(yaw)) for x in d])
        euler = frames.matrix_to_euler_ned(np.moveaxis(QuadDynamics.rotation(list(state.T)), -1, 0))  # (3, 3, B) -> (B, 3, 3)
        psi = euler[:, 2]
        euler[:, 2] = yaw + (psi - yaw + np.pi) % (2.0 * np.pi) - np.pi
        out = np.empty((len(state), len(VARIABLES)))
        out[:, 0:6] = state[:, 0:6]
        out[:, 6:9] = deriv[:, 3:6]
        out[:, 9:12] = euler
        out[:, 12:15] = state[:, 10:13]
        out[:, 15:18] = deriv[:, 10:13]
        return out, euler[:, 2]

    # ---------------------------------------------------------------- anchoring
    def anchor(self, log: FlightLog, anchors: np.ndarray, observer: Observer) -> tuple[list, Disturbance, np.ndarray, np.ndarray]:
        """(start states: 17 (B,) arrays, disturbances, voltages (B,), continuous yaw (B,)) at ``anchors`` rows of
        ``log``, causally (module docstring)."""
        anchors = np.asarray(anchors, dtype=int)
        measured = state_measurement(log)
        volts = self.voltages(log)
        rotor = self.rotor_history(log) * (volts / self.reference_voltage)[:, None]
        states = _states(measured, rotor)
        targets = self.dynamics.omega_commands(self.esc_commands(log.t, log.t, log.u), volts)
        d = self.dynamics.batch_derivative(states, [targets[:, i] for i in range(4)], self.wind_at(log.t))
        modelled = np.column_stack([np.broadcast_to(np.asarray(d[k], dtype=float), (len(log),)) for k in (3, 4, 5, 10, 11, 12)])
        disturbance = observed_disturbance(log.t, measured, modelled, anchors, observer)
        return [x[anchors] for x in states], disturbance, volts[anchors], measured[anchors, 11].copy()


def _states(measured: np.ndarray, rotor: np.ndarray) -> list:
    """The simulator's state (17 (N,) arrays) of measured rows (VARIABLES order, raw) and rotor speeds (N, 4)."""
    quat = Rotation.from_matrix(frames.euler_ned_to_matrix(measured[:, 9:12])).as_quat()  # x, y, z, w
    columns = [measured[:, 0:3], measured[:, 3:6], quat[:, [3, 0, 1, 2]], measured[:, 12:15], rotor]
    return [np.ascontiguousarray(c[:, i]) for c in columns for i in range(c.shape[1])]


class TruthStream(PhysicsStream):
    """Live stream of one window (:class:`~quad_modelling.core.models.streaming.WindowStream`): the scalar
    derivative stepped over the real interval since the previous sample (``push_at``) or the warm rows' median
    interval (``push``). The logged commands of the last δ are kept, and forgotten, as the physics model's stream
    keeps them (its ``params`` here is the :class:`TruthDynamics`, whose ``delay`` it reads)."""

    def __init__(self, truth: TruthDynamics, state: list, disturbance: Disturbance, voltage: float, yaw: float,
                 times: np.ndarray, commands: np.ndarray, period_s: float):
        super().__init__(truth, [float(x) for x in state], disturbance, times, commands, period_s)
        self.truth = truth
        self.voltage = voltage
        self.yaw = np.array([yaw])
        self.derivative = truth.derivative(disturbance, batch=False)

    def _commands_at(self, times: np.ndarray) -> np.ndarray:
        return self.truth.esc_commands(times, np.asarray(self.times), np.concatenate(self.commands))

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        previous = self.times[-1]
        dt = t_s - previous
        if not dt > 0:
            raise DataError(f"truth stream: sample time {t_s:.6f} s is not after the previous {previous:.6f} s")
        self.state = self.truth.advance(self.state, previous, dt, self._commands_at, self.voltage, self.derivative, batch=False)
        self.times.append(float(t_s))
        self.commands.append(np.asarray(command, dtype=float).reshape(1, 4))
        self._forget()
        out, self.yaw = self.truth.outputs(self.state, t_s, self._commands_at, self.voltage, self.disturbance, self.yaw, batch=False)
        return out[0]


class TruthPredictor:
    """The ``truth`` model (module docstring): window, multi-step and live forms, all causal.

    ``notes``: the simulator notes to predict with (a log's ``meta.notes``); None: each log's own. ``observer``:
    the disturbance observer (:data:`NO_OBSERVER` by default; the physics model's with ``Observer()``).
    """

    def __init__(self, notes: dict | None = None, observer: Observer = NO_OBSERVER, trim: TrimConfig | None = None,
                 name: str = "truth", notes_source: str = ""):
        self.notes = notes
        self.notes_source = notes_source
        self.observer = observer
        self.trim = trim or TrimConfig()
        self.name = name
        self._cache: tuple[str, TruthDynamics] | None = None

    def simulator(self, log: FlightLog) -> TruthDynamics:
        """The simulator of ``log`` (of the notes given, else the log's own; DataError naming the log without)."""
        notes = self.notes if self.notes is not None else log.meta.notes
        where = self.notes_source if self.notes is not None else log.meta.source
        key = json.dumps(notes, sort_keys=True, default=str)
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, TruthDynamics.from_notes(notes, where))
        return self._cache[1]

    def check_flight(self, log: FlightLog) -> None:
        """DataError naming ``log`` when the model cannot predict it (no simulator notes), before any window."""
        self.simulator(log)

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, TruthStream]:
        """Warm rows -> (their measurement (W, 18) as predictions, stream anchored on the last warm row)."""
        if len(warm) < 2:
            raise DataError(f"{warm.meta.source}: the truth model needs at least 2 warm-start samples, got {len(warm)}")
        truth = self.simulator(warm)
        state, disturbance, volts, yaw = truth.anchor(warm, np.array([len(warm) - 1]), self.observer)
        period = float(np.median(np.diff(warm.t)))
        stream = TruthStream(truth, [x[0] for x in state], disturbance, float(volts[0]), float(yaw[0]), warm.t, warm.u, period)
        return state_measurement(warm), stream

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) prediction in the evaluation's trimmed convention, made by the live calls with each sample's stamp."""
        return trim_prediction(window, predict_window_by_stream(self, window, warm_samples), self.trim)

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute open-loop predictions from each start row (IDSIA multi-step), causal."""
        starts = np.asarray(starts, dtype=int)
        if starts.size and (starts.min() < 0 or starts.max() + horizon >= len(segment)):
            raise DataError(f"{segment.meta.source}: multi-step starts + horizon {horizon} leave the segment")
        truth = self.simulator(segment)
        state, disturbance, volts, yaw = truth.anchor(segment, starts, self.observer)
        derivative = truth.derivative(disturbance, batch=True)

        def commands_at(times: np.ndarray) -> np.ndarray:
            return truth.esc_commands(times, segment.t, segment.u)

        out = np.empty((len(starts), horizon + 1, len(VARIABLES)))
        for h in range(horizon + 1):
            t = segment.t[starts + h]
            out[:, h], yaw = truth.outputs(state, t, commands_at, volts, disturbance, yaw, batch=True)
            if h < horizon:
                state = truth.advance(state, t, segment.t[starts + h + 1] - t, commands_at, volts, derivative, batch=True)
        return out


def _make_truth(arg: str, vehicle) -> TruthPredictor:
    """``truth``, ``truth:L,A`` (the disturbance observer's linear/angular histories [s], as ``physics:L,A``;
    default none), ``truth:NOTES.json`` (the simulator notes from a JSON file instead of each log's), or both
    (``truth:NOTES.json,L,A``)."""
    parts = [part for part in arg.split(",") if part] if arg else []
    files = [part for part in parts if part.endswith(".json")]
    histories = [part for part in parts if not part.endswith(".json")]
    try:
        if len(files) > 1 or len(histories) > 2:
            raise ValueError(arg)
        values = [float(x) for x in histories]
        observer = NO_OBSERVER if not values else Observer(values[0], values[1] if len(values) == 2 else values[0])
    except ValueError as err:
        raise ConfigError(f"model spec truth:{arg}: the argument is a simulator notes file NOTES.json and/or the "
                          f"disturbance observer's history in seconds, linear[,angular] (0 = off), e.g. truth:0.5,0.5") from err
    name = f"truth:{','.join(histories)}" if histories else "truth"
    if not files:
        return TruthPredictor(observer=observer, name=name)
    path = Path(files[0])
    try:
        notes = json.loads(path.read_text())
    except OSError as err:
        raise ConfigError(f"model spec truth:{arg}: cannot read the simulator notes file {path} ({err.strerror})") from err
    except ValueError as err:
        raise ConfigError(f"model spec truth:{arg}: the simulator notes file {path} is not JSON ({err})") from err
    except RecursionError as err:
        raise ConfigError(f"model spec truth:{arg}: the simulator notes file {path} nests deeper than JSON can be read") from err
    sim_params_from_notes(notes, str(path))  # refuse notes that are not a simulator's, here
    return TruthPredictor(notes, observer=observer, name=name, notes_source=str(path))


register_model("truth", _make_truth)
