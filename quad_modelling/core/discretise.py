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

The motor filter, the scalar case (:func:`discrete_motor`, :func:`motor_thrusts`; the greybox's thrust lag, the one motor
filter): a first-order lag from trimmed command to rotor thrust deviation, continuous (thesis Eq 3-3 ... 3-7, :mod:`quad_modelling.core.models.greybox`):

.. math::

    \\dot T_i = A_m T_i + K u_i, \\qquad K = 2 B_m \\sqrt{a m g / 4},
    \\qquad \\tau_m = -1 / A_m

with :math:`T_i` rotor i's thrust deviation from hover [N], :math:`u_i` its
trimmed command [command units], :math:`A_m` [1/s], :math:`K` [N/s per command unit].
Held over a sample period :math:`\\Delta t` (zero-order hold, the scalar case of :func:`zero_order_hold`):

.. math::

    T_{k+1} = p\\, T_k + g\\, u_k, \\qquad p = e^{A_m \\Delta t}, \\qquad
    g = K \\frac{p - 1}{A_m},

so a unit command step reaches :math:`1 - e^{-t/\\tau_m}` of its steady thrust
:math:`-K / A_m = g / (1 - p)` at time :math:`t`, one sample after the step
(the thrust answers the command of the previous sample). The filter starts in
steady state of the first command, :math:`T_0 = g\\, u_0 / (1 - p)`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import linalg, signal

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


def discrete_motor(motor_a_m: float, input_gain: float, dt: float) -> tuple[float, float]:
    """(p, g) of the module docstring from A_m [1/s], K [N/s per command unit] and ``dt`` [s]."""
    pole = math.exp(motor_a_m * dt)
    return pole, input_gain * (pole - 1.0) / motor_a_m


def motor_thrusts(u: np.ndarray, pole: float, gain: float, axis: int = 0) -> np.ndarray:
    """Thrust deviations T [N] of trimmed commands ``u`` through the discrete motor (p, g), time along ``axis``.

    :math:`T_{k+1} = p T_k + g u_k` from the steady state of the first command (module docstring);
    same shape as ``u``.
    """
    u = np.asarray(u, dtype=float)
    first = np.take(u, [0], axis=axis)
    steady = gain / (1.0 - pole) * first  # the filter state that holds T_0 = g u_0 / (1 - p)
    thrusts, _ = signal.lfilter([0.0, gain], [1.0, -pole], u, axis=axis, zi=steady)
    return thrusts
