r"""Training the hybrid's residual net with a multi-step (rollout) loss through a torch twin of the physics step.

Data. Every gap-free part of each training span (:func:`~quad_modelling.core.windows.gap_free_runs`) is one
segment, prepared as the evaluation's multi-step form sees a segment: measured states
(:func:`~quad_modelling.core.preprocess.state_measurement`, raw rows), rotor speeds from the lag filter over the
segment's commands, the physics observer's disturbance at every row as an anchor, and the observer's rows
(:func:`~quad_modelling.core.models.hybrid.observer_rows`). :class:`~quad_modelling.core.training.rollout.RolloutWindows`
cuts windows of ``n_h`` history rows + the anchor + K steps from them (never across a segment), a seeded
``DataLoader`` batches them. Only the segments' rows are held (float32, in the datasets; the float64 arrays are
dropped before training); the net's input statistics, the naive scales and the output scale are summed segment by
segment (:func:`feature_statistics`, :func:`naive_scales`, :func:`acceleration_scale`), never over a stacked copy.

Mirror images (``mirror_images``, the default). The training flights are joined by their images under the physics
model's symmetries (:func:`~quad_modelling.core.physics.symmetry.model_symmetries`; for the Crazyflie the mirror
images across x and y and the turn by 180°): the same flight as flown in a mirror, which the physics model answers
with the mirrored motion, so the net learns the residual of both. A shape flown one way round teaches the other
way too: held out by shape (``bench/bench_models.py``), the hybrid's pooled SimErr ratios went from 0.662 / 0.346 (AV / Vel)
to 0.642 / 0.334, the figure-8 (which turns both ways) from 0.750 / 0.342 to 0.677 / 0.289, far beyond the spread of
three seeds (docs/narx.md). The validation flights stay as flown. The windows per epoch are the same, drawn from four
times the rows.

Loss. From each anchor a the hybrid is rolled out K steps through the torch twin
(:mod:`~quad_modelling.core.training.physics_torch`) -- observer correction from the net at the history rows,
then the net inside every step -- and compared with the measured velocity and body rates by the measure the
multi-step table reports (the Euclidean error norm of each group, summed over the horizons, over the naive
model's):

.. math::

    L = \frac{1}{2 B K} \sum_b \sum_{h=1}^{K} \Big( \frac{\lVert \hat v_b(a+h) - v_b(a+h) \rVert_\epsilon}{S_v}
        + \frac{\lVert \hat\omega_b(a+h) - \omega_b(a+h) \rVert_\epsilon}{S_\omega} \Big),
    \qquad \lVert e \rVert_\epsilon = \sqrt{\lVert e \rVert^2 + \epsilon^2} - \epsilon

with :math:`S_v, S_\omega` the naive (held-state) model's mean error norm over the same horizons on the
training windows, :math:`S = \mathrm{mean}_{a,h} \lVert y(a+h) - y(a) \rVert`, so L is the mean of the two
SimErr ratios to naive of the batch (L = 1: as good as naive) and the groups weigh alike; ε = 1e-3 S keeps the
gradient finite at zero error. Adam, mini-batches, early stopping on whole
training flights held back for validation (:func:`~quad_modelling.core.training.rollout.hold_back_flights`),
the best validation epoch restored; epoch 0 is the bare physics model (zero last layer), so a net that does
not beat the physics model on validation is not kept. Seeded and deterministic (one torch thread).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models import physics
from quad_modelling.core.models.hybrid import COMMAND_FILTERS_S, HybridModel, hybrid_commands, observer_dict, observer_rows
from quad_modelling.core.models.physics import Observer
from quad_modelling.core.physics import arrays, rigid_body, rotors
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.symmetry import model_symmetries
from quad_modelling.core.models.residual_net import ResidualNet
from quad_modelling.core.training.rollout import (
    VAL_FRACTION,
    RolloutConfig,
    RolloutWindows,
    hold_back_flights,
    seeded_torch,
    train_rollout,
)
from quad_modelling.core.preprocess import measured_variables, state_measurement
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import gap_free_runs, rows_between
from quad_modelling.errors import ConfigError, DataError


HYBRID_HIDDEN = (32, 32)
"""Default widths of the residual net's hidden layers (21 inputs and 12 of the command filters, 6 outputs: about 2.3k weights)."""


HYBRID_ROLLOUT = RolloutConfig(horizon=50, stride=1, val_stride=5, batch_size=256, max_epochs=12, patience=3,
                               learning_rate=2e-3, grad_clip=1.0, windows_per_epoch=8192, val_batch_size=2048)
"""Default rollout settings of the hybrid: 8192 windows (32 Adam steps of 256) per epoch, at most 12 epochs, patience 3;
the validation loss in batches of 2048 windows.

The rollout is bound by the cost of each tensor operation (about 200 per step of the torch twin, on (B, 3) tensors,
and 101 autograd nodes back), not by the batch: a batch of 512 windows costs 1.4x one of 256 on one thread (measured
before the step ran as a TorchScript trace, :func:`~quad_modelling.core.training.rollout.traced_step`). Measured by
shape on the NanoBench flights (bench/results/training_time_b512.md): 16 steps of 512 per epoch at step size 2.8e-3
trained in 0.63-0.75x the CPU time, with held-out SimErr ratios 0.668 / 0.346 (AV / Vel) against 0.664 / 0.344: a
little accuracy lost, so not the default. 1024 windows at 4e-3 stopped at epoch 5 on two folds (the validation loss rose), and a cosine decay of
the step size cost angular velocity (0.679): the training still improves at epoch 12."""


@dataclass(frozen=True)
class HybridTrainingConfig:
    """Settings of :func:`train_hybrid` (defaults: what the leave-one-shape-out bench uses).

    hidden: widths of the net's tanh hidden layers. observer: the disturbance observer (the physics model's default).
    rollout: K, stride, batch, epochs, patience, learning rate (:class:`RolloutConfig`).
    val_fraction: fraction of the training flights held back (whole flights) for early stopping.
    mirror_images: train on the training flights' images under the physics model's symmetries too (module docstring).
    command_filters_s: time constants [s] of the net's command filters
        (:data:`~quad_modelling.core.models.hybrid.COMMAND_FILTERS_S`; empty: none, the 21 inputs of before).
    """

    hidden: tuple[int, ...] = HYBRID_HIDDEN
    observer: Observer = field(default_factory=Observer)
    rollout: RolloutConfig = field(default_factory=lambda: HYBRID_ROLLOUT)
    val_fraction: float = VAL_FRACTION
    mirror_images: bool = True
    command_filters_s: tuple[float, ...] = COMMAND_FILTERS_S

    def __post_init__(self) -> None:
        if not self.hidden or min(self.hidden) < 1:
            raise ConfigError(f"hybrid training: hidden layer widths must be >= 1, got {self.hidden}")
        if not all(tau > 0 for tau in self.command_filters_s):
            raise ConfigError(f"hybrid training: command filter time constants must be > 0 s, got {list(self.command_filters_s)}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["hidden"] = list(self.hidden)
        d["command_filters_s"] = list(self.command_filters_s)
        d["observer"] = observer_dict(self.observer)
        return d


# ---- data --------------------------------------------------------------------------------------------
def segment_arrays(p: PhysicsParameters, segment: FlightLog, observer: Observer, filters: tuple[float, ...] = ()) -> dict[str, np.ndarray]:
    """Row-aligned arrays of one gap-free segment for :class:`RolloutWindows` (module docstring); ``u`` (N, 8 + 4M) holds
    the delayed commands the rotors answer, the logged ones and the inputs of the command filters of time constants
    ``filters`` (:func:`~quad_modelling.core.models.hybrid.hybrid_commands`)."""
    measured = state_measurement(segment)
    rows = np.arange(len(segment))
    commands = hybrid_commands(p, segment.u, segment.t, physics.battery_voltage(p, segment), filters)  # per-row voltage (training only)
    rotor = rotors.rotor_speeds(p, commands[:, :4], segment.t)
    disturbance = physics.disturbance_estimate(p, segment.t, commands[:, :4], measured, rotor, rows, observer)
    dt = np.diff(segment.t)
    arrays = {
        "pos": measured[:, 0:3], "vel": measured[:, 3:6], "rot": physics.measured_states(p, measured, rotor, rows).rot.reshape(-1, 9),
        "rates": measured[:, 12:15], "rotor": rotor, "u": commands, "dt": np.append(dt, np.median(dt))[:, None],
        "d": np.concatenate([disturbance.linear_n, disturbance.angular_b], axis=1),
    }
    for part, history in (("lin", observer.linear_s), ("ang", observer.angular_s)):
        first, span = observer_rows(segment.t, rows, history)
        if history <= 0:  # that part of the observer is off: no history row counts
            first, span = rows, np.zeros(len(rows))
        arrays[f"obs_n_{part}"] = (rows - first)[:, None].astype(float)
        arrays[f"obs_span_{part}"] = np.where(span > 0, span, 1.0)[:, None]
    return arrays


def flight_segments(p: PhysicsParameters, logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None],
                    observer: Observer, filters: tuple[float, ...] = ()) -> list[dict[str, np.ndarray]]:
    """The arrays of every gap-free part (of two rows or more) of each flight's span (None: the whole flight), with the
    command filters of time constants ``filters`` [s] (:func:`segment_arrays`)."""
    segments = []
    for log, span in zip(logs, spans):
        log.require(("gyro_b",), "hybrid training (its loss compares gyro rates)")
        start, stop = (0, len(log)) if span is None else rows_between(log, *span)
        for a, b in gap_free_runs(log, start, stop):
            if b - a >= 2:
                segments.append(segment_arrays(p, log.slice(a, b), observer, filters))
    return segments


def feature_statistics(segments: list[dict[str, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    r"""(mean, standard deviation) (21 + 4M,) of the net inputs at every measured row of ``segments`` (the net's
    normalisation), one segment at a time: each segment's count :math:`n_i`, mean :math:`\bar f_i` and
    :math:`M_i = \sum (f - \bar f_i)^2` are merged by Chan's rule,
    :math:`M = M_a + M_b + δ^2 n_a n_b / (n_a + n_b)` with :math:`δ = \bar f_b − \bar f_a`, so no array of
    every row's inputs is built; std = :math:`\sqrt{M / n}` (population, as ``np.std``)."""
    from quad_modelling.core.models.hybrid import net_features

    count, mean, m2 = 0, None, None
    for s in segments:
        state = rigid_body.PhysicsState(s["pos"], s["vel"], s["rot"].reshape(-1, 3, 3), s["rates"], s["rotor"],
                                     np.zeros(len(s["vel"])))
        f = net_features(state, s["u"])
        n, f_mean = len(f), f.mean(axis=0)
        f_m2 = ((f - f_mean) ** 2).sum(axis=0)
        if mean is None:
            count, mean, m2 = n, f_mean, f_m2
            continue
        delta = f_mean - mean
        total = count + n
        mean = mean + delta * (n / total)
        m2 = m2 + f_m2 + delta**2 * (count * n / total)
        count = total
    if mean is None:
        raise DataError("hybrid training: no training segment")
    return mean, np.sqrt(m2 / count)


def naive_scales(segments: list[dict[str, np.ndarray]], horizon: int) -> tuple[float, float]:
    """(S_v [m/s], S_ω [rad/s]): the held-state model's mean velocity / rate error norm over horizons 1..K (module docstring)."""
    sums, count = np.zeros(2), 0
    for s in segments:
        n = len(s["vel"])
        for h in range(1, min(horizon, n - 1) + 1):
            sums += [np.linalg.norm(s["vel"][h:] - s["vel"][:-h], axis=1).sum(),
                     np.linalg.norm(s["rates"][h:] - s["rates"][:-h], axis=1).sum()]
            count += n - h
    if count == 0:
        raise DataError("hybrid training: no segment longer than one step")
    return tuple(np.maximum(sums / count, 1e-9))


def acceleration_scale(p: PhysicsParameters, logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None]) -> np.ndarray:
    """(6,) output scale of the net: RMS of (measured − modelled) linear acceleration in B [m/s²] and angular
    acceleration [rad/s²] over the ``spans`` of ``logs``, less each flight's mean (the observer's part): the size of
    what is left for the net to correct."""
    squares, rows = np.zeros(6), 0  # summed per flight: no array of every row is kept
    for log, span in zip(logs, spans):
        if span is not None:
            log = log.slice(*rows_between(log, *span))
        if len(log) < 2:
            continue
        measured = measured_variables(log)
        commands = physics.rotor_commands(p, log)
        rotor = rotors.rotor_speeds(p, commands, log.t)
        state = physics.measured_states(p, measured, rotor, np.arange(len(log)))
        acc_n, ang_acc = rigid_body.accelerations(p, state.vel_n, state.rot, state.rates, rotor, rotors.rotor_acceleration(p, rotor, commands),
                                                  state.pos_n)
        lin_b = arrays.rotate_back(state.rot, measured[:, 6:9] - acc_n)
        residual = np.concatenate([lin_b, measured[:, 15:18] - ang_acc], axis=1)
        residual = residual[np.all(np.isfinite(residual), axis=1)]
        squares += ((residual - residual.mean(axis=0)) ** 2).sum(axis=0)
        rows += len(residual)
    return np.maximum(np.sqrt(squares / rows), 1e-3) if rows else np.ones(6)


# ---- the torch module and the loss -------------------------------------------------------------------
def _make_module(in_mean, in_std, out_scale, hidden):
    import torch

    class Net(torch.nn.Module):
        """The residual MLP (residual_net.ResidualNet's equations); last layer zero."""

        def __init__(self) -> None:
            super().__init__()
            widths = [len(in_mean), *hidden]
            self.hidden = torch.nn.ModuleList(torch.nn.Linear(a, b) for a, b in zip(widths[:-1], widths[1:]))
            self.last = torch.nn.Linear(widths[-1], len(out_scale))
            torch.nn.init.zeros_(self.last.weight)
            torch.nn.init.zeros_(self.last.bias)
            self.register_buffer("in_mean", torch.as_tensor(in_mean, dtype=torch.float32))
            self.register_buffer("in_std", torch.as_tensor(in_std, dtype=torch.float32))
            self.register_buffer("out_scale", torch.as_tensor(out_scale, dtype=torch.float32))

        def forward(self, f):
            h = (f - self.in_mean) / self.in_std
            for layer in self.hidden:
                h = torch.tanh(layer(h))
            return self.last(h) * self.out_scale

        def to_numpy(self) -> ResidualNet:
            layers = [*self.hidden, self.last]
            return ResidualNet([l.weight.detach().double().numpy().copy() for l in layers],
                               [l.bias.detach().double().numpy().copy() for l in layers],
                               self.in_mean.double().numpy().copy(), self.in_std.double().numpy().copy(),
                               self.out_scale.double().numpy().copy())

    return Net()


def _features(vel_n, rot, rates, u, rotor):
    import torch

    vel_b = (rot * vel_n[..., :, None]).sum(dim=-2)
    return torch.cat([vel_b, rot[..., 2, :], rates, u[..., :4], rotor, u[..., 4:]], dim=-1)


def _make_step(tp, net):
    """The torch Module of one rollout step of the hybrid (the module docstring's loss): the net's correction at the
    state, then the twin step, ``forward(pos_n, vel_n, rot, rates, rotor, yaw, u (B, 8), dt (B,), d (B, 6))`` -> the
    next state's six tensors; ``net`` is its submodule (shared, not copied)."""
    import torch

    from quad_modelling.core.physics import arrays
    from quad_modelling.core.training import physics_torch as pt

    class Step(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = net

        def forward(self, pos_n, vel_n, rot, rates, rotor, yaw, u, dt, d):
            delta = self.net(_features(vel_n, rot, rates, u, rotor))
            lin = d[..., :3] + arrays.rotate(rot, delta[..., :3])
            return tuple(pt.step(tp, pt.TorchState(pos_n, vel_n, rot, rates, rotor, yaw), u[..., :4], dt, lin, d[..., 3:] + delta[..., 3:]))

    return Step()


def rollout_loss(tp, history: int, horizon: int, scales: tuple[float, float]):
    """``loss_fn(module, batch)`` of :func:`train_rollout` (module docstring): observer, then K twin steps, each the
    :func:`_make_step` module run as a TorchScript trace (:func:`~quad_modelling.core.training.rollout.traced_step`,
    made at the first batch for each net: the same losses and gradients bit for bit, in less time)."""
    import torch

    from quad_modelling.core.training.rollout import traced_step

    scale_v, scale_w = (float(s) for s in scales)
    eps_v, eps_w = 1e-3 * scale_v, 1e-3 * scale_w
    traced = {}  # net -> its traced step

    def norm(e, eps):
        return torch.sqrt((e * e).sum(dim=-1) + eps * eps) - eps

    def loss_fn(net, batch):
        a = history
        rot = batch["rot"].reshape(*batch["rot"].shape[:2], 3, 3)
        # observer: mean of the net's correction over the history rows first..a-1, weighted by Δt_j / span
        f_hist = _features(batch["vel"][:, :a], rot[:, :a], batch["rates"][:, :a], batch["u"][:, :a], batch["rotor"][:, :a])
        delta = net(f_hist)
        c_hist = torch.cat([(rot[:, :a] * delta[..., None, :3]).sum(dim=-1), delta[..., 3:]], dim=-1)
        back = torch.arange(a, 0, -1, dtype=batch["dt"].dtype)[None, :]  # rows before the anchor: a - j
        corrections = []
        for part, cols in (("lin", slice(0, 3)), ("ang", slice(3, 6))):
            weight = batch["dt"][:, :a, 0] * (back <= batch[f"obs_n_{part}"][:, a]) / batch[f"obs_span_{part}"][:, a]
            corrections.append((c_hist[..., cols] * weight[..., None]).sum(dim=1))
        d = batch["d"][:, a] - torch.cat(corrections, dim=1)
        b = len(d)
        state = (batch["pos"][:, a], batch["vel"][:, a], rot[:, a], batch["rates"][:, a], batch["rotor"][:, a], torch.zeros_like(d[:, 0]))
        if net not in traced:
            traced[net] = traced_step(_make_step(tp, net), (*state, batch["u"][:, a], batch["dt"][:, a, 0], d))
        step = traced[net]
        velocities, rates = [], []
        for k in range(horizon):
            state = step(*state, batch["u"][:, a + k], batch["dt"][:, a + k, 0], d)
            velocities.append(state[1])
            rates.append(state[3])
        # the error norms of every step at once (B, K): a few operations instead of a dozen per step
        loss = norm(torch.stack(velocities, dim=1) - batch["vel"][:, a + 1:a + horizon + 1], eps_v).sum() / scale_v \
            + norm(torch.stack(rates, dim=1) - batch["rates"][:, a + 1:a + horizon + 1], eps_w).sum() / scale_w
        return loss / (2.0 * b * horizon)

    return loss_fn


# ---- training ----------------------------------------------------------------------------------------
def train_hybrid(p: PhysicsParameters, vehicle: str, logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None],
                 config: HybridTrainingConfig = HybridTrainingConfig(), seed: int = 0, progress: bool = False,
                 val_flights: Sequence[int] | None = None) -> HybridModel:
    """Train a hybrid model on the ``spans`` of ``logs`` (module docstring); deterministic for a seed.

    Whole flights are held back for validation (``val_flights`` by index, else ``config.val_fraction`` of them;
    a single flight validates on its own windows). Returns the model with the net of the best validation epoch
    and the training record (losses per epoch, best/stopping epoch, flights) in ``model.training``.
    """
    import torch

    from quad_modelling.core.training import physics_torch as pt

    if not logs or len(logs) != len(spans):
        raise DataError(f"hybrid training: {len(logs)} flights for {len(spans)} spans")
    names = sorted({log.meta.vehicle for log in logs})
    if names != [vehicle]:
        raise DataError(f"hybrid training: flights are for vehicle(s) {names}, the physics model for {vehicle!r}")
    rc = config.rollout
    started = time.perf_counter()
    indices = list(range(len(logs)))
    train_idx, val_idx = hold_back_flights(indices, config.val_fraction, val_flights, seed)
    dts = np.concatenate([np.diff(log.t) for log in logs])
    images = model_symmetries(p)[1:] if config.mirror_images else ()  # [0] is the identity
    train_logs, train_spans = [logs[i] for i in train_idx], [spans[i] for i in train_idx]
    train_segments = flight_segments(p, [*train_logs, *(s.image(log) for s in images for log in train_logs)],
                                     train_spans * (1 + len(images)), config.observer, config.command_filters_s)
    val_segments = flight_segments(p, [logs[i] for i in val_idx], [spans[i] for i in val_idx], config.observer,
                                   config.command_filters_s)
    # history rows of a window: the most observer rows any anchor has (50 at 100 Hz and 0.5 s)
    history = max([int(s[f"obs_n_{part}"].max()) for s in train_segments + val_segments for part in ("lin", "ang")] + [1])
    if not any(len(s["u"]) > history + rc.horizon for s in train_segments):
        raise DataError(f"hybrid training: no gap-free part of the training spans holds the {history + rc.horizon + 1} rows one "
                        f"{rc.horizon}-step window with its observer history needs")
    in_mean, in_std = feature_statistics(train_segments)
    scales = naive_scales(train_segments, rc.horizon)
    out_scale = acceleration_scale(p, train_logs, train_spans)
    samples = int(sum(len(s["u"]) for s in train_segments)) // (1 + len(images))  # the flights' own rows
    train_set = RolloutWindows(train_segments, history, rc.horizon + 1, rc.stride)
    val_set = RolloutWindows(val_segments, history, rc.horizon + 1, rc.val_stride) if val_segments else None
    del train_segments, val_segments  # the datasets hold the rows (float32): the float64 copies go before training
    prepared = time.perf_counter() - started
    with seeded_torch(seed, rc.threads):
        net = _make_module(in_mean, np.maximum(in_std, 1e-6), out_scale, config.hidden)
        loss_fn = rollout_loss(pt.TorchParameters.from_params(p, torch.float32), history, rc.horizon, scales)
        record = train_rollout(net, loss_fn, train_set, val_set, rc, seed, progress, desc="hybrid rollout training")
        residual = net.to_numpy()
    training = {
        "seed": seed, "dt": float(np.median(dts)), "config": config.to_dict(), "history_rows": history,
        "naive_error": {"velocity": scales[0], "angular_velocity": scales[1]},
        "flights": [logs[i].meta.source for i in train_idx], "validation_flights": [logs[i].meta.source for i in val_idx],
        "mirror_images": [s.name for s in images],
        "spans": [None if s is None else list(s) for s in spans], "windows": len(train_set),
        "validation_windows": 0 if val_set is None else len(val_set),
        "samples": samples, "prepare_seconds": round(prepared, 3),
        "rollout": {**record.to_dict(), "val_windows": len(val_set) if val_set is not None else len(train_set)},
    }
    return HybridModel(p, residual, vehicle, config.observer, training, config.command_filters_s)


def train_hybrid_on_flights(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], vehicle: VehicleConfig,
                            config: HybridTrainingConfig = HybridTrainingConfig(), seed: int = 0, progress: bool = False,
                            val_flights: Sequence[int] | None = None) -> HybridModel:
    """:func:`train_hybrid` with the physics constants of ``vehicle`` (ConfigError naming any missing one); the
    model's training record names the vehicle file (``vehicle_file``), so a load with other constants can say which
    ``--vehicle`` to pass."""
    model = train_hybrid(PhysicsParameters.from_vehicle(vehicle), vehicle.name, logs, spans, config, seed, progress, val_flights)
    model.training["vehicle_file"] = vehicle.file_path
    return model
