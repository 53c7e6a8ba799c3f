r"""Direct model (``direct:PATH``): the physics model whose body rates come from a direct multi-horizon regression.

Why. On the real NanoBench flights the logged motor commands, read through the rigid body and the rotor map, explain
the body rates poorly (issue #28); a linear regression from what is known at the anchor to the rates h rows later
needs no torque model and beat every model on every held-out shape (docs/narx.md, ``bench/results/command_limit.md``).

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
(D = 3 n_ω + 3 n_b + 4 (L + H + 1), n_b the :data:`ANCHOR_INPUTS` in the file's ``config.anchor_inputs``), zero
beyond horizon h's own :math:`D_h = 3 n_\omega + 3 n_b + 4 (L + h + 1)`, and ``bias`` (H, 3). Files of session 19
have neither anchor input (``anchor_inputs`` absent, D 6 fewer) and load as they were.

Fit (:func:`quad_modelling.core.training.direct.fit_rate_regression`): per h, ridge regression on the moments of z
over every training anchor (λ = :data:`RATE_RIDGE`), then :data:`ROBUST_STEPS` reweighted refits for the mean absolute
error (:mod:`quad_modelling.core.training.direct`).

The vertical map (files since session 22; absent in older ones, and when a training flight had no accelerometer; on
a flight without one the physics integrates v_D in every form, :meth:`DirectModel.uses_vertical`).
The logged commands read through the rotor map predict the vertical velocity poorly (held out by shape no better than
holding it on the linear ramps; docs/narx.md), so the down velocity gets maps of its own, fitted as the rates':

.. math::

    \hat v_{D,s+h} = v_{D,s} + c_h + \sum_{i=0}^{n_v-1} A_{h,i}\, v_{D,s-i} + B_h\, \bar a_{D,s} + C_h \cos\phi_s\cos\theta_s
                     + \sum_{k=-L}^{h} E_{h,k}\, u_{s+k}, \qquad
    \bar a_{D,s} = \frac{1}{n_a} \sum_{i=0}^{n_a-1} a_{D,s-i}

:math:`v_D` the measured velocity's down component [m/s, N]; :math:`a_{D,j} = (R_j f_{B,j})_D + g` the down
acceleration at row j from the accelerometer's specific force f_B [m/s²] (the thrust the rotors give now), averaged
over the last n_a = :data:`ACCELERATION_ROWS` rows up to the anchor (the accelerometer's vibration noise; files before
session 24 hold n_a = 1, the anchor's row alone); :math:`\cos\phi\cos\theta` the share of the thrust pointing down;
n_v = :data:`VELOCITY_HISTORY`. These inputs were chosen on three folds (B3, B6, B9): the body-rate history and the
observer's vertical disturbance changed nothing there and were left out; n_a on the training shapes only
(``bench/bench_direct_vertical_acceleration.py``).

The rest of the state. The physics model (:mod:`~quad_modelling.core.models.physics`: anchor, disturbance observer,
rotor map, thrust, translation) runs as usual with these rates given at the end of each of the first H steps
(:func:`~quad_modelling.core.physics.rigid_body.step`'s ``rates_next``): the attitude turns with them and tilts the
thrust. The vertical map's down velocity is given the same way (``down_velocity_next``): the horizontal velocity
stays the physics model's, the position moves with both. After H rows the physics integrates again from the last
given state. The model's angular
accelerations (``roll_acc..yaw_acc``) are the physics model's, not the regression's.

Rows, not seconds: the regression counts rows of the training flights' sample period (the file's ``dt``); a flight
whose median period differs by more than :data:`PERIOD_TOLERANCE` is refused in one line. Model files are ``.npz``
(kind ``direct``, :mod:`~quad_modelling.core.models.model_files`) with the physics constants they were trained
with; loading refuses another vehicle or changed constants, as the hybrid's. No torch: fit and prediction are numpy.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models import physics
from quad_modelling.core.models.hybrid import physics_constants, trained_parameters
from quad_modelling.core.models.model_files import FORMAT, FORMAT_VERSION, header_int, read_model_file
from quad_modelling.core.models.physics import Disturbance, PhysicsPredictor, PhysicsStream
from quad_modelling.core.models.streaming import WindowByStream
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import PhysicsState
from quad_modelling.core.preprocess import TrimConfig, state_measurement
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError, DataError, ModelError, reason

KIND = "direct"

HORIZON = 50
"""Horizons with a regression [rows]: 0.5 s at 100 Hz, the multi-step protocol's SimErr horizon."""

RATE_HISTORY = 10
"""n_ω: measured body-rate rows up to and including the anchor (0.1 s at 100 Hz)."""

COMMAND_LEAD = 10
"""L: command rows before the anchor (0.1 s; the Crazyflie's identified command delay is 40 ms)."""

VELOCITY_HISTORY = 5
"""n_v: measured down-velocity rows up to and including the anchor (the vertical map's; 0.05 s at 100 Hz, the first
choice of session 22's scratch study, not tuned)."""

MAX_ACCELERATION_ROWS = 1000
"""Most rows a model file's vertical map may average (10 s at 100 Hz): an edited 10^9 asked for terabytes."""

ACCELERATION_ROWS = 5
"""n_a: rows of down acceleration averaged up to and including the anchor (the vertical map's; 0.05 s at 100 Hz).
Chosen on the training shapes only among 1, 3, 5 and 10 (``bench/bench_direct_vertical_acceleration.py``, nested
leave-one-shape-out, session 24): the training shapes pick 5 in four folds of six and 3 in two (their inner scores
within 0.003); 1 before."""

RATE_RIDGE = 1e-3
"""λ of the rate maps: ridge penalty on the standardised inputs, per sample. Chosen on the training shapes only
(``bench/bench_direct_ridge.py``, nested leave-one-shape-out over 1e-4..1e-2; session 23); 1e-2 before, from
``bench/bench_command_limit.py``."""

VERTICAL_RIDGE = 1e-2
"""λ of the vertical map, as :data:`RATE_RIDGE` (set before any held-out score, not varied)."""

ROBUST_STEPS = 1
"""Reweighted refits after the least-squares one (module docstring). One: three changed no fold's held-out AV SimErr
ratio by more than 0.01 (session 20, held out by shape on the NanoBench flights)."""

ANCHOR_INPUTS: tuple[str, ...] = ("body_velocity", "angular_disturbance")
r"""The anchor's 3-vectors among the inputs, in order: v^B_s and \hat d^ω_s (module docstring)."""

ROBUST_FLOOR = 0.5
"""δ / median(r_s): the smallest error an anchor's weight counts, so that well-fitted anchors do not dominate."""

PERIOD_TOLERANCE = 0.1
"""Largest relative difference between a flight's median sample period and the model's ``dt``."""

ARRAYS = ("weights", "bias", "vertical_weights", "vertical_bias")
"""The arrays a direct model file may hold (the vertical map's two since session 22)."""

VERTICAL_SETTINGS = ("velocity_history", "command_lead", "acceleration_rows")
"""The vertical map's settings a direct model file may hold (``config.vertical``; ``acceleration_rows`` since session 24:
a file with a setting not listed is refused, as an unread array is)."""

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


class HorizonMaps:
    """Per-horizon linear maps from z = (anchor block a_s, u_{s-L} .. u_{s+h}) to the change of K outputs h rows after
    the anchor: ``weights`` (H, D, K), zero beyond horizon h's own D_h = A + 4 (L + h + 1), and ``bias`` (H, K)."""

    def __init__(self, weights: np.ndarray, bias: np.ndarray, anchor_size: int, lead: int, outputs: int, what: str):
        weights, bias = np.asarray(weights, dtype=float), np.asarray(bias, dtype=float)
        horizon = len(bias)
        self.anchor_size, self.lead = anchor_size, lead
        size = self.feature_count(horizon)
        if horizon < 1 or bias.shape != (horizon, outputs) or weights.shape != (horizon, size, outputs):
            raise ModelError(f"direct model: {what} weights {weights.shape} and bias {bias.shape} do not fit {horizon} horizons "
                             f"of {size} inputs")
        if not (np.isfinite(weights).all() and np.isfinite(bias).all()):
            raise ModelError(f"direct model: {what} weights or bias hold NaN or infinity")
        self.weights, self.bias, self.horizon = weights, bias, horizon
        self._stacked: dict[int, np.ndarray] = {}  # given -> the maps side by side (changes_from)

    def feature_count(self, horizon: int) -> int:
        """D_h of this layout."""
        return self.anchor_size + 4 * (self.lead + horizon + 1)

    def changes(self, z: np.ndarray, given: int) -> np.ndarray:
        """(S, given, K) predicted changes for h = 1..given from inputs ``z`` (S, >= D_given)."""
        out = np.empty((len(z), given, self.bias.shape[1]))
        for h in range(1, given + 1):
            d = self.feature_count(h)
            out[:, h - 1] = z[:, :d] @ self.weights[h - 1, :d] + self.bias[h - 1]
        return out

    def changes_from(self, z: np.ndarray, given: int) -> np.ndarray:
        """(given, K) the changes for h = 1..given from one anchor's inputs ``z`` (D_given): the maps side by side in one
        matrix product (horizon h's weights are zero past its own D_h), stacked once per ``given``."""
        stacked = self._stacked.get(given)
        if stacked is None:
            d = self.feature_count(given)
            stacked = self._stacked[given] = np.ascontiguousarray(self.weights[:given, :d].transpose(1, 0, 2).reshape(d, -1))
        return (z @ stacked).reshape(given, -1) + self.bias[:given]

    def change_at(self, h: int, z: np.ndarray) -> np.ndarray:
        """(K,) the predicted change h rows after the anchor from one anchor's inputs ``z`` (at least D_h of them)."""
        d = self.feature_count(h)
        return z[:d] @ self.weights[h - 1, :d] + self.bias[h - 1]


class RateRegression(HorizonMaps):
    """The body rates' maps (module docstring): ``weights`` (H, D, 3), ``bias`` (H, 3)."""

    def __init__(self, weights: np.ndarray, bias: np.ndarray, rate_history: int = RATE_HISTORY, lead: int = COMMAND_LEAD,
                 anchor_inputs: Sequence[str] = ANCHOR_INPUTS):
        unknown = [name for name in anchor_inputs if name not in ANCHOR_INPUTS]
        if unknown:
            raise ModelError(f"direct model: unknown anchor input {unknown[0]!r}; known: {', '.join(ANCHOR_INPUTS)}")
        super().__init__(weights, bias, 3 * rate_history + 3 * len(anchor_inputs), lead, 3, "rate")
        self.rate_history = rate_history
        self.anchor_inputs = tuple(anchor_inputs)

    def features(self, log: FlightLog, anchors: np.ndarray, horizon: int, angular_disturbance: np.ndarray | None = None) -> np.ndarray:
        """:func:`anchor_features` in this regression's layout."""
        return anchor_features(log, anchors, horizon, angular_disturbance, self.rate_history, self.lead, self.anchor_inputs)

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


def vertical_feature_count(horizon: int, velocity_history: int = VELOCITY_HISTORY, lead: int = COMMAND_LEAD) -> int:
    """D_h of the vertical map: n_v down velocities, the down acceleration, the tilt, 4 (L + h + 1) commands."""
    return velocity_history + 2 + 4 * (lead + horizon + 1)


def vertical_features(log: FlightLog, anchors: np.ndarray, horizon: int, velocity_history: int = VELOCITY_HISTORY,
                      lead: int = COMMAND_LEAD, acceleration_rows: int = ACCELERATION_ROWS) -> np.ndarray:
    """(S, D_horizon) inputs of the vertical map at ``anchors`` of ``log`` (module docstring): v_D at rows s .. s-n_v+1,
    the mean down acceleration ā_D over rows s .. s-n_a+1 (a_D = (R f_B)_D + g [m/s²] from the accelerometer), the
    tilt cos φ cos θ (the share of the thrust that points down), then the commands u_{s-L} .. u_{s+horizon}; rows
    before 0 are row 0."""
    anchors = np.asarray(anchors, dtype=int)
    past = np.maximum(anchors[:, None] - np.arange(velocity_history)[None, :], 0)
    rows = np.maximum(anchors[:, None] + np.arange(-lead, horizon + 1)[None, :], 0)
    euler = log.euler[anchors]
    averaged = np.maximum(anchors[:, None] - np.arange(acceleration_rows)[None, :], 0)
    down_acc = down_acceleration(log, averaged.ravel()).reshape(averaged.shape).mean(axis=1)
    tilt = frames.tilt_cosine(euler)
    return np.concatenate([log.vel_n[past, 2], down_acc[:, None], tilt[:, None], log.u[rows].reshape(len(anchors), -1)], axis=1)


class VerticalRegression(HorizonMaps):
    """The down velocity's maps (module docstring): ``weights`` (H, D, 1), ``bias`` (H, 1)."""

    def __init__(self, weights: np.ndarray, bias: np.ndarray, velocity_history: int = VELOCITY_HISTORY, lead: int = COMMAND_LEAD,
                 acceleration_rows: int = ACCELERATION_ROWS):
        if not isinstance(acceleration_rows, (int, np.integer)) or not 1 <= acceleration_rows <= MAX_ACCELERATION_ROWS:
            raise ModelError(f"direct model: the vertical map's acceleration_rows {acceleration_rows!r} must be a whole number "
                             f"in 1..{MAX_ACCELERATION_ROWS}")
        super().__init__(weights, bias, velocity_history + 2, lead, 1, "vertical")
        self.velocity_history = velocity_history
        self.acceleration_rows = int(acceleration_rows)

    def features(self, log: FlightLog, anchors: np.ndarray, horizon: int) -> np.ndarray:
        """:func:`vertical_features` in this map's layout."""
        return vertical_features(log, anchors, horizon, self.velocity_history, self.lead, self.acceleration_rows)

    def velocities(self, log: FlightLog, anchors: np.ndarray, horizon: int) -> np.ndarray:
        """(S, G + 1) down velocities [m/s] at rows s .. s + G of each anchor s (G = min(horizon, H)): row 0 the
        measured v_D(s), row h the map's."""
        anchors = np.asarray(anchors, dtype=int)
        given = min(horizon, self.horizon)
        out = np.empty((len(anchors), given + 1))
        out[:, 0] = log.vel_n[anchors, 2]
        out[:, 1:] = out[:, :1] + self.changes(self.features(log, anchors, given), given)[..., 0]
        return out


class DirectModel:
    """Physics constants + observer + rate regression + vertical map (None: the physics integrates v_D) (module docstring)."""

    def __init__(self, vehicle: VehicleConfig, regression: RateRegression, dt: float, training: dict | None = None,
                 vertical: VerticalRegression | None = None):
        self.physics = PhysicsPredictor(vehicle)
        self.params: PhysicsParameters = self.physics.params
        self.regression = regression
        self.vertical = vertical
        self.dt = float(dt)
        self.vehicle = vehicle.name
        self.training = dict(training or {})

    def uses_vertical(self, log: FlightLog) -> bool:
        """Whether the vertical map predicts v_D on ``log``: the model has one and the flight an accelerometer (the
        map's input); else the physics integrates v_D, as in a model without the map."""
        return self.vertical is not None and log.acc_b is not None

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute open-loop predictions from each start row, causal (IDSIA multi-step)."""
        return self.predict_horizons_of([(segment, starts)], horizon, with_accelerations=True)[0]

    def predict_horizons_of(self, parts: Sequence[tuple[FlightLog, np.ndarray]], horizon: int,
                            with_accelerations: bool = False) -> list[np.ndarray]:
        """:meth:`predict_horizons` of each (segment, starts) of ``parts`` in one batch (as the physics model's), the
        acceleration columns NaN unless ``with_accelerations``; segments with and without the vertical map
        (:meth:`uses_vertical`) in a batch each."""
        flags = [self.uses_vertical(segment) for segment, _ in parts]
        if any(flags) and not all(flags):
            out: list = [None] * len(parts)
            for flag in (True, False):
                index = [i for i, f in enumerate(flags) if f == flag]
                for i, result in zip(index, self.predict_horizons_of([parts[i] for i in index], horizon, with_accelerations)):
                    out[i] = result
            return out
        inputs, rates, down = [], [], []
        for segment, starts in parts:
            starts = np.asarray(starts, dtype=int)
            check_period(segment, self.dt)
            inputs.append(self.physics.horizon_inputs(segment, starts, horizon))
            rates.append(self.regression.rates(segment, starts, horizon, inputs[-1][1].angular_b))
            if self.uses_vertical(segment):
                down.append(self.vertical.velocities(segment, starts, horizon))
        if not inputs:
            return []
        states, disturbances, commands, intervals = zip(*inputs)
        state = PhysicsState(*(np.concatenate([getattr(s, f.name) for s in states]) for f in fields(PhysicsState)))
        disturbance = Disturbance(np.concatenate([d.linear_n for d in disturbances]), np.concatenate([d.angular_b for d in disturbances]))
        out = physics.rollout(self.params, state, disturbance, np.concatenate(commands), np.concatenate(intervals),
                              with_accelerations, np.concatenate(rates), np.concatenate(down) if down else None)
        return np.split(out, np.cumsum([len(dt) for dt in intervals])[:-1])

    # ---- files ------------------------------------------------------------------
    def header(self) -> dict:
        return {
            "format": FORMAT, "format_version": FORMAT_VERSION, "kind": KIND, "vehicle": self.vehicle,
            "variables": list(VARIABLES), "outputs": list(OUTPUTS),
            "config": {"horizon": self.regression.horizon, "rate_history": self.regression.rate_history,
                       "command_lead": self.regression.lead, "anchor_inputs": list(self.regression.anchor_inputs),
                       "vertical": None if self.vertical is None else {"velocity_history": self.vertical.velocity_history,
                                                                       "command_lead": self.vertical.lead,
                                                                       "acceleration_rows": self.vertical.acceleration_rows}},
            "dt": self.dt,
            "training": {**self.training, "physics": physics_constants(self.params)},
        }

    def save(self, path: str | Path, force: bool = False) -> Path:
        """Write the ``.npz`` model file atomically (never overwrites without ``force``)."""
        from quad_modelling.atomic import atomic_output

        path = Path(path)
        with atomic_output(path, force) as tmp:
            with open(tmp, "wb") as stream:
                vertical = {} if self.vertical is None else {"vertical_weights": self.vertical.weights, "vertical_bias": self.vertical.bias}
                np.savez(stream, header=np.array(json.dumps(self.header())), weights=self.regression.weights,
                         bias=self.regression.bias, **vertical)
        return path


def check_period(log: FlightLog, dt: float) -> None:
    """DataError unless ``log``'s median sample period is ``dt`` [s] within :data:`PERIOD_TOLERANCE` (module docstring)."""
    if len(log) < 2:
        return
    period = float(np.median(np.diff(log.t)))
    if not abs(period - dt) <= PERIOD_TOLERANCE * dt:
        raise DataError(f"{log.meta.source}: sample period {period * 1e3:.1f} ms, the direct model counts rows of "
                        f"{dt * 1e3:.1f} ms (its training flights'); resample the flight or train on flights of its rate")


def load_direct(path: str | Path, vehicle: VehicleConfig) -> DirectModel:
    """Load a direct model file for ``vehicle``; ModelError (one line) for another vehicle, changed physics
    constants or a corrupt file."""
    path = Path(path)
    header, contents = read_model_file(path, KIND, OUTPUTS, vehicle.name, ARRAYS.__contains__)
    try:
        config = header["config"]
        stored = header["training"]["physics"]
        if not isinstance(stored, dict):
            raise TypeError("training.physics is not a mapping")
        regression = RateRegression(contents["weights"], contents["bias"], header_int(config["rate_history"]),
                                    header_int(config["command_lead"]), tuple(config.get("anchor_inputs", ())))  # session 19's: none
        if "horizon" in config and header_int(config["horizon"]) != len(contents["weights"]):
            raise ModelError(f"config.horizon {config['horizon']} but weights for {len(contents['weights'])} horizons")
        layout = config.get("vertical")  # files before session 22: none
        if layout is not None and not isinstance(layout, dict):
            raise TypeError("config.vertical is not a mapping")
        if layout is None and "vertical_weights" in contents:
            raise ModelError("config.vertical is null but the file holds the vertical map's arrays: which is meant?")
        unread = sorted(set(layout or {}) - set(VERTICAL_SETTINGS))
        if unread:
            raise ModelError(f"direct model file holds vertical-map setting {unread[0]!r}, which this program's direct "
                             "model does not read (a file from a newer quad-modelling?)")
        vertical = None if layout is None else VerticalRegression(contents["vertical_weights"], contents["vertical_bias"],
                                                                  header_int(layout["velocity_history"]), header_int(layout["command_lead"]),
                                                                  layout.get("acceleration_rows", 1))  # before session 24: 1
        dt = float(header["dt"])
    except ModelError as err:  # a setting out of range or not read: the message with the file's name
        raise ModelError(f"{path}: {err}") from err
    except (KeyError, TypeError, ValueError) as err:
        raise ModelError(f"{path}: direct model file lacks its settings ({reason(err)})") from err
    trained_parameters(path, KIND, stored, header["training"].get("vehicle_file"), vehicle)
    if not dt > 0:
        raise ModelError(f"{path}: direct model sample period dt {dt} must be positive")
    return DirectModel(vehicle, regression, dt, dict(header.get("training", {})), vertical)


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
        self.vertical = model.vertical if model.uses_vertical(warm) else None
        if self.vertical is not None:
            self.vertical_inputs = list(self.vertical.features(warm, np.array([last]), 0)[0])
            self.anchor_down = float(warm.vel_n[last, 2])
        self.pushed = 0

    def given_rates(self, command: np.ndarray) -> np.ndarray | None:
        self.pushed += 1
        command = np.asarray(command, dtype=float).reshape(4)
        if self.vertical is not None and self.pushed <= self.vertical.horizon:
            self.vertical_inputs.extend(command)
        if self.pushed > self.regression.horizon:
            return None
        self.inputs.extend(command)
        return (self.anchor_rates + self.regression.change_at(self.pushed, np.asarray(self.inputs)))[None, :]

    def given_down_velocity(self) -> np.ndarray | None:
        if self.vertical is None or not 0 < self.pushed <= self.vertical.horizon:
            return None
        return self.anchor_down + self.vertical.change_at(self.pushed, np.asarray(self.vertical_inputs))


def down_acceleration(log: FlightLog, rows: np.ndarray) -> np.ndarray:
    """(len(rows),) a_D = (R f_B)_D + g [m/s²] at ``rows`` of ``log``: the down component of
    :func:`~quad_modelling.core.preprocess.nav_acceleration` (:func:`~quad_modelling.core.frames.body_to_down`)."""
    log.require(("acc_b",), "the direct model's vertical map (the accelerometer's down acceleration is an input)")
    return frames.body_to_down(log.acc_b[rows], log.euler[rows]) + GRAVITY


class DirectPredictor(WindowByStream):
    """The ``direct:PATH`` model: window (trimmed), multi-step and live forms, all causal (its carried forecast and
    compiled window stream: :mod:`~quad_modelling.core.live.direct`)."""

    def __init__(self, model: DirectModel, name: str = "direct", trim: TrimConfig | None = None) -> None:
        self.model = model
        self.name = name
        self.trim = trim or TrimConfig()

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, DirectStream]:
        """Warm rows -> (their measurement (W, 18), stream anchored on the last warm row)."""
        if len(warm) < 2:
            raise DataError(f"{warm.meta.source}: the direct model needs at least 2 warm-start samples, got {len(warm)}")
        warm.require(("gyro_b",), "the direct model (body rates at the anchor)")
        check_period(warm, self.model.dt)
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
