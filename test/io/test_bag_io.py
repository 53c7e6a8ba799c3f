from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import StoragePlugin

from quad_modelling.cli import main
from quad_modelling.errors import BagError, DataError, OutputExistsError
from quad_modelling.io import bag_io, topics
from quad_modelling.io.bag_io import read_bag, summarize_bag, write_bag
from quad_modelling.io.matlog import read_matlog, write_matlog
from quad_modelling.io.nanobench import read_nanobench
from test.conftest import FIXTURES, REPO, synthetic_log

CONTRACT = {
    "/quad/motor_input": "sensor_msgs/msg/JointState",
    "/quad/mocap/odom": "nav_msgs/msg/Odometry",
    "/quad/imu": "sensor_msgs/msg/Imu",
    "/quad/battery": "sensor_msgs/msg/BatteryState",
}


def test_nanobench_csv_to_bag_to_flight_log_is_lossless(tmp_path):
    log = read_nanobench(FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz")
    back = read_bag(write_bag(log, tmp_path / "bag"))
    # t is Unix time: nanosecond stamps hold it to the float64 resolution (2.4e-7 s at 1.7e9 s).
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=5e-7)
    for name in ("u", "acc_b", "gyro_b", "pos_n", "vel_n", "euler"):
        np.testing.assert_allclose(getattr(back, name), getattr(log, name), rtol=1e-12, atol=1e-12, err_msg=name)
    # sensor_msgs/BatteryState.voltage is a float32: the voltage keeps 7 significant digits.
    np.testing.assert_allclose(back.vbat, log.vbat, rtol=1e-7)
    assert back.omega is None
    assert back.meta.vehicle == "crazyflie21" and back.meta.notes["format"] == "nanobench"


def test_mat_to_bag_to_mat_is_equal(tmp_path):
    log = synthetic_log(vehicle="linkquad")  # yaw runs from -3 to 4 rad: crosses ±pi, unwrapped on read
    write_matlog(log, tmp_path / "a.mat")
    write_bag(read_matlog(tmp_path / "a.mat"), tmp_path / "bag")
    write_matlog(read_bag(tmp_path / "bag"), tmp_path / "b.mat")
    again = read_matlog(tmp_path / "b.mat")
    np.testing.assert_allclose(again.vbat, log.vbat, rtol=1e-7)  # float32 in BatteryState
    again.vbat = log.vbat
    assert again.allclose(log, rtol=1e-12, atol=1e-12)
    assert again.meta.notes == log.meta.notes


def test_plain_rosbags_and_mcap_read_the_contract_topics(tmp_path):
    write_bag(synthetic_log(), tmp_path / "bag")
    with Reader(tmp_path / "bag") as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == CONTRACT
        assert reader.message_count == 4 * 400
        odom_conn = next(c for c in reader.connections if c.topic == "/quad/mocap/odom")
        _, _, raw = next(iter(reader.messages(connections=[odom_conn])))
        odom = bag_io.TYPESTORE.deserialize_cdr(raw, odom_conn.msgtype)
        assert (odom.header.frame_id, odom.child_frame_id) == ("world", "base_link")
    mcap_file = next((tmp_path / "bag").glob("*.mcap"))
    assert mcap_file.name == "bag.mcap"
    with open(mcap_file, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert {ch.topic for ch in summary.channels.values()} == set(CONTRACT)
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}


def test_summary_counts_rates_and_vehicle(tmp_path):
    write_bag(synthetic_log(n=250, rate=250.0), tmp_path / "bag")
    summary = summarize_bag(tmp_path / "bag")
    assert summary.message_count == 1000 and summary.storage == "mcap"
    assert summary.duration_s == pytest.approx(249 / 250)
    assert all(t.count == 250 and t.rate_hz == pytest.approx(250.0) for t in summary.topics)
    assert summary.custom_data["quad_modelling.vehicle"] == "crazyflie21"


def test_existing_bag_needs_force_and_nothing_is_left_on_failure(tmp_path):
    write_bag(synthetic_log(), tmp_path / "bag")
    with pytest.raises(OutputExistsError):
        write_bag(synthetic_log(seed=1), tmp_path / "bag")
    write_bag(synthetic_log(seed=1), tmp_path / "bag", force=True)
    assert read_bag(tmp_path / "bag").meta.notes == {"seed": 1}

    def explode(_):
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_bag(synthetic_log(n=2000), tmp_path / "other", progress=explode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


@pytest.mark.parametrize("offset, advice", [(-5.0, "shift the time column to start at or after 0"),
                                             (3e9, "check the time column's unit")])
def test_times_a_bag_cannot_stamp_are_one_line_and_nothing_is_written(tmp_path, capsys, offset, advice):
    """A flight from t = -5 s, or at 3e9 s (microseconds since boot read as seconds), ended in an OverflowError or a
    struct.error traceback from the writer: refused in one line naming the times, the .mat output still works."""
    log = synthetic_log(n=300)
    log.t = log.t - log.t[0] + offset
    flight = write_matlog(log, tmp_path / "shifted.mat")
    assert main(["convert", str(flight), "-o", str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{flight}: sample times {offset:.6g}.." in err[0] and advice in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shifted.mat"]
    assert main(["convert", str(flight), "-o", str(tmp_path / "copy.mat")]) == 0


def test_truncated_mcap_is_a_bag_error(tmp_path):
    write_bag(synthetic_log(), tmp_path / "bag")
    mcap_file = tmp_path / "bag" / "bag.mcap"
    data = mcap_file.read_bytes()
    mcap_file.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match="bag"):
        read_bag(tmp_path / "bag")


def test_garbage_mcap_is_a_bag_error(tmp_path):
    write_bag(synthetic_log(), tmp_path / "bag")
    (tmp_path / "bag" / "bag.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    with pytest.raises(BagError, match="bag"):
        read_bag(tmp_path / "bag")


def test_not_a_bag(tmp_path):
    with pytest.raises(BagError, match="no such bag"):
        read_bag(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="empty: not a bag: the directory holds no metadata.yaml and no .mcap or .db3 file"):
        read_bag(tmp_path / "empty")


def _write_raw_bag(path, messages_by_topic):
    """A bag with hand-made messages: {topic_key: [(stamp_ns, msg), ...]}."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.set_custom_data("quad_modelling.vehicle", "crazyflie21")
        for key, messages in messages_by_topic.items():
            msgtype = topics.MEASUREMENT_TOPICS[key]
            conn = writer.add_connection(topics.topic_name("/quad", key), msgtype, typestore=bag_io.TYPESTORE)
            for ns, msg in messages:
                writer.write(conn, ns, bag_io.TYPESTORE.serialize_cdr(msg, msgtype))


def _motor(ns, effort=(1.0, 2.0, 3.0, 4.0)):
    return bag_io.BAG_TYPES.JointState(header=bag_io.BAG_TYPES.header("base_link", ns), name=list(topics.MOTOR_NAMES),
                             position=np.zeros(0), velocity=np.zeros(0), effort=np.array(effort, dtype=float))


def _imu(ns, gyro=(0.0, 0.0, 0.0)):
    return bag_io.BAG_TYPES.Imu(header=bag_io.BAG_TYPES.header("base_link", ns), orientation=bag_io.BAG_TYPES.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                      orientation_covariance=topics.NO_ORIENTATION, angular_velocity=bag_io.BAG_TYPES.vector3(gyro),
                      angular_velocity_covariance=np.zeros(9), linear_acceleration=bag_io.BAG_TYPES.vector3((0.0, 0.0, 9.81)),
                      linear_acceleration_covariance=np.zeros(9))


def _odom(ns):
    return bag_io.BAG_TYPES.Odometry(
        header=bag_io.BAG_TYPES.header("world", ns), child_frame_id="base_link",
        pose=bag_io.BAG_TYPES.PoseWithCovariance(pose=bag_io.BAG_TYPES.Pose(position=bag_io.BAG_TYPES.Point(x=0.0, y=0.0, z=1.0),
                                                        orientation=bag_io.BAG_TYPES.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)), covariance=np.zeros(36)),
        twist=bag_io.BAG_TYPES.TwistWithCovariance(twist=bag_io.BAG_TYPES.Twist(linear=bag_io.BAG_TYPES.vector3((0, 0, 0)), angular=bag_io.BAG_TYPES.vector3((0, 0, 0))), covariance=np.zeros(36)))


STAMPS = [1_000_000_000 + 10_000_000 * k for k in range(10)]


def test_missing_required_topic_is_named(tmp_path):
    _write_raw_bag(tmp_path / "bag", {"motor_input": [(s, _motor(s)) for s in STAMPS], "imu": [(s, _imu(s)) for s in STAMPS]})
    with pytest.raises(BagError, match=r"missing required topic\(s\) \['/quad/mocap/odom'\]"):
        read_bag(tmp_path / "bag")


def test_nan_in_a_message_names_topic_and_index(tmp_path):
    imu = [(s, _imu(s, gyro=(np.nan, 0.0, 0.0) if k == 4 else (0.0, 0.0, 0.0))) for k, s in enumerate(STAMPS)]
    _write_raw_bag(tmp_path / "bag", {"motor_input": [(s, _motor(s)) for s in STAMPS], "mocap/odom": [(s, _odom(s)) for s in STAMPS], "imu": imu})
    with pytest.raises(DataError, match="topic /quad/imu message 4 holds a non-finite value"):
        read_bag(tmp_path / "bag")


def test_a_motor_message_short_of_an_effort_is_named_not_corrupt(tmp_path):
    """A JointState with 3 efforts was "corrupt or truncated bag (DataError: ...)": the message is named as it is."""
    motors = [(s, _motor(s, effort=(1.0, 2.0, 3.0) if k == 6 else (1.0, 2.0, 3.0, 4.0))) for k, s in enumerate(STAMPS)]
    _write_raw_bag(tmp_path / "bag", {"motor_input": motors, "mocap/odom": [(s, _odom(s)) for s in STAMPS], "imu": [(s, _imu(s)) for s in STAMPS]})
    with pytest.raises(DataError) as err:
        read_bag(tmp_path / "bag")
    assert str(err.value) == f"{tmp_path / 'bag'}: topic /quad/motor_input message 6 has 3 efforts, expected 4"


def test_stamps_going_backwards_are_named(tmp_path):
    bad = STAMPS[:5] + [STAMPS[3]] + STAMPS[6:]
    _write_raw_bag(tmp_path / "bag", {"motor_input": [(s, _motor(s)) for s in bad], "mocap/odom": [(s, _odom(s)) for s in STAMPS], "imu": [(s, _imu(s)) for s in STAMPS]})
    with pytest.raises(DataError, match="topic /quad/motor_input header stamps do not increase at message 4"):
        read_bag(tmp_path / "bag")


def test_topics_at_other_stamps_are_interpolated_onto_motor_time(tmp_path):
    odom_stamps = [s - 5_000_000 for s in STAMPS] + [STAMPS[-1] + 5_000_000]
    _write_raw_bag(tmp_path / "bag", {"motor_input": [(s, _motor(s)) for s in STAMPS], "mocap/odom": [(s, _odom(s)) for s in odom_stamps],
                                      "imu": [(s, _imu(s, gyro=(0.001 * k, 0, 0))) for k, s in enumerate(STAMPS)]})
    log = read_bag(tmp_path / "bag")
    assert len(log) == 10 and log.pos_n[0, 2] == pytest.approx(-1.0)
    np.testing.assert_allclose(log.gyro_b[:, 0], 0.001 * np.arange(10))


def test_a_flight_without_imu_writes_and_reads_a_bag_without_the_imu_topic(tmp_path):
    log = synthetic_log()
    pose = type(log)(**{**{f: getattr(log, f) for f in ("t", "u", "pos_n", "vel_n", "euler", "vbat", "omega", "meta")},
                        "acc_b": None, "gyro_b": None})
    write_bag(pose, tmp_path / "bag")
    assert [t.name for t in summarize_bag(tmp_path / "bag").topics] == ["/quad/battery", "/quad/mocap/odom", "/quad/motor_input"]
    back = read_bag(tmp_path / "bag")
    np.testing.assert_allclose(back.vbat, pose.vbat, rtol=1e-7)  # float32 in BatteryState
    back.vbat = pose.vbat
    assert back.acc_b is None and back.gyro_b is None and back.allclose(pose, rtol=1e-12, atol=1e-12)
    with pytest.raises(BagError, match=r"run-bag needs topic\(s\) \['/quad/imu'\], which the bag does not have"):
        bag_io.read_bag_metadata(tmp_path / "bag").require_live_topics()


def test_an_imu_without_accelerometer_marks_it_unmeasured_by_covariance(tmp_path):
    log = synthetic_log()
    gyro_only = type(log)(**{**{f: getattr(log, f) for f in ("t", "u", "gyro_b", "pos_n", "vel_n", "euler", "vbat", "omega", "meta")},
                             "acc_b": None})
    write_bag(gyro_only, tmp_path / "bag")
    with Reader(tmp_path / "bag") as reader:
        connection = next(c for c in reader.connections if c.topic == "/quad/imu")
        _, _, raw = next(reader.messages(connections=[connection]))
        msg = bag_io.TYPESTORE.deserialize_cdr(raw, connection.msgtype)
    assert msg.linear_acceleration_covariance[0] == -1 and msg.angular_velocity_covariance[0] == 0
    back = read_bag(tmp_path / "bag")
    assert back.acc_b is None and np.allclose(back.gyro_b, log.gyro_b, atol=1e-12)


GAP_STAMPS = [1_000_000_000 + 10_000_000 * k for k in range(3000)]  # 30 s at 100 Hz from t = 1 s
"""A 30 s flight whose motion capture drops out for 6.68 s: no odometry strictly between t = 5 s and 11.68 s."""


def _write_gap_bag(path):
    odom = [s for s in GAP_STAMPS if not 5_000_000_000 < s < 11_680_000_000]
    _write_raw_bag(path, {"motor_input": [(s, _motor(s)) for s in GAP_STAMPS], "mocap/odom": [(s, _odom(s)) for s in odom],
                          "imu": [(s, _imu(s)) for s in GAP_STAMPS]})
    return path


GAP_WARNING = ("topic /quad/mocap/odom has no message for 6.68 s (t=4.000..10.680 s into the flight), longer than 0.5 s: "
               "marked as a measurement gap, not interpolated through; windows and training segments overlapping it are left out")


def test_a_motion_capture_gap_is_marked_in_the_notes_not_refused(tmp_path):
    log = read_bag(_write_gap_bag(tmp_path / "bag"))
    assert len(log) == 3000
    assert log.meta.notes["measurement_gaps"] == [
        {"topic": "/quad/mocap/odom", "start_s": 5.0, "end_s": 11.68, "fields": ["pos_n", "vel_n", "euler"]}]
    assert log.meta.notes["warnings"] == [f"{tmp_path / 'bag'}: {GAP_WARNING}"]
    assert np.isfinite(log.pos_n).all()  # the rows inside are interpolated to keep the log finite, and never used


def test_a_bag_round_trip_keeps_the_gap_as_a_gap(tmp_path):
    log = read_bag(_write_gap_bag(tmp_path / "bag"))
    write_bag(log, tmp_path / "copy")
    with Reader(tmp_path / "copy") as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        odom = next(c for c in reader.connections if c.topic == "/quad/mocap/odom")
        odom_stamps = [ns for _, ns, _ in reader.messages(connections=[odom])]
    assert counts == {"/quad/motor_input": 3000, "/quad/mocap/odom": 3000 - 667, "/quad/imu": 3000}
    assert not [ns for ns in odom_stamps if 5_000_000_000 < ns < 11_680_000_000]  # no fabricated sample inside
    assert 5_000_000_000 in odom_stamps and 11_680_000_000 in odom_stamps
    back = read_bag(tmp_path / "copy")
    assert back.meta.notes["measurement_gaps"] == log.meta.notes["measurement_gaps"]
    assert back.meta.notes["warnings"] == [f"{tmp_path / 'copy'}: {GAP_WARNING}"]  # found again, not repeated
    assert back.allclose(log, rtol=0, atol=1e-12)


def test_a_flight_with_a_gap_is_not_written_as_a_mat_log(tmp_path):
    log = read_bag(_write_gap_bag(tmp_path / "bag"))
    with pytest.raises(DataError, match=r"bag has measurement gaps \(/quad/mocap/odom 4\.00\.\.10\.68 s\): a \.mat log has one "
                                        r"time base; convert to a bag"):
        write_matlog(log, tmp_path / "flight.mat")
    assert not (tmp_path / "flight.mat").exists()


def test_an_imu_gap_is_marked_and_left_out_of_the_imu_topic_only(tmp_path):
    long_imu = [s for s in GAP_STAMPS if not 2_000_000_000 < s < 3_000_000_000]
    _write_raw_bag(tmp_path / "bag", {"motor_input": [(s, _motor(s)) for s in GAP_STAMPS], "mocap/odom": [(s, _odom(s)) for s in GAP_STAMPS],
                                      "imu": [(s, _imu(s)) for s in long_imu]})
    log = read_bag(tmp_path / "bag")
    assert log.meta.notes["measurement_gaps"] == [{"topic": "/quad/imu", "start_s": 2.0, "end_s": 3.0, "fields": ["acc_b", "gyro_b"]}]
    write_bag(log, tmp_path / "copy")
    with Reader(tmp_path / "copy") as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {
            "/quad/motor_input": 3000, "/quad/mocap/odom": 3000, "/quad/imu": 3000 - 99}
    short_imu = STAMPS[:2] + STAMPS[8:]  # a 70 ms hole, shorter than 0.5 s: interpolated, not marked
    _write_raw_bag(tmp_path / "short", {"motor_input": [(s, _motor(s)) for s in STAMPS], "mocap/odom": [(s, _odom(s)) for s in STAMPS],
                                        "imu": [(s, _imu(s)) for s in short_imu]})
    assert "measurement_gaps" not in read_bag(tmp_path / "short").meta.notes


def test_imu_on_another_clock_is_refused_with_its_offset(tmp_path):
    _write_raw_bag(tmp_path / "bag", {"motor_input": [(s, _motor(s)) for s in STAMPS], "mocap/odom": [(s, _odom(s)) for s in STAMPS],
                                      "imu": [(s + 100_000_000_000, _imu(s + 100_000_000_000)) for s in STAMPS]})
    with pytest.raises(DataError, match=r"topic /quad/imu stamps are offset by \+100\.000 s from /quad/motor_input "
                                        r"\(spans 100\.000\.\.100\.090 s of a 0\.090 s flight\): another clock\?"):
        read_bag(tmp_path / "bag")


def _recorded_with_crcs(source: Path, target: Path) -> Path:
    """``source`` (a bag of this project: rosbags stores no CRCs) rewritten by the mcap library as rosbag2 records
    it: uncompressed chunks with their CRCs and the data section's."""
    import shutil

    from mcap.writer import CompressionType, Writer

    target.mkdir()
    shutil.copy(source / "metadata.yaml", target / "metadata.yaml")
    (mcap_file,) = source.glob("*.mcap")
    with open(mcap_file, "rb") as stream, open(target / mcap_file.name, "wb") as out:
        reader = make_reader(stream)
        writer = Writer(out, compression=CompressionType.NONE, enable_crcs=True, enable_data_crcs=True)
        writer.start(reader.get_header().profile, "test")
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages():
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas.get(channel.schema_id, 0), channel.metadata)
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time, message.sequence)
        writer.finish()
    return target


def test_a_damaged_byte_in_a_recorded_bag_fails_its_crc_in_one_line(tmp_path):
    """rosbag2 stores CRCs; rosbags reads without checking them, so one flipped byte in an uncompressed chunk's message
    read as another number. The CRCs are checked: one line naming the file; the intact copy reads as the original."""
    from quad_modelling.io.loader import load_flight

    source = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
    recorded = _recorded_with_crcs(source, tmp_path / "recorded")
    assert load_flight(recorded).allclose(load_flight(source), rtol=0, atol=0)
    (mcap_file,) = recorded.glob("*.mcap")
    data = bytearray(mcap_file.read_bytes())
    data[len(data) // 3] ^= 0x10  # inside a chunk, among the messages
    mcap_file.write_bytes(bytes(data))
    with pytest.raises(BagError, match=rf"{recorded}: {mcap_file.name} is damaged: crc validation failed in Chunk"):
        load_flight(recorded)
    assert main(["info", str(recorded)]) == 2
