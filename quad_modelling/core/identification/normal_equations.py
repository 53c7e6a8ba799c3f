r"""Linear least squares from streamed normal equations: the physics identification's per-channel solver.

Each channel's design is summed block by block into :math:`X^T X, X^T y, y^T y` (:class:`NormalEquations`), so the
memory of a fit does not grow with the number of flights; :func:`solve_channels` solves each channel on the
columns its flights excite (:func:`excited_columns`) and gives its covariance from the thinned rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_CONDITION = 1e10
"""Largest condition number of a channel's column-scaled normal matrix: beyond it the flights do not excite the
channel's constants apart (e.g. collective-only manoeuvres leave roll and pitch unexcited) and they are kept."""


@dataclass
class NormalEquations:
    r"""Sufficient statistics of one channel's least squares :math:`\min_θ \lVert y − Xθ\rVert^2`, summed block by block:
    :math:`X^T X` (k, k), :math:`X^T y` (k,), :math:`y^T y`, the row count n; and the same of the rows thinned to every
    ``thin``-th of the stacked design (rows 0, thin, 2 thin, … in stacking order) for the uncertainty. The memory is
    O(k²), whatever the number of rows."""

    xtx: np.ndarray
    xty: np.ndarray
    yty: float = 0.0
    n: int = 0
    thin: int = 1
    xtx_thin: np.ndarray | None = None
    xty_thin: np.ndarray | None = None
    yty_thin: float = 0.0
    n_thin: int = 0

    @classmethod
    def empty(cls, k: int, thin: int) -> NormalEquations:
        return cls(np.zeros((k, k)), np.zeros(k), thin=thin, xtx_thin=np.zeros((k, k)), xty_thin=np.zeros(k))

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        """Add the rows (x (m, k), y (m,)) that follow the ones already added."""
        # einsum, not BLAS: tall-skinny products are 100x slower with a multithreaded BLAS on a busy 2-core machine
        xtx, xty, yty = np.einsum("ij,ik->jk", x, x), np.einsum("ij,i->j", x, y), float(np.einsum("i,i->", y, y))
        self.xtx += xtx
        self.xty += xty
        self.yty += yty
        if self.thin == 1:  # every row kept: the same sums
            self.xtx_thin += xtx
            self.xty_thin += xty
            self.yty_thin += yty
            kept_rows = len(y)
        else:
            kept = slice((-self.n) % self.thin, None, self.thin)  # the rows whose stacked index is a multiple of thin
            xt, yt = x[kept], y[kept]
            self.xtx_thin += np.einsum("ij,ik->jk", xt, xt)
            self.xty_thin += np.einsum("ij,i->j", xt, yt)
            self.yty_thin += float(np.einsum("i,i->", yt, yt))
            kept_rows = len(yt)
        self.n += len(y)
        self.n_thin += kept_rows


def quadratic(xtx: np.ndarray, xty: np.ndarray, yty: float, coef: np.ndarray) -> float:
    r""":math:`\lVert y − Xθ\rVert^2 = y^T y − 2 θ^T X^T y + θ^T X^T X θ` (≥ 0) from the normal-equation sums."""
    return max(float(yty - 2.0 * coef @ xty + coef @ xtx @ coef), 0.0)


def solve_channels(design: dict[str, NormalEquations]) -> dict[str, dict]:
    """Least squares per channel from its normal equations: coefficients, covariance s² (X_t^T X_t)^{-1} of the thinned
    rows, SSR, the thinned rows' residual variance s², SSR at θ = 0."""
    out = {}
    for name, ne in design.items():
        ssr0 = float(ne.yty)
        k = len(ne.xty)
        used = excited_columns(ne.xtx, ne.n)
        coef = np.full(k, np.nan)  # NaN: a constant the flights do not excite
        cov = np.full((k, k), np.nan)
        if not used:
            out[name] = {"coef": coef, "cov": cov, "ssr": ssr0, "s2": np.nan, "ssr0": ssr0, "n": ne.n}
            continue
        block = np.ix_(used, used)
        theta = np.linalg.solve(ne.xtx[block], ne.xty[used])
        coef[used] = theta
        ssr = quadratic(ne.xtx[block], ne.xty[used], ne.yty, theta)
        s2 = quadratic(ne.xtx_thin[block], ne.xty_thin[used], ne.yty_thin, theta) / max(ne.n_thin - len(used), 1)
        try:
            cov[block] = np.linalg.inv(ne.xtx_thin[block]) * s2
        except np.linalg.LinAlgError:
            pass  # the thinned rows alone are singular: the sigmas stay NaN
        out[name] = {"coef": coef, "cov": cov, "ssr": ssr, "s2": s2, "ssr0": ssr0, "n": ne.n}
    return out


def excited_columns(gram: np.ndarray, rows: int) -> list[int]:
    """The leading columns of a design (normal matrix ``gram`` = X^T X of ``rows`` rows) whose column-scaled normal
    matrix has a condition number within :data:`MAX_CONDITION` (columns are ordered by importance: the thrust or
    torque gain first, then drag terms)."""
    for k in range(gram.shape[0], 0, -1):
        part = gram[:k, :k]
        scale = np.sqrt(np.diag(part))
        if rows > k and np.all(scale > 0) and np.linalg.cond(part / np.outer(scale, scale)) <= MAX_CONDITION:
            return list(range(k))
    return []
