"""Message <-> array conversions (no DDS): frames, round trips, stamps."""

import numpy as np

from quad_modelling.core.preprocess import measured_variables
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.io import topics
from quad_modelling.io.topics import stamps_ns
from quad_modelling.nodes import messages
from test.conftest import synthetic_log


def test_stamps_round_trip_exactly_as_the_bag_reader_computes_time():
    t = 1772662595.495331584 + np.arange(50) * 0.01
    ns = stamps_ns(t)
    back = np.array([topics.stamp_ns(messages.ns_stamp(int(n))) for n in ns])
    assert np.array_equal(back, ns)
    assert np.array_equal(topics.stamps_to_seconds(back), ns / 1e9)


def test_measurement_messages_are_enu_flu_and_convert_back_to_the_log():
    log = synthetic_log(n=60)
    arrays = messages.measurement_messages(log)
    ns = stamps_ns(log.t)
    odom = [topics.odometry_fields(arrays.odometry(i, int(ns[i]))) for i in range(len(log))]
    imu = [topics.imu_fields(arrays.imu(i, int(ns[i]))) for i in range(len(log))]
    motor = [topics.motor_fields(arrays.motor(i, int(ns[i]))) for i in range(len(log))]
    # ENU position = (y_N, x_N, -z_N); FLU specific force = (x, -y, -z) of FRD.
    assert np.allclose(np.array(odom)[:, 0:3], log.pos_n[:, [1, 0, 2]] * [1, 1, -1])
    assert np.allclose(np.array(imu)[:, 0:3], log.acc_b * [1, -1, -1])
    msg = arrays.odometry(0, int(ns[0]))
    assert (msg.header.frame_id, msg.child_frame_id) == ("world", "base_link")
    back = topics.measurement_log(ns, [m[0] for m in motor], odom, imu, "crazyflie21", "test",
                                    omega=np.array([m[1] for m in motor]))
    assert np.allclose(back.pos_n, log.pos_n) and np.allclose(back.vel_n, log.vel_n, atol=1e-12)
    assert np.allclose(back.euler, log.euler, atol=1e-12)  # yaw unwrapped like the bag reader
    assert np.allclose(back.acc_b, log.acc_b) and np.allclose(back.gyro_b, log.gyro_b)
    assert np.array_equal(back.u, log.u) and np.allclose(back.omega, log.omega)


def test_level_hover_prediction_has_upward_flu_acceleration_and_north_is_enu_y():
    y = np.zeros((1, len(VARIABLES)))
    y[0, 0] = 2.0   # 2 m north
    y[0, 8] = -1.0  # accelerating up (NED z down)
    y[0, 14] = 0.5  # yaw rate, FRD z down
    odom, accel = topics.prediction_fields(y)
    assert np.allclose(odom[0, 0:3], [0.0, 2.0, 0.0])
    assert np.allclose(odom[0, 3:7], [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)])  # yaw 0 NED = facing north: +90° about ENU z
    assert np.allclose(accel[0, 0:3], [0.0, 0.0, 1.0 + GRAVITY])  # the specific force an IMU measures: 1 m/s² + g up
    assert np.allclose(odom[0, 10:13], [0.0, 0.0, -0.5])
    o, a = messages.prediction_messages(7_000_000_123, odom[0], accel[0], "greybox/base_link")
    assert (o.header.frame_id, o.child_frame_id, a.header.frame_id) == ("world", "greybox/base_link", "greybox/base_link")
    assert topics.stamp_ns(o.header.stamp) == 7_000_000_123


def test_predicted_accel_is_the_imus_specific_force_so_a_subscriber_compares_them_directly():
    """<model>/accel carries the IMU's convention (gravity included, body FLU): a prediction equal to the measured
    acceleration (a_N = R f_B + g e_z) is published as exactly the measured imu linear_acceleration."""
    log = synthetic_log(n=200)
    y = measured_variables(log)
    _, accel = topics.prediction_fields(y)
    imu = np.array([topics.imu_fields(m) for m in (messages.measurement_messages(log).imu(i, i) for i in range(len(log)))])
    assert np.allclose(accel[:, 0:3], imu[:, 0:3], atol=1e-9)
    assert abs(np.median(np.linalg.norm(accel[:, 0:3], axis=1)) - GRAVITY) < 1.0  # near hover: |f| ~ g, not ~ 0


def test_predictions_round_trip_through_odometry_and_accel():
    log = synthetic_log(n=200)
    y = measured_variables(log)
    odom, accel = topics.prediction_fields(y)
    msgs = [messages.prediction_messages(i, odom[i], accel[i], "m/base_link") for i in range(len(y))]
    back = topics.predictions_from_fields([topics.predicted_odometry_fields(o) for o, _ in msgs],
                                            [topics.accel_fields(a) for _, a in msgs])
    assert np.allclose(back, y, atol=1e-9)


def test_serialized_predictions_deserialize_to_the_filled_messages():
    """The predictor publishes CDR bytes written at probed offsets: they deserialize to exactly the messages filled
    the ordinary way, for stamps from 0 to the largest int32 second, any float and two frame names (rclpy's own
    serialization may differ in the alignment padding, which no reader reads)."""
    from geometry_msgs.msg import AccelStamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message, serialize_message

    rng = np.random.default_rng(5)
    for child, world in (("m/base_link", "world"), ("a_much_longer_model_name/base_link", "odom")):
        serialized = messages.SerializedPredictions(child, world)
        stamps = [0, 999_999_999, (2**31 - 1) * 10**9 + 999_999_999, *rng.integers(0, 2**31 * 10**9, 40).tolist()]  # sec is an int32
        for ns in stamps:
            odom, accel = rng.normal(size=13) * rng.choice([1e-300, 1.0, 1e300]), rng.normal(size=6)
            odom_bytes, accel_bytes = serialized.fill(ns, odom, accel)
            o, a = messages.prediction_messages(ns, odom, accel, child, world)
            assert deserialize_message(odom_bytes, Odometry) == o and deserialize_message(accel_bytes, AccelStamped) == a
            assert serialized.odometry(ns, odom) == odom_bytes
            assert topics.stamp_ns(deserialize_message(odom_bytes, Odometry).header.stamp) == ns
            assert (len(odom_bytes), len(accel_bytes)) == (len(serialize_message(o)), len(serialize_message(a)))


def test_malformed_and_non_finite_messages_are_recognised():
    from sensor_msgs.msg import JointState

    assert topics.motor_fields(JointState(effort=[1.0, 2.0])) is None
    u, omega = topics.motor_fields(JointState(effort=[1.0, 2.0, 3.0, 4.0], velocity=[float("nan")] * 4))
    assert omega is None and np.array_equal(u, [1, 2, 3, 4])
    assert not topics.all_finite([0.0, float("nan")]) and topics.all_finite([0.0, 1.0])


def test_one_conversion_gives_byte_identical_messages_in_rclpy_and_rosbags():
    """The same MeasurementMessages code over both bindings gives the same messages.

    Compared as CDR after a rosbags round trip of rclpy's bytes: Fast CDR leaves its
    alignment padding bytes uninitialised, so the raw bytes may differ there.
    """
    from rclpy.serialization import serialize_message

    from quad_modelling.io.bag_io import BAG_TYPES, TYPESTORE
    from test.io.test_topics import log_through_messages

    log = synthetic_log(n=40)
    ns = stamps_ns(log.t)
    ours, bags = messages.measurement_messages(log), topics.MeasurementMessages(log, BAG_TYPES)
    for row in (0, 17, 39):
        for key, msg in ours.row(row, int(ns[row])).items():
            msgtype = topics.MEASUREMENT_TOPICS[key]
            from_rclpy = TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(serialize_message(msg), msgtype), msgtype)
            assert bytes(from_rclpy) == bytes(TYPESTORE.serialize_cdr(bags.row(row, int(ns[row]))[key], msgtype)), (row, key)
    back = log_through_messages(log, messages.RCLPY_TYPES)  # FlightLog -> rclpy messages -> FlightLog
    assert np.array_equal(back.pos_n, log.pos_n) and np.array_equal(back.u, log.u) and np.array_equal(back.acc_b, log.acc_b)
    np.testing.assert_allclose(back.euler, log.euler, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.vel_n, log.vel_n, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.vbat, log.vbat, rtol=1e-7)  # rclpy keeps BatteryState.voltage as a float32


def test_odometry_in_ned_or_frd_frames_or_a_twist_in_the_pose_frame_is_reported_not_dropped():
    """A stack's odometry in map_ned / base_link_frd was read as ENU / FLU without a word (review of session 33): one
    fault, the message still read; the contract's frames (and ENU names other than world) say nothing."""
    from nav_msgs.msg import Odometry

    from quad_modelling.nodes.messages import check_odometry_frames

    class Faults:
        def __init__(self):
            self.reports = []

        def report(self, kind, text):
            self.reports.append((kind, text))

    for world, child, said in (("world", "base_link", False), ("map", "base_link", False), ("map_ned", "base_link_frd", True),
                               ("world", "body_FRD", True), ("odom", "odom", True)):
        msg, faults = Odometry(), Faults()
        msg.header.frame_id, msg.child_frame_id = world, child
        check_odometry_frames(faults, msg)
        assert bool(faults.reports) is said, (world, child)
        if said:
            assert faults.reports[0][0] == "odom_frames" and f"frames {world!r} / {child!r}" in faults.reports[0][1]
