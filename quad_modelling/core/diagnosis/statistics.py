"""Scores of the diagnosis: window gaps, shrink, bootstraps (of windows; of blocks of starts), sign test, correlations."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

from quad_modelling.core.evaluation.metrics import rms, tic
from quad_modelling.core.evaluation.windowed import window_mean
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import EVAL_VARIABLES, INDEX

BOOTSTRAP = 1000
"""Bootstrap resamples of the held-out windows (seed :data:`BOOTSTRAP_SEED`)."""


BOOTSTRAP_SEED = 7


# ----------------------------------------------------------------------------- scores


def _scored(batch: WindowBatch, values: np.ndarray, columns: Sequence[int] | None) -> np.ndarray:
    """(W, N - warm, k): the rows of ``values`` (W, N, 18) after the warm start, columns ``columns`` (all when None)."""
    cols = np.arange(values.shape[2]) if columns is None else np.asarray(columns, dtype=int)
    return values[:, batch.warm :][:, :, cols]


def window_rms(batch: WindowBatch, predicted: np.ndarray, columns: Sequence[int] | None = None) -> np.ndarray:
    """(W, k) RMS error per window and variable over the scored rows (after the warm start):
    :func:`~quad_modelling.core.evaluation.metrics.rms` over the samples axis."""
    return rms(_scored(batch, batch.measured, columns), _scored(batch, predicted, columns), axis=1)


def window_tic(batch: WindowBatch, predicted: np.ndarray, columns: Sequence[int] | None = None) -> np.ndarray:
    """(W, k) Theil inequality coefficient per window and variable over the scored rows:
    :func:`~quad_modelling.core.evaluation.metrics.tic` over the samples axis."""
    return tic(_scored(batch, batch.measured, columns), _scored(batch, predicted, columns), axis=1)


def normalised_window_gap(batch: WindowBatch, predicted: np.ndarray, cols: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """(W,) sum over ``cols`` of RMS_v / s_v per window."""
    return (window_rms(batch, predicted, cols) / scales[cols]).sum(axis=1)


def shrink_of(before: np.ndarray, after: np.ndarray) -> float:
    """1 - sum(after) / sum(before) of per-window normalised gaps (0 when the base gap is zero)."""
    total = float(np.sum(before))
    return 1.0 - float(np.sum(after)) / total if total > 0 else 0.0


def bootstrap_shrink(before: np.ndarray, after: np.ndarray, resamples: int = BOOTSTRAP, seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """(5 %, 95 %) bootstrap quantiles of the shrink over windows (resampled with replacement)."""
    if len(before) < 2:
        return (float("nan"), float("nan"))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(before), size=(resamples, len(before)))
    b, a = before[idx].sum(axis=1), after[idx].sum(axis=1)
    s = 1.0 - a / np.where(b > 0, b, 1.0)
    return float(np.quantile(s, 0.05)), float(np.quantile(s, 0.95))


def sign_test(improved: int, total: int) -> float:
    """One-sided binomial p-value of at least ``improved`` of ``total`` windows improving by chance (p = 1/2)."""
    if total == 0:
        return 1.0
    return float(stats.binomtest(improved, total, 0.5, alternative="greater").pvalue)


def variable_scores(batch: WindowBatch, predicted: np.ndarray, names: Sequence[str] = EVAL_VARIABLES) -> dict[str, dict[str, float]]:
    cols = np.array([INDEX[v] for v in names])
    r = window_mean(window_rms(batch, predicted, cols))
    t = window_mean(window_tic(batch, predicted, cols))
    return {v: {"rms": float(r[i]), "tic": float(t[i])} for i, v in enumerate(names)}


def correction_correlation(batch: WindowBatch, delta_a: np.ndarray, delta_b: np.ndarray, cols: np.ndarray, scales: np.ndarray) -> float:
    """Pearson correlation of two (W, N, 18) arrays over the scored rows of ``cols`` (each column scaled)."""
    a = (delta_a[:, batch.warm :, cols] / scales[cols]).ravel()
    b = (delta_b[:, batch.warm :, cols] / scales[cols]).ravel()
    sa, sb = a.std(), b.std()
    if sa == 0 or sb == 0:
        return 0.0
    return float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))


# ----------------------------------------------------------------------------- the physics base's block bootstrap


BLOCK_BOOTSTRAP = 400
"""Bootstrap resamples of the physics base's shrink and its 5 % bound
(:mod:`~quad_modelling.core.diagnosis.physics_base`: blocks of held-out starts)."""


def block_draws(scores: Sequence, seed: int = 0) -> np.ndarray:
    r"""(BLOCK_BOOTSTRAP, len(scores)) J of each score (a :class:`~quad_modelling.core.diagnosis.physics_base.HeldOutScore`:
    per-start ``model`` and ``naive`` errors, ``blocks``) on the same :data:`BLOCK_BOOTSTRAP` block resamples of their
    starts (the scores are of the same starts: their blocks are the first's). A resample draws as many blocks as there
    are, with replacement; J being a mean over the groups of ratios of sums over starts, a draw is its blocks' counts
    :math:`c` (BLOCK_BOOTSTRAP, K) times the per-block sums: :math:`J = \operatorname{mean}_g (c\, E_g) / (c\, N_g)`."""
    rng = np.random.default_rng(seed)
    _, block = np.unique(scores[0].blocks, return_inverse=True)
    n_blocks = int(block.max()) + 1
    picks = rng.integers(0, n_blocks, (BLOCK_BOOTSTRAP, n_blocks))
    counts = np.zeros((BLOCK_BOOTSTRAP, n_blocks))
    np.add.at(counts, (np.repeat(np.arange(BLOCK_BOOTSTRAP), n_blocks), picks.ravel()), 1.0)
    draws = np.empty((BLOCK_BOOTSTRAP, len(scores)))
    for j, score in enumerate(scores):
        sums_model, sums_naive = np.zeros((n_blocks, score.model.shape[1])), np.zeros((n_blocks, score.naive.shape[1]))
        np.add.at(sums_model, block, score.model)
        np.add.at(sums_naive, block, score.naive)
        draws[:, j] = np.mean((counts @ sums_model) / (counts @ sums_naive), axis=1)
    return draws


def shrink(before, after, seed: int = 0) -> tuple[float, float]:
    """(S, its bootstrap 5 % bound) of the score ``after`` against ``before`` (the physics base's S = 1 - J_after /
    J_before; the same starts, :func:`block_draws`)."""
    draws = block_draws([before, after], seed)
    return float(1.0 - after.j / before.j), float(np.quantile(1.0 - draws[:, 1] / draws[:, 0], 0.05))
