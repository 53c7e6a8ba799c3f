"""Physical bounds of a vehicle: a prediction beyond them is a model failure, never a valid answer.

A finite but absurd prediction (a diverged model, 1e30) must not be published as valid (issue #15).
The bounds come from the vehicle config (:class:`~quad_modelling.core.models.greybox.GreyboxParameters`),
with the rotor speed at full command from the motor model,

.. math::

    \\Omega_{max} = \\Omega_0 + \\frac{B_m}{|A_m|} (u_{max} - u_{min}), \\qquad
    T_{max} = a\\,\\Omega_{max}^2 \\ \\text{(per rotor)},

    a_{max} = M \\left(\\frac{4 T_{max}}{m} + g\\right), \\qquad
    \\alpha_{max} = M \\frac{r_{max}\\, 2 T_{max}}{\\min(I_{xx}, I_{yy})}

(the thrust by :func:`~quad_modelling.core.physics.rotors.rotor_thrusts`; :math:`r_{max}` the largest rotor arm, :math:`M` = :data:`MARGIN`, a divergence guard: see there). Against the state at the
window's anchor (position :math:`p_a`, velocity :math:`v_a`, rates :math:`\\omega_a`), a prediction
:math:`\\tau` seconds from the anchor must satisfy, with :math:`\\tau' = |\\tau| + \\tau_s`
(:data:`SLACK_S`, for the anchor's own smoothing and measurement noise):

.. math::

    |a| \\le a_{max},\\quad |\\dot\\omega| \\le \\alpha_{max},\\quad
    |v - v_a| \\le a_{max} \\tau',\\quad
    |p - p_a| \\le |v_a| \\tau' + \\tfrac12 a_{max} \\tau'^2,\\quad
    |\\omega - \\omega_a| \\le \\alpha_{max} \\tau'

(Euclidean norms; N frame; rows of :data:`~quad_modelling.core.variables.VARIABLES`). The
LinkQuad's Table 3-1 constants are not mutually consistent (units of u unstated), so its bounds are
loose; they still reject a diverged model by orders of magnitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from quad_modelling.core.physics.rotors import rotor_thrusts
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig

MARGIN = 1000.0
"""Factor M over the vehicle's full-thrust figures. The bounds guard against a *diverged* model, not a poor
one: on the bundled NanoBench flight the thesis's linear greybox, open loop over a 10 s window, reaches
213 x the Crazyflie's full-thrust acceleration, 74 x its velocity bound and 36 x its position bound (its
known drift; offline scores those windows, and live must equal offline), while the physics model stays
below 0.14 x. M = 1000 keeps every window of the bundled flight (worst: 0.21 M) and rejects a model that
has blown up (1e30, or 1e6 m/s² on a 27 g vehicle)."""

SLACK_S = 0.1
"""τ_s [s] added to the time from the anchor (anchor smoothing, measurement noise)."""

POSITION, VELOCITY, ACCELERATION = slice(0, 3), slice(3, 6), slice(6, 9)
RATES, ANGULAR_ACCELERATION = slice(12, 15), slice(15, 18)


@dataclass(frozen=True)
class PhysicalBounds:
    """a_max [m/s²] and alpha_max [rad/s²] of one vehicle (module docstring)."""

    max_acceleration: float
    max_angular_acceleration: float

    @classmethod
    def from_vehicle(cls, vehicle: VehicleConfig) -> PhysicalBounds:
        from quad_modelling.core.models.greybox import GreyboxParameters

        p = GreyboxParameters.from_vehicle(vehicle)
        omega_max = p.hover_rotor_speed + p.motor_b_m / abs(p.motor_a_m) * (vehicle.input_max - vehicle.input_min)
        thrust = float(rotor_thrusts(p.thrust_constant, omega_max))
        arm = float(np.max(np.linalg.norm(np.asarray(p.motor_positions, dtype=float), axis=1)))
        return cls(MARGIN * (4.0 * thrust / p.mass + GRAVITY), MARGIN * arm * 2.0 * thrust / min(p.ixx, p.iyy))

    def violation(self, predictions: np.ndarray, elapsed_s, anchor: np.ndarray) -> str | None:
        """The first bound (N, 18) ``predictions`` break, ``elapsed_s`` (N,) [s] from the anchor row ``anchor`` (18,),
        as one sentence; None when every row is inside (one vectorised test: it runs on every live input)."""
        y = np.atleast_2d(predictions)
        base = anchor.tolist()
        speed_a = math.hypot(*base[VELOCITY])
        if len(y) == 1:  # the live predictor's case, one row per input: the same test in floats (~10x faster)
            row, tau_s = y[0].tolist(), abs(float(elapsed_s if np.ndim(elapsed_s) == 0 else np.ravel(elapsed_s)[0])) + SLACK_S
            values = [math.hypot(*row[ACCELERATION]), math.hypot(*row[ANGULAR_ACCELERATION])] + [
                math.hypot(*(a - b for a, b in zip(row[part], base[part]))) for part in (VELOCITY, POSITION, RATES)]
            if all(v <= limit for v, limit in zip(values, self._limits(tau_s, speed_a))):  # NaN counts as beyond
                return None
        elapsed = np.broadcast_to(np.asarray(elapsed_s, dtype=float), (len(y),))
        tau = np.abs(elapsed) + SLACK_S
        vectors = np.empty((len(y), len(CHECKS), 3))
        vectors[:, 0] = y[:, ACCELERATION]
        vectors[:, 1] = y[:, ANGULAR_ACCELERATION]
        vectors[:, 2] = y[:, VELOCITY] - anchor[VELOCITY]
        vectors[:, 3] = y[:, POSITION] - anchor[POSITION]
        vectors[:, 4] = y[:, RATES] - anchor[RATES]
        values = np.sqrt(np.einsum("nij,nij->ni", vectors, vectors))
        limits = np.column_stack([np.broadcast_to(limit, tau.shape) for limit in self._limits(tau, speed_a)])
        bad = ~(values <= limits)  # NaN counts as beyond
        if not bad.any():
            return None
        row, check = np.argwhere(bad)[0]
        name, unit = CHECKS[check]
        return f"{name} {values[row, check]:.3g} {unit} beyond the vehicle's bound {limits[row, check]:.3g} {unit} " \
               f"{elapsed[row]:.3f} s from the anchor"


    def _limits(self, tau, speed_a: float) -> tuple:
        """The five bounds of :data:`CHECKS` at τ' = ``tau`` [s] (float or array) from an anchor moving at ``speed_a``
        [m/s] (module docstring)."""
        a_max, alpha_max = self.max_acceleration, self.max_angular_acceleration
        return a_max, alpha_max, a_max * tau, speed_a * tau + 0.5 * a_max * tau ** 2, alpha_max * tau


CHECKS = (("acceleration", "m/s²"), ("angular acceleration", "rad/s²"), ("velocity change", "m/s"),
          ("position change", "m"), ("rate change", "rad/s"))
"""The bounds in the order :meth:`PhysicalBounds.violation` tests them (module docstring)."""
