r"""Direct model (``direct:PATH``): the physics model whose body rates come from a direct multi-horizon regression.

Why. On the real NanoBench flights the logged 100 Hz motor commands, read through the rigid body and the rotor map,
explain the body rates poorly: the physics model's angular-velocity SimErr is 0.82 of naive's held out by shape,
and no model reached half of naive (issue #28). A regression straight from what is known at the anchor to the
rates h rows later needs no torque model. Linear, it beat every model on every held-out shape
(``bench/results/command_limit.md``); a small MLP on the same inputs did worse (it does not carry to a new shape).

For each horizon h = 1..H (H = the file's ``horizon``, :data:`HORIZON` rows by default) one linear map from the
anchor s's inputs to the change of the body rates:

.. math::

    \hat\omega_{s+h} = \omega_s + b_h + \sum_{i=0}^{n_\omega-1} V_{h,i}\, \omega_{s-i}
                       + \sum_{k=-L}^{h} W_{h,k}\, u_{s+k}

:math:`\omega` the gyro's body rates [rad/s, FRD]; :math:`u` the four logged motor commands [command unit];
:math:`n_\omega` = :data:`RATE_HISTORY` rows of rates up to the anchor; L = :data:`COMMAND_LEAD` rows of commands
before it. Causal: the rates at row s + h use the commands up to that row and the measured rates up to the anchor
(rows before a flight's first are its first row). The weights are stored as one array ``weights`` (H, D, 3) over
the features :math:`z = (\omega_s, \dots, \omega_{s-n_\omega+1}, u_{s-L}, \dots, u_{s+H})` (D = 3 n_ω + 4 (L + H + 1)),
zero beyond horizon h's own :math:`D_h = 3 n_\omega + 4 (L + h + 1)`, and ``bias`` (H, 3).

Fit (:func:`fit_rate_regression`): per h, ridge regression on every anchor of the training spans' gap-free parts
with room for the lead and H rows after it, the penalty on the standardised inputs,

.. math::

    \min_{w}\ \tfrac{1}{n} \sum_s \lVert \Delta\omega_{s,h} - b_h - w^T z_{s,h} \rVert^2 + \lambda \sum_j \sigma_j^2 w_j^2,
    \qquad w = (C_{zz} + \lambda\, \mathrm{diag}\, \sigma^2)^{-1} C_{z\Delta\omega}, \qquad b_h = \mu_{\Delta\omega} - w^T \mu_z

(C the covariances, σ² their diagonal, λ = :data:`RIDGE`), from the moments of z accumulated over the flights: one
pass, no design matrix held. Every h's inputs are a leading block of z, so one Gram matrix serves all of them.

The rest of the state. The physics model (:mod:`~quad_modelling.core.models.physics`: anchor, disturbance observer,
rotor map, thrust, translation) runs as usual with these rates given at the end of each of the first H steps
(:func:`~quad_modelling.core.physics.rigid_body.step`'s ``rates_next``): the attitude turns with them and tilts the
thrust. After H rows the physics integrates the rates again from the last given one. The model's angular
accelerations (``roll_acc..yaw_acc``) are the physics model's, not the regression's.

Rows, not seconds: the regression counts rows of the training flights' sample period (the file's ``dt``); a flight
whose median period differs by more than :data:`PERIOD_TOLERANCE` is refused in one line. Model files are ``.npz``
(kind ``direct``, :mod:`~quad_modelling.core.models.model_files`) with the physics constants they were trained
with; loading refuses another vehicle or changed constants, as the hybrid's. No torch: fit and prediction are numpy.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path

import numpy as np

from quad_modelling.core.export.casadi_model import ExportedModel, casadi_functions, given_rates_step
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models import physics
from quad_modelling.core.models.forecast import CompiledWindowStream, PhysicsForecast, Step, compile_step
from quad_modelling.core.models.hybrid import physics_constants, trained_parameters
from quad_modelling.core.models.model_files import FORMAT, FORMAT_VERSION, read_model_file
from quad_modelling.core.models.physics import Disturbance, PhysicsPredictor, PhysicsStream
from quad_modelling.core.models.streaming import WindowByStream
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import PhysicsState
from quad_modelling.core.preprocess import TrimConfig, state_measurement
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import gap_free_runs, rows_between
from quad_modelling.errors import ConfigError, DataError, ModelError, reason

KIND = "direct"

HORIZON = 50
"""Horizons with a regression [rows]: 0.5 s at 100 Hz, the multi-step protocol's SimErr horizon."""

RATE_HISTORY = 10
"""n_ω: measured body-rate rows up to and including the anchor (0.1 s at 100 Hz)."""

COMMAND_LEAD = 10
"""L: command rows before the anchor (0.1 s; the Crazyflie's identified command delay is 40 ms)."""

RIDGE = 1e-2
"""λ: ridge penalty on the standardised inputs, per sample. Set before any held-out score and not tuned
(``bench/bench_command_limit.py`` used it first)."""

PERIOD_TOLERANCE = 0.1
"""Largest relative difference between a flight's median sample period and the model's ``dt``."""

OUTPUTS: tuple[str, ...] = ("roll_rate", "pitch_rate", "yaw_rate")
"""The variables the regression predicts (the header's ``outputs``)."""


def feature_count(horizon: int, rate_history: int = RATE_HISTORY, lead: int = COMMAND_LEAD) -> int:
    """D_h: inputs of horizon h's map (module docstring)."""
    return 3 * rate_history + 4 * (lead + horizon + 1)


def anchor_features(u: np.ndarray, rates: np.ndarray, anchors: np.ndarray, horizon: int, rate_history: int = RATE_HISTORY,
                    lead: int = COMMAND_LEAD) -> np.ndarray:
    """(S, D_horizon) inputs z at ``anchors`` of commands ``u`` (N, 4) and body rates ``rates`` (N, 3): the rates
    ω_s .. ω_{s-n_ω+1}, then the commands u_{s-L} .. u_{s+horizon}; rows before 0 are row 0."""
    anchors = np.asarray(anchors, dtype=int)
    past = np.maximum(anchors[:, None] - np.arange(rate_history)[None, :], 0)
    rows = np.maximum(anchors[:, None] + np.arange(-lead, horizon + 1)[None, :], 0)
    return np.concatenate([rates[past].reshape(len(anchors), -1), u[rows].reshape(len(anchors), -1)], axis=1)


class RateRegression:
    """The per-horizon maps (module docstring): ``weights`` (H, D, 3), ``bias`` (H, 3)."""

    def __init__(self, weights: np.ndarray, bias: np.ndarray, rate_history: int = RATE_HISTORY, lead: int = COMMAND_LEAD):
        weights, bias = np.asarray(weights, dtype=float), np.asarray(bias, dtype=float)
        horizon = len(bias)
        if horizon < 1 or bias.shape != (horizon, 3) or weights.shape != (horizon, feature_count(horizon, rate_history, lead), 3):
            raise ModelError(f"direct model: weights {weights.shape} and bias {bias.shape} do not fit {horizon} horizons of "
                             f"{feature_count(horizon, rate_history, lead)} inputs")
        if not (np.isfinite(weights).all() and np.isfinite(bias).all()):
            raise ModelError("direct model: weights or bias hold NaN or infinity")
        self.weights, self.bias = weights, bias
        self.horizon, self.rate_history, self.lead = horizon, rate_history, lead

    def rates(self, u: np.ndarray, rates: np.ndarray, anchors: np.ndarray, horizon: int) -> np.ndarray:
        """(S, G + 1, 3) body rates [rad/s] at rows s .. s + G of each anchor s (G = min(horizon, H)): row 0 the
        measured ω_s, row h the map's :math:`\\hat\\omega_{s+h}`. Needs ``u`` up to row max(s) + G."""
        anchors = np.asarray(anchors, dtype=int)
        given = min(horizon, self.horizon)
        z = anchor_features(u, rates, anchors, given, self.rate_history, self.lead)
        out = np.empty((len(anchors), given + 1, 3))
        out[:, 0] = rates[anchors]
        for h in range(1, given + 1):
            d = feature_count(h, self.rate_history, self.lead)
            out[:, h] = out[:, 0] + z[:, :d] @ self.weights[h - 1, :d] + self.bias[h - 1]
        return out

    def rate_at(self, h: int, z: np.ndarray) -> np.ndarray:
        """(3,) :math:`\\hat\\omega_{s+h} - \\omega_s` from one anchor's inputs ``z`` (at least D_h of them)."""
        d = feature_count(h, self.rate_history, self.lead)
        return z[:d] @ self.weights[h - 1, :d] + self.bias[h - 1]


def fit_rate_regression(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], horizon: int = HORIZON,
                        ridge: float = RIDGE) -> tuple[RateRegression, int]:
    """(the maps fitted on the ``spans`` [s from each flight's start; None: the whole flight] of ``logs``, number of
    anchors): ridge per horizon from accumulated moments (module docstring). DataError when no gap-free part of a
    span holds the lead and ``horizon`` rows after an anchor, or a flight lacks the gyro."""
    if horizon < 1:
        raise ConfigError(f"direct model: horizon {horizon} must be >= 1")
    size = feature_count(horizon)
    n, sum_z, sum_zz = 0, np.zeros(size), np.zeros((size, size))
    sum_y, sum_zy = np.zeros((horizon, 3)), np.zeros((horizon, size, 3))
    for log, span in zip(logs, spans):
        log.require(("gyro_b",), "the direct model's training (its regression predicts the gyro rates)")
        start, stop = (0, len(log)) if span is None else rows_between(log, *span)
        for a, b in gap_free_runs(log, start, stop):
            anchors = np.arange(a + max(COMMAND_LEAD, RATE_HISTORY - 1), b - horizon)
            if not anchors.size:
                continue
            z = anchor_features(log.u, log.gyro_b, anchors, horizon)
            change = log.gyro_b[anchors[:, None] + np.arange(1, horizon + 1)[None, :]] - log.gyro_b[anchors][:, None, :]  # (S, H, 3)
            n += len(anchors)
            sum_z += z.sum(axis=0)
            sum_zz += z.T @ z
            sum_y += change.sum(axis=0)
            sum_zy += np.einsum("sd,shk->hdk", z, change)
    if n < size:
        raise DataError(f"direct model: {n} training anchors for {size} inputs; the training spans need more gap-free rows "
                        f"({COMMAND_LEAD} before and {horizon} after each anchor)")
    mean_z, mean_y = sum_z / n, sum_y / n
    covariance = sum_zz / n - np.outer(mean_z, mean_z)
    variance = np.maximum(np.diag(covariance), 1e-12)
    weights, bias = np.zeros((horizon, size, 3)), np.zeros((horizon, 3))
    for h in range(1, horizon + 1):
        d = feature_count(h)
        cross = sum_zy[h - 1, :d] / n - np.outer(mean_z[:d], mean_y[h - 1])
        weights[h - 1, :d] = np.linalg.solve(covariance[:d, :d] + ridge * np.diag(variance[:d]), cross)
        bias[h - 1] = mean_y[h - 1] - mean_z[:d] @ weights[h - 1, :d]
    return RateRegression(weights, bias), n


class DirectModel:
    """Physics constants + observer + rate regression (module docstring)."""

    def __init__(self, vehicle: VehicleConfig, regression: RateRegression, dt: float, training: dict | None = None):
        self.physics = PhysicsPredictor(vehicle)
        self.params: PhysicsParameters = self.physics.params
        self.regression = regression
        self.dt = float(dt)
        self.vehicle = vehicle.name
        self.training = dict(training or {})

    def check_rate(self, log: FlightLog) -> None:
        """DataError unless ``log``'s median sample period is the model's ``dt`` (:func:`check_period`)."""
        check_period(log, self.dt)

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute open-loop predictions from each start row, causal (IDSIA multi-step)."""
        return self.predict_horizons_of([(segment, starts)], horizon, with_accelerations=True)[0]

    def predict_horizons_of(self, parts: Sequence[tuple[FlightLog, np.ndarray]], horizon: int,
                            with_accelerations: bool = False) -> list[np.ndarray]:
        """:meth:`predict_horizons` of each (segment, starts) of ``parts`` in one batch (as the physics model's), the
        acceleration columns NaN unless ``with_accelerations``."""
        inputs, rates = [], []
        for segment, starts in parts:
            starts = np.asarray(starts, dtype=int)
            self.check_rate(segment)
            inputs.append(self.physics.horizon_inputs(segment, starts, horizon))
            rates.append(self.regression.rates(segment.u, segment.gyro_b, starts, horizon))
        if not inputs:
            return []
        states, disturbances, commands, intervals = zip(*inputs)
        state = PhysicsState(*(np.concatenate([getattr(s, f.name) for s in states]) for f in fields(PhysicsState)))
        disturbance = Disturbance(np.concatenate([d.linear_n for d in disturbances]), np.concatenate([d.angular_b for d in disturbances]))
        out = physics.rollout(self.params, state, disturbance, np.concatenate(commands), np.concatenate(intervals),
                              with_accelerations, np.concatenate(rates))
        return np.split(out, np.cumsum([len(dt) for dt in intervals])[:-1])

    # ---- files ------------------------------------------------------------------
    def header(self) -> dict:
        return {
            "format": FORMAT, "format_version": FORMAT_VERSION, "kind": KIND, "vehicle": self.vehicle,
            "variables": list(VARIABLES), "outputs": list(OUTPUTS),
            "config": {"horizon": self.regression.horizon, "rate_history": self.regression.rate_history,
                       "command_lead": self.regression.lead},
            "dt": self.dt,
            "training": {**self.training, "physics": physics_constants(self.params)},
        }

    def save(self, path: str | Path, force: bool = False) -> Path:
        """Write the ``.npz`` model file atomically (never overwrites without ``force``)."""
        from quad_modelling.atomic import atomic_output

        path = Path(path)
        with atomic_output(path, force) as tmp:
            with open(tmp, "wb") as stream:
                np.savez(stream, header=np.array(json.dumps(self.header())), weights=self.regression.weights,
                         bias=self.regression.bias)
        return path


def check_period(log: FlightLog, dt: float) -> None:
    """DataError unless ``log``'s median sample period is ``dt`` [s] within :data:`PERIOD_TOLERANCE` (module docstring)."""
    if len(log) < 2:
        return
    period = float(np.median(np.diff(log.t)))
    if not abs(period - dt) <= PERIOD_TOLERANCE * dt:
        raise DataError(f"{log.meta.source}: sample period {period * 1e3:.1f} ms, the direct model counts rows of "
                        f"{dt * 1e3:.1f} ms (its training flights'); resample the flight or train on flights of its rate")


def train_direct(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], vehicle: VehicleConfig) -> DirectModel:
    """A direct model of ``vehicle`` with its regression fitted on ``spans`` of ``logs``, which must share one sample
    period (the first flight's median; DataError naming a flight of another). Its training record names the vehicle
    file (``vehicle_file``), so a load with other constants can say which file to pass."""
    if not logs or len(logs) != len(spans):
        raise DataError(f"direct model: {len(logs)} training flights for {len(spans)} spans")
    dt = float(np.median(np.diff(logs[0].t))) if len(logs[0]) > 1 else 0.0
    if not dt > 0:
        raise DataError(f"{logs[0].meta.source}: too few rows to train the direct model")
    for log in logs:
        check_period(log, dt)
    regression, anchors = fit_rate_regression(logs, spans)
    return DirectModel(vehicle, regression, dt, {"samples": anchors, "flights": [log.meta.source for log in logs], "ridge": RIDGE,
                                                 "vehicle_file": str(vehicle.path)})


def load_direct(path: str | Path, vehicle: VehicleConfig) -> DirectModel:
    """Load a direct model file for ``vehicle``; ModelError (one line) for another vehicle, changed physics
    constants or a corrupt file."""
    path = Path(path)
    header, contents = read_model_file(path, KIND, OUTPUTS, vehicle.name)
    try:
        config = header["config"]
        stored = header["training"]["physics"]
        if not isinstance(stored, dict):
            raise TypeError("training.physics is not a mapping")
        regression = RateRegression(contents["weights"], contents["bias"], int(config["rate_history"]), int(config["command_lead"]))
        dt = float(header["dt"])
    except (KeyError, TypeError, ValueError) as err:
        raise ModelError(f"{path}: direct model file lacks its settings ({reason(err)})") from err
    trained_parameters(path, KIND, stored, header["training"].get("vehicle_file"), vehicle)
    if not dt > 0:
        raise ModelError(f"{path}: direct model sample period dt {dt} must be positive")
    return DirectModel(vehicle, regression, dt, dict(header.get("training", {})))


# ---- the predictor protocols (offline window, multi-step, live) --------------------------------------
class DirectStream(PhysicsStream):
    """Live stream of one window: :class:`~quad_modelling.core.models.physics.PhysicsStream` with the body rates of
    the first H samples after the anchor given by the regression (the anchor's rates and commands kept)."""

    def __init__(self, model: DirectModel, state: PhysicsState, disturbance: Disturbance, warm: FlightLog, voltage: float | None):
        super().__init__(model.params, state, disturbance, warm.t, warm.u, float(np.median(np.diff(warm.t))), voltage)
        self.regression = model.regression
        last = len(warm) - 1
        self.inputs = list(anchor_features(warm.u, warm.gyro_b, np.array([last]), 0, model.regression.rate_history,
                                           model.regression.lead)[0])
        self.anchor_rates = np.asarray(warm.gyro_b[last], dtype=float)
        self.pushed = 0

    def given_rates(self, command: np.ndarray) -> np.ndarray | None:
        self.pushed += 1
        if self.pushed > self.regression.horizon:
            return None
        self.inputs.extend(np.asarray(command, dtype=float).reshape(4))
        return (self.anchor_rates + self.regression.rate_at(self.pushed, np.asarray(self.inputs)))[None, :]


class DirectForecast(PhysicsForecast):
    """The receding horizon's carried forecast (:mod:`~quad_modelling.core.models.forecast`): the physics model's
    (commands of the last δ, rotor speeds, yaw, observer rows) and the regression's anchor inputs (the last n_ω rates
    and L + 1 commands), rolled out by the compiled :func:`~quad_modelling.core.export.casadi_model.given_rates_step`
    chained h times, the regression's rates given for the first min(h, H) steps."""

    def __init__(self, model: DirectModel, step: Step, derivative: Step, steps: int):
        self.regression = model.regression
        super().__init__(step, derivative, model.params, model.physics.observer, steps)
        self._w, self._g = np.zeros((steps, 3)), np.zeros(steps)
        self._g[:min(steps, self.regression.horizon)] = 1.0
        self._buffer.set_arg(4, memoryview(self._w))
        self._buffer.set_arg(5, memoryview(self._g))

    def reset(self) -> None:
        super().reset()
        self.rate_rows: deque = deque(maxlen=self.regression.rate_history)
        self.command_rows: deque = deque(maxlen=self.regression.lead + 1)

    def add(self, rows: FlightLog, first: int) -> None:
        super().add(rows, first)
        self.rate_rows.extend(np.asarray(rows.gyro_b[first:], dtype=float))
        self.command_rows.extend(np.asarray(rows.u[first:], dtype=float))

    def predict(self, t_after: np.ndarray, u_after: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        r = self.regression
        given = min(len(t_after), r.horizon)
        rates = list(self.rate_rows)[::-1]  # ω_s, ω_{s-1}, ...; before the first row added, that row (anchor_features)
        commands = list(self.command_rows)
        rates += [rates[-1]] * (r.rate_history - len(rates))
        commands = [commands[0]] * (r.lead + 1 - len(commands)) + commands
        z = np.concatenate([np.ravel(rates), np.ravel(commands), np.ravel(u_after[:given])])
        for k in range(given):
            self._w[k] = rates[0] + r.rate_at(k + 1, z)
        return super().predict(t_after, u_after, rows)


class CompiledDirectStream(CompiledWindowStream):
    """A :class:`DirectStream` stepped by a compiled step with given rates (:meth:`DirectPredictor.compiled_stream`),
    as the physics model's window stream is by :class:`~quad_modelling.core.models.forecast.CompiledWindowStream`: the
    same numbers (test), without numpy's per-call cost on a batch of one."""

    def __init__(self, stream: DirectStream, step: Step):
        super().__init__(stream, step, None)
        self._w, self._g = np.zeros(3), np.zeros(1)
        self._buffer.set_arg(5, memoryview(self._w))
        self._buffer.set_arg(6, memoryview(self._g))

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        given = self.stream.given_rates(command)
        self._g[0] = 0.0 if given is None else 1.0
        if given is not None:
            self._w[:] = given[0]
        return super().push_at(command, t_s)


class DirectPredictor(WindowByStream):
    """The ``direct:PATH`` model: window (trimmed), multi-step, live and carried-forecast forms, all causal."""

    def __init__(self, model: DirectModel, name: str = "direct", trim: TrimConfig | None = None) -> None:
        self.model = model
        self.name = name
        self.trim = trim or TrimConfig()
        self._steps: dict[str, Step] = {}  # the compiled steps, built once per predictor

    def _compiled(self, vehicle: VehicleConfig) -> dict[str, Step]:
        """The compiled given-rates step (``F_given``), the continuous dynamics (``f_disturbed``) and the window
        stream's step and outputs in one call (``W_given``: as :func:`~quad_modelling.core.models.forecast.window_step`)."""
        if not self._steps:
            import casadi

            exported = ExportedModel(vehicle, self.model.params, self.model.physics.observer, "physics", None)
            step, derivative = given_rates_step(exported), casadi_functions(exported)["f_disturbed"]
            x, u, dt, d, w, g = (casadi.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(6))
            u_now = casadi.SX.sym("u_now", step.sparsity_in(1))
            after = step(x, u, dt, d, w, g)
            window = casadi.Function("W_given", [x, u, dt, d, u_now, w, g], [after, derivative(after, u_now, d)],
                                     ["x", "u", "dt", "d", "u_now", "w", "g"], ["x_next", "xdot"])
            self._steps = {"step": compile_step(step), "derivative": compile_step(derivative), "window": compile_step(window)}
        return self._steps

    def carried_forecast(self, vehicle: VehicleConfig, period_s: float, steps: int) -> DirectForecast:
        """The receding horizon's carried form (:class:`DirectForecast`)."""
        compiled = self._compiled(vehicle)
        return DirectForecast(self.model, compiled["step"], compiled["derivative"], steps)

    def compiled_stream(self, vehicle: VehicleConfig, stream: DirectStream):
        """``stream`` stepped by the compiled window step (:class:`CompiledDirectStream`), or itself without a C compiler."""
        window = self._compiled(vehicle)["window"]
        return CompiledDirectStream(stream, window) if window.compiled else stream

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, DirectStream]:
        """Warm rows -> (their measurement (W, 18), stream anchored on the last warm row)."""
        if len(warm) < 2:
            raise DataError(f"{warm.meta.source}: the direct model needs at least 2 warm-start samples, got {len(warm)}")
        warm.require(("gyro_b",), "the direct model (body rates at the anchor)")
        self.model.check_rate(warm)
        measured = state_measurement(warm, self.model.physics.vehicle)
        state, disturbance, _ = physics.anchor_state(self.model.params, warm, np.array([len(warm) - 1]), self.model.physics.observer, measured)
        voltage = physics.battery_voltage(self.model.params, warm)
        return measured, DirectStream(self.model, state, disturbance, warm, None if voltage is None else float(voltage[-1]))



    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        return self.model.predict_horizons(segment, starts, horizon)

    def predict_horizons_of(self, parts: Sequence[tuple[FlightLog, np.ndarray]], horizon: int) -> list[np.ndarray]:
        return self.model.predict_horizons_of(parts, horizon)


def make_direct_predictor(arg: str, vehicle: VehicleConfig) -> DirectPredictor:
    """Registry factory for ``direct:PATH``."""
    if not arg:
        raise ConfigError("model spec direct needs a model file: direct:PATH")
    return DirectPredictor(load_direct(arg, vehicle))
