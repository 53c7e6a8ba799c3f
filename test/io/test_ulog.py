"""PX4 ULog reader: the two SITL samples (test/data/px4, BSD-3) and the mapping rules on synthetic topics."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from quad_modelling.core import frames
from quad_modelling.errors import DataError
from quad_modelling.io.bag_io import read_bag, summarize_bag, write_bag
from quad_modelling.io.loader import detect_format, load_flight
from quad_modelling.io.ulog import flight_from_topics, topics_of

PX4 = Path(__file__).resolve().parents[1] / "data" / "px4"
EVENTS = PX4 / "sample_px4_events.ulg"
GROUND = PX4 / "sample_logging_tagged_and_default_params.ulg"


@pytest.fixture(scope="module")
def events():
    return load_flight(EVENTS)


def test_samples_are_shipped_with_their_licence():
    assert (PX4 / "LICENSE.md").read_text().startswith("Copyright (c) 2016, PX4 Pro Drone Autopilot")
    assert detect_format(EVENTS) == "px4-ulog"


@pytest.mark.parametrize("path, vehicle, samples", [(EVENTS, "px4_iris", 152), (GROUND, "px4_iris_pwm", 98)])
def test_both_samples_convert_to_bags_with_the_contract_topics(tmp_path, path, vehicle, samples):
    log = load_flight(path)
    assert (log.meta.vehicle, len(log)) == (vehicle, samples)
    write_bag(log, tmp_path / "bag")
    counts = {t.name: t.count for t in summarize_bag(tmp_path / "bag").topics}
    assert {"/quad/motor_input", "/quad/mocap/odom", "/quad/imu"} <= set(counts)
    assert counts["/quad/motor_input"] == counts["/quad/imu"] == counts["/quad/mocap/odom"] == samples
    assert read_bag(tmp_path / "bag").allclose(log, rtol=1e-6, atol=1e-6)


def test_a_log_cut_inside_a_message_converts_what_it_holds_and_says_where_it_ends(tmp_path, events):
    """pyulog stops without a word at a message the file ends inside (a log whose writer lost power): the reader
    says so, naming the byte; cut inside the message's 3-byte header, the same byte; cut exactly between two
    messages the file looks complete (no word: nothing tells it apart)."""
    whole = EVENTS.read_bytes()
    assert not any("ends inside a message" in w for w in events.meta.notes.get("warnings", []))
    half = tmp_path / "half.ulg"
    half.write_bytes(whole[:len(whole) // 2])
    warnings = load_flight(half).meta.notes["warnings"]
    assert len(warnings) == 1 and warnings[0].startswith(f"{half}: the file ends inside a message at byte 781570 of 781573 ")
    assert warnings[0].endswith("read up to there, 14.64 s into the log")
    damaged = bytearray(whole)
    damaged[1553475] = 0  # a whole file with one header byte zeroed: pyulog resyncs in 512-byte chunks, short at the end
    (tmp_path / "damaged.ulg").write_bytes(bytes(damaged))
    assert not any("ends inside a message" in w for w in load_flight(tmp_path / "damaged.ulg").meta.notes.get("warnings", []))
    for cut, said in ((781571, True), (781570, False)):  # one byte of the cut message's header; none of it
        part = tmp_path / f"cut{cut}.ulg"
        part.write_bytes(whole[:cut])
        notes = load_flight(part).meta.notes
        assert any("ends inside a message at byte 781570 of" in w for w in notes.get("warnings", [])) is said, cut


def test_a_message_pyulog_cannot_unpack_is_said_with_the_byte_it_stopped_at(tmp_path):
    """pyulog takes a data message of size 0 (a damaged size field) for the end of the file and returned the first
    6 of 152 samples without a word: the reader says where pyulog stopped."""
    whole = bytearray(EVENTS.read_bytes())
    offset = 16  # the ULog header; then messages of (uint16 size, uint8 type, body)
    while not (offset > len(whole) // 2 and whole[offset + 2] == ord("D")):
        offset += 3 + int.from_bytes(whole[offset:offset + 2], "little")
    whole[offset:offset + 2] = b"\x00\x00"
    (tmp_path / "zero.ulg").write_bytes(bytes(whole))
    log = load_flight(tmp_path / "zero.ulg")
    (warning,) = log.meta.notes["warnings"]
    assert len(log) < 152 and warning.startswith(f"{tmp_path / 'zero.ulg'}: pyulog stopped at a message it could not "
                                                 f"unpack near byte {offset + 3} of {len(whole)}")


def test_time_base_is_the_motor_topic_and_disarmed_time_is_dropped(events):
    notes = events.meta.notes
    assert events.sample_rate == pytest.approx(10.0, rel=1e-3)  # actuator_motors is logged at 10 Hz
    assert events.duration == pytest.approx(15.1, abs=1e-6)
    assert notes["disarmed"] == "dropped 14.90 s before arming and 0.90 s after disarming (vehicle_status)"
    assert notes["interpolated"] == ["battery_status", "sensor_combined", "vehicle_attitude", "vehicle_local_position"]
    assert notes["sources"]["pos_n, vel_n"] == "vehicle_local_position, 10.0 Hz, linear"
    assert notes["sources"]["euler"] == "vehicle_attitude q, 20.0 Hz, slerp"


def test_events_flight_physics(events):
    """Climb to 2.2 m and back: specific force in NED averages -g; commands sit mid-range."""
    acc_n = frames.body_to_nav(events.acc_b, events.euler)
    # Mean vertical specific force = -g + (vz_end - vz_start)/T, and the flight starts and ends at rest.
    assert acc_n[:, 2].mean() == pytest.approx(-frames.STANDARD_GRAVITY, abs=0.06)  # measured -9.760
    assert np.abs(acc_n[:, :2].mean(axis=0)).max() < 0.02  # measured 0.010
    assert np.abs(events.euler[:, :2]).max() < 0.02  # gentle SITL flight, quaternion order (w first) right
    assert events.pos_n[:, 2].min() == pytest.approx(-2.159, abs=1e-3)
    assert np.median(events.u, axis=0) == pytest.approx([0.435, 0.437, 0.435, 0.439], abs=2e-3)
    assert events.u.max() < 0.56 and events.u.min() >= 0.0


def test_events_position_matches_integrated_velocity_until_touchdown(events):
    """NED position = ∫ vel_n dt within 0.1 m over the first 8 s (take-off, climb, hover).

    After touchdown (about 11 s in) PX4's estimate itself disagrees: z stops at +0.4 m while vz
    stays near 0.6 m/s, 1.35 m apart at the end; that is in the log, not in the reader.
    """
    early = events.t - events.t[0] < 8.0
    integrated = cumulative_trapezoid(events.vel_n[early], events.t[early], initial=0, axis=0)
    error = np.abs(events.pos_n[early] - events.pos_n[0] - integrated).max(axis=0)
    assert error.max() < 0.1  # measured 0.08 m (z)


def test_never_armed_log_is_kept_whole_and_marked():
    log = load_flight(GROUND)
    assert np.all(log.u == 900.0)  # PWM disarmed value
    assert log.meta.notes["disarmed"].startswith("never armed (vehicle_status)")
    assert log.meta.notes["pwm_range"] == "1075..1950 us (PWM_MAIN_MIN/MAX)"
    assert log.acc_b[:, 2].mean() == pytest.approx(-9.87, abs=0.03)  # at rest on the ground, FRD z down


def synthetic_topics(n: int = 200, rate: float = 100.0) -> dict:
    """Hovering vehicle, every topic at the same rate: 0.5 commands, level attitude, 1 m up."""
    stamp = (10.0 + np.arange(n) / rate) * 1e6
    ones = np.ones(n)
    return {
        "actuator_motors": {"timestamp": stamp, **{f"control[{i}]": 0.5 * ones for i in range(4)},
                            **{f"control[{i}]": np.full(n, np.nan) for i in range(4, 12)}},
        "vehicle_local_position": {"timestamp": stamp, "x": 0 * ones, "y": 0 * ones, "z": -ones, "vx": 0 * ones, "vy": 0 * ones, "vz": 0 * ones},
        "vehicle_attitude": {"timestamp": stamp, "q[0]": ones, "q[1]": 0 * ones, "q[2]": 0 * ones, "q[3]": 0 * ones},
        "sensor_combined": {"timestamp": stamp, **{f"gyro_rad[{i}]": 0 * ones for i in range(3)},
                            "accelerometer_m_s2[0]": 0 * ones, "accelerometer_m_s2[1]": 0 * ones, "accelerometer_m_s2[2]": -9.81 * ones},
        "vehicle_status": {"timestamp": stamp[:1], "arming_state": np.array([2])},
    }


def test_mapping_on_synthetic_topics_gives_the_hover():
    log = flight_from_topics(synthetic_topics(), {"CA_ROTOR_COUNT": 4}, "synthetic.ulg")
    assert len(log) == 200 and log.sample_rate == pytest.approx(100.0)
    assert np.all(log.u == 0.5) and np.allclose(log.pos_n, [0, 0, -1]) and np.allclose(log.acc_b, [0, 0, -9.81])
    assert log.vbat is None and log.meta.notes["disarmed"] == "dropped 0.00 s before arming and 0.00 s after disarming (vehicle_status)"


def test_a_missing_required_topic_is_one_line_naming_it():
    topics = synthetic_topics()
    del topics["vehicle_attitude"]
    with pytest.raises(DataError) as err:
        flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "flight.ulg")
    assert str(err.value) == (
        "flight.ulg: missing PX4 topic(s) vehicle_attitude (found: actuator_motors, sensor_combined, "
        "vehicle_local_position, vehicle_status)"
    )


@pytest.mark.parametrize("params, message", [
    ({"CA_ROTOR_COUNT": 6}, "flight.ulg: 6 rotors (CA_ROTOR_COUNT); only 4-rotor vehicles are read"),
    ({"MAV_TYPE": 22}, "flight.ulg: MAV_TYPE 22 is a VTOL airframe; only plain quadrotors are read"),
])
def test_other_airframes_are_refused_naming_the_rotor_count(params, message):
    with pytest.raises(DataError) as err:
        flight_from_topics(synthetic_topics(), params, "flight.ulg")
    assert str(err.value) == message


def test_multi_instance_topics_use_instance_0_and_say_so():
    topics = synthetic_topics()
    second = {**topics["sensor_combined"], "accelerometer_m_s2[2]": np.full(200, -5.0)}
    data_list = [SimpleNamespace(name=name, multi_id=0, data=data) for name, data in topics.items()]
    data_list.append(SimpleNamespace(name="sensor_combined", multi_id=1, data=second))
    chosen, notes = topics_of(data_list)
    assert notes == {"instances": {"sensor_combined": "2 instances logged, instance 0 used"}}
    log = flight_from_topics(chosen, {"CA_ROTOR_COUNT": 4}, "flight.ulg", notes=notes)
    assert np.allclose(log.acc_b[:, 2], -9.81)


def _battery(rate_hz: float, start_s: float, end_s: float, volts: float, connected: bool = True) -> dict:
    stamp = (10.0 + np.arange(start_s, end_s, 1 / rate_hz)) * 1e6
    return {"timestamp": stamp, "voltage_v": np.full(len(stamp), volts), "connected": np.full(len(stamp), connected)}


def test_the_battery_is_the_lowest_connected_instance_and_bounds_nothing():
    """PX4 logs every battery slot: instance 0 unused (0 V, not connected), instance 1 the pack, starting 0.5 s late."""
    topics = synthetic_topics()  # 2 s at 100 Hz from 10 s
    data_list = [SimpleNamespace(name=name, multi_id=0, data=data) for name, data in topics.items()]
    data_list += [SimpleNamespace(name="battery_status", multi_id=0, data=_battery(10, 0.0, 2.0, 0.0, connected=False)),
                  SimpleNamespace(name="battery_status", multi_id=1, data=_battery(10, 0.5, 2.0, 15.2))]
    chosen, notes = topics_of(data_list)
    assert notes == {"instances": {"battery_status": "2 instances logged, instance 1 used (the lowest connected)"}}
    log = flight_from_topics(chosen, {"CA_ROTOR_COUNT": 4}, "flight.ulg", notes=notes)
    assert len(log) == 200 and np.all(log.vbat == pytest.approx(15.2))  # the 0.5 s before its first reading kept, held
    assert "battery" not in log.meta.notes  # 0.5 s late: within BATTERY_PAUSE_S


def test_battery_readings_not_connected_are_skipped_and_a_pause_is_noted():
    topics = synthetic_topics(n=1000)  # 10 s
    battery = _battery(10, 0.0, 10.0, 16.0)
    battery["voltage_v"] = 16.0 - 0.1 * np.arange(100) / 10  # 16 V falling 0.1 V/s
    battery["connected"][20:25] = False  # 2.0-2.4 s: disconnected, reported at whatever voltage
    keep = (battery["timestamp"] < 15e6) | (battery["timestamp"] >= 18e6)  # silent from 5.0 s to 8.0 s
    topics["battery_status"] = {key: value[keep] for key, value in battery.items()}
    log = flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "flight.ulg")
    inside = log.t <= 19.9  # the last reading; held after it
    np.testing.assert_allclose(log.vbat[inside], 16.0 - 0.1 * (log.t[inside] - 10.0), atol=1e-9)  # across the skip and pause
    assert np.all(log.vbat[~inside] == pytest.approx(16.0 - 0.99))
    note = log.meta.notes["battery"]
    assert note.startswith("5 of 70 readings at or below 0 V or not finite skipped (a battery not connected)")
    assert "1 pause(s) longer than 2 s interpolated (longest 3.1 s from 4.9 s into the flight)" in note


def test_a_battery_without_a_connected_reading_is_left_out_and_said():
    topics = {**synthetic_topics(), "battery_status": _battery(10, 0.0, 2.0, 0.0, connected=False)}
    log = flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "flight.ulg")
    assert log.vbat is None and "vbat" not in log.meta.notes["sources"]
    assert log.meta.notes["battery"] == ("20 of 20 readings at or below 0 V or not finite skipped (a battery not connected): no usable "
                                         "reading, the flight is read without a voltage")


def test_a_position_gap_is_marked_not_interpolated_through(tmp_path):
    from rosbags.rosbag2 import Reader

    topics = synthetic_topics()
    keep = np.r_[0:50, 150:200]  # 1 s without position
    topics["vehicle_local_position"] = {k: v[keep] for k, v in topics["vehicle_local_position"].items()}
    log = flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "flight.ulg")
    assert len(log) == 200
    [gap] = log.meta.notes["measurement_gaps"]
    assert gap["topic"] == "vehicle_local_position" and gap["fields"] == ["pos_n", "vel_n"]
    assert (gap["start_s"], gap["end_s"]) == (pytest.approx(10.49), pytest.approx(11.5))
    assert log.meta.notes["warnings"] == [
        "flight.ulg: topic vehicle_local_position has no message for 1.01 s (t=0.490..1.500 s into the flight), longer than "
        "0.5 s: marked as a measurement gap, not interpolated through; windows and training segments overlapping it are left out"]
    write_bag(log, tmp_path / "bag")  # the bag keeps it as a gap of the odometry
    with Reader(tmp_path / "bag") as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {"/quad/motor_input": 200, "/quad/mocap/odom": 100, "/quad/imu": 200}
    assert read_bag(tmp_path / "bag").meta.notes["measurement_gaps"] == [
        {"topic": "/quad/mocap/odom", "start_s": pytest.approx(10.49), "end_s": pytest.approx(11.5), "fields": ["pos_n", "vel_n", "euler"]}]


def test_pwm_log_with_a_normalised_vehicle_is_refused():
    with pytest.raises(DataError, match="motor commands come from actuator_outputs .us. but vehicle px4_iris takes normalised"):
        load_flight(GROUND, vehicle="px4_iris")


def test_cli_convert_then_info_on_the_ulog_and_the_bag(tmp_path, capsys):
    from quad_modelling.cli import main

    assert main(["convert", str(EVENTS), "-o", str(tmp_path / "events")]) == 0
    assert main(["info", str(tmp_path / "events"), "--json"]) == 0
    capsys.readouterr()
    assert main(["info", str(EVENTS)]) == 0
    out = capsys.readouterr().out
    assert "samples:   152 at 10.00 Hz, duration 15.100 s" in out
    assert "  euler:          vehicle_attitude q, 20.0 Hz, slerp" in out
    assert "disarmed:  dropped 14.90 s before arming and 0.90 s after disarming (vehicle_status)" in out


def test_a_pwm_vehicle_reads_actuator_outputs_of_a_log_that_holds_both():
    """The events sample logs actuator_motors (0..1) and actuator_outputs (PWM): with the PWM vehicle it was refused
    ("motor commands come from actuator_motors ... but vehicle px4_iris_pwm takes us"); the outputs are read."""
    log = load_flight(EVENTS, vehicle="px4_iris_pwm")
    assert log.meta.vehicle == "px4_iris_pwm" and log.meta.notes["sources"]["u"].startswith("actuator_outputs")
    assert 900.0 <= float(log.u.min()) and float(log.u.max()) <= 2000.0 and float(log.u.max()) > 1000.0
    assert load_flight(EVENTS).meta.notes["sources"]["u"].startswith("actuator_motors")  # the default: unchanged


def _odometry_topics(velocity_frame: np.ndarray, yaw: float, vel_n: np.ndarray) -> dict:
    """synthetic_topics with vehicle_odometry instead of vehicle_local_position: attitude yawed by ``yaw`` [rad] and
    tilted, the velocity ``vel_n`` (NED) given in NED or the body frame as ``velocity_frame`` says per message."""
    topics = synthetic_topics()
    n = len(topics["actuator_motors"]["timestamp"])
    euler = np.tile([0.1, -0.2, yaw], (n, 1))
    quat = frames.euler_ned_to_rotation(euler).as_quat()  # x, y, z, w of R_NED<-FRD
    vel = np.tile(vel_n, (n, 1))
    body = velocity_frame == 3
    vel[body] = frames.nav_to_body(vel[body], euler[body])
    del topics["vehicle_local_position"]
    topics["vehicle_odometry"] = {"timestamp": topics["actuator_motors"]["timestamp"], "pose_frame": np.ones(n, int),
                                  "velocity_frame": velocity_frame, **{f"position[{i}]": np.zeros(n) for i in range(3)},
                                  **{f"velocity[{i}]": vel[:, i] for i in range(3)},
                                  **{f"q[{i}]": quat[:, [3, 0, 1, 2][i]] for i in range(4)}}
    return topics


@pytest.mark.parametrize("frames_of", ["body", "switching"])
def test_body_frame_odometry_velocity_is_rotated_into_ned_by_its_own_attitude(frames_of):
    vel_n = np.array([1.5, -0.7, 0.3])
    frame = np.full(200, 3) if frames_of == "body" else np.where(np.arange(200) < 100, 1, 3)
    log = flight_from_topics(_odometry_topics(frame, 2.0, vel_n), {"CA_ROTOR_COUNT": 4}, "odometry.ulg")
    assert np.abs(log.vel_n - vel_n).max() < 1e-9
    switch = [w for w in log.meta.notes.get("warnings", []) if "the frame changes within the recording" in w]
    if frames_of == "switching":  # said, as the bag reader says it
        assert switch == ["odometry.ulg: velocity from vehicle_odometry velocity_frame 1 = NED in 100 messages; "
                          "3 = FRD (body, rotated into NED) in 100 messages: the frame changes within the recording, "
                          "each message read in its own frame"]
    else:
        assert switch == []


def test_an_odometry_frame_is_read_only_where_its_numbers_are_finite():
    """PX4 marks invalid numbers NaN; the frame such a message names means nothing (the bag reader skips it too):
    the velocity_frame 0 of 20 messages with NaN velocity was the error, not the NaN numbers themselves."""
    topics = _odometry_topics(np.full(200, 1), 0.0, np.array([0.4, 0.1, 0.0]))
    topics["vehicle_odometry"]["velocity_frame"][:20] = 0
    for i in range(3):
        topics["vehicle_odometry"][f"velocity[{i}]"][:20] = np.nan
    with pytest.raises(DataError, match=r"odometry.ulg: field vel_n column 0 \(north\) is not finite at sample 1 of 200 \(t=0.000 s into the flight\)$"):
        flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "odometry.ulg")  # the not-finite rule, as any NaN row
    topics["vehicle_odometry"]["velocity_frame"][:20] = 1  # the same rows in a frame that is read: the same error
    with pytest.raises(DataError, match="is not finite at sample 1 of 200"):
        flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "odometry.ulg")


@pytest.mark.parametrize("field, value", [("velocity_frame", 2), ("velocity_frame", 0), ("pose_frame", 2)])
def test_odometry_in_an_unknown_or_earth_frd_frame_is_refused_in_one_line(field, value):
    topics = _odometry_topics(np.full(200, 1), 0.0, np.zeros(3))
    topics["vehicle_odometry"][field] = np.where(np.arange(200) < 150, 1, value)
    with pytest.raises(DataError) as err:
        flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "odometry.ulg")
    message = str(err.value)
    assert "\n" not in message and "odometry.ulg" in message and f"{field} {sorted([1, value])}" in message


def test_body_frame_odometry_without_a_valid_attitude_is_no_traceback():
    """PX4 writes NaN for an attitude not (yet) valid: the body-frame velocity of such a message has no frame to be
    read in; the flight reads (or is refused in one line), never a traceback (the rotation raised ValueError)."""
    vel_n = np.array([0.5, 0.2, 0.0])
    topics = _odometry_topics(np.full(200, 3), 1.0, vel_n)
    for i in range(4):
        topics["vehicle_odometry"][f"q[{i}]"][:3] = np.nan
    topics["vehicle_odometry"]["q[0]"][3] = 0.0
    for i in range(1, 4):
        topics["vehicle_odometry"][f"q[{i}]"][3] = 0.0
    try:
        log = flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "odometry.ulg")
    except DataError as err:
        assert "\n" not in str(err) and "odometry.ulg" in str(err)
    else:
        finite = np.all(np.isfinite(log.vel_n), axis=1)
        assert np.abs(log.vel_n[finite] - vel_n).max() < 1e-9 and finite.sum() >= 190


def test_a_nan_attitude_before_arming_is_dropped_with_it_and_one_in_flight_is_one_line():
    """PX4 logs a NaN quaternion while its estimator is not aligned (before arming): the samples the kept span's slerp
    does not read are not checked; a NaN one inside the flight is refused naming the topic and sample (it was scipy's
    "zero norm quaternions" traceback: a NaN norm passed the unit check)."""
    topics = synthetic_topics()
    topics["vehicle_status"] = {"timestamp": topics["vehicle_attitude"]["timestamp"][[0, 20]], "arming_state": np.array([1, 2])}
    for i in range(4):
        topics["vehicle_attitude"][f"q[{i}]"][:10] = np.nan
    log = flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "prearm.ulg")
    assert len(log) == 180 and np.allclose(log.euler, 0.0)
    for i in range(4):
        topics["vehicle_attitude"][f"q[{i}]"][100] = np.nan
    with pytest.raises(DataError) as err:
        flight_from_topics(topics, {"CA_ROTOR_COUNT": 4}, "midflight.ulg")
    assert str(err.value) == "midflight.ulg: topic vehicle_attitude q at sample 100 has norm nan, not 1"


def test_repeated_attitude_stamps_keep_the_last_sample_at_the_span_end_too():
    """Of two samples with one stamp the slerp reads the later (as the reader always has), also where the kept span
    ends on them (slicing the samples the span reads first took the earlier: yaw 15 deg for 25)."""
    from scipy.spatial.transform import Rotation

    from quad_modelling.io.ulog import attitude

    stamps = np.array([0.0, 1.0, 2.0, 2.0, 3.0])
    quat = Rotation.from_euler("z", [[0], [10], [20], [40], [50]], degrees=True).as_quat(scalar_first=True)
    yaw = np.degrees(attitude(stamps, quat, np.array([0.5, 1.5, 1.9, 2.0]), "x.ulg"))[:, 2]
    np.testing.assert_allclose(yaw, [5.0, 25.0, 37.0, 40.0], atol=1e-9)
