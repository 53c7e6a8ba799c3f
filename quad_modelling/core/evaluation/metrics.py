"""The one scorer: the error measures of the thesis (chapter 5.1, DESIGN 7) and of the IDSIA multi-step benchmark.

Every RMS/TIC in the suite -- a window of ``quad-modelling evaluate``, a window the live
evaluator node closes, a diagnosis window batch -- is computed here. The functions are pure;
``axis`` is the axis the mean runs over (the samples), every other axis is kept, so the same
function scores one signal (N,), the variables of one window (N, k) with ``axis=0``, or every
window and variable of a batch (W, N, k) with ``axis=1``.

With :math:`y_m` the measurement, :math:`y_p` the prediction and :math:`n` samples:

.. math::

    \\operatorname{RMS}(y) = \\sqrt{\\tfrac1n \\sum y^2}, \\qquad
    RMS = \\operatorname{RMS}(y_m - y_p), \\qquad
    TIC = \\frac{\\operatorname{RMS}(y_m - y_p)}{\\operatorname{RMS}(y_m) + \\operatorname{RMS}(y_p)}

TIC (Theil inequality coefficient, thesis Eq 5-2) lies in [0, 1]: 0 is a perfect prediction,
1 a prediction of zero or of an opposite-sign signal. Zero signals: a zero error gives RMS = 0;
a zero prediction of a non-zero measurement (the dummy model, thesis Fig 5.2) or a non-zero
prediction of a zero measurement gives TIC = 1; when both signals are identically zero the
quotient is 0/0 and the prediction is perfect: TIC = 0.

Multi-step mode (IDSIA nano-drone benchmark): from S start samples s, with
:math:`e_{s,h}` the error of a group (position, velocity, orientation, angular velocity) at
step s + h -- the Euclidean norm of the error 3-vector (:func:`vector_error_norm`), or for the
orientation the geodesic angle between the two attitudes
(:func:`quad_modelling.core.frames.geodesic_angle`):

.. math::

    \\mathrm{MAE}_h = \\tfrac1S \\sum_s e_{s,h}, \\qquad
    \\mathrm{SimErr} = \\sum_{h=1}^{H} \\mathrm{MAE}_h, \\quad H = 50
"""

from __future__ import annotations

import numpy as np

from quad_modelling.errors import DataError

SIM_ERR_HORIZON = 50
"""H of SimErr [samples]: the IDSIA nano-drone benchmark sums MAE_h over h = 1..50."""


def root_mean_square(values: np.ndarray, axis: int | tuple[int, ...] = 0) -> np.ndarray:
    """:math:`\\sqrt{\\tfrac1n \\sum y^2}` of ``values`` over ``axis`` (the samples); 0 for a zero signal."""
    values = np.asarray(values, dtype=float)
    return np.sqrt(np.mean(values**2, axis=axis))


def rms(measured: np.ndarray, predicted: np.ndarray, axis: int | tuple[int, ...] = 0) -> np.ndarray:
    """RMS of the error :math:`y_m - y_p` over ``axis`` (thesis Eq 5-1), in the variables' unit."""
    return root_mean_square(np.asarray(measured, dtype=float) - np.asarray(predicted, dtype=float), axis)


def tic(measured: np.ndarray, predicted: np.ndarray, axis: int | tuple[int, ...] = 0) -> np.ndarray:
    """Theil inequality coefficient over ``axis`` (thesis Eq 5-2), in [0, 1]; 0 where both signals are zero."""
    numerator = rms(measured, predicted, axis)
    denominator = root_mean_square(measured, axis) + root_mean_square(predicted, axis)
    safe = np.where(denominator > 0, denominator, 1.0)
    return np.where(denominator > 0, numerator / safe, 0.0)


def vector_error_norm(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Euclidean norm of the error over the last axis (3-vectors): :math:`e = \\lVert y_m - y_p \\rVert`."""
    return np.linalg.norm(np.asarray(measured, dtype=float) - np.asarray(predicted, dtype=float), axis=-1)


def mae_by_horizon(error_norms: np.ndarray) -> np.ndarray:
    """MAE_h: the mean over starts (axis 0) of the error norms :math:`e_{s,h}` (S, H, ...) -> (H, ...).

    ``error_norms[s, h-1]`` is the error at step h after start s (:func:`vector_error_norm` or a
    geodesic angle); DataError when there is no start.
    """
    error_norms = np.asarray(error_norms, dtype=float)
    if error_norms.shape[0] == 0:
        raise DataError("MAE_h needs at least one start sample, got none")
    return error_norms.mean(axis=0)


def sim_err(mae: np.ndarray, horizon: int = SIM_ERR_HORIZON) -> float:
    """SimErr = sum of MAE_h over h = 1..``horizon`` (``mae[h-1]`` = MAE_h; DataError when shorter)."""
    mae = np.asarray(mae, dtype=float)
    if len(mae) < horizon:
        raise DataError(f"SimErr sums MAE_h over h = 1..{horizon}, got only {len(mae)} horizons")
    return float(np.sum(mae[:horizon]))
