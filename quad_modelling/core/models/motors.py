"""The motor: first-order lag from trimmed command to rotor thrust deviation (the one motor filter).

Continuous (thesis Eq 3-3 ... 3-7, :mod:`quad_modelling.core.models.greybox`):

.. math::

    \\dot T_i = A_m T_i + K u_i, \\qquad K = 2 B_m \\sqrt{a m g / 4},
    \\qquad \\tau_m = -1 / A_m

with :math:`T_i` rotor i's thrust deviation from hover [N], :math:`u_i` its
trimmed command [command units], :math:`A_m` [1/s], :math:`K` [N/s per command unit].
Held over a sample period :math:`\\Delta t` (zero-order hold, the scalar case of
:func:`quad_modelling.core.discretise.zero_order_hold`):

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
from scipy import signal


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
