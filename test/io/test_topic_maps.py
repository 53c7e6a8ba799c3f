"""Topic maps: PX4 and crazyswarm2 recordings read with the definitions stored in the bag (DESIGN 5a).

The bags are written into tmp_path from a NanoBench fixture flight by :mod:`test.stack_bags` (real px4_msgs and
crazyflie_interfaces definitions, float32 fields, PX4 stamps in integer microseconds).

Bound of the equality with the CSV (``test_evaluate_numbers_equal_the_csv``): every recorded number is rounded to
float32 (relative error <= 2**-24 ~ 6e-8) and PX4's stamps to 1 us (<= 0.5 us of a 10 ms step, 5e-5 of a step). The
scores are RMS/TIC of differences between predictions and measurements; accelerations and angular accelerations are
finite differences of the 100 Hz float32 velocities and rates, which scales the rounding by up to 1/dt relative to the
signal. The bound used is a relative 1e-4 of each number (absolute 1e-9 near zero): about 1700 float32 steps, above the
5e-5 the stamp rounding can shift a step by. Measured (10 s fixture, 2 s windows, default models greybox and dummy):
crazyswarm2 1.3e-6, PX4 1.0e-5. The physics model is left out: its open-loop windows move by up to 40 % when the stamps
alone are rounded to 1 us (docs/formats.md).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from functools import partial

import numpy as np
import pytest

from quad_modelling.cli import main
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import BagError, ConfigError, DataError
from quad_modelling.io.loader import load_flight
from quad_modelling.io.topic_maps import choose_topic_map, load_topic_map
from test.stack_bags import crazyswarm2_messages, px4_messages, write_stack_bag

CSV = "test/fixtures/nanobench/B7_oval_medium_rep2_first1000.csv.gz"
RELATIVE_BOUND = 1e-4
ABSOLUTE_FLOOR = 1e-9
EVALUATE = ["--vehicle", "crazyflie21", "--preset", "short", "--drop", "1:1", "--train", "0%:50%", "--eval", "50%:100%",
            "--window", "2"]


@pytest.fixture(scope="module")
def flight():
    return load_flight(CSV)


@pytest.fixture(scope="module")
def bags(flight, tmp_path_factory):
    """The fixture flight as a PX4 bag (MCAP, two batteries), a PX4 PWM bag (sqlite3) and a crazyswarm2 bag."""
    root = tmp_path_factory.mktemp("stack_bags")
    cf = load_vehicle("crazyflie21")
    return {
        "px4": write_stack_bag(root / "px4", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max), battery_ids=(1, 2))),
        "px4_pwm": write_stack_bag(root / "px4_pwm", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max), pwm=True),
                                   storage="sqlite3"),
        "crazyswarm2": write_stack_bag(root / "cs2", partial(crazyswarm2_messages, log=flight)),
    }


def _numbers(document, prefix=""):
    """Every float of an evaluate results.json by its path (hex-float sums as floats)."""
    if isinstance(document, dict):
        return {k: v for key, value in document.items() for k, v in _numbers(value, f"{prefix}/{key}").items()}
    if isinstance(document, list):
        return {k: v for i, value in enumerate(document) for k, v in _numbers(value, f"{prefix}[{i}]").items()}
    if isinstance(document, str) and document.startswith(("0x", "-0x")):
        return {prefix: float.fromhex(document)}
    if isinstance(document, float):
        return {prefix: document}
    return {}


def _evaluate(path, out) -> dict:
    assert main(["evaluate", str(path), *EVALUATE, "-o", str(out)]) == 0
    return _numbers(json.loads((out / "results.json").read_text()))


@pytest.mark.slow
def test_evaluate_numbers_equal_the_csv(bags, tmp_path):
    """Done-when of issue 27: the same evaluate numbers from the CSV, the PX4 bag and the crazyswarm2 bag."""
    reference = _evaluate(CSV, tmp_path / "csv")
    assert len(reference) > 500
    for name in ("px4", "crazyswarm2"):
        numbers = _evaluate(bags[name], tmp_path / name)
        assert numbers.keys() == reference.keys()
        worst = max(abs(numbers[k] - v) / max(abs(v), ABSOLUTE_FLOOR / RELATIVE_BOUND) for k, v in reference.items()
                    if math.isfinite(v))
        assert worst <= RELATIVE_BOUND, (name, worst)
        assert all(math.isnan(numbers[k]) for k, v in reference.items() if math.isnan(v))


def test_flight_fields_within_float32_rounding(flight, bags):
    for name in ("px4", "crazyswarm2"):
        log = load_flight(bags[name], vehicle="crazyflie21")
        assert len(log) == len(flight) and log.meta.vehicle == "crazyflie21"
        np.testing.assert_allclose(log.t - log.t[0], flight.t - flight.t[0], atol=1e-6)  # PX4: microsecond stamps
        np.testing.assert_allclose(log.u, flight.u, atol=65535 * 2**-24 * 2)  # float32 of 0..1 scaled back to PWM
        for field in ("pos_n", "vel_n", "euler", "acc_b", "gyro_b", "vbat"):
            scale = np.max(np.abs(getattr(flight, field)))
            np.testing.assert_allclose(getattr(log, field), getattr(flight, field), atol=4 * scale * 2**-24, err_msg=f"{name} {field}")


def test_multi_instance_battery_reads_the_first_instance(flight, bags):
    log = load_flight(bags["px4"], vehicle="crazyflie21")
    np.testing.assert_allclose(log.vbat, flight.vbat, atol=1e-5)  # battery id 2 publishes vbat + 1 on the same topic
    assert log.meta.notes["instances"] == {"/fmu/out/battery_status": "2 instances seen, id 1 used"}


def test_pwm_outputs_in_sqlite3_for_a_normalised_and_a_pwm_vehicle(flight, bags):
    """actuator_outputs (us, range 900..2000) read for a vehicle in us as recorded and for one in 0..1 mapped linearly."""
    ratio = flight.u / 65535  # crazyflie21 commands as a fraction of their range
    as_us = load_flight(bags["px4_pwm"], vehicle="px4_iris_pwm")
    np.testing.assert_allclose(as_us.u, 900 + 1100 * ratio, atol=2000 * 2**-24)
    normalised = load_flight(bags["px4_pwm"], vehicle="px4_iris")
    np.testing.assert_allclose(normalised.u, ratio, atol=2 * 2**-24)
    assert as_us.meta.notes["sources"]["commands"].startswith("/fmu/out/actuator_outputs output[0]")


def test_the_map_is_chosen_from_the_topics(bags):
    assert choose_topic_map({"/fmu/out/vehicle_odometry", "/fmu/out/actuator_motors"}, "bag").name == "px4"
    chosen = choose_topic_map({"/cf5/pose", "/cf5/log_motors", "/cf5/log_velocity"}, "bag")
    assert chosen.name == "crazyswarm2" and "/cf5/pose" in chosen.topics
    assert choose_topic_map({"/quad/motor_input", "/quad/mocap/odom"}, "bag").is_contract
    with pytest.raises(BagError, match="match several topic maps; choose one with --topic-map crazyswarm2:cf1 or crazyswarm2:cf2"):
        choose_topic_map({f"/cf{k}/{t}" for k in (1, 2) for t in ("pose", "log_motors", "log_velocity")}, "bag")
    assert load_topic_map("crazyswarm2:cf2").topics["/cf2/pose"].msgtype == "geometry_msgs/msg/PoseStamped"


# --- bad input: one line, exit 2 --------------------------------------------------------------------------

def _fails(capsys, *argv) -> str:
    assert main(list(argv)) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_a_bag_matching_no_map_lists_topics_and_maps(flight, tmp_path, capsys):
    bag = write_stack_bag(tmp_path / "bag", partial(crazyswarm2_messages, log=flight), skip=("/cf231/log_motors",))
    err = _fails(capsys, "info", str(bag), "--json", "--topic-map", "crazyswarm2")
    assert "commands from /cf231/log_motors (crazyflie_interfaces/msg/LogDataGeneric): not in the bag" in err
    err = _fails(capsys, "evaluate", str(bag), *EVALUATE, "-o", str(tmp_path / "out"))
    assert "no topic map matches the bag's topics ['/cf231/log_battery', '/cf231/log_imu', '/cf231/log_velocity', '/cf231/pose']" in err
    assert "maps tried: quad (needs commands from /quad/motor_input (sensor_msgs/msg/JointState)" in err and "px4 (needs" in err
    assert "crazyswarm2 (needs commands from /cf231/log_motors" in err


def test_a_map_naming_a_missing_field_names_it_topic_and_type(bags, tmp_path, capsys):
    text = open("config/topic_maps/px4.yaml").read().replace("voltage_v", "volts")
    (tmp_path / "mine.yaml").write_text(text)
    err = _fails(capsys, "convert", str(bags["px4"]), "--topic-map", str(tmp_path / "mine.yaml"), "--vehicle", "crazyflie21",
                 "-o", str(tmp_path / "out"))
    assert "field 'volts' of topic /fmu/out/battery_status (px4_msgs/msg/BatteryStatus): px4_msgs/msg/BatteryStatus has no field 'volts'" in err
    assert not (tmp_path / "out").exists()


def test_a_bag_without_stored_definitions_is_refused(flight, tmp_path):
    cf = load_vehicle("crazyflie21")
    bag = write_stack_bag(tmp_path / "old", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max)),
                          storage="sqlite3", store_definitions=False)
    with pytest.raises(BagError, match=r"topic /fmu/out/\w+ \(px4_msgs/msg/\w+\): the bag stores no message definition"):
        load_flight(bag, vehicle="crazyflie21")


@pytest.mark.parametrize("change, message", [
    (("unit: m, frame: NED", "unit: furlong, frame: NED"), "fields.position: unknown unit 'furlong' for position; known: m, mm"),
    (("frame: NED/FRD", "frame: NWU"), "fields.attitude: unknown frame 'NWU'; known: ENU/FLU, NED/FRD"),
    (("stamp_unit: us, optional: true}", "stamp_unit: fortnights, optional: true}"), "unknown stamp_unit 'fortnights'"),
    (("stamp_unit: us, optional: true}", "stamp_unit: us, optional: yes-please}"), "optional must be true or false, got 'yes-please'"),
    ((", order: wxyz, frame: NED/FRD,", ", frame: NED/FRD,"), "fields.attitude: give the quaternion's order (xyzw: geometry_msgs; wxyz: PX4)"),
    (("frames: {1: NED, 3: FRD}", "frames: {1: NED, 2: ENU}"),
     "fields.velocity: frames ['ENU']: a message's frame must be the field's frame NED or a body frame rotated into it (known: NED, FLU, FRD)"),
    (("frame_field: velocity_frame, ", ""), "fields.velocity: missing key 'frame_field'"),
    (("unit: normalised, range: [0, 1]}", "unit: normalised, range: [0, .inf]}"), "fields.commands: range [0, inf] must be finite numbers"),
    (("unit: normalised, range: [0, 1]}", "unit: normalised, range: [-1e308, 1e308]}"),
     "fields.commands: range [-1e+308, 1e+308] must be finite numbers"),
])
def test_a_map_with_unknown_units_or_frames_is_refused(bags, tmp_path, capsys, change, message):
    text = open("config/topic_maps/px4.yaml").read()
    assert change[0] in text
    (tmp_path / "bad.yaml").write_text(text.replace(change[0], change[1], 1))
    err = _fails(capsys, "info", str(bags["px4"]), "--topic-map", str(tmp_path / "bad.yaml"))
    assert message in err and str(tmp_path / "bad.yaml") in err


def test_stamps_from_another_clock_are_refused(flight, tmp_path):
    """The crazyswarm2 pose on ROS time and the log blocks stamped on board (ms since boot): another clock."""
    board = (np.round((flight.t - flight.t[0]) * 1e3) * 1e6).astype(np.int64) + 10**9
    ros = (flight.t * 1e9).astype(np.int64)

    def mixed(writer):
        for (topic, ns, msg), (_, board_ns, board_msg) in zip(crazyswarm2_messages(writer, flight, stamps=ros),
                                                              crazyswarm2_messages(writer, flight, stamps=board)):
            yield (topic, ns, msg) if topic.endswith("/pose") else (topic, board_ns, board_msg)
    bag = write_stack_bag(tmp_path / "mixed", mixed)
    with pytest.raises(DataError, match=r"topic /cf231/pose stamps span 1772662595\.\d+\.\.\d+\.\d+ s, topic /cf231/log_motors "
                                        r"1\.000\.\.10\.\d+ s: stamps from another clock"):
        load_flight(bag)


def test_map_files_are_validated_in_one_line():
    with pytest.raises(ConfigError, match="no such built-in map; known: quad, crazyswarm2, px4"):
        load_topic_map("ardupilot")
    with pytest.raises(ConfigError, match="'cf1' is not a robot name for map px4"):
        load_topic_map("px4:cf1")


def test_info_shows_what_the_map_reads_and_convert_writes_the_contract(bags, flight, tmp_path, capsys):
    assert main(["info", str(bags["crazyswarm2"]), "--vehicle", "crazyflie21"]) == 0
    out = capsys.readouterr().out
    assert "/cf231/log_imu" in out and "flight:    " in out and "(bag, topic map crazyswarm2)" in out
    assert "velocity:       /cf231/log_velocity values[stateEstimate.vx], values[stateEstimate.vy], values[stateEstimate.vz] (m/s, ENU), 100.0 Hz" in out
    assert main(["convert", str(bags["px4"]), "--topic-map", "px4", "--vehicle", "crazyflie21", "-o", str(tmp_path / "quad")]) == 0
    mapped, contract = load_flight(bags["px4"], vehicle="crazyflie21"), load_flight(tmp_path / "quad")
    assert contract.meta.vehicle == "crazyflie21" and contract.allclose(mapped, rtol=1e-12, atol=1e-12)


def test_an_optional_topic_recorded_without_a_message_is_read_as_absent(flight, tmp_path, capsys):
    """A topic in the bag with no message (its publisher's QoS never matched the recorder's) refused the whole flight
    ("topic /fmu/out/sensor_combined has no messages"); an optional one is now left out as an absent one is, said once."""
    cf = load_vehicle("crazyflie21")
    messages = partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max))
    empty = write_stack_bag(tmp_path / "empty_imu", messages, empty=("/fmu/out/sensor_combined",))
    absent = write_stack_bag(tmp_path / "no_imu", messages, skip=("/fmu/out/sensor_combined",))
    read, reference = load_flight(empty, vehicle="crazyflie21"), load_flight(absent, vehicle="crazyflie21")
    assert read.acc_b is None and read.gyro_b is None and read.allclose(reference, rtol=0, atol=0)
    assert read.meta.notes["warnings"] == [f"{empty}: optional topic(s) /fmu/out/sensor_combined recorded with no message: read without them"]
    required = write_stack_bag(tmp_path / "empty_motors", messages, empty=("/fmu/out/actuator_motors",))
    with pytest.raises(DataError, match="topic /fmu/out/actuator_motors has no messages"):
        load_flight(required, vehicle="crazyflie21")


def test_px4s_versioned_battery_topic_is_read(flight, tmp_path):
    """BatteryStatus is at MESSAGE_VERSION 1 in px4_msgs, so newer PX4 publishes /fmu/out/battery_status_v1: it was
    silently not read (the battery is optional), leaving the flight without a voltage."""
    cf = load_vehicle("crazyflie21")

    def versioned(writer):
        for topic, ns, msg in px4_messages(writer, log=flight, input_range=(cf.input_min, cf.input_max)):
            yield (topic + "_v1" if topic == "/fmu/out/battery_status" else topic), ns, msg

    log = load_flight(write_stack_bag(tmp_path / "px4_v1", versioned), vehicle="crazyflie21")
    assert log.vbat is not None and np.allclose(log.vbat, flight.vbat, atol=1e-6)


def test_stamps_in_another_unit_than_the_maps_are_named_as_such(flight, tmp_path, capsys):
    """Stamps 1000x finer than stamp_unit said were read as a 100 kHz flight of 0.04 s with no word; 1000x coarser,
    "share no common time span" gave no hint of the unit."""
    from test.conftest import REPO

    cf = load_vehicle("crazyflie21")
    bag = write_stack_bag(tmp_path / "px4", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max)))
    ns_map = tmp_path / "px4_ns.yaml"
    ns_map.write_text((REPO / "config" / "topic_maps" / "px4.yaml").read_text().replace("stamp_unit: us", "stamp_unit: ns"))
    err = _fails(capsys, "info", str(bag), "--topic-map", str(ns_map), "--vehicle", "crazyflie21")
    assert "topic /fmu/out/actuator_motors read at 1000" in err and "its stamps are in a unit 1000x coarser than the map's stamp_unit, ns" in err
    coarse = write_stack_bag(tmp_path / "px4_coarse", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max),
                                                               stamps_us=(np.arange(len(flight)) * 10_000_000 + 10**9)))
    err = _fails(capsys, "info", str(coarse), "--vehicle", "crazyflie21")
    assert "(or their stamps are in a unit finer than the map's stamp_unit, us" in err or "check the map's stamp_unit, us" in err, err


def test_run_bag_of_a_stack_without_imu_is_refused_naming_the_topic(flight, tmp_path, capsys):
    cf = load_vehicle("crazyflie21")
    bag = write_stack_bag(tmp_path / "px4", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max)),
                          skip=("/fmu/out/sensor_combined",))
    err = _fails(capsys, "run-bag", str(bag), "--vehicle", "crazyflie21", "-o", str(tmp_path / "out"))
    assert f"{bag}: run-bag needs an IMU" in err and "topic map px4 reads it from /fmu/out/sensor_combined, which the bag lacks" in err
    assert not (tmp_path / "out").exists()


def test_a_contract_bag_under_another_namespace_is_read_as_the_contract(tmp_path, capsys):
    """convert --namespace writes the contract under /my_drone/cf1: every verb reads it back (the namespace found from
    the topics, or named as quad:/NAMESPACE), with the numbers of the same flight under /quad."""
    from test.conftest import REPO

    bag = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
    moved = tmp_path / "namespaced"
    assert main(["convert", str(bag), "-o", str(moved), "--namespace", "/my_drone/cf1"]) == 0
    original = load_flight(bag)
    for requested in (None, "quad", "quad:/my_drone/cf1"):
        log = load_flight(moved, topic_map=requested)
        assert np.array_equal(log.u, original.u) and np.array_equal(log.pos_n, original.pos_n), requested
    topics = ["/my_drone/cf1/motor_input", "/my_drone/cf1/mocap/odom", "/my_drone/cf1/imu"]
    chosen = choose_topic_map(topics, "bag")
    assert chosen.is_contract and chosen.namespace == "/my_drone/cf1" and load_topic_map("quad").namespace == "/quad"
    assert main(["evaluate", str(moved), "--topic-map", "quad:my_drone", "--preset", "short", "-o", str(tmp_path / "e")]) == 2
    assert "(a map takes NAME:/NAMESPACE)" in capsys.readouterr().err
    for named in ("/other", "/quad"):  # the namespace named is the one read: applied twice it read /quadr/motor_input,
        missing = choose_topic_map(topics, "bag", f"quad:{named}").missing(topics)  # and quad:/quad read /my_drone/cf1
        assert missing[0] == f"commands from {named}/motor_input (sensor_msgs/msg/JointState)", missing
    two = topics + ["/other/motor_input", "/other/mocap/odom"]  # two contracts: the user chooses
    with pytest.raises(BagError, match="choose one with --topic-map quad:/my_drone/cf1 or quad:/other"):
        choose_topic_map(two, "bag")


def test_a_px4_bag_under_a_vehicle_namespace_is_read_as_px4(flight, tmp_path):
    """PX4's multi-vehicle SITL publishes /px4_1/fmu/out/...: the px4 map is found under the namespace (or named as
    px4:/px4_1), with the numbers of the same flight recorded without it; two vehicles in one bag: the user chooses."""
    cf = load_vehicle("crazyflie21")
    messages = partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max))
    plain = write_stack_bag(tmp_path / "plain", messages)

    def namespaced(writer):
        for topic, ns, msg in messages(writer):
            yield "/px4_1" + topic, ns, msg
    moved = write_stack_bag(tmp_path / "px4_1", namespaced)
    reference = load_flight(plain, vehicle="crazyflie21")
    for requested in (None, "px4", "px4:/px4_1"):
        log = load_flight(moved, vehicle="crazyflie21", topic_map=requested)
        assert np.array_equal(log.u, reference.u) and np.array_equal(log.pos_n, reference.pos_n), requested
    topics = ["/px4_1/fmu/out/vehicle_odometry", "/px4_1/fmu/out/actuator_motors"]
    two = topics + [t.replace("px4_1", "px4_2") for t in topics]
    for requested in (None, "px4"):
        with pytest.raises(BagError, match="px4:/px4_1 or px4:/px4_2"):
            choose_topic_map(two, "bag", requested)
    assert list(load_topic_map("px4:/px4_2").topics)[0] == "/px4_2/fmu/out/vehicle_odometry"


def test_a_contract_bag_missing_a_topic_says_which_not_corrupt(tmp_path):
    """A BagError naming the missing topics was re-wrapped as 'corrupt or truncated bag' (a BagError is an OSError)."""
    from quad_modelling.io.bag_io import read_bag
    from test.conftest import REPO

    with pytest.raises(BagError) as caught:
        read_bag(REPO / "bags" / "nanobench_B7_oval_medium_rep2", namespace="/elsewhere")
    assert "missing required topic(s) ['/elsewhere/motor_input', '/elsewhere/mocap/odom']" in str(caught.value)
    assert "corrupt" not in str(caught.value)


def test_a_yaml_topic_map_takes_the_vehicle_the_bag_records(tmp_path):
    """formats.md: default_vehicle is used when neither --vehicle nor the bag names one. A copy of the contract map read
    as a YAML map (no default_vehicle) takes the bag's recorded crazyflie21 (it asked for --vehicle before)."""
    from test.conftest import REPO

    bag = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
    log = load_flight(bag, topic_map=str(REPO / "config" / "topic_maps" / "quad.yaml"))
    assert log.meta.vehicle == "crazyflie21" and len(log) > 4000


def test_a_message_without_a_mapped_field_is_named_not_called_corrupt(tmp_path):
    """A map reading effort[4] of a 4-effort JointState (or a stack's 3-effort message): topic, message index and
    field in one line (it read 'corrupt or truncated bag (IndexError ...)')."""
    from test.conftest import REPO

    text = (REPO / "config" / "topic_maps" / "quad.yaml").read_text().replace('"effort[3]"]', '"effort[4]"]')
    (tmp_path / "beyond.yaml").write_text(text)
    with pytest.raises(DataError) as caught:
        load_flight(REPO / "bags" / "nanobench_B7_oval_medium_rep2", topic_map=str(tmp_path / "beyond.yaml"))
    assert "topic /quad/motor_input message 0 has no usable field effort[4] (IndexError" in str(caught.value)
    assert "corrupt" not in str(caught.value)


def test_a_yaml_map_with_a_robot_placeholder_takes_its_robot_after_the_file_name(tmp_path):
    """A copy of crazyswarm2.yaml (as the docs suggest) on a bag of two robots: FILE.yaml:ROBOT binds it, and the error
    without a robot names that form (it suggested NAME:ROBOT, which no file map took)."""
    from quad_modelling.io.topic_maps import topic_map_file
    from test.conftest import REPO

    copy = tmp_path / "cs2_onboard.yaml"
    copy.write_text((REPO / "config" / "topic_maps" / "crazyswarm2.yaml").read_text())
    two = ["/cf1/pose", "/cf1/cmd_motors", "/cf2/pose", "/cf2/cmd_motors"]
    bound = load_topic_map(f"{copy}:cf2")
    assert all(name.startswith("/cf2/") for name in bound.topics) and topic_map_file(f"{copy}:cf2") == str(copy)
    with pytest.raises(BagError, match=rf"name one with --topic-map {copy}:ROBOT"):
        choose_topic_map(two, "bag", str(copy))
    with pytest.raises(ConfigError, match="is not a robot name for map"):
        load_topic_map(f"{copy}:bad-name")


@pytest.mark.parametrize("slow, field", [("/fmu/out/vehicle_odometry", "position"), ("/fmu/out/actuator_motors", "commands")])
def test_a_mapped_stream_slower_than_the_gap_rule_is_refused_in_one_line(flight, tmp_path, slow, field):
    """Odometry (or the commands) at ~14 Hz beside 100 Hz streams: every step is a 70 ms gap. One line naming topic
    and rate (it gave one warning per step -- 309 lines for PX4's 10 Hz actuator_motors -- and convert wrote a bag
    without motion capture)."""
    cf = load_vehicle("crazyflie21")

    def slow_stream(writer):
        kept = 0
        for topic, ns, msg in px4_messages(writer, log=flight, input_range=(cf.input_min, cf.input_max)):
            if topic == slow:
                kept += 1
                if kept % 7:
                    continue
            yield topic, ns, msg

    bag = write_stack_bag(tmp_path / "slow", slow_stream)
    with pytest.raises(DataError) as caught:
        load_flight(bag)
    assert str(caught.value).startswith(f"{bag}: topic {slow} ({field}) is sampled at 14.3 Hz (mean step 70 ms)")
    assert str(caught.value).endswith("record it at 20 Hz or more (or check the map's stamp_unit, us)")


@pytest.mark.parametrize("change, expected", [
    (("order: wxyz", "order: xyzw"), ["the attitude and the accelerometer disagree on where gravity is"]),
    (('"velocity[2]"], unit: m/s, frame: NED,\n             frame_field: velocity_frame, frames: {1: NED, 3: FRD}',
      '"velocity[2]"], unit: m/s, frame: ENU,\n             frame_field: velocity_frame, frames: {1: ENU, 3: FLU}'),
     ["the velocity's N axis does not follow", "the velocity's E axis does not follow"]),
    (('order: wxyz, frame: NED/FRD,\n             frame_field: pose_frame, frames: {1: NED/FRD}',
      'order: wxyz, frame: ENU/FLU,\n             frame_field: pose_frame, frames: {1: ENU/FLU}'), ["does not follow the attitude's"]),
    (('"gyro_rad[2]"], unit: rad/s, frame: FRD', '"gyro_rad[2]"], unit: rad/s, frame: FLU'), ["does not follow the attitude's"]),
    (('"gyro_rad[2]"], unit: rad/s', '"gyro_rad[2]"], unit: deg/s'), ["does not follow the attitude's"]),
    # a position in m read as mm: the correlation holds, the scale does not (nothing was said)
    (('"position[2]"], unit: m,', '"position[2]"], unit: mm,'), ["on the N axis the position's derivative is 0.001 x the velocity"]),
])
def test_a_yaml_map_read_in_the_wrong_order_or_frame_warns_naming_it(bags, flight, tmp_path, change, expected):
    """A user's map with the quaternion order or the velocity frame wrong reads without an error; the measurements
    then disagree with each other (gravity 2 g off, the velocity not the position's derivative): a warning names it.
    The map as shipped: no such warning."""
    from quad_modelling.core.preprocess import flight_warnings

    text = open("config/topic_maps/px4.yaml").read()
    assert change[0] in text
    (tmp_path / "mine.yaml").write_text(text.replace(change[0], change[1], 1))
    warnings = flight_warnings(load_flight(bags["px4"], vehicle="crazyflie21", topic_map=str(tmp_path / "mine.yaml")))
    assert all(any(e in w and w.endswith("topic map px4") for w in warnings) for e in expected), warnings
    shipped = flight_warnings(load_flight(bags["px4"], vehicle="crazyflie21"))
    assert not [w for w in shipped if "disagree" in w or "does not follow" in w]


def test_a_gap_a_map_found_by_its_50_ms_rule_survives_convert(flight, tmp_path):
    """A 0.3 s hole in the odometry is marked by the topic-map reader (50 ms rule); the contract bag convert writes
    from it was read by the 0.5 s rule and lost the mark (its windows over interpolated rows were scored). The gap's
    rule travels in the notes: the converted bag marks the same gap."""
    from quad_modelling.core.preprocess import marked_gaps

    cf = load_vehicle("crazyflie21")

    def with_hole(writer):
        odometry = 0
        for topic, ns, msg in px4_messages(writer, log=flight, input_range=(cf.input_min, cf.input_max)):
            odometry += topic == "/fmu/out/vehicle_odometry"
            if not (topic == "/fmu/out/vehicle_odometry" and 401 <= odometry <= 429):  # 29 of the 100 Hz messages
                yield topic, ns, msg

    bag = write_stack_bag(tmp_path / "px4_gap", with_hole)
    mapped = load_flight(bag, vehicle="crazyflie21")
    assert main(["convert", str(bag), "--vehicle", "crazyflie21", "-o", str(tmp_path / "quad")]) == 0
    converted = load_flight(tmp_path / "quad")
    (gap,) = marked_gaps(mapped)
    assert 0.29 < gap.end_s - gap.start_s < 0.32 and mapped.meta.notes["gap_rule_s"] == 0.05
    (again,) = marked_gaps(converted)
    assert (again.start_s, again.end_s) == pytest.approx((gap.start_s, gap.end_s), abs=1e-6)


def test_a_hole_in_the_command_topic_is_a_marked_gap_not_a_refused_flight(flight, tmp_path, capsys):
    """A bridge's link loss: every topic silent for 1 s. info said nothing and evaluate refused the flight ('gap of
    1010 ms ... exceeds the 50 ms'); the hole is now a marked gap of the time base, a warning, and the windows and
    multi-step segments around it are scored (as an odometry hole's are), through convert too."""
    from quad_modelling.core.preprocess import marked_gaps

    cf = load_vehicle("crazyflie21")

    def link_loss(writer):
        first = None
        for topic, ns, msg in px4_messages(writer, log=flight, input_range=(cf.input_min, cf.input_max)):
            first = ns if first is None else first
            if not 4.0e9 < ns - first < 5.0e9:
                yield topic, ns, msg

    bag = write_stack_bag(tmp_path / "px4_loss", link_loss)
    log = load_flight(bag, vehicle="crazyflie21")
    base = [g for g in marked_gaps(log) if g.topic == "/fmu/out/actuator_motors"]
    assert len(base) == 1 and 0.99 < base[0].end_s - base[0].start_s < 1.02 and base[0].fields == ("u",)
    spans = ["--drop", "0:0", "--train", "0:4", "--eval", "5:9.9", "--window", "2"]
    assert main(["evaluate", str(bag), "--vehicle", "crazyflie21", *spans, "-o", str(tmp_path / "e")]) == 0
    assert "/fmu/out/actuator_motors" in capsys.readouterr().err  # the gap's warning
    results = json.loads((tmp_path / "e" / "results.json").read_text())
    assert results["windows"]["greybox"] == {"train": 2, "eval": 2} and results["horizons"]["starts"] > 0
    assert main(["convert", str(bag), "--vehicle", "crazyflie21", "-o", str(tmp_path / "quad")]) == 0
    converted = [g for g in marked_gaps(load_flight(tmp_path / "quad")) if g.fields == ("u",)]
    assert len(converted) == 1 and (converted[0].start_s, converted[0].end_s) == pytest.approx((base[0].start_s, base[0].end_s))


def test_a_damaged_bag_without_crcs_that_loses_messages_says_so(flight, tmp_path):
    """rosbags reads past 4 KB zeroed inside an uncompressed chunk of a bag without CRCs and loses the messages there
    without an error: the counts the bag's metadata gives are compared with the messages read, a warning per topic."""
    import shutil

    from quad_modelling.core.preprocess import flight_warnings

    cf = load_vehicle("crazyflie21")
    bag = write_stack_bag(tmp_path / "px4", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max)))
    assert not [w for w in flight_warnings(load_flight(bag, vehicle="crazyflie21")) if "messages the bag's metadata" in w]
    damaged = tmp_path / "damaged"
    shutil.copytree(bag, damaged)
    (mcap_file,) = damaged.glob("*.mcap")
    data = bytearray(mcap_file.read_bytes())
    data[len(data) // 2: len(data) // 2 + 4096] = bytes(4096)
    mcap_file.write_bytes(bytes(data))
    warnings = [w for w in flight_warnings(load_flight(damaged, vehicle="crazyflie21")) if "messages the bag's metadata" in w]
    assert len(warnings) == 4 and all(re.search(r"topic /fmu/out/\w+: \d+ of the 1000 messages the bag's metadata counts "
                                                r"were read: the file is damaged or was cut", w) for w in warnings)


def test_a_topic_map_the_input_cannot_take_is_refused_in_one_line(bags, tmp_path, capsys):
    """info on a PX4 bag with --topic-map quad printed the topics and exited 0 (evaluate refused it); convert of a CSV
    with --topic-map ignored the map unread. Both are one line, exit 2, nothing written."""
    err = _fails(capsys, "info", str(bags["px4"]), "--topic-map", "quad")
    assert f"{bags['px4']}: topic map quad reads commands from /quad/motor_input" in err
    err = _fails(capsys, "convert", str(CSV), "--topic-map", "px4", "-o", str(tmp_path / "out"))
    assert "--topic-map px4: a topic map applies to bags only, and no input is one" in err
    err = _fails(capsys, "info", str(CSV), "--topic-map", "px4")
    assert "--topic-map px4: a topic map applies to bags only" in err
    assert not (tmp_path / "out").exists()
    for verb, args in (("evaluate", [str(CSV)]), ("identify", [str(CSV)]), ("train", [str(CSV), "--direct"]),
                       ("diagnose", ["--train", str(CSV), "--test", str(CSV)])):  # the map was ignored, exit 0
        out = tmp_path / ("out.yaml" if verb == "identify" else "out.npz" if verb == "train" else "out")
        err = _fails(capsys, verb, *args, "--topic-map", "crazyswarm2", "-o", str(out))
        assert f"--topic-map crazyswarm2: a topic map applies to bags only, and no input is one ({CSV} is a nanobench input)" in err
        assert not out.exists()


def test_a_commands_range_in_the_wrong_unit_is_a_warning(flight, tmp_path):
    """A px4 map whose actuator_motors range says [0, 100] for PX4's 0..1 put the commands at 1 % of the input range
    with no word (greybox TIC acc_z 0.34 -> 0.92)."""
    from test.conftest import REPO

    cf = load_vehicle("crazyflie21")
    bag = write_stack_bag(tmp_path / "px4", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max)))
    assert not [w for w in load_flight(bag, vehicle="crazyflie21").meta.notes.get("warnings", []) if "input range" in w]
    wrong = tmp_path / "px4_range.yaml"
    wrong.write_text((REPO / "config" / "topic_maps" / "px4.yaml").read_text().replace("range: [0, 1]", "range: [0, 100]"))
    warnings = load_flight(bag, vehicle="crazyflie21", topic_map=str(wrong)).meta.notes["warnings"]
    (line,) = [w for w in warnings if "input range" in w]
    assert "the commands reach 0." in line and "check the commands' range: topic map px4" in line, line


# --- the frames VehicleOdometry names in each message (velocity_frame, pose_frame) ---------------------------------

ODOMETRY = "/fmu/out/vehicle_odometry"


def _odometry_frames(flight, frame_of, expected: list | None = None, field: str = "velocity_frame"):
    """The fixture flight's PX4 messages (yaw about 90 deg) with odometry message i's ``field`` set to ``frame_of(i)``;
    a velocity_frame of 3 (BODY_FRD) holds the NED velocity rotated into the body by the message's own float32 q,
    rounded to float32 as PX4 sends it. ``expected`` collects each odometry message's NED velocity in float64: the
    float32 numbers as sent, a body one rotated back by scipy (the truth, independent of the reader)."""
    from scipy.spatial.transform import Rotation

    cf = load_vehicle("crazyflie21")

    def messages(writer):
        index = 0
        for topic, ns, msg in px4_messages(writer, log=flight, input_range=(cf.input_min, cf.input_max)):
            if topic == ODOMETRY:
                frame, index = frame_of(index), index + 1
                velocity = np.asarray(msg.velocity, dtype=float)
                if field == "velocity_frame" and frame == 3:
                    r_ned_frd = Rotation.from_quat(np.asarray(msg.q, dtype=float), scalar_first=True)
                    body = r_ned_frd.inv().apply(velocity).astype(np.float32)
                    msg = dataclasses.replace(msg, velocity=body)
                    velocity = r_ned_frd.apply(body.astype(float))
                msg = dataclasses.replace(msg, **{field: frame})
                if expected is not None:
                    expected.append(velocity)
            yield topic, ns, msg
    return messages


@pytest.mark.parametrize("body_from", [0, 500])
def test_a_body_frame_velocity_is_rotated_into_ned_by_each_messages_attitude(flight, tmp_path, body_from):
    """velocity_frame 3 (BODY_FRD) was read as NED: on this flight at yaw 90 deg north and east swapped, with no word
    (on a hover the consistency check cannot see it). Every message now rotated by its own q; a recording that changes
    frame half-way (body_from 500) is read message by message and warns."""
    expected: list = []
    bag = write_stack_bag(tmp_path / "px4_body", _odometry_frames(flight, lambda i: 3 if i >= body_from else 1, expected))
    log = load_flight(bag, vehicle="crazyflie21")
    assert len(log) == len(flight) and np.ptp(flight.euler[:, 2]) < 0.1 and abs(flight.euler[0, 2] - math.pi / 2) < 0.05
    np.testing.assert_allclose(log.vel_n, np.array(expected), rtol=0, atol=1e-12)  # the NED truth of the numbers sent
    scale = np.max(np.abs(flight.vel_n))
    np.testing.assert_allclose(log.vel_n, flight.vel_n, rtol=0, atol=8 * scale * 2**-24)  # the flight's, to float32
    frames_note = log.meta.notes["frames"]["velocity"]
    body = f"3 = FRD (body, rotated into NED by each message's attitude) in {len(flight) - body_from} messages"
    assert frames_note == f"{ODOMETRY} velocity_frame " + ("; ".join(["1 = NED in 500 messages", body]) if body_from else body)
    changes = [w for w in log.meta.notes.get("warnings", []) if "the frame changes within the recording" in w]
    assert len(changes) == (1 if body_from else 0), changes
    assert not [w for w in log.meta.notes.get("warnings", []) if "disagree" in w or "does not follow" in w]


@pytest.mark.parametrize("field, frame, message", [
    ("velocity_frame", 2, "velocity_frame is 2; topic map px4 reads velocity only with velocity_frame 1 = NED (world), 3 = FRD (body)"),
    ("velocity_frame", 0, "velocity_frame is 0; topic map px4 reads velocity only with velocity_frame 1 = NED (world), 3 = FRD (body)"),
    ("pose_frame", 2, "pose_frame is 2; topic map px4 reads position only with pose_frame 1 = NED (world)"),
])
def test_an_odometry_frame_the_map_does_not_read_is_refused_in_one_line(flight, tmp_path, capsys, field, frame, message):
    """FRD (an earth-fixed frame at an arbitrary heading) and UNKNOWN are refused, as the ULog reader refuses them,
    naming the bag, topic, message and field: here from message 700 on (a change of frame mid-recording)."""
    bag = write_stack_bag(tmp_path / "px4_frd", _odometry_frames(flight, lambda i: frame if i >= 700 else 1, field=field))
    err = _fails(capsys, "info", str(bag), "--vehicle", "crazyflie21")
    assert f"{bag}: topic {ODOMETRY} message 700: {message}" in err, err


def test_another_instances_odometry_frame_is_not_checked(flight, tmp_path):
    """A user map reading odometry with ``instance:`` (here told apart by ``quality``): the frames of the instance
    not read were checked before it was dropped, so a second odometry in an FRD frame refused the whole bag."""
    text = open("config/topic_maps/px4.yaml").read()
    line = "/fmu/out/vehicle_odometry: {type: px4_msgs/msg/VehicleOdometry, stamp: timestamp_sample, stamp_unit: us}"
    assert line in text
    (tmp_path / "two.yaml").write_text(text.replace(line, line[:-1] + ", instance: quality}", 1))
    plain = _odometry_frames(flight, lambda i: 1)

    def two_odometries(writer):
        for topic, ns, msg in plain(writer):
            yield topic, ns, msg
            if topic == ODOMETRY:  # a second estimator's odometry, FRD-referenced (velocity_frame 2)
                yield topic, ns, dataclasses.replace(msg, quality=1, velocity_frame=2, velocity=np.zeros(3, np.float32))

    bag = write_stack_bag(tmp_path / "two_odometries", two_odometries)
    log = load_flight(bag, vehicle="crazyflie21", topic_map=str(tmp_path / "two.yaml"))
    assert log.meta.notes["instances"] == {ODOMETRY: "2 instances seen, quality 0 used"}
    scale = np.max(np.abs(flight.vel_n))
    np.testing.assert_allclose(log.vel_n, flight.vel_n, rtol=0, atol=8 * scale * 2**-24)


def test_an_undeserialisable_message_is_named_by_topic_and_index(flight, tmp_path):
    """As the contract reader names it (it was "corrupt or truncated bag (SerdeError: ...)")."""
    from quad_modelling.io.bag_io import ForeignBagWriter
    from test.stack_bags import definitions

    cf = load_vehicle("crazyflie21")
    seen = {}
    with ForeignBagWriter(tmp_path / "cut", definitions()) as writer:
        for topic, ns, msg in crazyswarm2_messages(writer, flight):
            seen[topic] = seen.get(topic, -1) + 1
            if topic.endswith("/log_motors") and seen[topic] == 7:
                raw = writer.store.serialize_cdr(msg, msg.__msgtype__)[:12]  # cut inside its header's frame id
                writer._writer.write(writer.connection(topic, msg.__msgtype__), ns, raw)
            else:
                writer.write(topic, ns, msg)
    with pytest.raises(BagError) as err:
        load_flight(tmp_path / "cut", vehicle=cf)
    assert str(err.value).startswith(f"{tmp_path / 'cut'}: topic /cf231/log_motors message 7: cannot deserialise (")


def test_a_kinematic_stream_that_stops_mid_flight_cuts_the_rest_and_says_so(flight, tmp_path):
    """The rows after the odometry's last message are cut (no extrapolation), and now said: it was a note only, a
    42 s flight converted to 20 s at exit 0 without a word (topics discovered a moment apart cut under 1 s: silent)."""
    cf = load_vehicle("crazyflie21")
    stop_ns = None

    def stopped(writer):
        nonlocal stop_ns
        for topic, ns, msg in px4_messages(writer, log=flight, input_range=(cf.input_min, cf.input_max)):
            stop_ns = stop_ns or ns + 4 * 10**9
            if not (topic == "/fmu/out/vehicle_odometry" and ns > stop_ns):
                yield topic, ns, msg
    log = load_flight(write_stack_bag(tmp_path / "stopped", stopped), vehicle=cf)
    assert log.duration == pytest.approx(4.0, abs=0.02)
    (warning,) = [w for w in log.meta.notes.get("warnings", []) if " cut: " in w]
    assert re.fullmatch(rf"{tmp_path / 'stopped'}: 6\.0\d s of the 9\.9\d s of commands cut: /fmu/out/vehicle_odometry "
                        r"ends 6\.0\d s before them \(rows outside the span every kinematic stream covers\)", warning)
    whole = load_flight(write_stack_bag(tmp_path / "whole", partial(px4_messages, log=flight, input_range=(cf.input_min, cf.input_max))),
                        vehicle=cf)
    assert not any(" cut: " in w for w in whole.meta.notes.get("warnings", []))
