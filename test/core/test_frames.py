import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quad_modelling.core import frames


def test_world_and_body_conversions_are_involutions():
    v = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, -6.0]])
    np.testing.assert_array_equal(frames.enu_to_ned(v), [[2.0, 1.0, -3.0], [5.0, -4.0, 6.0]])
    np.testing.assert_array_equal(frames.ned_to_enu(frames.enu_to_ned(v)), v)
    np.testing.assert_array_equal(frames.flu_to_frd(v), [[1.0, -2.0, -3.0], [-4.0, -5.0, 6.0]])
    np.testing.assert_array_equal(frames.frd_to_flu(frames.flu_to_frd(v)), v)


def test_units_scale_to_si():
    assert frames.to_si(1.0, "g") == pytest.approx(9.80665)
    assert frames.to_si(180.0, "deg") == pytest.approx(np.pi)
    assert frames.to_si(1500.0, "us") == pytest.approx(1.5e-3)
    assert frames.from_si(frames.to_si(3.0, "deg/s"), "deg/s") == pytest.approx(3.0)
    with pytest.raises(KeyError, match="furlong"):
        frames.to_si(1.0, "furlong")


def test_yaw_east_in_ned_points_body_x_east_in_enu():
    # Yaw +90 deg in NED: the nose points east. In ENU the body x axis is then +x (east).
    quat = frames.euler_ned_to_quat_enu(np.array([0.0, 0.0, np.pi / 2]))
    nose_enu = Rotation.from_quat(quat).apply([1.0, 0.0, 0.0])
    np.testing.assert_allclose(nose_enu, [1.0, 0.0, 0.0], atol=1e-12)


def test_roll_right_wing_down_in_both_conventions():
    # Positive FRD roll puts the right wing down: body +y (FRD right) gets a +z_NED (down) component.
    quat = frames.euler_ned_to_quat_enu(np.array([0.3, 0.0, 0.0]))
    left_wing_enu = Rotation.from_quat(quat).apply([0.0, 1.0, 0.0])  # FLU +y = left wing
    assert left_wing_enu[2] == pytest.approx(np.sin(0.3))  # left wing up in ENU


def test_euler_quaternion_round_trip():
    rng = np.random.default_rng(1)
    euler = np.column_stack([rng.uniform(-1.2, 1.2, 200), rng.uniform(-1.2, 1.2, 200), rng.uniform(-3.1, 3.1, 200)])
    back = frames.quat_enu_to_euler_ned(frames.euler_ned_to_quat_enu(euler))
    np.testing.assert_allclose(back, euler, atol=1e-12)


def test_odometry_round_trip_and_body_twist():
    pos = np.array([[1.0, 2.0, -3.0]])
    vel = np.array([[1.0, 0.0, 0.0]])  # flying north
    euler = np.array([[0.0, 0.0, np.pi / 2]])  # nose east: the body sees the velocity to its left
    position_enu, quat, twist_flu = frames.to_odometry(pos, vel, euler)
    np.testing.assert_allclose(position_enu, [[2.0, 1.0, 3.0]])
    np.testing.assert_allclose(twist_flu, [[0.0, 1.0, 0.0]], atol=1e-12)  # FLU +y = left
    p, v, e = frames.from_odometry(position_enu, quat, twist_flu)
    np.testing.assert_allclose(p, pos)
    np.testing.assert_allclose(v, vel, atol=1e-12)
    np.testing.assert_allclose(e, euler, atol=1e-12)


def test_geodesic_angle_of_a_pure_roll():
    a = np.zeros((1, 3))
    b = np.array([[0.25, 0.0, 0.0]])
    assert frames.geodesic_angle(a, b)[0] == pytest.approx(0.25)


def test_closed_form_rotations_equal_scipy():
    rng = np.random.default_rng(2)
    euler = np.column_stack([rng.uniform(-1.5, 1.5, 300), rng.uniform(-1.5, 1.5, 300), rng.uniform(-3.1, 3.1, 300)])
    np.testing.assert_allclose(frames.euler_ned_to_matrix(euler), frames.euler_ned_to_rotation(euler).as_matrix(), atol=1e-14)
    vectors = rng.standard_normal((300, 3))
    np.testing.assert_allclose(frames.body_to_nav(vectors, euler), frames.euler_ned_to_rotation(euler).apply(vectors), atol=1e-12)
    np.testing.assert_allclose(frames.nav_to_body(frames.body_to_nav(vectors, euler), euler), vectors, atol=1e-12)
    _, quat, _ = frames.to_odometry(np.zeros((300, 3)), vectors, euler)
    reference = Rotation.from_quat(frames.euler_ned_to_quat_enu(euler))
    np.testing.assert_allclose(Rotation.from_quat(quat).as_matrix(), reference.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(frames.body_to_nav(vectors[0], euler[0]), frames.euler_ned_to_rotation(euler[0]).apply(vectors[0]), atol=1e-12)


def test_one_prediction_row_in_floats_equals_the_array_forms():
    """prediction_row_to_ros (the live predictor's per-input conversion, plain floats) against to_odometry,
    specific_force and frd_to_flu on the same rows, attitudes over the whole range."""
    rng = np.random.default_rng(5)
    pos, vel, acc, rates, angular_acc = (rng.standard_normal((100, 3)) for _ in range(5))
    euler = np.column_stack([rng.uniform(-3.1, 3.1, 100), rng.uniform(-1.5, 1.5, 100), rng.uniform(-6.0, 6.0, 100)])
    position, quat, twist = frames.to_odometry(pos, vel, euler)
    expected_odom = np.hstack([position, quat, twist, frames.frd_to_flu(rates)])
    expected_accel = np.hstack([frames.frd_to_flu(frames.specific_force(acc, euler, 9.81)), frames.frd_to_flu(angular_acc)])
    for i in range(100):
        odom, accel = frames.prediction_row_to_ros(*(a[i].tolist() for a in (pos, vel, acc, euler, rates, angular_acc)), 9.81)
        assert all(isinstance(v, float) for v in (*odom, *accel))
        np.testing.assert_allclose(odom, expected_odom[i], atol=1e-13)
        np.testing.assert_allclose(accel, expected_accel[i], atol=1e-13)


def test_the_closed_form_quaternion_conversion_equals_scipys():
    """quat_enu_to_euler_ned (closed form, the live forecast's per-row conversion) against scipy's Rotation: random
    attitudes away from θ = ±π/2, unnormalised quaternions included."""
    rng = np.random.default_rng(4)
    quat = rng.normal(size=(500, 4)) * rng.uniform(0.5, 2.0, (500, 1))
    r_ned = frames.ENU_TO_NED @ Rotation.from_quat(quat).as_matrix() @ frames.FLU_TO_FRD
    expected = Rotation.from_matrix(r_ned).as_euler("ZYX")[:, ::-1]
    keep = np.abs(expected[:, 1]) < 1.5
    np.testing.assert_allclose(frames.quat_enu_to_euler_ned(quat)[keep], expected[keep], atol=1e-12)
    np.testing.assert_allclose(frames.quat_enu_to_euler_ned(quat[0]), expected[0], atol=1e-12)
    with pytest.raises(ValueError, match="zero norm"):
        frames.quat_enu_to_euler_ned(np.zeros(4))


def test_a_few_odometry_rows_in_floats_equal_the_array_forms():
    """from_odometry converts up to FLOAT_ROWS rows as floats (odometry_row_to_ned, the live forecast's 2 rows
    per input): the same numbers as its array form (more rows) to rounding, unnormalised quaternions, attitudes over
    the whole range and at θ = ±π/2 included; a zero or NaN quaternion is a ValueError in both."""
    rng = np.random.default_rng(6)
    quat = rng.normal(size=(400, 4)) * rng.uniform(0.5, 2.0, (400, 1))
    quat[:4] = frames.euler_ned_to_quat_enu(np.array([[0.3, np.pi / 2, 1.0], [-0.2, -np.pi / 2, -2.0],
                                                      [3.1, 0.1, 3.14159], [-3.1, -0.1, -3.14159]]))
    position, twist = rng.normal(0.0, 5.0, (400, 3)), rng.normal(0.0, 3.0, (400, 3))
    expected = frames.from_odometry(position, quat, twist)  # 400 rows: the array form
    rows = frames.FLOAT_ROWS
    for first in range(0, 400, rows):
        got = frames.from_odometry(position[first:first + rows], quat[first:first + rows], twist[first:first + rows])
        for name, value, reference in zip(("pos_n", "vel_n", "euler"), got, expected):
            assert value.shape == (rows, 3), name
            np.testing.assert_allclose(value, reference[first:first + rows], rtol=0, atol=1e-12, err_msg=name)
    one = frames.from_odometry(position[:1], quat[:1], twist[:1])
    assert all(isinstance(v, float) for part in frames.odometry_row_to_ned(position[0], quat[0], twist[0]) for v in part)
    np.testing.assert_array_equal(one[2][0], frames.odometry_row_to_ned(position[0].tolist(), quat[0].tolist(), twist[0].tolist())[2])
    for bad in (np.zeros((1, 4)), np.full((1, 4), np.nan)):
        for count in (1, rows + 1):  # float and array forms
            with pytest.raises(ValueError, match="zero norm"):
                frames.from_odometry(np.zeros((count, 3)), np.repeat(bad, count, axis=0), np.zeros((count, 3)))


def test_a_few_matrices_and_euler_rows_in_floats_equal_the_array_forms():
    """euler_ned_to_matrix and matrix_to_euler_ned convert up to FLOAT_ROWS rows as floats: the array forms' numbers
    (more rows) to rounding, a single (3,) / (3, 3) argument too; θ = ±π/2 and a rounding-unnormalised matrix (|R_31|
    just over 1) included; NaN stays NaN."""
    rng = np.random.default_rng(12)
    euler = np.column_stack([rng.uniform(-np.pi, np.pi, 400), rng.uniform(-np.pi / 2, np.pi / 2, 400), rng.uniform(-np.pi, np.pi, 400)])
    euler[:2, 1] = np.pi / 2, -np.pi / 2
    matrices = frames.euler_ned_to_matrix(euler)  # 400 rows: the array forms
    matrices_off = matrices.copy()
    matrices_off[2, 2, 0] = 1.0 + 1e-15
    angles = frames.matrix_to_euler_ned(matrices_off)
    rows = frames.FLOAT_ROWS
    for first in range(0, 400, rows):
        part = slice(first, first + rows)
        np.testing.assert_allclose(frames.euler_ned_to_matrix(euler[part]), matrices[part], rtol=0, atol=1e-15)
        np.testing.assert_allclose(frames.matrix_to_euler_ned(matrices_off[part]), angles[part], rtol=0, atol=1e-12)
    assert frames.euler_ned_to_matrix(euler[5]).shape == (1, 3, 3) and frames.matrix_to_euler_ned(matrices[5]).shape == (1, 3)
    assert np.isnan(frames.matrix_to_euler_ned(np.full((3, 3), np.nan))).all()
    assert np.isnan(frames.euler_ned_to_matrix(np.array([np.nan, 0.0, 0.0]))[0, 1:, 1:]).all()


def test_the_down_component_alone_is_body_to_navs_and_needs_no_yaw():
    """body_to_down is body_to_nav's D component for any yaw (R's third row holds none): rows and one (3,) vector;
    level, it is the vector's own z."""
    rng = np.random.default_rng(13)
    euler = np.column_stack([rng.uniform(-np.pi, np.pi, 300), rng.uniform(-np.pi / 2, np.pi / 2, 300), rng.uniform(-np.pi, np.pi, 300)])
    vectors = rng.normal(size=(300, 3)) * 9.81
    down = frames.body_to_down(vectors, euler)
    np.testing.assert_allclose(down, frames.body_to_nav(vectors, euler)[:, 2], rtol=0, atol=1e-13)
    turned = euler + np.array([0.0, 0.0, 2.0])
    np.testing.assert_array_equal(frames.body_to_down(vectors, turned), down)
    assert np.isclose(frames.body_to_down(vectors[7], euler[7]), down[7], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(frames.body_to_down(vectors, np.zeros((300, 3))), vectors[:, 2])


def test_a_few_angles_unwrap_to_numpys_numbers():
    """unwrap_angles of up to FLOAT_UNWRAP_ROWS angles (floats) gives np.unwrap's numbers bit for bit: random jumps,
    steps of exactly ±π and 2π, NaN and ±inf (carried to every later row, as numpy does); longer vectors and
    (N, 3) arrays are np.unwrap's along axis 0."""
    rng = np.random.default_rng(11)
    for _ in range(20000):
        angles = rng.normal(0.0, 4.0, rng.integers(1, frames.FLOAT_UNWRAP_ROWS + 1))
        if len(angles) > 1 and rng.random() < 0.2:
            angles[1] = angles[0] + rng.choice([np.pi, -np.pi, 2 * np.pi, -2 * np.pi])
        if rng.random() < 0.1:
            angles[rng.integers(len(angles))] = rng.choice([np.nan, np.inf, -np.inf])
        with np.errstate(invalid="ignore"):
            expected = np.unwrap(angles)
        np.testing.assert_array_equal(frames.unwrap_angles(angles), expected)
    long, wide = rng.normal(0.0, 4.0, 50), rng.normal(0.0, 4.0, (50, 3))
    np.testing.assert_array_equal(frames.unwrap_angles(long), np.unwrap(long))
    np.testing.assert_array_equal(frames.unwrap_angles(wide), np.unwrap(wide, axis=0))
    assert np.abs(np.diff(frames.unwrap_angles(np.array([3.1, -3.1, 3.0])))).max() < np.pi


def test_closed_form_geodesic_angle_equals_scipys_magnitude():
    """Random attitudes (pitch within ±1.43 rad), near pairs and far ones, any leading shape: scipy's relative
    rotation magnitude to 1e-12."""
    rng = np.random.default_rng(7)
    a = rng.uniform(-3.0, 3.0, (4000, 3)) * np.array([1.0, 0.48, 1.0])
    b = a + rng.normal(0.0, 1e-3, a.shape)
    b[:500] = rng.uniform(-3.0, 3.0, (500, 3)) * np.array([1.0, 0.48, 1.0])
    expected = (frames.euler_ned_to_rotation(a).inv() * frames.euler_ned_to_rotation(b)).magnitude()
    np.testing.assert_allclose(frames.geodesic_angle(a, b), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(frames.geodesic_angle(a.reshape(40, 100, 3), b.reshape(40, 100, 3)),
                               expected.reshape(40, 100), rtol=0, atol=1e-12)


def test_euler_rates_give_the_body_rates_of_the_rotation_they_trace():
    """[ω]× = Rᵀ dR/dt: the body rates of attitudes R(η(t)) along a smooth Euler path, by a central difference of
    the rotation matrices, equal the ZYX kinematics of η and dη/dt."""
    t = np.linspace(0.0, 2.0, 201)
    euler = np.column_stack([0.4 * np.sin(2 * t), -0.3 * np.cos(3 * t), 1.5 * t])
    euler_dot = np.column_stack([0.8 * np.cos(2 * t), 0.9 * np.sin(3 * t), np.full_like(t, 1.5)])
    rot = frames.euler_ned_to_matrix(euler)
    dt = t[1] - t[0]
    skew = np.einsum("nji,njk->nik", rot[1:-1], (rot[2:] - rot[:-2]) / (2 * dt))
    from_matrices = np.column_stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]])
    np.testing.assert_allclose(frames.euler_rates_to_body_rates(euler, euler_dot)[1:-1], from_matrices, atol=1e-3)  # O(dt²) difference error


def test_a_non_finite_quaternion_is_the_furthest_from_unit_norm():
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
    assert frames.non_unit_quaternion(quat) is None
    quat[1] = [0.0, 0.0, 0.0, 1.5]
    quat[3, 0] = np.nan
    row, norm = frames.non_unit_quaternion(quat)
    assert row == 3 and np.isnan(norm)
    quat[3, 0] = np.inf
    assert frames.non_unit_quaternion(quat)[0] == 3
