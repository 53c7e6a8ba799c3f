r"""Hybrid model (``hybrid:PATH``): the nonlinear physics model plus a residual net inside its integration loop.

Base: :mod:`quad_modelling.core.models.physics` (state :math:`x = (p_N, v_N, R, \omega, \Omega)`, its
semi-implicit Euler :func:`~quad_modelling.core.models.physics.step` over the real sample intervals, its command
delay, its causal anchor). At every step k a small tanh MLP (:class:`~quad_modelling.core.models.residual_net.ResidualNet`)
corrects the linear and angular accelerations from the current model state and command:

.. math::

    f_k = \big(R_k^T v_{N,k},\ R_k^T e_z,\ \omega_k,\ \tilde u_k,\ \Omega_k,\ u_k,\ z_{1,k} - u_k, \dots,
    z_{M,k} - u_k\big) \in \mathbb{R}^{21 + 4M}, \qquad
    (\Delta a_{B,k}, \Delta\alpha_k) = \mathrm{net}(f_k)

    \dot v_N = a_{phys} + \hat d_v + R_k \Delta a_{B,k}, \qquad
    \dot\omega = \alpha_{phys} + \hat d_\omega + \Delta\alpha_k

(:math:`R_k^T v_N` body-frame velocity [m/s, FRD], :math:`R_k^T e_z` the gravity direction in B (roll and
pitch, yaw-free), :math:`\omega` body rates [rad/s], :math:`\tilde u` the commands the rotors answer (the physics
model's delayed commands, :func:`~quad_modelling.core.physics.rotors.delayed_commands`), :math:`\Omega` rotor speeds
[rad/s], :math:`u_k` the command logged at sample k (the controller's newest, which the rotors answer only after
the delay; a model input, like every command); :math:`z_j` the logged commands through a first-order lag of time
constant :math:`\tau_j` (the *command filters*, :data:`COMMAND_FILTERS_S`; their memory of the commands of the last
0.03-1 s, which the rotor speeds' one lag does not hold),

.. math::

    z_{j,0} = u_0, \qquad z_{j,k+1} = u_k + (z_{j,k} - u_k)\, e^{-(t_{k+1} - t_k)/\tau_j}

(:func:`filtered_commands`: :math:`z_{j,k}` reads the commands of rows < k); :math:`\Delta a_B` [m/s², FRD],
:math:`\Delta\alpha` [rad/s², FRD]). The corrected accelerations are
handed to the physics step as its per-step disturbance, so the hybrid integrates exactly as the physics model
does and reduces to it when the net's last layer is zero (a fresh net).

Causality. Every net input is the model's own predicted state and the command of that sample, so a
prediction from anchor a uses the measurements up to row a only (through the physics anchor). The constant
disturbance :math:`\hat d = (\hat d_v, \hat d_\omega)` is the physics model's observer applied to the *hybrid*:
the mean over the observer rows j = first..a-1 (the last :class:`~quad_modelling.core.models.physics.Observer`
history before the anchor, linear and angular each their own, as
:func:`~quad_modelling.core.models.physics.disturbance_estimate`) of measured minus modelled acceleration
(the angular part with the observer's trim convention), where the model now includes the net evaluated at
the measured rows,

.. math::

    \hat d(a) = \hat d_{phys}(a) - \frac{1}{t_a - t_{first}} \sum_{j=first}^{a-1}
                \big(R_j \Delta a_{B,j},\ \Delta\alpha_j\big)\, \Delta t_j

so the net learns a function of the state while the observer keeps the slowly varying bias (battery sag,
a thrust-scale error) -- the net's correction is not counted twice. Training: :mod:`quad_modelling.core.training.hybrid`.

Model files (``.npz`` through :mod:`~quad_modelling.core.models.model_files`, kind ``hybrid``): the net's
arrays, the physics constants it was trained on and the observer's histories; loading refuses another vehicle or
changed physics constants in one line. Prediction is numpy only (no torch).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models import physics
from quad_modelling.core.models.model_files import FORMAT, FORMAT_VERSION, header_flag, header_float, read_model_file
from quad_modelling.core.models.physics import Disturbance, Observer, PhysicsStream
from quad_modelling.core.physics.arrays import as_array, exp, is_symbolic, rotate, rotate_back
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import PhysicsState
from quad_modelling.core.physics.rotors import delayed_commands, effective_commands, first_order_scan
from quad_modelling.core.models.residual_net import ResidualNet
from quad_modelling.core.models.streaming import WindowByStream
from quad_modelling.core.preprocess import TrimConfig, state_measurement
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.vehicle import RENAMED_KEYS, VehicleConfig
from quad_modelling.errors import ConfigError, DataError, ModelError, reason

KIND = "hybrid"

FEATURES: tuple[str, ...] = (
    "vel_b_x", "vel_b_y", "vel_b_z", "down_b_x", "down_b_y", "down_b_z", "roll_rate", "pitch_rate", "yaw_rate",
    "u1", "u2", "u3", "u4", "rotor1", "rotor2", "rotor3", "rotor4", "u_logged1", "u_logged2", "u_logged3", "u_logged4",
)
"""The net's inputs f_k without command filters (module docstring): body velocity [m/s], gravity direction R^T e_z in
B, body rates [rad/s], delayed commands [input unit], rotor speeds [rad/s], logged commands [input unit]; with
filters :func:`features` adds their differences to the logged commands."""

COMMAND_FILTERS_S: tuple[float, ...] = (0.03, 0.1, 0.3)
"""Time constants τ_j [s] of a trained hybrid's command filters (module docstring): one near the rotor lag, one near
the attitude loop's response, one slower; chosen once, before any score, and not tuned. Held out by shape on the
NanoBench flights they took the hybrid's angular-velocity SimErr ratio from 0.642 to 0.580 pooled (every fold lower,
docs/narx.md). A model file without them (saved before) has none, and predicts as it did."""

CORRECTIONS: tuple[str, ...] = ("acc_b_x", "acc_b_y", "acc_b_z", "roll_acc", "pitch_acc", "yaw_acc")
"""The net's outputs: linear acceleration correction Δa_B [m/s², FRD], angular acceleration correction Δα [rad/s², FRD]."""

TRAINED_ON: tuple[str, ...] = ("vel_x", "vel_y", "vel_z", "roll_rate", "pitch_rate", "yaw_rate")
"""The variables the rollout loss compares (the header's ``outputs``)."""


def features(filters: tuple[float, ...]) -> tuple[str, ...]:
    """The net's input names with command filters of time constants ``filters`` [s]: :data:`FEATURES`, then per
    filter j and rotor i ``u_filtered_<τ_j in ms>ms_<i>`` (:math:`z_{j} - u`, module docstring)."""
    return FEATURES + tuple(f"u_filtered_{tau * 1000:g}ms_{i}" for tau in filters for i in range(1, 5))


def filtered_commands(u: np.ndarray, t: np.ndarray, filters: tuple[float, ...], start: np.ndarray | None = None) -> np.ndarray:
    r"""(N, M, 4) the command filters' states :math:`z_{j,k}` (module docstring) of the logged commands ``u`` (N, 4)
    stamped ``t`` (N,) [s], time constants ``filters`` (M,) [s]; ``start`` (M, 4): :math:`z_{j,0}` (None: :math:`u_0`,
    the filters settled on the first command). Row k reads the commands of rows < k only. The recursion over the
    whole series at once, as the rotor lag's (:func:`~quad_modelling.core.physics.rotors.first_order_scan`); one
    command held over the rows (a receding horizon's held inputs) in its closed form
    :math:`z_{j,k} = u_0 + (z_{j,0} - u_0)\, e^{-(t_k - t_0)/\tau_j}` (a quarter of the scan's cost)."""
    u, t = np.asarray(u, dtype=float), np.asarray(t, dtype=float)
    z = np.empty((len(u), len(filters), 4))
    if not len(u):
        return z
    z[0] = u[0] if start is None else start
    if (u[1:-1] == u[0]).all():  # held (two rows always): row k reads u_0 .. u_{k-1}, all u_0 (the last row's by none)
        z[1:] = filter_step(z[0], u[0], (t[1:] - t[0])[:, None], filters)
        return z
    decay = np.exp(-np.diff(t)[:, None, None] / np.asarray(filters, dtype=float)[None, :, None]) \
        * np.ones((1, len(filters), 4))
    gain, offset = first_order_scan(decay, (1.0 - decay) * u[:-1, None, :])
    z[1:] = gain * z[0] + offset
    return z


def filter_step(z, u, dt, filters: tuple[float, ...]):
    r"""The filters' states (..., M, 4) an interval ``dt`` [s] (scalar, or (..., 1)) after ``z`` (M, 4), the command
    ``u`` (4,) held over it: :math:`z_j' = u + (z_j - u)\, e^{-dt/\tau_j}`, the lag written once: the live streams' step,
    :func:`filtered_commands`' held closed form (dt = t_k - t_0) and, on symbolic arrays, the compiled steps'
    (:func:`~quad_modelling.core.export.casadi_model.filtered_step`)."""
    u, dt = as_array(u), np.asarray(dt, dtype=object if is_symbolic(u) else float)
    decay = exp(-dt / np.asarray(filters, dtype=float))
    return u + (as_array(z) - u) * decay[..., None]


def filter_inputs(z: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The net's filter inputs :math:`z_{j,k} - u_k`: (..., M, 4) states ``z`` and (..., 4) logged commands ``u`` ->
    (..., 4 M), filter by filter (numpy or symbolic arrays)."""
    z = as_array(z)
    return (z - as_array(u)[..., None, :]).reshape(*z.shape[:-2], -1)


def net_features(state: PhysicsState, u: np.ndarray) -> np.ndarray:
    """(B, 21 + 4M) inputs f_k (:func:`features`) of states ``state`` under commands ``u`` (B, 8 + 4M): the delayed
    commands the rotors answer, the logged ones, the command filters' inputs (:func:`hybrid_commands`)."""
    rot = state.rot
    vel_b = rotate_back(rot, state.vel_n)
    u = as_array(u)
    return np.concatenate([vel_b, rot[:, 2, :], state.rates, u[:, :4], state.rotor, u[:, 4:]], axis=1)


def hybrid_commands(p: PhysicsParameters, u: np.ndarray, t: np.ndarray, voltage=None, filters: tuple[float, ...] = ()) -> np.ndarray:
    """(N, 8 + 4M) commands of the hybrid per row: the commands the rotors answer (delayed, through the command path's
    terms with ``voltage``: :func:`~quad_modelling.core.physics.rotors.effective_commands`), the logged commands
    ``u`` (N, 4) stamped ``t`` (N,) [s], and the inputs of the command filters of time constants ``filters`` [s]
    (:func:`filter_inputs`, the filters started on row 0)."""
    u = np.asarray(u, dtype=float)
    parts = [effective_commands(p, delayed_commands(p, u, t), voltage), u]
    if filters:
        parts.append(filter_inputs(filtered_commands(u, t, filters), u))
    return np.concatenate(parts, axis=-1)


def physics_constants(p: PhysicsParameters) -> dict[str, float | list]:
    """The physics constants a hybrid model file records (and a load compares): the vehicle's physics constants,
    mass, inertias, rotor inertia, rotor positions and spins."""
    return {**{k: float(v) for k, v in p.vehicle_values().items()}, "mass": float(p.mass), "izz": float(p.inertia[2]),
            "prop_inertia": float(p.prop_inertia), "positions": np.asarray(p.positions, float).tolist(),
            "spins": np.asarray(p.spins, float).tolist()}


class ConstantsChangedError(ModelError):
    """A model file trained on other physics constants than the vehicle given holds (:func:`trained_parameters`)."""


def trained_parameters(path: Path, kind: str, stored: dict, vehicle_file: str | None, vehicle: VehicleConfig) -> PhysicsParameters:
    """The physics parameters of ``vehicle``, if they are the constants ``stored`` in model file ``path`` at training
    (:func:`physics_constants`); else ModelError (one line) naming the changed constants and the vehicle file to pass."""
    stored = {RENAMED_KEYS.get(k, k): v for k, v in stored.items()}  # a file saved before effective_ixx/iyy (physics_ixx/iyy)
    params = PhysicsParameters.from_vehicle(vehicle)
    current = physics_constants(params)
    changed = sorted(k for k in set(stored) | set(current)
                     if not np.allclose(np.asarray(stored.get(k, np.nan), float), np.asarray(current.get(k, np.nan), float), rtol=1e-12, atol=0))
    if changed:
        which = vehicle_file or f"FILE (the one given to train --{kind})"
        raise ConstantsChangedError(f"{path}: the {kind} model was trained with other physics constants of vehicle {vehicle.name!r} than "
                         f"{vehicle.path} holds ({', '.join(changed)}); pass the vehicle it was trained with: --vehicle "
                         f"{which} (export: as its VEHICLE; a node: parameter vehicle), or retrain it on these constants")
    return params


def observer_rows(t: np.ndarray, anchors: np.ndarray, history_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(first row (S,), span t_a - t_first (S,) [s]) of one part of the disturbance observer at ``anchors``: the rows
    of :func:`quad_modelling.core.models.physics.disturbance_estimate` (a test holds the two equal)."""
    anchors = np.asarray(anchors, dtype=int)
    first = np.minimum(np.searchsorted(t, t[anchors] - history_s - 1e-9, side="left"), anchors)
    return first, t[anchors] - t[first]


def observer_dict(observer: Observer) -> dict:
    return {"linear_s": observer.linear_s, "angular_s": observer.angular_s, "angular_trim": observer.angular_trim}


class HybridModel:
    """Physics constants + residual net + observer history (module docstring); numpy inference."""

    def __init__(self, params: PhysicsParameters, net: ResidualNet, vehicle: str, observer: Observer = Observer(),
                 training: dict | None = None, filters: tuple[float, ...] = ()) -> None:
        self.filters = tuple(float(tau) for tau in filters)  # the command filters' time constants [s]
        if not all(tau > 0 for tau in self.filters):
            raise ModelError(f"hybrid command filter time constants must be > 0 s, got {list(self.filters)}")
        if net.n_inputs != len(features(self.filters)) or net.n_outputs != len(CORRECTIONS):
            raise ModelError(f"hybrid residual net takes {net.n_inputs} inputs and gives {net.n_outputs} outputs, "
                             f"expected {len(features(self.filters))} and {len(CORRECTIONS)} ({len(self.filters)} command filters)")
        self.params = params
        self.net = net
        self.vehicle = vehicle
        self.observer = observer
        self.training = dict(training or {})

    # ---- the corrected dynamics ------------------------------------------------
    def correction(self, state: PhysicsState, u: np.ndarray) -> np.ndarray:
        """(B, 6) net correction as disturbance accelerations: (R Δa_B [m/s², N], Δα [rad/s², B]); ``u`` (B, 8 + 4M) as
        :func:`hybrid_commands` (so are the ``u`` of :meth:`step`, :meth:`outputs` and :meth:`rollout`)."""
        delta = self.net.forward(net_features(state, u))
        return np.concatenate([rotate(state.rot, delta[:, :3]), delta[:, 3:]], axis=1)

    def corrected(self, state: PhysicsState, u: np.ndarray, disturbance: Disturbance) -> Disturbance:
        """The per-step disturbance handed to the physics step: observer estimate plus net correction."""
        c = self.correction(state, u)
        return Disturbance(disturbance.linear_n + c[:, :3], disturbance.angular_b + c[:, 3:])

    def step(self, state: PhysicsState, u: np.ndarray, dt, disturbance: Disturbance) -> PhysicsState:
        """One hybrid step: :func:`physics.step` with the net's correction added to the disturbance."""
        return physics.step(self.params, state, u[:, :4], dt, self.corrected(state, u, disturbance))

    def outputs(self, state: PhysicsState, u: np.ndarray, disturbance: Disturbance) -> np.ndarray:
        """(B, 18) absolute VARIABLES of ``state`` under ``u``: :func:`physics.outputs` with the corrected accelerations."""
        return physics.outputs(self.params, state, u[:, :4], self.corrected(state, u, disturbance))

    # ---- the anchor -------------------------------------------------------------
    def anchor(self, log: FlightLog, anchors: np.ndarray, measured: np.ndarray | None = None) -> tuple[PhysicsState, Disturbance]:
        """(start states, hybrid observer disturbances) at rows ``anchors`` of ``log``, from rows <= anchor only."""
        if measured is None:
            measured = state_measurement(log)
        anchors = np.asarray(anchors, dtype=int)
        state, base, rotor = physics.anchor_state(self.params, log, anchors, self.observer, measured)
        last = int(anchors.max()) if len(anchors) else 0
        if self.net.is_zero() or last == 0:
            return state, base
        rows = np.arange(last)
        commands = hybrid_commands(self.params, log.u, log.t, physics.battery_voltage(self.params, log), self.filters)
        c = self.correction(physics.measured_states(self.params, measured, rotor, rows), commands[rows])
        integral = np.concatenate([np.zeros((1, 6)), np.cumsum(c * np.diff(log.t[: last + 1])[:, None], axis=0)])
        corrected = []
        for history, cols, d in ((self.observer.linear_s, slice(0, 3), base.linear_n), (self.observer.angular_s, slice(3, 6), base.angular_b)):
            first, span = observer_rows(log.t, anchors, history)
            ok = (span > 0) & (history > 0)
            mean = (integral[anchors, cols] - integral[first, cols]) / np.where(ok, span, 1.0)[:, None]
            corrected.append(d - np.where(ok[:, None], mean, 0.0))
        return state, Disturbance(*corrected)

    # ---- predictions ------------------------------------------------------------
    def rollout(self, state: PhysicsState, disturbance: Disturbance, u: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """(B, H + 1, 18) open-loop outputs as :func:`physics.rollout`: row h after h steps, with command u[:, h]."""
        horizon = dt.shape[1]
        out = np.empty((len(state.pos_n), horizon + 1, len(VARIABLES)))
        for h in range(horizon + 1):
            step_disturbance = self.corrected(state, u[:, h], disturbance)
            out[:, h] = physics.outputs(self.params, state, u[:, h, :4], step_disturbance)
            if h < horizon:
                state = physics.step(self.params, state, u[:, h, :4], dt[:, h], step_disturbance)
        return out

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute open-loop predictions from each start row, causal (IDSIA multi-step)."""
        starts = np.asarray(starts, dtype=int)
        if starts.size and (starts.min() < 0 or starts.max() + horizon >= len(segment)):
            raise DataError(f"{segment.meta.source}: multi-step starts + horizon {horizon} leave the segment")
        segment.require(("gyro_b",), "the hybrid model's multi-step form (body rates at each anchor)")
        state, disturbance = self.anchor(segment, starts)
        rows = starts[:, None] + np.arange(horizon + 1)[None, :]
        parts = [physics.horizon_commands(self.params, segment, starts, rows), segment.u[rows]]
        if self.filters:
            parts.append(filter_inputs(filtered_commands(segment.u, segment.t, self.filters), segment.u)[rows])
        commands = np.concatenate(parts, axis=-1)
        return self.rollout(state, disturbance, commands, np.diff(segment.t)[rows[:, :-1]])

    # ---- files ------------------------------------------------------------------
    def header(self) -> dict:
        return {
            "format": FORMAT, "format_version": FORMAT_VERSION, "kind": KIND, "vehicle": self.vehicle,
            "variables": list(VARIABLES), "outputs": list(TRAINED_ON),
            "config": {"hidden": list(self.net.hidden), "features": list(features(self.filters)), "corrections": list(CORRECTIONS),
                       "observer": observer_dict(self.observer), "command_filters_s": list(self.filters)},
            "dt": float(self.training.get("dt", 0.01)),
            "training": {**self.training, "physics": physics_constants(self.params)},
        }

    def save(self, path: str | Path, force: bool = False) -> Path:
        """Write the ``.npz`` model file atomically (never overwrites without ``force``)."""
        from quad_modelling.atomic import atomic_output

        path = Path(path)
        with atomic_output(path, force) as tmp:
            with open(tmp, "wb") as stream:
                np.savez(stream, header=np.array(json.dumps(self.header())), **self.net.arrays())
        return path


def load_hybrid(path: str | Path, vehicle: VehicleConfig) -> HybridModel:
    """Load a hybrid model file for ``vehicle``; ModelError (one line) for another vehicle, changed physics
    constants, or a corrupt file."""
    path = Path(path)
    header, contents = read_model_file(path, KIND, TRAINED_ON, vehicle.name, ResidualNet.stores)
    net = ResidualNet.from_arrays(contents, str(path))
    try:
        config = header["config"]
        observer = Observer(header_float(config["observer"]["linear_s"]), header_float(config["observer"]["angular_s"]),
                            header_flag(config["observer"]["angular_trim"]))
        stored = header["training"]["physics"]
        inputs = list(config["features"])
        filters = tuple(header_float(tau) for tau in config.get("command_filters_s", ()))  # none in a file saved before them
        if not isinstance(stored, dict):
            raise TypeError("training.physics is not a mapping")
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise ModelError(f"{path}: hybrid model file lacks its settings ({reason(err)})") from err
    if inputs != list(features(filters)):
        raise ModelError(f"{path}: hybrid net inputs {inputs} differ from this program's {list(features(filters))}; retrain the model")
    params = trained_parameters(path, KIND, stored, header["training"].get("vehicle_file"), vehicle)
    try:
        return HybridModel(params, net, vehicle.name, observer, dict(header.get("training", {})), filters)
    except (ModelError, ConfigError) as err:
        raise ModelError(f"{path}: {err}") from err


# ---- the predictor protocols (offline window, multi-step, live) --------------------------------------
class HybridStream(PhysicsStream):
    """Live stream of one window, as :class:`~quad_modelling.core.models.physics.PhysicsStream` (the logged commands
    of the last δ kept for the delay; ``push_at(command, t_s)`` steps over the real interval since the previous
    sample, ``push(command)`` by the warm rows' median interval) with the hybrid's step and outputs."""

    def __init__(self, model: HybridModel, state: PhysicsState, disturbance: Disturbance, times: np.ndarray,
                 commands: np.ndarray, period_s: float, voltage: float | None = None, filtered: np.ndarray | None = None) -> None:
        super().__init__(model.params, state, disturbance, times, commands, period_s, voltage)
        self.model = model
        self.filtered = filtered  # the command filters' states (M, 4) at the last sample (None: no filters)

    def net_commands(self, t_s: float, logged: np.ndarray) -> np.ndarray:
        """(1, 8 + 4M) the hybrid's commands at sample ``t_s`` whose logged command is ``logged`` (1, 4), the filters at
        their current states (:func:`hybrid_commands`' row)."""
        parts = [self._command_at(t_s), logged]
        if self.filtered is not None:
            parts.append(filter_inputs(self.filtered, logged[0])[None, :])
        return np.concatenate(parts, axis=1)

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        previous = self.times[-1]
        dt = t_s - previous
        if not dt > 0:
            raise DataError(f"hybrid stream: sample time {t_s:.6f} s is not after the previous {previous:.6f} s")
        logged = self.commands[-1]  # the command logged at the previous sample
        self.state = self.model.step(self.state, self.net_commands(previous, logged), dt, self.disturbance)
        if self.filtered is not None:
            self.filtered = filter_step(self.filtered, logged[0], dt, self.model.filters)
        self.times.append(float(t_s))
        self.commands.append(np.asarray(command, dtype=float).reshape(1, 4))
        self._forget()
        return self.model.outputs(self.state, self.net_commands(t_s, self.commands[-1]), self.disturbance)[0]


class HybridPredictor(WindowByStream):
    """The ``hybrid:PATH`` model: window (trimmed), multi-step and live forms, all causal."""

    def __init__(self, model: HybridModel, name: str = "hybrid", trim: TrimConfig | None = None) -> None:
        self.model = model
        self.name = name
        self.trim = trim or TrimConfig()

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, HybridStream]:
        """Warm rows -> (their measurement (W, 18), stream anchored on the last warm row; the observer sees the warm rows)."""
        if len(warm) < 2:
            raise DataError(f"{warm.meta.source}: the hybrid model needs at least 2 warm-start samples, got {len(warm)}")
        warm.require(("gyro_b",), "the hybrid model (body rates at the anchor)")
        measured = state_measurement(warm)
        state, disturbance = self.model.anchor(warm, np.array([len(warm) - 1]), measured)
        period = float(np.median(np.diff(warm.t)))
        voltage = physics.battery_voltage(self.model.params, warm)
        filtered = filtered_commands(warm.u, warm.t, self.model.filters)[-1] if self.model.filters else None
        return measured, HybridStream(self.model, state, disturbance, warm.t, warm.u, period,
                                      None if voltage is None else float(voltage[-1]), filtered)



    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        return self.model.predict_horizons(segment, starts, horizon)


def make_hybrid_predictor(arg: str, vehicle: VehicleConfig) -> HybridPredictor:
    """Registry factory for ``hybrid:PATH``."""
    if not arg:
        raise ConfigError("model spec hybrid needs a model file: hybrid:PATH")
    return HybridPredictor(load_hybrid(arg, vehicle))
