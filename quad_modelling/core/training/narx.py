"""Training the NARX nets (thesis chapter 4): series-parallel rows streamed in chunks from the flights' arrays, torch fit, flight segments."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.narx import (
    MIN_STD,
    OUTPUTS,
    NarxConfig,
    NarxModel,
    measured_outputs,
)
from quad_modelling.core.training.rollout import (
    VAL_FRACTION,
    RolloutConfig,
    RolloutWindows,
    hold_back_flights,
    seeded_torch,
    train_rollout,
)
from quad_modelling.core.windows import gap_free_runs, rows_between
from quad_modelling.errors import ConfigError, DataError


@dataclass
class Segment:
    """One contiguous training series: engine commands ``u`` (N, n_u) and outputs ``y`` (N, 6)."""

    u: np.ndarray
    y: np.ndarray
    source: str = ""
    span: tuple[float, float] = (0.0, 0.0)


# ---- training -----------------------------------------------------------------
def _noisy_outputs(segments: list[Segment], snr_db: tuple[float | None, ...], rng: np.random.Generator) -> list[np.ndarray]:
    """Copies of each segment's y with white noise of variance var(y_k)/10^(SNR_k/10) added."""
    all_y = np.concatenate([s.y for s in segments])
    power = all_y.var(axis=0)
    std = np.array([0.0 if snr is None else math.sqrt(p / 10.0 ** (snr / 10.0)) for p, snr in zip(power, snr_db)])
    return [s.y + rng.standard_normal(s.y.shape) * std for s in segments]


SERIES_PARALLEL_CHUNK = 4096
"""Training rows per chunk of the series-parallel loss (:func:`_fit`): the full-batch loss and its gradient are
summed chunk by chunk, so the memory of a training step is O(chunk), not O(rows)."""


def series_parallel_rows(segments: list[Segment], noisy: list[np.ndarray], u_mean: np.ndarray, u_std: np.ndarray,
                         y_mean: np.ndarray, y_std: np.ndarray, y_step: np.ndarray, config: NarxConfig) -> RolloutWindows:
    r"""Every series-parallel training row of ``segments`` as a window of n_h + 1 rows (n_h = ``config.warm_samples``).

    Row t ≥ n_h of a segment is the window of rows t − n_h … t of its arrays ``u`` = ũ (normalised commands),
    ``y`` = ỹ (normalised outputs, with the ``noisy`` ones' target noise) and ``target`` =
    :math:`(ỹ(t) − ρ\,ỹ(t−1)) / s` (ρ = 1, s = ``y_step`` for incremental nets, else ρ = 0, s = 1;
    computed in float64 before the float32 cast); :func:`regressors` turns a batch of them into the
    regressors. Same rows, same order as the stacked regressor matrix of all segments; nothing per row is stored.
    """
    arrays = []
    for s, y in zip(segments, noisy):
        y_norm = (y - y_mean) / y_std
        previous = np.vstack([y_norm[:1], y_norm[:-1]]) if config.incremental else np.zeros_like(y_norm)
        arrays.append({"u": (s.u - u_mean) / u_std, "y": y_norm, "target": (y_norm - previous) / y_step})
    return RolloutWindows(arrays, config.warm_samples, 1, 1)


def regressors(batch: dict, config: NarxConfig) -> tuple:
    r"""(X_u (B, |D_u|·n_u), X_y (B, 6, n_y), target (B, 6)) of a batch of :func:`series_parallel_rows` windows.

    With n_h = ``config.warm_samples`` the window's row n_h is t: X_u = [ũ(t − d)]_{d∈D_u} (the order of
    :func:`~quad_modelling.core.models.narx.lagged_inputs`), X_y[k] = ỹ_k(t − n_y … t − 1), oldest first.
    """
    import torch

    n_h, n_y = config.warm_samples, config.output_delays
    x_u = torch.cat([batch["u"][:, n_h - d] for d in config.input_delays], dim=1)
    return x_u, batch["y"][:, n_h - n_y: n_h].transpose(1, 2).contiguous(), batch["target"][:, n_h]


def train_narx(
    segments: list[Segment],
    dt: float,
    vehicle: str,
    config: NarxConfig = NarxConfig(),
    seed: int = 0,
    progress: bool = False,
    kind: str = "narx",
    training: dict | None = None,
    rollout: RolloutConfig | None = None,
    val_segments: list[Segment] | None = None,
) -> NarxModel:
    """Train the six nets on ``segments`` (see module doc); deterministic for a seed.

    1. Series-parallel: ``config.epochs`` L-BFGS steps on the one-step MSE (the thesis's training;
       with ``rollout`` None this is all).
    2. With ``rollout``: closed-loop fine-tuning over ``rollout.horizon`` steps from every start
       (:func:`~quad_modelling.core.training.rollout.train_rollout`, loss = mean squared
       normalised error over the horizon, :func:`rollout_loss`), early-stopped on the windows of
       ``val_segments`` (whole validation flights; None or empty = on the training loss), the
       best epoch's weights kept. The stopping epoch and losses go to ``training["rollout"]``.

    Each segment is a contiguous series at sample period ``dt`` [s]; lags never
    cross segment boundaries. Normalisation statistics come from the training
    segments only. Returns a model whose weights are float64 numpy arrays.
    ``training`` is stored in the model header (spans, sources...).
    """
    if not segments:
        raise DataError("NARX training: no training data")
    n_u = segments[0].u.shape[1]
    for s in [*segments, *(val_segments or [])]:
        if s.u.ndim != 2 or s.u.shape[1] != n_u or s.y.shape != (len(s.u), len(OUTPUTS)):
            raise DataError(f"{s.source}: training segment shapes u {s.u.shape}, y {s.y.shape} do not fit {n_u} inputs, {len(OUTPUTS)} outputs")
    usable = [s for s in segments if len(s.u) > config.warm_samples]
    if not usable:
        raise DataError(f"NARX training: every segment is shorter than the {config.warm_samples + 1} samples one training row needs")
    rng = np.random.default_rng(seed)
    all_u = np.concatenate([s.u for s in usable])
    all_y = np.concatenate([s.y for s in usable])
    u_mean, u_std = all_u.mean(axis=0), np.maximum(all_u.std(axis=0), MIN_STD)
    y_mean, y_std = all_y.mean(axis=0), np.maximum(all_y.std(axis=0), MIN_STD)
    if config.incremental:  # s_k = std of the normalised change per sample (narx module doc)
        steps = np.concatenate([np.diff((s.y - y_mean) / y_std, axis=0) for s in usable])
        y_step = np.maximum(steps.std(axis=0), MIN_STD)
    else:
        y_step = np.ones(len(OUTPUTS))
    noisy = _noisy_outputs(usable, config.noise_snr_db, rng)
    rows = series_parallel_rows(usable, noisy, u_mean, u_std, y_mean, y_std, y_step, config)
    del noisy

    info: dict = {}
    with seeded_torch(seed):
        nets = _make_nets(len(OUTPUTS), config.hidden, len(config.input_delays) * n_u, config.output_delays, y_step, config.incremental)
        _fit(nets, rows, config, progress)
    if rollout is not None:
        def windows(parts: list[Segment], stride: int) -> RolloutWindows | None:
            arrays = [{"u": (s.u - u_mean) / u_std, "y": (s.y - y_mean) / y_std} for s in parts
                      if len(s.u) >= config.warm_samples + rollout.horizon]
            return RolloutWindows(arrays, config.warm_samples, rollout.horizon, stride) if arrays else None

        train_windows, val_windows = windows(usable, rollout.stride), windows(val_segments or [], rollout.val_stride)
        if train_windows is None:
            raise DataError(f"NARX rollout training: no training segment holds {config.warm_samples + rollout.horizon} samples "
                            f"(warm start {config.warm_samples} + horizon {rollout.horizon})")
        history = train_rollout(nets, lambda module, batch: rollout_loss(module, batch, config, rollout.horizon),
                                train_windows, val_windows, rollout, seed, progress, "NARX rollout training")
        info["rollout"] = {**dataclasses.asdict(rollout), **history.to_dict(),
                           "train_windows": len(train_windows), "val_windows": 0 if val_windows is None else len(val_windows),
                           "validation": [{"source": s.source, "span": list(s.span)} for s in (val_segments or [])]}
    weights = {name: param.detach().double().numpy().copy() for name, param in nets.named_parameters()}
    return NarxModel(
        config=config, dt=float(dt), vehicle=vehicle, **weights,
        u_mean=u_mean, u_std=u_std, y_mean=y_mean, y_std=y_std, y_step=y_step, kind=kind,
        training={
            "seed": seed,
            "samples": len(rows),
            "weights": int(sum(w.size for w in weights.values())),
            "segments": [{"source": s.source, "span": list(s.span)} for s in usable],
            **info,
            **(training or {}),
        },
    )


def rollout_loss(nets, batch: dict, config: NarxConfig, horizon: int):
    """Mean over the batch, the ``horizon`` closed-loop steps and the six outputs of (ŷ − y)² in normalised units."""
    predicted = nets.rollout(batch["u"], batch["y"], config.input_delays, config.warm_samples, horizon)
    return ((predicted - batch["y"][:, config.warm_samples:]) ** 2).mean()


def _make_nets(nets: int, hidden: int, inputs: int, feedback: int, y_step: np.ndarray, incremental: bool):
    """A torch module of ``nets`` independent one-hidden-layer sigmoid nets (torch imported lazily).

    ``forward`` gives the nets' raw output w_2·h + b_2 (series-parallel); ``rollout`` the closed loop
    ỹ(t) = ρ ỹ(t−1) + s (w_2·h + b_2) with s = ``y_step``, ρ = 1 if ``incremental`` else 0.
    """
    import torch

    class BatchedNets(torch.nn.Module):
        """K independent one-hidden-layer nets evaluated together (einsum over the net axis k)."""

        def __init__(self, nets: int, hidden: int, inputs: int, feedback: int) -> None:
            super().__init__()
            self.register_buffer("y_step", torch.as_tensor(np.asarray(y_step), dtype=torch.float32)[:, None, None])
            self.rho = 1.0 if incremental else 0.0
            bound = 1.0 / math.sqrt(inputs + feedback)  # torch.nn.Linear's default scale
            self.w_u = torch.nn.Parameter(torch.empty(nets, hidden, inputs).uniform_(-bound, bound))
            self.w_y = torch.nn.Parameter(torch.empty(nets, hidden, feedback).uniform_(-bound, bound))
            self.b_1 = torch.nn.Parameter(torch.empty(nets, hidden).uniform_(-bound, bound))
            bound_out = 1.0 / math.sqrt(hidden)
            self.w_2 = torch.nn.Parameter(torch.empty(nets, hidden).uniform_(-bound_out, bound_out))
            self.b_2 = torch.nn.Parameter(torch.zeros(nets))

        def forward(self, x_u, x_y):
            z = torch.einsum("nd,khd->nkh", x_u, self.w_u) + torch.einsum("nkd,khd->nkh", x_y, self.w_y) + self.b_1
            return torch.einsum("nkh,kh->nk", torch.sigmoid(z), self.w_2) + self.b_2

        def rollout(self, u_norm, y_norm, input_delays: tuple[int, ...], history: int, horizon: int):
            """Closed loop over a batch of windows (B, history + horizon, ·) -> predicted ỹ (B, horizon, K).

            Step j predicts row history + j from the commands' taps ũ(t − d) and the fed-back
            ỹ(t − n_y … t − 1): measured for rows < history, its own predictions after.
            """
            n_y = self.w_y.shape[2]
            taps = torch.stack([u_norm[:, history - d: history - d + horizon] for d in input_delays], dim=2)
            z_u = torch.einsum("bjd,khd->jkbh", taps.flatten(2), self.w_u) + self.b_1[None, :, None, :]  # lagged_inputs order
            feedback = y_norm[:, history - n_y: history].permute(2, 0, 1)  # (K, B, n_y), oldest first
            w_y, w_2, b_2 = self.w_y.transpose(1, 2), self.w_2[:, :, None], self.b_2[:, None, None]
            outputs = []
            for z_j in z_u.unbind(0):  # one backward for all steps (indexing z_u[j] would zero-fill its gradient per step)
                y = torch.baddbmm(b_2, torch.sigmoid(torch.baddbmm(z_j, feedback, w_y)), w_2) * self.y_step  # (K, B, 1)
                if self.rho:
                    y = y + feedback[:, :, -1:]
                outputs.append(y)
                feedback = torch.cat([feedback[:, :, 1:], y], dim=2)
            return torch.cat(outputs, dim=2).permute(1, 2, 0)

    return BatchedNets(nets, hidden, inputs, feedback)


def series_parallel_loss(nets, rows: RolloutWindows, config: NarxConfig, chunk: int = SERIES_PARALLEL_CHUNK) -> float:
    r"""The full-batch series-parallel loss, its gradient added to the parameters' ``.grad`` (the caller zeroes them).

    .. math::

        L = \sum_k \frac{1}{N} \sum_{t} \big(f_k(X_u(t), X_y(t)) − \mathrm{target}_k(t)\big)^2

    (the summed per-net MSE over the N rows of ``rows``), evaluated and back-propagated ``chunk`` rows at a
    time in a fixed order (a ``DataLoader`` over ``rows``, :func:`regressors`): chunk c of :math:`n_c` rows adds
    its per-net MSE times :math:`n_c / N`, the chunks' values added in float64. The loss and gradient of one
    full batch, to float32 rounding, in O(chunk) memory; bit for bit when N ≤ ``chunk``.
    """
    from quad_modelling.core.training.rollout import rollout_loader

    count, total = len(rows), 0.0
    for batch in rollout_loader(rows, chunk, shuffle=False):
        x_u, x_y, target = regressors(batch, config)
        loss = ((nets(x_u, x_y) - target) ** 2).mean(dim=0).sum() * (len(target) / count)  # one chunk: the one-batch loss bit for bit
        loss.backward()
        total += float(loss.detach())
    return total


def _fit(nets, rows: RolloutWindows, config: NarxConfig, progress: bool) -> None:
    """Full-batch L-BFGS on :func:`series_parallel_loss` (the thesis's series-parallel training), in place."""
    import torch
    from tqdm import tqdm

    optimiser = torch.optim.LBFGS(
        nets.parameters(), lr=1.0, max_iter=config.iterations_per_epoch, history_size=20,
        line_search_fn="strong_wolfe", tolerance_grad=1e-9, tolerance_change=1e-12,
    )

    def loss_fn():
        optimiser.zero_grad()
        return torch.tensor(series_parallel_loss(nets, rows, config), dtype=torch.float64)

    bar = tqdm(range(config.epochs), desc="NARX training", unit="epoch", disable=not progress, leave=False)
    for _ in bar:
        loss = optimiser.step(loss_fn)
        bar.set_postfix(mse=f"{float(loss) / len(OUTPUTS):.4g}")


# ---- the improved (default) training ----------------------------------------------
PRETRAIN_EPOCHS = 3
"""Series-parallel L-BFGS epochs before the rollout fine-tuning (a start; the rollout does the rest)."""

DEFAULT_ROLLOUT = RolloutConfig(horizon=50, batch_size=128, max_epochs=20, patience=4, learning_rate=3e-3,
                                windows_per_epoch=4096)
"""Rollout fine-tuning of ``quad-modelling train`` (K = 50 steps = 0.5 s at 100 Hz, the SimErr horizon)."""


def rollout_preset(hidden: int = 10, output_delays: int = 20, input_delays: tuple[int, ...] = tuple(range(20)),
                   epochs: int = PRETRAIN_EPOCHS, **rollout) -> tuple[NarxConfig, RolloutConfig]:
    """The default training: incremental thesis-sized nets, no target noise, ``epochs`` series-parallel
    epochs, then :data:`DEFAULT_ROLLOUT` with ``rollout`` overrides (horizon, max_epochs...)."""
    config = NarxConfig(hidden=hidden, output_delays=output_delays, input_delays=tuple(input_delays), epochs=epochs,
                        noise_snr_db=(None,) * len(OUTPUTS), incremental=True)
    return config, dataclasses.replace(DEFAULT_ROLLOUT, **rollout)


# ---- flights -> training data -----------------------------------------------------
def span_indices(log: FlightLog, span: tuple[float, float]) -> tuple[int, int]:
    """Row range [i0, i1) of the span [a, b) seconds from the flight start, by the evaluation's row rule
    (:func:`~quad_modelling.core.windows.rows_between`); DataError when it holds fewer than 2 rows."""
    a, b = span
    i0, i1 = rows_between(log, a, b)
    if i1 - i0 < 2:
        raise DataError(f"{log.meta.source}: span {a:g}:{b:g} s holds no data (flight lasts {log.duration:.1f} s)")
    return i0, i1


def flight_segments(logs: list[FlightLog], spans: list[tuple[float, float] | None]) -> list[Segment]:
    """The NARX training segments of each (log, span), span None = the whole flight: one per part of the span
    between marked measurement gaps (:func:`~quad_modelling.core.windows.gap_free_runs`; lags never cross a gap)."""
    segments = []
    for log, span in zip(logs, spans):
        i0, i1 = (0, len(log)) if span is None else span_indices(log, span)
        for a, b in gap_free_runs(log, i0, i1):
            if b - a < 2:
                continue
            part = log.slice(a, b)
            segments.append(Segment(part.u, measured_outputs(part), log.meta.source,
                                    (float(part.t[0] - log.t[0]), float(part.t[-1] - log.t[0]))))
    return segments


def common_sample_period(logs: list[FlightLog]) -> float:
    """The logs' shared sample period [s]; DataError when they differ by more than 1 %."""
    periods = [1.0 / log.sample_rate for log in logs]
    if max(periods) > 1.01 * min(periods):
        listing = ", ".join(f"{log.meta.source}: {p * 1e3:.2f} ms" for log, p in zip(logs, periods))
        raise DataError(f"training flights have different sample periods ({listing}); resample them first")
    return float(np.mean(periods))


def validation_split(logs: list[FlightLog], spans: list[tuple[float, float] | None], fraction: float = VAL_FRACTION,
                     chosen: list[int] | None = None, seed: int = 0) -> tuple[list[Segment], list[Segment]]:
    """(training, validation) segments: whole flights held back (:func:`hold_back_flights`).

    A single flight cannot give a validation flight: then the last ``fraction`` of its span
    is held back instead (a later stretch of the same flight).
    """
    pairs = list(zip(logs, spans))
    train, val = hold_back_flights(pairs, fraction, chosen, seed)
    if not val and len(pairs) == 1 and fraction > 0:
        log, span = pairs[0]
        a, b = (0.0, log.duration) if span is None else span
        cut = b - fraction * (b - a)
        if (cut - a) * log.sample_rate < 2 * NarxConfig().warm_samples:  # said as the option, not as a segment's length
            raise ConfigError(f"--val-fraction {fraction:g} of the one flight {log.meta.source} leaves {cut - a:.2f} s to train "
                              f"on; hold back less (or give validation flights, --val-flights)")
        return flight_segments([log], [(a, cut)]), flight_segments([log], [(cut, b)])
    return flight_segments(*map(list, zip(*train))), flight_segments(*map(list, zip(*val))) if val else []


def train_narx_on_flights(
    logs: list[FlightLog],
    spans: list[tuple[float, float] | None],
    config: NarxConfig = NarxConfig(),
    seed: int = 0,
    progress: bool = False,
    rollout: RolloutConfig | None = None,
    val_fraction: float = VAL_FRACTION,
    val_flights: list[int] | None = None,
) -> NarxModel:
    """Train a NARX model on spans [s from each flight's start] of flight logs of one vehicle.

    ``rollout`` None: the thesis's series-parallel training on every flight. Otherwise the
    flights ``val_flights`` (indices), or ``val_fraction`` of them, are held back whole for
    early stopping (:func:`validation_split`) and the nets are fine-tuned closed loop.
    """
    vehicles = sorted({log.meta.vehicle for log in logs})
    if len(vehicles) != 1:
        raise DataError(f"training flights are for different vehicles {vehicles}")
    period = common_sample_period(logs)
    if rollout is None:
        return train_narx(flight_segments(logs, spans), period, vehicles[0], config, seed, progress)
    train, val = validation_split(logs, spans, val_fraction, val_flights, seed)
    return train_narx(train, period, vehicles[0], config, seed, progress, rollout=rollout, val_segments=val)
