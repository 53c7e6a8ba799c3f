"""Error measures of the thesis (chapter 5.1) and of the IDSIA multi-step benchmark.

All functions are pure and work column-wise on (N,) or (N, k) arrays.

.. math::

    RMS = \\sqrt{\\tfrac1n \\sum (y_m - y_p)^2}, \\qquad
    TIC = \\frac{\\sqrt{\\tfrac1n \\sum (y_m - y_p)^2}}
               {\\sqrt{\\tfrac1n \\sum y_m^2} + \\sqrt{\\tfrac1n \\sum y_p^2}}

TIC (Theil inequality coefficient, thesis Eq 5-2) lies in [0, 1]: 0 is a
perfect prediction, 1 a prediction of zero (or of zero measurements). When
both signals are identically zero the prediction is perfect: TIC = 0.
"""

from __future__ import annotations

import numpy as np


def rms(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Root mean square of the error, per column (thesis Eq 5-1)."""
    error = np.asarray(measured, dtype=float) - np.asarray(predicted, dtype=float)
    return np.sqrt(np.mean(error**2, axis=0))


def tic(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Theil inequality coefficient per column (thesis Eq 5-2); 0 where both signals are zero."""
    measured = np.asarray(measured, dtype=float)
    predicted = np.asarray(predicted, dtype=float)
    numerator = rms(measured, predicted)
    denominator = np.sqrt(np.mean(measured**2, axis=0)) + np.sqrt(np.mean(predicted**2, axis=0))
    safe = np.where(denominator > 0, denominator, 1.0)
    return np.where(denominator > 0, numerator / safe, 0.0)


def vector_error_norm(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Euclidean norm of the error over the last axis (3-vectors)."""
    return np.linalg.norm(np.asarray(measured, dtype=float) - np.asarray(predicted, dtype=float), axis=-1)


def sim_err(mae_by_horizon: np.ndarray) -> float:
    """SimErr = sum of MAE_h over h = 1..H (IDSIA nano-drone benchmark); ``mae_by_horizon[h-1]`` = MAE_h."""
    return float(np.sum(mae_by_horizon))
