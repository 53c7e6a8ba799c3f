r"""Direct model (``direct:PATH``): the physics model whose body rates come from a direct multi-horizon regression.

Why. On the real NanoBench flights the logged 100 Hz motor commands, read through the rigid body and the rotor map,
explain the body rates poorly: the physics model's angular-velocity SimErr is 0.82 of naive's held out by shape,
and no model reached half of naive (issue #28). A regression straight from what is known at the anchor to the
rates h rows later needs no torque model. Linear, it beat every model on every held-out shape
(``bench/results/command_limit.md``); a small MLP on the same inputs did worse (it does not carry to a new shape).

For each horizon h = 1..H (H = the file's ``horizon``, :data:`HORIZON` rows by default) one linear map from the
anchor s's inputs to the change of the body rates:

.. math::

    \hat\omega_{s+h} = \omega_s + b_h + \sum_{i=0}^{n_\omega-1} V_{h,i}\, \omega_{s-i} + P_h\, v^B_s + Q_h\, \hat d^\omega_s
                       + \sum_{k=-L}^{h} W_{h,k}\, u_{s+k}

:math:`\omega` the gyro's body rates [rad/s, FRD]; :math:`v^B_s = R_s^T v^N_s` the measured velocity at the anchor in
the body frame [m/s, FRD] (the rotor drag's moment and the position loop's answer grow with it);
:math:`\hat d^\omega_s` the physics model's disturbance observer's angular acceleration at the anchor [rad/s², FRD]
(what its torque model missed over the observer's window: a trim or CG torque the short rate history cannot
separate from the commands' answer); :math:`u` the four logged motor commands [command unit];
:math:`n_\omega` = :data:`RATE_HISTORY` rows of rates up to the anchor; L = :data:`COMMAND_LEAD` rows of commands
before it. Causal: the rates at row s + h use the commands up to that row and the measurements up to the anchor (rows before a flight's first are its first row). The weights are stored as
one array ``weights`` (H, D, 3) over the features
:math:`z = (\omega_s, \dots, \omega_{s-n_\omega+1}, v^B_s, \hat d^\omega_s, u_{s-L}, \dots, u_{s+H})`
(D = 3 n_ω + 3 n_a + 4 (L + H + 1), n_a the :data:`ANCHOR_INPUTS` in the file's ``config.anchor_inputs``), zero
beyond horizon h's own :math:`D_h = 3 n_\omega + 3 n_a + 4 (L + h + 1)`, and ``bias`` (H, 3). Files of session 19
have neither anchor input (``anchor_inputs`` absent, D 6 fewer) and load as they were.

Fit (:func:`fit_rate_regression`): per h, ridge regression on every anchor of the training spans' gap-free parts
with room for the lead and H rows after it, the penalty on the standardised inputs, each anchor weighted by
:math:`c_s`,

.. math::

    \min_{w}\ \frac{\sum_s c_s \lVert \Delta\omega_{s,h} - b_h - w^T z_{s,h} \rVert^2}{\sum_s c_s}
        + \lambda \sum_j \sigma_j^2 w_j^2,
    \qquad w = (C_{zz} + \lambda\, \mathrm{diag}\, \sigma^2)^{-1} C_{z\Delta\omega}, \qquad b_h = \mu_{\Delta\omega} - w^T \mu_z

(C the c-weighted covariances, σ² their diagonal, λ = :data:`RIDGE`), from the moments of z accumulated over the
flights: no design matrix held. Every h's inputs are a leading block of z, so one Gram matrix serves all of them.
The score is a mean *absolute* error, so after the least-squares fit (c = 1) :data:`ROBUST_STEPS` reweighted refits
(IRLS for the absolute error) give each anchor :math:`c_s = 1 / \max(r_s, \delta)`, :math:`r_s` its mean error norm
over h = 1..H in the previous fit and δ = :data:`ROBUST_FLOOR` times their median: a few violent anchors (a gust, a
propeller strike) no longer pull every map.

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
from collections.abc import Callable, Sequence
from dataclasses import fields
from pathlib import Path

import numpy as np

from quad_modelling.core import frames
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

ROBUST_STEPS = 1
"""Reweighted refits after the least-squares one (module docstring). One: three changed no fold's held-out AV SimErr
ratio by more than 0.01 (session 20, held out by shape on the NanoBench flights)."""

ANCHOR_INPUTS: tuple[str, ...] = ("body_velocity", "angular_disturbance")
r"""The anchor's 3-vectors among the inputs, in order: v^B_s and \hat d^ω_s (module docstring)."""

ROBUST_FLOOR = 0.5
"""δ / median(r_s): the smallest error an anchor's weight counts, so that well-fitted anchors do not dominate."""

PERIOD_TOLERANCE = 0.1
"""Largest relative difference between a flight's median sample period and the model's ``dt``."""

OUTPUTS: tuple[str, ...] = ("roll_rate", "pitch_rate", "yaw_rate")
"""The variables the regression predicts (the header's ``outputs``)."""


def feature_count(horizon: int, rate_history: int = RATE_HISTORY, lead: int = COMMAND_LEAD,
                  anchor_inputs: Sequence[str] = ANCHOR_INPUTS) -> int:
    """D_h: inputs of horizon h's map (module docstring)."""
    return 3 * rate_history + 3 * len(anchor_inputs) + 4 * (lead + horizon + 1)


def anchor_features(log: FlightLog, anchors: np.ndarray, horizon: int, angular_disturbance: np.ndarray | None = None,
                    rate_history: int = RATE_HISTORY, lead: int = COMMAND_LEAD,
                    anchor_inputs: Sequence[str] = ANCHOR_INPUTS) -> np.ndarray:
    """(S, D_horizon) inputs z at ``anchors`` of ``log``: the rates ω_s .. ω_{s-n_ω+1}, the ``anchor_inputs`` (the
    body velocity v^B_s; the observer's angular disturbance ``angular_disturbance`` (S, 3) [rad/s²] at the anchors),
    then the commands u_{s-L} .. u_{s+horizon}; rows before 0 are row 0."""
    anchors = np.asarray(anchors, dtype=int)
    past = np.maximum(anchors[:, None] - np.arange(rate_history)[None, :], 0)
    rows = np.maximum(anchors[:, None] + np.arange(-lead, horizon + 1)[None, :], 0)
    extra = []
    for name in anchor_inputs:
        if name == "body_velocity":
            extra.append(frames.nav_to_body(log.vel_n[anchors], log.euler[anchors]).reshape(len(anchors), 3))
        elif angular_disturbance is None:
            raise ValueError("the direct model's angular_disturbance input needs the observer's disturbance at the anchors")
        else:
            extra.append(np.asarray(angular_disturbance, dtype=float).reshape(len(anchors), 3))
    return np.concatenate([log.gyro_b[past].reshape(len(anchors), -1), *extra, log.u[rows].reshape(len(anchors), -1)], axis=1)


class RateRegression:
    """The per-horizon maps (module docstring): ``weights`` (H, D, 3), ``bias`` (H, 3)."""

    def __init__(self, weights: np.ndarray, bias: np.ndarray, rate_history: int = RATE_HISTORY, lead: int = COMMAND_LEAD,
                 anchor_inputs: Sequence[str] = ANCHOR_INPUTS):
        weights, bias = np.asarray(weights, dtype=float), np.asarray(bias, dtype=float)
        horizon = len(bias)
        unknown = [name for name in anchor_inputs if name not in ANCHOR_INPUTS]
        if unknown:
            raise ModelError(f"direct model: unknown anchor input {unknown[0]!r}; known: {', '.join(ANCHOR_INPUTS)}")
        size = feature_count(horizon, rate_history, lead, anchor_inputs)
        if horizon < 1 or bias.shape != (horizon, 3) or weights.shape != (horizon, size, 3):
            raise ModelError(f"direct model: weights {weights.shape} and bias {bias.shape} do not fit {horizon} horizons of "
                             f"{size} inputs")
        if not (np.isfinite(weights).all() and np.isfinite(bias).all()):
            raise ModelError("direct model: weights or bias hold NaN or infinity")
        self.weights, self.bias = weights, bias
        self.horizon, self.rate_history, self.lead = horizon, rate_history, lead
        self.anchor_inputs = tuple(anchor_inputs)

    def feature_count(self, horizon: int) -> int:
        """D_h of this regression's layout."""
        return feature_count(horizon, self.rate_history, self.lead, self.anchor_inputs)

    def features(self, log: FlightLog, anchors: np.ndarray, horizon: int, angular_disturbance: np.ndarray | None = None) -> np.ndarray:
        """:func:`anchor_features` in this regression's layout."""
        return anchor_features(log, anchors, horizon, angular_disturbance, self.rate_history, self.lead, self.anchor_inputs)

    def changes(self, z: np.ndarray, given: int) -> np.ndarray:
        """(S, given, 3) :math:`\\hat\\omega_{s+h} - \\omega_s` for h = 1..given from inputs ``z`` (S, >= D_given)."""
        out = np.empty((len(z), given, 3))
        for h in range(1, given + 1):
            d = self.feature_count(h)
            out[:, h - 1] = z[:, :d] @ self.weights[h - 1, :d] + self.bias[h - 1]
        return out

    def rates(self, log: FlightLog, anchors: np.ndarray, horizon: int, angular_disturbance: np.ndarray | None = None) -> np.ndarray:
        """(S, G + 1, 3) body rates [rad/s] at rows s .. s + G of each anchor s of ``log`` (G = min(horizon, H)): row 0
        the measured ω_s, row h the map's :math:`\\hat\\omega_{s+h}`. Needs the commands up to row max(s) + G, and
        the observer's ``angular_disturbance`` (S, 3) at the anchors if it is an input."""
        anchors = np.asarray(anchors, dtype=int)
        given = min(horizon, self.horizon)
        out = np.empty((len(anchors), given + 1, 3))
        out[:, 0] = log.gyro_b[anchors]
        out[:, 1:] = out[:, :1] + self.changes(self.features(log, anchors, given, angular_disturbance), given)
        return out

    def rate_at(self, h: int, z: np.ndarray) -> np.ndarray:
        """(3,) :math:`\\hat\\omega_{s+h} - \\omega_s` from one anchor's inputs ``z`` (at least D_h of them)."""
        d = self.feature_count(h)
        return z[:d] @ self.weights[h - 1, :d] + self.bias[h - 1]


Part = tuple[FlightLog, np.ndarray, "np.ndarray | None"]
"""One gap-free part of a training span: (flight, anchors (S,), the observer's angular disturbance (S, 3) or None)."""


def training_parts(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], horizon: int,
                   angular_disturbance: Callable[[FlightLog, np.ndarray], np.ndarray] | None) -> list[Part]:
    """Every gap-free part of the ``spans`` [s from each flight's start; None: the whole flight] with the history
    before and ``horizon`` rows after each anchor, with ``angular_disturbance(flight, anchors)`` if given. DataError
    when a flight lacks the gyro."""
    parts = []
    for log, span in zip(logs, spans):
        log.require(("gyro_b",), "the direct model's training (its regression predicts the gyro rates)")
        start, stop = (0, len(log)) if span is None else rows_between(log, *span)
        for a, b in gap_free_runs(log, start, stop):
            anchors = np.arange(a + max(COMMAND_LEAD, RATE_HISTORY - 1), b - horizon)
            if anchors.size:
                parts.append((log, anchors, None if angular_disturbance is None else angular_disturbance(log, anchors)))
    return parts


def rate_changes(log: FlightLog, anchors: np.ndarray, horizon: int) -> np.ndarray:
    """(S, horizon, 3) measured Δω_{s,h} = ω_{s+h} - ω_s [rad/s] for h = 1..horizon."""
    return log.gyro_b[anchors[:, None] + np.arange(1, horizon + 1)[None, :]] - log.gyro_b[anchors][:, None, :]


def weighted_ridge(parts: Sequence[Part], weights: Sequence[np.ndarray], horizon: int, ridge: float,
                   anchor_inputs: Sequence[str]) -> RateRegression:
    """The maps minimising the c-weighted squared error plus the ridge (module docstring), from moments accumulated
    over ``parts`` with anchor weights ``weights`` (one array per part)."""
    size = feature_count(horizon, anchor_inputs=anchor_inputs)
    n, sum_z, sum_zz = 0.0, np.zeros(size), np.zeros((size, size))
    sum_y, sum_zy = np.zeros((horizon, 3)), np.zeros((horizon, size, 3))
    for (log, anchors, disturbance), c in zip(parts, weights):
        z = anchor_features(log, anchors, horizon, disturbance, anchor_inputs=anchor_inputs)
        change = rate_changes(log, anchors, horizon)
        cz = z * c[:, None]
        n += c.sum()
        sum_z += cz.sum(axis=0)
        sum_zz += cz.T @ z
        sum_y += np.einsum("s,shk->hk", c, change)
        sum_zy += np.einsum("sd,shk->hdk", cz, change)
    mean_z, mean_y = sum_z / n, sum_y / n
    covariance = sum_zz / n - np.outer(mean_z, mean_z)
    variance = np.maximum(np.diag(covariance), 1e-12)
    out, bias = np.zeros((horizon, size, 3)), np.zeros((horizon, 3))
    for h in range(1, horizon + 1):
        d = feature_count(h, anchor_inputs=anchor_inputs)
        cross = sum_zy[h - 1, :d] / n - np.outer(mean_z[:d], mean_y[h - 1])
        out[h - 1, :d] = np.linalg.solve(covariance[:d, :d] + ridge * np.diag(variance[:d]), cross)
        bias[h - 1] = mean_y[h - 1] - mean_z[:d] @ out[h - 1, :d]
    return RateRegression(out, bias, anchor_inputs=anchor_inputs)


def mean_error_norms(regression: RateRegression, parts: Sequence[Part]) -> list[np.ndarray]:
    """r_s per anchor of each part: the mean over h = 1..H of ||Δω_{s,h} - the map's|| [rad/s]."""
    h = regression.horizon
    return [np.linalg.norm(rate_changes(log, anchors, h) - regression.changes(regression.features(log, anchors, h, d), h), axis=2).mean(axis=1)
            for log, anchors, d in parts]


def fit_rate_regression(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], horizon: int = HORIZON,
                        ridge: float = RIDGE, robust_steps: int = ROBUST_STEPS,
                        angular_disturbance: Callable[[FlightLog, np.ndarray], np.ndarray] | None = None,
                        anchor_inputs: Sequence[str] | None = None) -> tuple[RateRegression, int]:
    """(the maps fitted on the ``spans`` [s from each flight's start; None: the whole flight] of ``logs``, number of
    anchors): ridge per horizon, then ``robust_steps`` reweighted refits (module docstring). The ``anchor_inputs``
    (default: the body velocity, and the observer's angular disturbance when ``angular_disturbance(flight, anchors)``
    (S, 3) gives it, as :func:`train_direct` does with the physics model's observer). DataError when no gap-free part
    of a span holds the lead and ``horizon`` rows after an anchor, or a flight lacks the gyro."""
    if horizon < 1:
        raise ConfigError(f"direct model: horizon {horizon} must be >= 1")
    if anchor_inputs is None:
        inputs = tuple(i for i in ANCHOR_INPUTS if i != "angular_disturbance" or angular_disturbance is not None)
    else:
        inputs = tuple(anchor_inputs)
    if "angular_disturbance" in inputs and angular_disturbance is None:
        raise ConfigError("direct model: the angular_disturbance input needs the observer's disturbance (angular_disturbance=)")
    parts = training_parts(logs, spans, horizon, angular_disturbance)
    n, size = sum(len(anchors) for _, anchors, _ in parts), feature_count(horizon, anchor_inputs=inputs)
    if n < size:
        raise DataError(f"direct model: {n} training anchors for {size} inputs; the training spans need more gap-free rows "
                        f"({COMMAND_LEAD} before and {horizon} after each anchor)")
    weights = [np.ones(len(anchors)) for _, anchors, _ in parts]
    regression = weighted_ridge(parts, weights, horizon, ridge, inputs)
    for _ in range(robust_steps):
        errors = mean_error_norms(regression, parts)
        floor = ROBUST_FLOOR * float(np.median(np.concatenate(errors)))
        weights = [1.0 / np.maximum(r, max(floor, 1e-12)) for r in errors]
        regression = weighted_ridge(parts, weights, horizon, ridge, inputs)
    return regression, n


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
            rates.append(self.regression.rates(segment, starts, horizon, inputs[-1][1].angular_b))
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
                       "command_lead": self.regression.lead, "anchor_inputs": list(self.regression.anchor_inputs)},
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
    model = PhysicsPredictor(vehicle)

    def observed(log: FlightLog, anchors: np.ndarray) -> np.ndarray:  # as the multi-step form anchors (horizon_inputs)
        return physics.anchor_state(model.params, log, anchors, model.observer)[1].angular_b

    regression, anchors = fit_rate_regression(logs, spans, angular_disturbance=observed)
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
        regression = RateRegression(contents["weights"], contents["bias"], int(config["rate_history"]), int(config["command_lead"]),
                                    tuple(config.get("anchor_inputs", ())))  # session 19's files: none
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
        self.inputs = list(model.regression.features(warm, np.array([last]), 0, disturbance.angular_b)[0])
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
    (commands of the last δ, rotor speeds, yaw, observer rows) and the regression's anchor inputs (the last n_ω rates,
    the last body velocity, the observer's disturbance and L + 1 commands), rolled out by the compiled
    :func:`~quad_modelling.core.export.casadi_model.given_rates_step` chained h times, the regression's rates given for the first min(h, H) steps."""

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
        self.body_velocity = np.zeros(3)  # v^B at the last row [m/s]

    def add(self, rows: FlightLog, first: int) -> None:
        super().add(rows, first)
        self.rate_rows.extend(np.asarray(rows.gyro_b[first:], dtype=float))
        self.command_rows.extend(np.asarray(rows.u[first:], dtype=float))
        if first < len(rows):
            self.body_velocity = frames.nav_to_body(rows.vel_n[-1], rows.euler[-1])

    def predict(self, t_after: np.ndarray, u_after: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        r = self.regression
        given = min(len(t_after), r.horizon)
        rates = list(self.rate_rows)[::-1]  # ω_s, ω_{s-1}, ...; before the first row added, that row (anchor_features)
        commands = list(self.command_rows)
        rates += [rates[-1]] * (r.rate_history - len(rates))
        commands = [commands[0]] * (r.lead + 1 - len(commands)) + commands
        anchor = {"body_velocity": self.body_velocity}
        if "angular_disturbance" in r.anchor_inputs:
            anchor["angular_disturbance"] = self.disturbance().angular_b[0]
        z = np.concatenate([np.ravel(rates), *(anchor[name] for name in r.anchor_inputs), np.ravel(commands),
                            np.ravel(u_after[:given])])
        # one contraction for every map: horizon h's weights are zero past its own D_h
        self._w[:given] = rates[0] + np.einsum("d,hdk->hk", z, r.weights[:given, :len(z)]) + r.bias[:given]
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
