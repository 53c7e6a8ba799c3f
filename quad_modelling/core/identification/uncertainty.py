"""Standard errors of least-squares estimates from autocorrelated residuals (windows of a flight).

The residuals of a fit on smoothed 100 Hz flight data are strongly autocorrelated (the evaluation
low-pass alone correlates neighbours over ~0.1 s; closed-loop disturbances over longer), so the
textbook covariance :math:`s^2 (J^T J)^{-1}` counts every sample as new information and is optimistic.
Here the covariance is the heteroscedasticity- and autocorrelation-consistent (HAC) sandwich of
Newey & West (1987, Econometrica 55(3) 703-708), with windows as independent blocks:

.. math::

    \\mathrm{cov}(\\hat\\beta) = (J^T J)^{-1}\\, S\\, (J^T J)^{-1}, \\qquad
    S = \\sum_w \\sum_{|l| \\le L} \\left(1 - \\frac{|l|}{L + 1}\\right) \\sum_t g_{w,t}\\, g_{w,t+l}^T,

with :math:`g_{w,t} = \\sum_v J_{w,t,v}\\, e_{w,t,v}` the score of window :math:`w` at sample :math:`t`
(summed over the variables :math:`v` fitted at that time), :math:`e` the residuals, :math:`J` the
Jacobian (for a linear regression, the regressors) and :math:`L` the Bartlett bandwidth in samples.
No term crosses a window boundary (windows are cut apart and trimmed separately). With :math:`L = 0`
and one variable this is White's covariance; for white residuals it tends to :math:`s^2 (J^T J)^{-1}`.
"""

from __future__ import annotations

import math

import numpy as np

HAC_BANDWIDTH_S = 1.0
"""Bartlett bandwidth of the HAC covariance [s]: ten times the ~0.1 s correlation the 5 Hz evaluation
low-pass gives the residuals, and the time a closed-loop attitude/height controller takes to cancel a
disturbance (its residuals stay correlated that long)."""


def bandwidth_samples(dt: float, stride: int = 1, bandwidth_s: float = HAC_BANDWIDTH_S) -> int:
    """The Bartlett bandwidth L in samples of period ``dt * stride`` [s]."""
    return max(int(math.ceil(bandwidth_s / (dt * stride))), 1)


def hac_covariance(jac: np.ndarray, residuals: np.ndarray, lags: int) -> np.ndarray:
    """(p, p) HAC covariance of the module docstring.

    ``jac``: (W, n, v, p) Jacobian of the residuals (or regressors) per window, sample, variable;
    ``residuals``: (W, n, v); ``lags``: Bartlett bandwidth L in samples. Raises
    :class:`numpy.linalg.LinAlgError` when :math:`J^T J` is singular: J's rank below p by numpy's SVD tolerance
    (singular values under max(shape) eps of the largest). LU alone (``inv``) raised only when a pivot came out
    exactly 0, which depends on the CPU's rounding: two collinear columns gave NaN sigmas on one machine and finite
    ones of 5e-4 on another.
    """
    w, n, v, p = jac.shape
    flat = jac.reshape(-1, p)
    rank = np.linalg.matrix_rank(flat)
    if rank < p:
        raise np.linalg.LinAlgError(f"J^T J is singular: its {p} columns have rank {rank}")
    bread = np.linalg.inv(flat.T @ flat)
    scores = np.einsum("wtvp,wtv->wtp", jac, residuals)  # (W, n, p)
    meat = np.einsum("wtp,wtq->pq", scores, scores)
    for lag in range(1, min(lags, n - 1) + 1):
        weight = 1.0 - lag / (lags + 1.0)
        cross = np.einsum("wtp,wtq->pq", scores[:, lag:], scores[:, :-lag])
        meat += weight * (cross + cross.T)
    return bread @ meat @ bread


def profile_sigma(chi2, x: float, h: float) -> float:
    """σ = sqrt(2 / χ²''(x)) from a central second difference with step ``h`` (one side only at x < h: a delay of
    0); NaN when the profile is not convex there (not identifiable from these flights)."""
    if x - h < 0:
        curvature = (chi2(x + 2 * h) - 2.0 * chi2(x + h) + chi2(x)) / h**2
    else:
        curvature = (chi2(x + h) - 2.0 * chi2(x) + chi2(x - h)) / h**2
    return float(np.sqrt(2.0 / curvature)) if curvature > 0 else float("nan")


def subsample_delay(best: float, low: float, mid: float, high: float, period: float) -> float:
    r"""δ [s] at the vertex of the parabola through J = ``low``, ``mid``, ``high`` at the whole-sample delays ``best`` - T,
    ``best``, ``best`` + T (T = ``period`` [s]): :math:`\delta = \delta_{best} + T \operatorname{clip}((J_- - J_+) /
    (2 (J_- - 2 J_0 + J_+)), -\tfrac12, \tfrac12)`. From whole samples only: between them the commands are
    interpolated linearly (:func:`~quad_modelling.core.physics.rotors.delayed_commands`), i.e. low-passed (cos(ωT/2) at
    half a sample: 5 % at 10 Hz, 100 Hz samples), which biases J up; checked against that J, the vertex was never kept
    (NanoBench helix fold, 15 / 25 ms injected: δ rose by 20 / 30 ms; vertices 16.2 / 26.2). Its own error (up to T/2
    on a lopsided profile: simulated 20 ms delays gave 18.4 / 22.8 / 19.2 ms) is in σ_δ as T/sqrt(12) in quadrature."""
    curvature = low - 2.0 * mid + high
    return best + float(np.clip(0.5 * (low - high) / curvature, -0.5, 0.5)) * period
