"""Zero-order-hold discretisation of a continuous linear system (the one place it is done).

For :math:`\\dot x = A x + B u` with :math:`u` held constant over each sample
period :math:`\\Delta t`, the exact discrete system is

.. math::

    x_{k+1} = A_d x_k + B_d u_k, \\qquad
    A_d = e^{A \\Delta t}, \\qquad
    B_d = \\int_0^{\\Delta t} e^{A s}\\, ds\\; B,

obtained together from one matrix exponential of the block matrix

.. math::

    \\exp\\left(\\begin{bmatrix} A & B \\\\ 0 & 0 \\end{bmatrix} \\Delta t\\right)
    = \\begin{bmatrix} A_d & B_d \\\\ 0 & I \\end{bmatrix}

(Van Loan 1978; what :func:`scipy.signal.cont2discrete` does for ``method="zoh"``).
Used by the greybox model (:mod:`quad_modelling.core.models.greybox`) and the
diagnosis base model (:mod:`quad_modelling.core.identification.base_model`).
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

from quad_modelling.errors import DataError

_CACHE: dict[tuple[bytes, bytes, tuple[int, ...], float], tuple[np.ndarray, np.ndarray]] = {}

CACHE_SIZE = 64
"""Discretisations remembered (a fit discretises the same matrices for every effect that leaves A alone)."""


def zero_order_hold(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_d, B_d) of the module docstring for A (n, n), B (n, m) and sample period ``dt`` [s].

    The results are read-only and memoised on the matrices' values.
    """
    if not dt > 0:
        raise DataError(f"zero-order hold: sample period must be positive, got {dt}")
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    key = (a.tobytes(), b.tobytes(), b.shape, float(dt))
    hit = _CACHE.get(key)
    if hit is not None:
        return hit
    n, m = a.shape[0], b.shape[1]
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a * dt
    block[:n, n:] = b * dt
    exponential = linalg.expm(block)
    a_d, b_d = exponential[:n, :n].copy(), exponential[:n, n:].copy()
    for matrix in (a_d, b_d):
        matrix.setflags(write=False)
    if len(_CACHE) >= CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = (a_d, b_d)
    return a_d, b_d
