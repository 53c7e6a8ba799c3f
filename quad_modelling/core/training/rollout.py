"""Closed-loop (rollout) training of recurrent models on flight windows: dataset, loader, early stopping.

Generic part of every multi-step trained model (NARX, the hybrid's residual nets). A
*segment* is a dict of row-aligned arrays cut from one gap-free part of one flight
(e.g. ``{"u": (N, 4) normalised commands, "y": (N, 6) normalised outputs}``; any keys,
any trailing shapes). A *rollout window* starting at row ``s`` of a segment is rows

.. math::

    s − n_h, …, s − 1, s, …, s + K − 1       (n_h = ``history``, K = ``horizon``)

of every array: the model may use the measured rows before ``s`` (its warm start) and
the exogenous channels over the whole window, and predicts rows ``s … s + K − 1``
closed loop (its own predictions fed back). The caller's ``loss_fn(module, batch)``
does that rollout and returns the loss, e.g. the mean over the K steps and the batch of
the squared normalised error, :math:`L = \\frac{1}{B K} \\sum_b \\sum_{k<K} \\lVert ŷ_b(s+k) − y_b(s+k)\\rVert^2`.

API
---
* :class:`RolloutWindows` -- a ``torch.utils.data.Dataset`` of every window of the
  segments (start stride ``stride``); indexing with a list of window numbers returns one
  batch (dict of float32 tensors shaped (B, n_h + K, ...)), gathered at once (no per-item
  Python loop); windows never cross a segment boundary.
* :func:`rollout_loader` -- a ``DataLoader`` over it yielding such batches, shuffled by a
  seeded generator (same seed, same batches), optionally ``windows_per_epoch`` of them.
* :func:`hold_back_flights` -- whole flights held back for validation
  (:data:`VAL_FRACTION` of them by default, or the ones named).
* :func:`train_rollout` -- Adam on ``loss_fn`` with gradient-norm clipping, the validation
  loss after every epoch, early stopping after ``patience`` epochs without improvement,
  and the weights of the best validation epoch restored; returns a :class:`RolloutHistory`
  (per-epoch losses, best epoch, stopping epoch).
* :func:`seeded_torch` -- the deterministic torch context every trainer runs in (seed,
  deterministic algorithms, a fixed number of threads).
* :func:`traced_step` -- a rollout's step module as a TorchScript trace (the same operations, run by
  TorchScript's interpreter instead of Python: a step of a few hundred small operations costs less).

torch is imported lazily (predicting never needs it).
"""

from __future__ import annotations

import contextlib
import copy
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from quad_modelling.errors import ConfigError, DataError

if TYPE_CHECKING:
    import torch

VAL_FRACTION = 0.2
"""Default fraction of the training flights held back (whole flights) for early stopping."""

T = TypeVar("T")


@dataclass(frozen=True)
class RolloutConfig:
    """Settings of :func:`train_rollout`.

    horizon: K, closed-loop steps per window (50 = 0.5 s at 100 Hz, the IDSIA SimErr horizon).
    stride: rows between consecutive training window starts; val_stride: the same for validation
        windows (the validation loss is a mean: every 5th start measures it at a fifth of the cost).
    batch_size: windows per mini-batch.
    max_epochs: most passes; patience: epochs without a better validation loss before stopping.
    learning_rate: Adam step size; weight_decay: Adam's L2 term; grad_clip: largest gradient norm.
    windows_per_epoch: windows drawn (without replacement) per epoch, None = all.
    threads: torch threads (1 = bit-identical runs on any machine).
    val_batch_size: windows per batch of the validation loss (None: batch_size); no gradient is kept there, so a
        larger batch costs little memory and saves the per-operation overhead of many small rollouts.
    """

    horizon: int = 50
    stride: int = 1
    val_stride: int = 5
    batch_size: int = 256
    max_epochs: int = 30
    patience: int = 5
    learning_rate: float = 3e-3
    weight_decay: float = 0.0
    grad_clip: float = 1.0
    windows_per_epoch: int | None = None
    threads: int = 1
    val_batch_size: int | None = None

    def __post_init__(self) -> None:
        if min(self.horizon, self.stride, self.val_stride, self.batch_size, self.threads) < 1 or self.max_epochs < 0 or self.patience < 1:
            raise ConfigError(f"rollout training: horizon, stride, batch_size, threads, patience must be >= 1 and max_epochs >= 0, got {self}")
        if not (self.learning_rate > 0 and self.grad_clip > 0 and self.weight_decay >= 0):
            raise ConfigError(f"rollout training: learning_rate and grad_clip must be > 0, weight_decay >= 0, got {self}")
        for name in ("windows_per_epoch", "val_batch_size"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ConfigError(f"rollout training: {name} must be >= 1 or None, got {getattr(self, name)}")


@dataclass
class RolloutHistory:
    """What :func:`train_rollout` did: losses per epoch (index 0 = before training), the best epoch restored."""

    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    best_epoch: int = 0
    epochs_run: int = 0
    stopped_early: bool = False
    seconds: float = 0.0
    validation_seconds: float = 0.0

    def to_dict(self) -> dict:
        return {"train_loss": self.train_loss, "val_loss": self.val_loss, "best_epoch": self.best_epoch,
                "epochs_run": self.epochs_run, "stopped_early": self.stopped_early, "seconds": round(self.seconds, 3),
                "validation_seconds": round(self.validation_seconds, 3)}


class RolloutWindows:
    """Every rollout window of ``segments`` (see module doc); a map-style dataset for ``torch.utils.data.DataLoader``.

    ``dataset[i]`` is window i as a dict of (n_h + K, ...) tensors; ``dataset[[i, j, ...]]``
    a batch of (B, n_h + K, ...) tensors, gathered from the segments' rows when asked. Segments
    shorter than n_h + K give no window.

    Memory: the segments' arrays once, as float32 (:attr:`arrays`), and two numbers per segment;
    nothing per window. Window i of segment k (the k-th with :attr:`first` [k] ≤ i < :attr:`first` [k+1])
    starts at joined row :attr:`offsets` [k] + (i − first[k]) · stride.
    """

    def __init__(self, segments: Sequence[Mapping[str, np.ndarray]], history: int, horizon: int, stride: int = 1) -> None:
        import torch

        if history < 0 or horizon < 1 or stride < 1:
            raise ConfigError(f"rollout windows: need history >= 0, horizon >= 1, stride >= 1, got {history}, {horizon}, {stride}")
        if not segments:
            raise DataError("rollout windows: no segments")
        keys = sorted(segments[0])
        self.history, self.horizon, self.length, self.stride = history, horizon, history + horizon, stride
        counts, offsets, offset = [], [], 0
        for n, segment in enumerate(segments):
            if sorted(segment) != keys:
                raise DataError(f"rollout windows: segment {n} has arrays {sorted(segment)}, expected {keys}")
            rows = {len(a) for a in segment.values()}
            if len(rows) != 1:
                raise DataError(f"rollout windows: segment {n} arrays have different lengths {sorted(rows)}")
            rows = rows.pop()
            counts.append(max(0, (rows - self.length) // stride + 1))
            offsets.append(offset)
            offset += rows
        self.first = torch.from_numpy(np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))  # (S + 1,) window numbers
        self.offsets = torch.as_tensor(offsets, dtype=torch.int64)  # (S,) first row of each segment in the joined arrays
        self.arrays = {k: torch.from_numpy(np.concatenate([np.asarray(s[k], dtype=np.float32) for s in segments])) for k in keys}
        self._steps = torch.arange(self.length)

    def __len__(self) -> int:
        return int(self.first[-1])

    def starts(self, index) -> torch.Tensor:
        """First joined row of each window in ``index`` (an int64 tensor of window numbers)."""
        import torch

        if len(index) and (int(index.min()) < 0 or int(index.max()) >= len(self)):
            raise IndexError(f"rollout windows: window numbers must lie in 0..{len(self) - 1}")
        segment = torch.searchsorted(self.first, index, right=True) - 1
        return self.offsets[segment] + (index - self.first[segment]) * self.stride

    def __getitem__(self, index) -> dict:
        import torch

        single = isinstance(index, (int, np.integer))
        idx = torch.as_tensor([index] if single else index, dtype=torch.int64)
        rows = self.starts(idx)[:, None] + self._steps[None, :]  # (B, L)
        batch = {k: a[rows] for k, a in self.arrays.items()}
        return {k: v[0] for k, v in batch.items()} if single else batch


def rollout_loader(dataset: RolloutWindows, batch_size: int, shuffle: bool = True, seed: int = 0,
                   windows_per_epoch: int | None = None):
    """A ``torch.utils.data.DataLoader`` yielding batches (dicts of (B, n_h + K, ...) tensors) of ``dataset``.

    Shuffled with a generator seeded by ``seed`` (the same seed gives the same batches);
    ``windows_per_epoch`` draws that many windows without replacement per pass.
    """
    import torch
    from torch.utils.data import BatchSampler, DataLoader, RandomSampler, SequentialSampler

    generator = torch.Generator().manual_seed(int(seed))
    if shuffle:
        count = None if windows_per_epoch is None else min(int(windows_per_epoch), len(dataset))
        sampler = RandomSampler(range(len(dataset)), num_samples=count, generator=generator)
    else:
        sampler = SequentialSampler(range(len(dataset)))
    return DataLoader(dataset, sampler=BatchSampler(sampler, batch_size=batch_size, drop_last=False), batch_size=None)


def hold_back_flights(flights: Sequence[T], fraction: float = VAL_FRACTION, chosen: Sequence[int] | None = None,
                      seed: int = 0) -> tuple[list[T], list[T]]:
    """(training, validation) flights: whole flights held back for early stopping.

    ``chosen`` names the validation flights by index; otherwise round(fraction · n) of them
    (at least one when n ≥ 2 and fraction > 0, never all) picked by a permutation seeded
    with ``seed``. One flight cannot be split into flights: it is returned with no validation.
    """
    n = len(flights)
    if chosen is not None:
        bad = [i for i in chosen if not 0 <= i < n]
        if bad or len(set(chosen)) != len(chosen) or len(chosen) >= n:
            raise ConfigError(f"validation flights {list(chosen)}: need distinct indices in 0..{n - 1}, leaving a training flight")
        val = sorted(chosen)
    else:
        if not 0 <= fraction < 1:
            raise ConfigError(f"validation fraction {fraction}: must lie in [0, 1)")
        count = 0 if n < 2 or fraction == 0 else min(n - 1, max(1, round(fraction * n)))
        val = sorted(np.random.default_rng(seed).permutation(n)[:count].tolist())
    return [f for i, f in enumerate(flights) if i not in val], [flights[i] for i in val]


@contextlib.contextmanager
def seeded_torch(seed: int, threads: int = 1) -> Iterator[None]:
    """Run the block with torch seeded, deterministic algorithms on and ``threads`` threads; restored after."""
    import torch

    old_threads, old_det = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True)
    torch.manual_seed(seed)
    try:
        yield
    finally:
        torch.set_num_threads(old_threads)
        torch.use_deterministic_algorithms(old_det)


def traced_step(module, example_inputs: tuple) -> Callable:
    """``module`` (a torch Module whose ``forward`` takes and returns tensors) as a TorchScript trace of its forward on
    ``example_inputs``, sharing its parameters (an optimiser of ``module`` trains the trace); the callable runs the
    trace with TorchScript's graph optimisation off.

    Why: a rollout step of small tensors is bound by the cost of each operation, much of it Python's (the physics
    functions, their backend checks, the tensors' indexing). The trace runs the same ATen operations from
    TorchScript's interpreter; without the graph optimisation the backward is autograd's own, so outputs and
    gradients are bit-identical to the module's (with it, TorchScript differentiates with its own formulas: the
    same to rounding, not bit for bit; CPU fusion is off in torch either way). Measured on the hybrid's 50-step
    rollout (B 256, one thread, torch 2.13, alternated in one process): forward and backward 0.81-0.85x; with the
    physics indexed without no-op slices (``x[..., k]``, not ``x[:, k]``, which a trace records as a full slice and
    its backward as a copy), 0.70x, and the whole training 0.71x (bench/results/training_time.md).
    ``torch.export``'s module runs the same operations from Python (1.0x); ``torch.compile`` was 3.5-4x faster but
    needs a C compiler and compiled for 55 s at each new batch shape. So the trace, although torch calls
    ``torch.jit.trace`` deprecated; its warnings are silenced here.

    The trace holds no Python branch on tensor values (the physics selects with ``where``) and no batch size, so it
    serves every batch size (test). It is made with gradients on, whatever the caller's mode, so it records the
    graph the training differentiates.
    """
    import warnings

    import torch

    with warnings.catch_warnings(), torch.enable_grad():
        warnings.simplefilter("ignore")  # "torch.jit.trace is deprecated", "torch.tensor results are registered as constants"
        trace = torch.jit.trace(module, tuple(example_inputs), check_trace=False)

    def run(*inputs):
        with torch.jit.optimized_execution(False):
            return trace(*inputs)

    return run


def mean_loss(module, loss_fn: Callable, dataset: RolloutWindows, batch_size: int) -> float:
    """The loss over every window of ``dataset`` (batch losses weighted by batch size), without gradients."""
    import torch

    total, count = 0.0, 0
    with torch.no_grad():
        for batch in rollout_loader(dataset, batch_size, shuffle=False):
            b = len(next(iter(batch.values())))
            total += float(loss_fn(module, batch)) * b
            count += b
    return total / max(count, 1)


def train_rollout(module, loss_fn: Callable, train: RolloutWindows, val: RolloutWindows | None,
                  config: RolloutConfig = RolloutConfig(), seed: int = 0, progress: bool = False,
                  desc: str = "rollout training") -> RolloutHistory:
    """Fit ``module`` (a torch Module) by Adam on ``loss_fn(module, batch)`` over ``train``'s windows.

    After every epoch the loss over ``val`` (or, with no validation windows, over ``train``)
    is measured; training stops after ``config.patience`` epochs without a lower one and the
    parameters of the best epoch (epoch 0 = the starting weights) are restored in place.
    Deterministic for a seed (:func:`seeded_torch`).
    """
    import torch
    from tqdm import tqdm

    if len(train) == 0:
        raise DataError(f"{desc}: no training window of {train.length} rows (history {train.history} + horizon {train.horizon})")
    check = val if val is not None and len(val) > 0 else train
    history = RolloutHistory()
    started = time.perf_counter()
    with seeded_torch(seed, config.threads):
        optimiser = torch.optim.Adam(module.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
        val_batch = config.val_batch_size or config.batch_size

        def validation_loss() -> float:
            clock = time.perf_counter()
            loss = mean_loss(module, loss_fn, check, val_batch)
            history.validation_seconds += time.perf_counter() - clock
            return loss

        best = validation_loss()
        history.val_loss.append(best)
        history.train_loss.append(float("nan"))
        best_state = copy.deepcopy(module.state_dict())
        since_best = 0
        bar = tqdm(range(1, config.max_epochs + 1), desc=desc, unit="epoch", disable=not progress, leave=False)
        for epoch in bar:
            total, count = 0.0, 0
            for batch in rollout_loader(train, config.batch_size, True, seed * 100_003 + epoch, config.windows_per_epoch):
                optimiser.zero_grad()
                loss = loss_fn(module, batch)
                if not torch.isfinite(loss):
                    raise DataError(f"{desc}: the rollout loss became {float(loss)} in epoch {epoch}; lower the learning rate")
                loss.backward()
                torch.nn.utils.clip_grad_norm_(module.parameters(), config.grad_clip)
                optimiser.step()
                b = len(next(iter(batch.values())))
                total += float(loss.detach()) * b
                count += b
            history.train_loss.append(total / count)
            current = validation_loss()
            history.val_loss.append(current)
            history.epochs_run = epoch
            if current < best and math.isfinite(current):
                best, history.best_epoch, since_best = current, epoch, 0
                best_state = copy.deepcopy(module.state_dict())
            else:
                since_best += 1
            bar.set_postfix(val=f"{current:.4g}", best=history.best_epoch)
            if since_best >= config.patience:
                history.stopped_early = True
                break
        module.load_state_dict(best_state)
    history.seconds = time.perf_counter() - started
    return history
