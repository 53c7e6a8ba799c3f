r"""The airframe's symmetries: the turns and mirror images of the body that leave the quadrotor as it was.

A map of the body plane, :math:`m` (2 x 2, one of the square's eight: the identity, turns by 90°, 180°, 270°, and the
mirror images across x, y and the two diagonals), extended to the body frame FRD as :math:`M = \mathrm{diag}(m, 1)`
(z, down, kept), is a symmetry of the airframe when it carries every rotor onto a rotor,

.. math:: m\, p_i = p_{\pi(i)} \quad (\text{within } 2\,\% \text{ of the arm}),

with the spin the image needs: a turn keeps a rotor's spin, a mirror image reverses it (a counter-clockwise propeller
seen in a mirror turns clockwise), :math:`s_{\pi(i)} = \det(m)\, s_i`, and when it keeps the inertia,
:math:`M\,\mathrm{diag}(I)\,M^T = \mathrm{diag}(I)` within 5 %. Under such a symmetry the motion of the vehicle
flown with the commands :math:`u'_{\pi(i)} = u_i` is the image of its motion under u: vectors (velocity, specific
force, position) map as :math:`v' = M v`, axial vectors (body rates, torques, angular acceleration) as
:math:`\omega' = \det(M)\, M \omega` (a mirror image turns a right-handed rotation into a left-handed one), the
attitude as :math:`R' = M R M^T` (the navigation frame mirrored by the same M, so gravity is kept).

For the Crazyflie's "x" airframe (rotors at 45°, spins alternating) the symmetries are the identity, the mirror
images across the x and the y axis, and the turn by 180°; a turn by 90° would carry a counter-clockwise rotor onto a
clockwise one. The physics model with constants p keeps those of them its switched-on asymmetric terms keep
(:func:`model_symmetries`: motor gains, a CG offset). The direct model's rate maps are fitted on the training flights
and their images under these (:mod:`quad_modelling.core.training.direct`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.physics.parameters import PhysicsParameters

POSITION_TOLERANCE = 0.02
"""A rotor's image must lie within this fraction of the largest rotor radius of a rotor (vehicle files give positions
to 0.1 mm or better; 2 % of a 46 mm Crazyflie arm is 0.9 mm)."""

INERTIA_TOLERANCE = 0.05
"""A symmetry that swaps the x and y axes needs I_xx and I_yy within this fraction of each other."""

PLANE_MAPS: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "identity": ((1, 0), (0, 1)),
    "turn 90°": ((0, -1), (1, 0)),
    "turn 180°": ((-1, 0), (0, -1)),
    "turn 270°": ((0, 1), (-1, 0)),
    "mirror x -> -x": ((-1, 0), (0, 1)),
    "mirror y -> -y": ((1, 0), (0, -1)),
    "mirror x <-> y": ((0, 1), (1, 0)),
    "mirror x <-> -y": ((0, -1), (-1, 0)),
}
"""The square's eight maps of the body plane (x forward, y right) [rows of m]."""


@dataclass(frozen=True)
class Symmetry:
    """One symmetry of the airframe: its name (a key of :data:`PLANE_MAPS`), the body map M (3, 3) and the commands'
    permutation: the image flight's command j is the original's ``source[j]`` (u' = u[:, source])."""

    name: str
    matrix: np.ndarray
    source: np.ndarray

    @property
    def axial(self) -> np.ndarray:
        """(3, 3) det(M) M: how body rates, torques and angular accelerations map."""
        return float(np.linalg.det(self.matrix)) * self.matrix

    def image(self, log: FlightLog) -> FlightLog:
        """``log`` as flown in this symmetry's mirror (module docstring): commands and rotor speeds permuted, position,
        velocity and specific force M v, body rates det(M) M ω, attitude M R M^T; time, battery and metadata kept."""
        rotation = self.matrix @ frames.euler_ned_to_matrix(log.euler) @ self.matrix.T
        euler = frames.matrix_to_euler_ned(rotation)
        euler[:, 2] = np.unwrap(euler[:, 2])
        return dataclasses.replace(
            log, u=log.u[:, self.source], omega=None if log.omega is None else log.omega[:, self.source],
            gyro_b=None if log.gyro_b is None else log.gyro_b @ self.axial.T,
            acc_b=None if log.acc_b is None else log.acc_b @ self.matrix.T,
            pos_n=log.pos_n @ self.matrix.T, vel_n=log.vel_n @ self.matrix.T, euler=euler)


def airframe_symmetries(positions: np.ndarray, yaw_signs: np.ndarray, inertia: np.ndarray) -> tuple[Symmetry, ...]:
    """Every symmetry of an airframe with rotors at ``positions`` (R, 2) [m, FRD x, y], spins ``yaw_signs`` (R,)
    (+1 counter-clockwise seen from above) and the diagonal ``inertia`` (3,) [kg m²], the identity first (module
    docstring). They form a group: the image of a symmetry under another is one."""
    positions, yaw_signs = np.asarray(positions, dtype=float), np.asarray(yaw_signs, dtype=float)
    inertia = np.asarray(inertia, dtype=float)
    tolerance = POSITION_TOLERANCE * float(np.hypot(*positions.T).max())
    found = []
    for name, rows in PLANE_MAPS.items():
        plane = np.array(rows, dtype=float)
        matrix = np.eye(3)
        matrix[:2, :2] = plane
        if not np.allclose(np.abs(matrix) @ inertia, inertia, rtol=INERTIA_TOLERANCE):
            continue
        images = positions @ plane.T
        distance = np.linalg.norm(images[:, None, :] - positions[None, :, :], axis=2)  # (image of i, rotor j)
        target = distance.argmin(axis=1)
        if (distance.min(axis=1) > tolerance).any() or len(set(target.tolist())) != len(positions):
            continue
        if not np.array_equal(yaw_signs[target], np.linalg.det(plane) * yaw_signs):
            continue
        source = np.empty(len(positions), dtype=int)
        source[target] = np.arange(len(positions))
        found.append(Symmetry(name, matrix, source))
    return tuple(found)


def model_symmetries(p: PhysicsParameters) -> tuple[Symmetry, ...]:
    r"""The symmetries of the physics model with constants ``p``: the airframe's (:func:`airframe_symmetries` of its
    rotor positions, spins and inertia) that also keep its switched-on asymmetric terms, the motor gains
    (:math:`g_{\pi(i)} = g_i`) and the CG offset (:math:`m c = c`); rotor drag, ground effect, battery scaling and the
    gyroscopic torques are symmetric under every one."""
    found = airframe_symmetries(p.positions, p.spins, np.asarray(p.inertia, dtype=float))
    if p.motor_gains is not None:
        gains = np.asarray(p.motor_gains, dtype=float)
        found = tuple(s for s in found if np.allclose(gains[s.source], gains, rtol=1e-9))
    if p.cg_offset is not None:
        offset = np.asarray(p.cg_offset, dtype=float)
        found = tuple(s for s in found if np.allclose(s.matrix[:2, :2] @ offset, offset, rtol=1e-9, atol=1e-12))
    return found
