"""The topic contract with rosbags' binding (no rclpy): FlightLog <-> messages, CDR stamps, recorded bags."""

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from quad_modelling.io import bag_io, topics
from quad_modelling.io.bag_io import (
    BAG_TYPES,
    TYPESTORE,
    read_bag_metadata,
    read_recorded,
    write_bag,
)
from test.conftest import synthetic_log


def log_through_messages(log, types):
    """FlightLog -> one message per topic and row (``types``' binding) -> fields -> FlightLog."""
    messages = topics.MeasurementMessages(log, types)
    ns = topics.stamps_ns(log.t)
    motor, odom, imu, vbat = [], [], [], []
    for row, stamp in enumerate(ns.tolist()):
        sample = messages.row(row, stamp)
        assert {topics.stamp_ns(m.header.stamp) for m in sample.values()} == {stamp}
        motor.append(topics.motor_fields(sample["motor_input"]))
        odom.append(topics.odometry_fields(sample["mocap/odom"]))
        imu.append(topics.imu_fields(sample["imu"]))
        vbat.append(sample["battery"].voltage)
    return topics.measurement_log(ns, [m[0] for m in motor], odom, imu, log.meta.vehicle, "messages",
                                  omega=np.array([m[1] for m in motor]), vbat=np.array(vbat))


def test_flight_log_to_rosbags_messages_and_back_is_lossless():
    log = synthetic_log(n=120)  # yaw crosses ±π: unwrapped on the way back
    back = log_through_messages(log, BAG_TYPES)
    assert np.array_equal(back.t, topics.stamps_ns(log.t) / 1e9)
    assert np.array_equal(back.u, log.u) and np.array_equal(back.omega, log.omega) and np.array_equal(back.vbat, log.vbat)
    assert np.array_equal(back.pos_n, log.pos_n)  # ENU <-> NED is a permutation and a sign: exact
    assert np.array_equal(back.acc_b, log.acc_b) and np.array_equal(back.gyro_b, log.gyro_b)
    np.testing.assert_allclose(back.euler, log.euler, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.vel_n, log.vel_n, rtol=0, atol=1e-12)


def test_cdr_stamp_is_read_and_rewritten_without_deserialising():
    msg = BAG_TYPES.imu(acc_flu=(0.1, -0.2, 9.8), gyro_flu=(0.01, 0.02, -0.03), ns=1_772_662_595_495_331_584)
    raw = bytes(TYPESTORE.serialize_cdr(msg, topics.MEASUREMENT_TOPICS["imu"]))
    assert topics.cdr_stamp_ns(raw) == 1_772_662_595_495_331_584
    moved = topics.cdr_restamped(raw, 1_772_662_638_000_000_007)
    assert len(moved) == len(raw) and moved[12:] == raw[12:]
    back = TYPESTORE.deserialize_cdr(moved, topics.MEASUREMENT_TOPICS["imu"])
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (1_772_662_638, 7)
    assert topics.imu_fields(back) == pytest.approx([0.1, -0.2, 9.8, 0.01, 0.02, -0.03], abs=0)
    with pytest.raises(ValueError, match="not a plain CDR message"):
        topics.cdr_stamp_ns(b"\x00\x01\x00\x00\x01")


def test_recorded_messages_are_the_bag_bytes_in_stamp_then_contract_order(tmp_path):
    log = synthetic_log(n=50)
    bag = write_bag(log, tmp_path / "bag")
    recorded = read_recorded(bag)
    ns = topics.stamps_ns(log.t)
    assert [m.topic for m in recorded[:5]] == ["motor_input", "mocap/odom", "imu", "battery", "motor_input"]
    assert [m.stamp_ns for m in recorded] == np.repeat(ns, 4).tolist()
    with Reader(bag) as reader:
        in_bag = {(c.topic, raw) for c, _, raw in reader.messages()}
    assert {(topics.topic_name("/quad", m.topic), m.raw) for m in recorded} == in_bag
    odom = TYPESTORE.deserialize_cdr(recorded[1].raw, topics.MEASUREMENT_TOPICS["mocap/odom"])
    assert topics.odometry_fields(odom)[0:3] == pytest.approx(log.pos_n[0, [1, 0, 2]] * [1, 1, -1], abs=0)


def test_bag_metadata_is_read_without_touching_a_message(tmp_path, monkeypatch):
    log = synthetic_log(n=300, vehicle="linkquad")
    bag = write_bag(log, tmp_path / "bag")

    def no_messages(*args, **kwargs):
        raise AssertionError("read_bag_metadata iterated the messages")

    monkeypatch.setattr(bag_io.Reader, "messages", no_messages)
    meta = read_bag_metadata(bag)
    assert (meta.vehicle, meta.message_count) == ("linkquad", 4 * 300)
    assert meta.source == "synthetic"
    assert meta.duration_s == pytest.approx((topics.stamps_ns(log.t)[-1] - topics.stamps_ns(log.t)[0]) / 1e9, abs=1e-9)


def test_motor_efforts_are_read_by_their_names_when_the_four_are_named():
    """A JointState named motor_4..motor_1 was read by position (motor 4's command as motor 1's)."""
    from types import SimpleNamespace

    from quad_modelling.io.topics import motor_fields

    reversed_names = SimpleNamespace(effort=[4.0, 3.0, 2.0, 1.0], velocity=[40.0, 30.0, 20.0, 10.0],
                                     name=["motor_4", "motor_3", "motor_2", "motor_1"])
    u, omega = motor_fields(reversed_names)
    assert u.tolist() == [1.0, 2.0, 3.0, 4.0] and omega.tolist() == [10.0, 20.0, 30.0, 40.0]
    unnamed = SimpleNamespace(effort=[1.0, 2.0, 3.0, 4.0], velocity=[], name=[])  # another stack's: the order sent
    assert motor_fields(unnamed)[0].tolist() == [1.0, 2.0, 3.0, 4.0] and motor_fields(unnamed)[1] is None
    other = SimpleNamespace(effort=[1.0, 2.0, 3.0, 4.0], velocity=[], name=["m4", "m3", "m2", "m1"])
    assert motor_fields(other)[0].tolist() == [1.0, 2.0, 3.0, 4.0]
