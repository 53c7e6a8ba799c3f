"""The one place that converts frames and units.

Internal (core) convention, as the thesis: navigation frame N = NED (x north,
y east, z down), body frame B = FRD (x forward, y right, z down), Euler angles
roll φ, pitch θ, yaw ψ in the ZYX (yaw-pitch-roll) sequence, SI units.

ROS convention (REP-103/REP-147): world frame ENU (x east, y north, z up), body
frame FLU (x forward, y left, z up).

Vectors convert with constant permutation/sign matrices, each its own inverse:

.. math::

    v_{NED} = M_{NE} v_{ENU},\\quad M_{NE} = \\begin{bmatrix}0&1&0\\\\1&0&0\\\\0&0&-1\\end{bmatrix}

    v_{FRD} = M_{FB} v_{FLU},\\quad M_{FB} = \\mathrm{diag}(1, -1, -1)

and attitudes (body-to-world rotations) as :math:`R_{NED←FRD} = M_{NE} R_{ENU←FLU} M_{FB}`.

Nothing outside this module flips a sign or scales a unit.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

STANDARD_GRAVITY = 9.80665
"""Standard gravity g0 [m/s²] (CGPM 1901; the unit 'g' of accelerometers)."""

ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""M_NE: maps an ENU vector to NED (and back: it is its own inverse)."""

FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])
"""M_FB: maps a FLU body vector to FRD (and back)."""

DEG = np.pi / 180.0
"""One degree in radians."""

# Units accepted by readers and mapping files, as (SI unit, factor to SI).
UNIT_FACTORS: dict[str, tuple[str, float]] = {
    "s": ("s", 1.0),
    "ms": ("s", 1e-3),
    "us": ("s", 1e-6),
    "ns": ("s", 1e-9),
    "m": ("m", 1.0),
    "mm": ("m", 1e-3),
    "m/s": ("m/s", 1.0),
    "m/s2": ("m/s2", 1.0),
    "g": ("m/s2", STANDARD_GRAVITY),
    "rad": ("rad", 1.0),
    "deg": ("rad", DEG),
    "rad/s": ("rad/s", 1.0),
    "deg/s": ("rad/s", DEG),
    "rad/s2": ("rad/s2", 1.0),
    "deg/s2": ("rad/s2", DEG),
    "V": ("V", 1.0),
    "1": ("1", 1.0),
    "PWM": ("PWM", 1.0),
}


def to_si(values: np.ndarray, unit: str) -> np.ndarray:
    """Scale ``values`` given in ``unit`` to its SI unit (see ``UNIT_FACTORS``).

    Raises KeyError naming the unit when it is unknown; callers wrap it with
    the file and field at fault.
    """
    if unit not in UNIT_FACTORS:
        raise KeyError(f"unknown unit {unit!r}; known: {', '.join(UNIT_FACTORS)}")
    return np.asarray(values, dtype=float) * UNIT_FACTORS[unit][1]


def from_si(values: np.ndarray, unit: str) -> np.ndarray:
    """Inverse of :func:`to_si`: SI values expressed in ``unit``."""
    if unit not in UNIT_FACTORS:
        raise KeyError(f"unknown unit {unit!r}; known: {', '.join(UNIT_FACTORS)}")
    return np.asarray(values, dtype=float) / UNIT_FACTORS[unit][1]


QUATERNION_NORM_TOLERANCE = 0.05
"""Largest deviation from 1 of a logged attitude quaternion's norm; beyond it the row is corrupt, not rounded."""


def quaternion_norm_off(quat) -> float | None:
    """The norm of one quaternion (4 numbers, any order) when it is off 1 beyond :data:`QUATERNION_NORM_TOLERANCE`
    (a zero quaternion has no rotation), else None: the per-message check (no numpy for four numbers)."""
    norm = math.sqrt(sum(c * c for c in quat))
    return norm if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE else None


def non_unit_quaternion(quat: np.ndarray) -> tuple[int, float] | None:
    """(row, norm) of the row of an (N, 4) quaternion array whose norm is furthest from 1, when beyond
    :data:`QUATERNION_NORM_TOLERANCE` (a zero quaternion has no rotation), else None; a non-finite norm is the
    furthest."""
    deviation = np.nan_to_num(np.abs(np.linalg.norm(quat, axis=1) - 1.0), nan=np.inf)
    if not np.any(deviation > QUATERNION_NORM_TOLERANCE):
        return None
    row = int(np.argmax(deviation))
    return row, float(np.linalg.norm(quat[row]))


def enu_to_ned(v: np.ndarray) -> np.ndarray:
    """World vector(s) ENU -> NED; ``v`` is (3,) or (N, 3)."""
    return np.asarray(v, dtype=float) @ ENU_TO_NED.T


def ned_to_enu(v: np.ndarray) -> np.ndarray:
    """World vector(s) NED -> ENU; ``v`` is (3,) or (N, 3)."""
    return np.asarray(v, dtype=float) @ ENU_TO_NED.T


def flu_to_frd(v: np.ndarray) -> np.ndarray:
    """Body vector(s) FLU -> FRD (also angular rates); ``v`` is (3,) or (N, 3): M_FB v, M_FB diagonal (the signs)."""
    return np.asarray(v, dtype=float) * _FLU_TO_FRD_SIGNS


def frd_to_flu(v: np.ndarray) -> np.ndarray:
    """Body vector(s) FRD -> FLU (also angular rates); ``v`` is (3,) or (N, 3)."""
    return np.asarray(v, dtype=float) * _FLU_TO_FRD_SIGNS


_FLU_TO_FRD_SIGNS = np.diag(FLU_TO_FRD).copy()
"""M_FB's diagonal: a body vector converts by its signs (a 3x3 product costs ~5x more on one row)."""


def euler_ned_to_rotation(euler: np.ndarray) -> Rotation:
    """Rotation R_NED←FRD from Euler angles (φ, θ, ψ) [rad], ZYX sequence."""
    euler = np.asarray(euler, dtype=float)
    return Rotation.from_euler("ZYX", euler[..., ::-1])


def rotation_to_euler_ned(rotation: Rotation) -> np.ndarray:
    """Euler angles (φ, θ, ψ) [rad] of R_NED←FRD, ZYX sequence; (N, 3) or (3,)."""
    return rotation.as_euler("ZYX")[..., ::-1]


def euler_ned_to_quat_enu(euler: np.ndarray) -> np.ndarray:
    """Attitude (φ, θ, ψ) NED/FRD [rad] -> quaternion (x, y, z, w) of R_ENU←FLU."""
    r_ned = euler_ned_to_rotation(euler).as_matrix()
    r_enu = ENU_TO_NED @ r_ned @ FLU_TO_FRD
    return Rotation.from_matrix(r_enu).as_quat()


def quat_enu_to_euler_ned(quat_xyzw: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of R_ENU←FLU -> Euler (φ, θ, ψ) NED/FRD [rad], (N, 3) or (3,), in closed form:
    the normalised quaternion's matrix (:func:`quat_to_matrix`), R_NED←FRD = M_NE R_ENU←FLU M_FB, then
    :func:`matrix_to_euler_ned`. The live receding-horizon forecast converts every input's motion-capture row,
    where scipy's Rotation (from_quat, from_matrix, as_euler) cost ~110 µs a call and this ~15 µs (tests hold the
    two equal to 1e-12; at θ = ±π/2 any split of φ and ψ is the same attitude). A zero quaternion is a ValueError,
    as scipy's."""
    q = np.asarray(quat_xyzw, dtype=float)
    r_ned = ENU_TO_NED @ quat_to_matrix(q.reshape(-1, 4)) @ FLU_TO_FRD
    return matrix_to_euler_ned(r_ned).reshape(q.shape[:-1] + (3,))


def quat_to_matrix(quat_xyzw: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of (N, 4) quaternions (x, y, z, w), each normalised first (ValueError for a zero
    one); the Hamilton convention, as scipy's ``Rotation.from_quat``."""
    q = np.asarray(quat_xyzw, dtype=float)
    norm = np.sqrt((q * q).sum(axis=1))
    if not np.all(norm > 0):
        raise ValueError("Found zero norm quaternions in `quat`.")
    entries = _quaternion_matrix_entries(*(q / norm[:, None]).T)
    r = np.empty((len(q), 3, 3))
    for i in range(3):
        for j in range(3):
            r[:, i, j] = entries[i][j]
    return r


def _quaternion_matrix_entries(x, y, z, w):
    """The entries of the rotation matrix of a unit quaternion (x, y, z, w), Hamilton, row by row: arrays
    (:func:`quat_to_matrix`) or floats (:func:`odometry_row_to_ned`), one formula."""
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
            (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
            (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)))


def quat_ned_to_euler_ned(quat_xyzw: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of R_NED←FRD (PX4's attitude, reordered from its w, x, y, z) -> Euler (φ, θ, ψ) [rad]."""
    return rotation_to_euler_ned(Rotation.from_quat(np.asarray(quat_xyzw, dtype=float)))


def body_to_nav(vectors_b: np.ndarray, euler: np.ndarray) -> np.ndarray:
    """Rotate body FRD vectors (N, 3) into N (NED) with attitudes (N, 3) [rad]: v_N = R v_B."""
    v = np.atleast_2d(np.asarray(vectors_b, dtype=float))
    return (euler_ned_to_matrix(euler) @ v[:, :, None]).reshape(np.shape(vectors_b))


def nav_to_body(vectors_n: np.ndarray, euler: np.ndarray) -> np.ndarray:
    """Rotate NED vectors (N, 3) into the body frame FRD with attitudes (N, 3): v_B = R^T v_N."""
    v = np.atleast_2d(np.asarray(vectors_n, dtype=float))
    return (v[:, None, :] @ euler_ned_to_matrix(euler)).reshape(np.shape(vectors_n))


def specific_force(acc_n: np.ndarray, euler: np.ndarray, gravity: float) -> np.ndarray:
    """Body FRD specific force (N, 3) [m/s²] of a kinematic acceleration in N (NED) (N, 3): what an
    accelerometer measures, :math:`f_B = R^T (a_N - g e_z)` (at rest: :math:`f_B = (0, 0, -g)` level)."""
    acc = np.array(acc_n, dtype=float, ndmin=2)
    acc[:, 2] -= gravity
    return nav_to_body(acc, euler).reshape(np.shape(acc_n))


def kinematic_acceleration(force_b: np.ndarray, euler: np.ndarray, gravity: float) -> np.ndarray:
    """Inverse of :func:`specific_force`: :math:`a_N = R f_B + g e_z` (N, 3) [m/s², NED]."""
    acc = np.atleast_2d(body_to_nav(force_b, euler)).copy()
    acc[:, 2] += gravity
    return acc.reshape(np.shape(force_b))


def body_to_down(vectors_b: np.ndarray, euler: np.ndarray) -> np.ndarray:
    r"""(R v_B)_D (...,): the down component of body FRD vectors (..., 3) rotated into N (NED) with attitudes (..., 3)
    [rad]: :func:`body_to_nav`'s D component alone, from R's third row, which holds no yaw:

    .. math:: (R v)_D = -\sin\theta\, v_x + \sin\phi \cos\theta\, v_y + \cos\phi \cos\theta\, v_z
    """
    phi, theta = euler[..., 0], euler[..., 1]
    cos_theta = np.cos(theta)
    return -np.sin(theta) * vectors_b[..., 0] + np.sin(phi) * cos_theta * vectors_b[..., 1] + np.cos(phi) * cos_theta * vectors_b[..., 2]


def tilt_cosine(euler: np.ndarray) -> np.ndarray:
    """R_33 = cos φ cos θ of Euler angles (..., 3) [rad]: the body z axis's down component (the share of a thrust
    along the body z axis that acts vertically)."""
    return np.cos(euler[..., 0]) * np.cos(euler[..., 1])


def euler_rates_to_body_rates(euler: np.ndarray, euler_dot: np.ndarray) -> np.ndarray:
    """Body rates (p, q, r) (N, 3) [rad/s, FRD] of ZYX Euler angles (φ, θ, ψ) (N, 3) [rad] changing at ``euler_dot``
    (N, 3) [rad/s]:

    .. math:: p = \\dot\\phi - \\dot\\psi \\sin\\theta, \\quad
              q = \\dot\\theta \\cos\\phi + \\dot\\psi \\sin\\phi \\cos\\theta, \\quad
              r = -\\dot\\theta \\sin\\phi + \\dot\\psi \\cos\\phi \\cos\\theta
    """
    phi, theta = euler[:, 0], euler[:, 1]
    d_phi, d_theta, d_psi = np.asarray(euler_dot, dtype=float).T
    return np.column_stack([
        d_phi - d_psi * np.sin(theta),
        d_theta * np.cos(phi) + d_psi * np.sin(phi) * np.cos(theta),
        -d_theta * np.sin(phi) + d_psi * np.cos(phi) * np.cos(theta),
    ])


def geodesic_angle(euler_a: np.ndarray, euler_b: np.ndarray) -> np.ndarray:
    r"""Angle [rad] of the rotation between two attitudes (φ, θ, ψ) (..., 3), elementwise over rows, in closed form:
    the quaternions :math:`q_a, q_b` (:func:`euler_ned_to_quat`), :math:`q = q_a^* \otimes q_b` with
    :math:`q_w = q_a \cdot q_b` and :math:`q_v = a_w b_v - b_w a_v - a_v \times b_v`, angle
    :math:`2\,\operatorname{atan2}(|q_v|, |q_w|)` (scipy's ``Rotation.magnitude``; its ``from_euler`` cost 0.36 µs a
    row, 1.6 s of a 20 s diagnosis; tests hold the two equal to 1e-12)."""
    ax, ay, az, aw = euler_ned_to_quat(euler_a)
    bx, by, bz, bw = euler_ned_to_quat(euler_b)
    w = ax * bx + ay * by + az * bz + aw * bw
    vx = aw * bx - bw * ax - (ay * bz - az * by)
    vy = aw * by - bw * ay - (az * bx - ax * bz)
    vz = aw * bz - bw * az - (ax * by - ay * bx)
    return 2.0 * np.arctan2(np.sqrt(vx * vx + vy * vy + vz * vz), np.abs(w))


def euler_ned_to_quat(euler: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Quaternion (x, y, z, w) of R_NED←FRD from Euler angles (φ, θ, ψ) (..., 3) [rad], ZYX: four (...) arrays."""
    half = 0.5 * np.asarray(euler, dtype=float)
    return _quat_entries(np.cos(half[..., 0]), np.sin(half[..., 0]), np.cos(half[..., 1]), np.sin(half[..., 1]),
                         np.cos(half[..., 2]), np.sin(half[..., 2]))


def euler_ned_to_matrix(euler: np.ndarray) -> np.ndarray:
    """R_NED←FRD as (N, 3, 3) matrices from (N, 3) Euler angles (φ, θ, ψ), ZYX, in closed form.

    .. math:: R = R_z(ψ) R_y(θ) R_x(φ)

    The same rotation as :func:`euler_ned_to_rotation`; written out because the
    live predictor converts one sample at a time, where scipy's Rotation costs
    ~100 µs per call and this ~10 µs (tests hold the two equal).
    """
    e = np.atleast_2d(np.asarray(euler, dtype=float))
    if len(e) <= FLOAT_ROWS:  # floats (FLOAT_ROWS)
        return np.array([_rotation_entries(*_cos_sin(angles)) for angles in e.tolist()]).reshape(len(e), 3, 3)
    entries = _rotation_entries(np.cos(e[:, 0]), np.sin(e[:, 0]), np.cos(e[:, 1]), np.sin(e[:, 1]), np.cos(e[:, 2]), np.sin(e[:, 2]))
    r = np.empty((len(e), 3, 3))
    for i in range(3):
        for j in range(3):
            r[:, i, j] = entries[i][j]
    return r


def _rotation_entries(cr, sr, cp, sp, cy, sy):
    """The entries of R_NED←FRD = R_z(ψ) R_y(θ) R_x(φ), row by row, from cos/sin of φ (r), θ (p), ψ (y): arrays
    (:func:`euler_ned_to_matrix`) or floats (:func:`prediction_row_to_ros`), one formula."""
    return ((cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
            (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
            (-sp, cp * sr, cp * cr))


def _quat_entries(cr, sr, cp, sp, cy, sy):
    """Quaternion (x, y, z, w) of R_NED←FRD from cos/sin of the *half* ZYX angles φ/2, θ/2, ψ/2 (arrays or floats)."""
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def _enu_flu_quaternion(x, y, z, w):
    """q_ENU←FLU = q(M_NE) ⊗ q_NED←FRD ⊗ q(M_FB) of q_NED←FRD = (x, y, z, w), expanded (Hamilton product), the overall
    sign chosen so w = (w + z)/√2 (:func:`to_odometry`)."""
    h = math.sqrt(0.5)
    return h * (x + y), h * (x - y), h * (w - z), h * (w + z)


def _quat_xyzw_of_euler_ned(euler: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of R_NED←FRD from (N, 3) ZYX Euler angles, closed form (half angles)."""
    return np.column_stack(euler_ned_to_quat(np.atleast_2d(euler)))


def to_odometry(pos_n: np.ndarray, vel_n: np.ndarray, euler: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Internal state -> nav_msgs/Odometry fields (REP-103/147), row-wise.

    Returns (position ENU [m], quaternion (x, y, z, w) of R_ENU←FLU, linear
    twist in the child (body FLU) frame [m/s]): Odometry's pose is in the world
    frame of its header, its twist in ``child_frame_id``.

    .. math::

        v_{FLU} = M_{FB} R_{NED←FRD}^T v_{NED}, \qquad
        q_{ENU←FLU} = q(M_{NE}) \otimes q_{NED←FRD} \otimes q(M_{FB})

    with q(M_NE) = (1/√2, 1/√2, 0, 0), a half turn about (x + y)/√2, and
    q(M_FB) = (1, 0, 0, 0), a half turn about x (both in x, y, z, w order).
    Closed form throughout: the live predictor calls this once per sample.
    """
    vel_b = nav_to_body(vel_n, euler)
    quat = np.column_stack(_enu_flu_quaternion(*_quat_xyzw_of_euler_ned(euler).T))
    return ned_to_enu(pos_n), quat.reshape(np.shape(euler)[:-1] + (4,)), frd_to_flu(vel_b)


def prediction_row_to_ros(pos_n, vel_n, acc_n, euler, rates, angular_acc, gravity: float) -> tuple[list[float], list[float]]:
    """One predicted state (each a 3-sequence of floats, NED/FRD) -> its ROS fields as floats: (position ENU,
    quaternion (x, y, z, w) of R_ENU←FLU, linear twist FLU, rates FLU) and (specific force FLU, angular acceleration
    FLU). The equations of :func:`to_odometry` and :func:`specific_force` (the same entry formulas) on plain floats:
    the live predictor converts one row per input, where the (N, 3) forms cost ~130 µs for one row and this ~15 µs."""
    half = [0.5 * a for a in euler]
    r = _rotation_entries(*_cos_sin(euler))
    quat = _enu_flu_quaternion(*_quat_entries(*_cos_sin(half)))

    def to_body(v):  # R^T v
        return [r[0][j] * v[0] + r[1][j] * v[1] + r[2][j] * v[2] for j in range(3)]

    def flu(v):  # M_FB v
        return [v[0], -v[1], -v[2]]

    twist = flu(to_body(vel_n))
    force = flu(to_body((acc_n[0], acc_n[1], acc_n[2] - gravity)))
    position = [pos_n[1], pos_n[0], -pos_n[2]]  # M_NE v
    return [*position, *quat, *twist, *flu(rates)], [*force, *flu(angular_acc)]


def _cos_sin(angles) -> tuple[float, ...]:
    """cos φ, sin φ, cos θ, sin θ, cos ψ, sin ψ of three angles (floats)."""
    return tuple(f(a) for a in angles for f in (math.cos, math.sin))


FLOAT_ROWS = 4
""":func:`from_odometry`, :func:`euler_ned_to_matrix` and :func:`matrix_to_euler_ned` convert up to this many rows as
floats (the same entry formulas): the live predictor's forecast converts 1-2 rows at a time per input, where a numpy
call costs 3-6 µs here (from_odometry's array form ~200 µs, its floats ~30 µs)."""


def from_odometry(position_enu: np.ndarray, quat_xyzw: np.ndarray, twist_flu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """nav_msgs/Odometry fields -> (pos_n, vel_n, euler), inverse of :func:`to_odometry`; (N, 3), (N, 4), (N, 3)
    rows of up to :data:`FLOAT_ROWS` as floats (the same numbers to rounding)."""
    quat = np.asarray(quat_xyzw, dtype=float)
    if quat.ndim == 2 and len(quat) <= FLOAT_ROWS:
        rows = [odometry_row_to_ned(*fields) for fields in zip(np.asarray(position_enu, dtype=float).tolist(), quat.tolist(),
                                                               np.asarray(twist_flu, dtype=float).tolist())]
        return tuple(np.array([row[k] for row in rows], dtype=float).reshape(len(rows), 3) for k in range(3))
    euler = quat_enu_to_euler_ned(quat)
    vel_n = body_to_nav(flu_to_frd(twist_flu), euler)
    return enu_to_ned(position_enu), vel_n, euler


def odometry_row_to_ned(position_enu, quat_xyzw, twist_flu) -> tuple[list[float], list[float], list[float]]:
    """One odometry row's fields (3-, 4-, 3-sequences of floats) -> (pos_n, vel_n, euler) as floats: the equations of
    :func:`from_odometry`'s array form (the same entry formulas) on plain floats. The quaternion normalised (a zero one
    is a ValueError, as :func:`quat_to_matrix`), R_NED←FRD = M_NE R_ENU←FLU M_FB taken row by row (rows 1, 0, -2 of
    R_ENU←FLU, columns times 1, -1, -1), the Euler angles of :func:`matrix_to_euler_ned`, v_N = R(φ, θ, ψ) M_FB v_FLU."""
    x, y, z, w = quat_xyzw
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not norm > 0:
        raise ValueError("Found zero norm quaternions in `quat`.")
    r = _quaternion_matrix_entries(x / norm, y / norm, z / norm, w / norm)  # R_ENU←FLU
    euler = [math.atan2(r[2][1], r[2][2]), -math.asin(min(max(-r[2][0], -1.0), 1.0)), math.atan2(r[0][0], r[1][0])]
    body = (twist_flu[0], -twist_flu[1], -twist_flu[2])  # M_FB v
    rotation = _rotation_entries(*_cos_sin(euler))
    velocity = [rotation[i][0] * body[0] + rotation[i][1] * body[1] + rotation[i][2] * body[2] for i in range(3)]
    return [position_enu[1], position_enu[0], -position_enu[2]], velocity, euler


def matrix_to_euler_ned(rotation: np.ndarray) -> np.ndarray:
    """(N, 3) Euler angles (φ, θ, ψ) [rad], ZYX, of (N, 3, 3) matrices R_NED←FRD, in closed form.

    .. math:: φ = \\operatorname{atan2}(R_{32}, R_{33}),\\quad θ = -\\arcsin R_{31},\\quad ψ = \\operatorname{atan2}(R_{21}, R_{11})

    The inverse of :func:`euler_ned_to_matrix` (ψ in (-π, π], θ clipped to [-π/2, π/2]); the physics
    model converts every predicted row, where scipy's Rotation is ~10x slower.
    """
    r = np.asarray(rotation, dtype=float).reshape(-1, 3, 3)
    if len(r) <= FLOAT_ROWS:  # floats (FLOAT_ROWS)
        return np.array([_matrix_row_to_euler(m) for m in r.reshape(-1, 9).tolist()]).reshape(len(r), 3)
    return np.column_stack([
        np.arctan2(r[:, 2, 1], r[:, 2, 2]),
        -np.arcsin(np.minimum(np.maximum(r[:, 2, 0], -1.0), 1.0)),  # np.clip's numbers at a tenth of its cost here
        np.arctan2(r[:, 1, 0], r[:, 0, 0]),
    ])


def _matrix_row_to_euler(m: list[float]) -> list[float]:
    """:func:`matrix_to_euler_ned` of one matrix's 9 entries (row-major) on floats."""
    return [math.atan2(m[7], m[8]), -math.asin(min(max(m[6], -1.0), 1.0)), math.atan2(m[3], m[0])]


FLOAT_UNWRAP_ROWS = 8
""":func:`unwrap_angles` unwraps a vector of up to this many angles as floats: the live predictor unwraps 2 rows of
yaw per input, where ``np.unwrap`` costs ~35 µs here and the floats ~3 µs."""


def unwrap_angles(angles: np.ndarray) -> np.ndarray:
    """Angles [rad] along axis 0 made continuous (``np.unwrap``): each step between neighbours taken into [-π, π],
    the correction added to every later row,

    .. math:: Δ_k = ψ_k - ψ_{k-1},\\quad Δ'_k = ((Δ_k + π) \\bmod 2π) - π \\;(π \\text{ for } Δ'_k = -π,\\, Δ_k > 0),
              \\quad \\hat ψ_k = ψ_k + \\sum_{j \\le k,\\, |Δ_j| \\ge π} (Δ'_j - Δ_j)

    A vector of up to :data:`FLOAT_UNWRAP_ROWS` on floats (the same operations in the same order: the same numbers)."""
    values = np.asarray(angles, dtype=float)
    if values.ndim != 1 or len(values) > FLOAT_UNWRAP_ROWS:
        return np.unwrap(values, axis=0)
    psi = values.tolist()
    out, correction = psi[:1], 0.0
    for previous, value in zip(psi, psi[1:]):
        step = value - previous
        if not abs(step) < math.pi:  # NaN too: np.unwrap carries it to every later row
            wrapped = (step + math.pi) % (2.0 * math.pi) - math.pi
            if wrapped == -math.pi and step > 0:
                wrapped = math.pi
            correction += wrapped - step
        out.append(value + correction)
    return np.array(out)
