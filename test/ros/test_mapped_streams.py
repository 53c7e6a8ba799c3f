"""Live through a topic map, the custom-type half (issue #27 item 3): px4_msgs and crazyflie_interfaces messages
generated from the stored definitions (test/data/ros_msgs) go through the node-side streams
(:mod:`quad_modelling.nodes.mapping.streams`) and give the arrays the offline reader gives for the same messages;
the evaluator reading a user map scores what it scores from the contract; a custom type whose package is not importable stops the node in one line naming the package to source.
"""

from __future__ import annotations

import os
import sys
from functools import partial
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from rclpy.parameter import Parameter

from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.mapped_flight import read_mapped_bag
from quad_modelling.io.topic_maps import load_topic_map
from quad_modelling.io.topics import stamps_ns
from quad_modelling.nodes import messages
from quad_modelling.nodes.common import BadParameter, run_node
from quad_modelling.nodes.evaluator_node import EvaluatorNode
from quad_modelling.nodes.mapping.streams import MEASURED_FIELDS, MappedStreams
from quad_modelling.nodes.predictor_node import PredictorNode
from test.conftest import synthetic_log
from test.ros.conftest import Capture, feed, hover_log, in_process_evaluator
from test.ros.test_evaluator_node import offset_prediction
from test.ros.test_predictor_topic_map_live import USER_MAP, user_messages
from test.stack_bags import crazyswarm2_messages, px4_messages, write_stack_bag


def live_rows(streams: MappedStreams, messages, vehicle):
    """Feed ``messages`` (topic, ns, message) as the predictor's on_mapped does; the log of every command row."""
    commands = []
    for topic, _, msg in messages:
        read = streams.read(topic, msg)
        if read is None:
            continue
        ns, fields = read
        assert streams.fault(fields) is None
        streams.store(ns, {f: v for f, v in fields.items() if f != "commands"})
        if "commands" in fields:
            commands.append((ns, streams.command(fields["commands"], vehicle)))
    stamps = np.array([ns for ns, _ in commands], dtype=np.int64)
    measured = [streams.at(int(ns), 0) for ns in stamps]
    return streams.rows_log(stamps, np.array([u for _, u in commands]), measured, vehicle.name, "live")


@pytest.mark.parametrize("stack", ["px4", "crazyswarm2:cf231"])
def test_generated_custom_type_messages_give_the_offline_readers_arrays(tmp_path, stack):
    vehicle = load_vehicle("crazyflie21")
    log = synthetic_log(n=150, seed=4)
    if stack == "px4":
        make = partial(px4_messages, log=log, input_range=(vehicle.input_min, vehicle.input_max), battery_ids=(1, 2))
    else:
        make = partial(crazyswarm2_messages, log=log)
    sent = []

    def recorded(writer):
        for item in make(writer):
            sent.append(item)
            yield item

    bag = write_stack_bag(tmp_path / "bag", recorded)
    topic_map = load_topic_map(stack)
    offline = read_mapped_bag(bag, topic_map, vehicle)
    streams = MappedStreams(topic_map, [*MEASURED_FIELDS, "battery"], 100_000_000, 4096, "test")
    live = live_rows(streams, sent, vehicle)
    assert len(live) == len(offline) == 150
    np.testing.assert_array_equal(live.t, offline.t)
    for field in ("u", "pos_n", "vel_n", "euler", "acc_b", "gyro_b", "vbat"):
        np.testing.assert_array_equal(getattr(live, field), getattr(offline, field), err_msg=field)
    if stack == "px4":  # the second battery (id 2, 1 V higher) is another instance: not read, as offline
        np.testing.assert_allclose(live.vbat, log.vbat, atol=1e-6)


@pytest.mark.parametrize("node", ["predictor", "evaluator"])
def test_a_custom_type_without_its_package_stops_the_node_in_one_line_naming_the_package(monkeypatch, capsys, node):
    monkeypatch.setitem(sys.modules, "px4_msgs", None)  # import px4_msgs raises ImportError, installed or not
    overrides = [Parameter("vehicle", value="crazyflie21"), Parameter("topic_map", value="px4")]
    code = run_node(lambda: (PredictorNode if node == "predictor" else EvaluatorNode)(parameter_overrides=overrides))
    assert code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in lines if line.startswith("error:")]
    assert errors == [f"error: {node}: topic_map px4 topic /fmu/out/actuator_motors: px4_msgs is not importable: "
                      "source the workspace that builds px4_msgs (docs/nodes.md)"]


def test_the_evaluator_leaves_recording_a_stacks_topics_to_ros2_bag_record(ros, tmp_path):
    overrides = [Parameter("topic_map", value="px4"), Parameter("record", value=str(tmp_path / "rec"))]
    niceness = os.nice(0)
    with pytest.raises(BadParameter, match=r"^evaluator: parameter record with topic_map='px4': record a stack's own topics with ros2 bag record"):
        EvaluatorNode(parameter_overrides=overrides)
    assert not (tmp_path / "rec").exists()
    assert os.nice(0) == niceness  # refused before its nice (10 by default) renices the process


def test_a_map_with_a_robot_placeholder_needs_the_robot_named(ros):
    with pytest.raises(BadParameter, match=r"topic_map='crazyswarm2'.*topic_map:=crazyswarm2:cf231"):
        PredictorNode(parameter_overrides=[Parameter("vehicle", value="crazyflie21"), Parameter("topic_map", value="crazyswarm2")])
    with pytest.raises(BadParameter) as caught:  # the parameter named, not the CLI's --topic-map
        PredictorNode(parameter_overrides=[Parameter("vehicle", value="crazyflie21"), Parameter("topic_map", value="nope")])
    assert str(caught.value).startswith("predictor: parameter topic_map='nope': no such built-in map; known: quad")


def test_the_evaluator_through_a_user_map_scores_what_it_scores_from_the_contract(ros, tmp_path):
    """The same flight and predictions to two evaluators: one reading the contract, one a user map of standard types
    (the live predictor test's); every scored window's RMS/TIC agree (measured: equal)."""
    map_file = tmp_path / "user_map.yaml"
    map_file.write_text(yaml.safe_dump(USER_MAP))
    log = hover_log(1100)
    prediction = offset_prediction(log, "vel_x", 0.25)
    common = {"window_s": 5.0, "models": ["m"], "figures": False, "vehicle": "crazyflie21"}
    contract, mapped = (in_process_evaluator(**values) for values in (common, {**common, "topic_map": str(map_file)}))
    for node in (contract, mapped):
        node.diag_pub = Capture()
    feed(contract, log, range(len(log)), predictions={"m": prediction})
    arrays = messages.measurement_messages(log)
    for row, ns in enumerate(stamps_ns(log.t).tolist()):
        for kind, msg in (("motor", arrays.motor(row, ns)), ("odom", arrays.odometry(row, ns)), ("imu", arrays.imu(row, ns))):  # as feed()
            for topic, user_msg in user_messages(kind, msg):
                mapped.on_mapped(topic, user_msg)
        o, a = messages.prediction_messages(ns, prediction[0][row], prediction[1][row], "m/base_link")
        mapped.on_pred_odom("m", o)
        mapped.on_pred_accel("m", a)
    for node in (contract, mapped):
        node.finish()
    want, got = (sorted((r for r in node.scores.records if r.scored), key=lambda r: (r.model, r.index)) for node in (contract, mapped))
    assert [(r.model, r.index) for r in got] == [(r.model, r.index) for r in want] == [("dummy", 0), ("dummy", 1), ("m", 0), ("m", 1)]
    for w, g in zip(want, got):
        np.testing.assert_allclose(g.rms, w.rms, rtol=0, atol=1e-9)
        np.testing.assert_allclose(g.tic, w.tic, rtol=0, atol=1e-9)
    assert all(abs(r.rms[INDEX["vel_x"]] - 0.25) < 1e-9 for r in got if r.model == "m")
    assert mapped.faults.summary() == "none"
    for node in (contract, mapped):
        node.destroy_node()


def test_a_battery_reading_at_or_below_zero_volts_is_a_range_fault():
    assert [MappedStreams.fault({"battery": [v]}) for v in (15.2, 0.0, -0.1, float("nan"))] == [None, "range", "range", "nan"]


def test_a_nan_command_is_kept_as_a_stopped_motor_and_reported_once_as_offline(tmp_path):
    """PX4 writes NaN for a stopped motor: live, as offline, the command reads as the map's lowest one; the node's
    fault log says so once and counts every such message (a review found it used silently)."""
    from types import SimpleNamespace

    from quad_modelling.nodes.common import FaultLog

    vehicle = load_vehicle("crazyflie21")
    log = synthetic_log(n=20, seed=4)
    sent = []

    def recorded(writer):
        for item in px4_messages(writer, log=log, input_range=(vehicle.input_min, vehicle.input_max)):
            sent.append(item)
            yield item

    write_stack_bag(tmp_path / "bag", recorded)
    topic_map = load_topic_map("px4")
    streams = MappedStreams(topic_map, [*MEASURED_FIELDS, "battery"], 100_000_000, 4096, "test")
    motors = [(topic, msg) for topic, _, msg in sent if topic == "/fmu/out/actuator_motors"][:3]
    warnings = []
    faults = FaultLog(SimpleNamespace(warning=warnings.append))
    for k, (topic, msg) in enumerate(motors):
        if k:
            msg.control[1] = float("nan")
        ns, fields = streams.admit(topic, msg, faults)
        command = streams.command(fields["commands"], vehicle)
        if k:
            assert command[1] == vehicle.input_min and np.all(np.isfinite(command))
    key = f"stopped_motor_{motors[0][0]}"
    assert faults.counts == {key: 2} and len(warnings) == 1 and "stopped motor" in warnings[0]


def test_a_message_the_map_cannot_read_is_a_fault_not_the_end_of_the_predictor(ros, tmp_path):
    """A JointState with 3 efforts on a user map's commands topic stopped the predictor with an IndexError traceback (exit
    2, no prediction for the rest of the flight); the evaluator dropped it. Both now drop it, counted once as
    ``bad_<topic>``, and read the next message."""
    from sensor_msgs.msg import JointState

    map_file = tmp_path / "user_map.yaml"
    map_file.write_text(yaml.safe_dump(USER_MAP))
    node = PredictorNode(parameter_overrides=[Parameter(k, value=v) for k, v in
                                              {"vehicle": "crazyflie21", "model": "greybox", "topic_map": str(map_file)}.items()])
    log = hover_log(20)
    arrays = messages.measurement_messages(log)
    short = JointState(header=arrays.motor(0, 0).header, name=["m1", "m2", "m3"], effort=[1000.0, 1000.0, 1000.0])
    warnings = []
    node.faults.logger = SimpleNamespace(warning=warnings.append)
    node.on_mapped("/user/motors", short)
    node.on_mapped("/user/motors", short)
    assert node.faults.counts == {"bad_/user/motors": 2} and len(warnings) == 1
    assert warnings[0].startswith("unusable /user/motors message dropped (") and "effort[3]" in warnings[0]
    node.on_mapped("/user/motors", arrays.motor(1, int(stamps_ns(log.t)[1])))  # the next one is read as before
    assert node.faults.counts == {"bad_/user/motors": 2}
    node.destroy_node()


def test_a_map_stamp_path_the_type_lacks_is_a_fault_not_the_end_of_the_predictor(tmp_path):
    """``stamp: header.nostamp`` in a user's map: the predictor stopped at the first message with an AttributeError
    traceback (exit 1; the evaluator dropped it). Now a ``bad_<topic>`` fault naming the path, as a short JointState."""
    import copy

    from sensor_msgs.msg import JointState

    from quad_modelling.nodes.common import FaultLog

    user_map = copy.deepcopy(USER_MAP)
    user_map["topics"]["/user/motors"]["stamp"] = "header.nostamp"
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(user_map))
    streams = MappedStreams(load_topic_map(str(tmp_path / "map.yaml")), list(MEASURED_FIELDS), 100_000_000, 4096, "test")
    warnings = []
    faults = FaultLog(SimpleNamespace(warning=warnings.append))
    motor = JointState(name=["m1", "m2", "m3", "m4"], effort=[1000.0] * 4)
    assert streams.admit("/user/motors", motor, faults) is None and faults.counts == {"bad_/user/motors": 1}
    assert "has no usable field header.nostamp (AttributeError" in warnings[0]


def test_a_map_path_the_message_type_lacks_stops_the_node_at_start_in_one_line(ros, tmp_path):
    """``pose.pose.position.q`` (or a stamp path the type lacks) in a user's map: the nodes ran and dropped every
    message (evaluate refuses the map in one line); the default message of each type is read at start."""
    import copy

    import pytest

    from quad_modelling.nodes.common import BadParameter

    user_map = copy.deepcopy(USER_MAP)
    user_map["topics"]["/user/motors"]["stamp"] = "header.nostamp"
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(user_map))
    with pytest.raises(BadParameter, match=r"topic /user/motors: sensor_msgs/msg/JointState has no field header.nostamp$"):
        PredictorNode(parameter_overrides=[Parameter(k, value=v) for k, v in
                                           {"vehicle": "crazyflie21", "model": "greybox", "topic_map": str(tmp_path / "map.yaml")}.items()])
    from quad_modelling.nodes.mapping.streams import lacking_attribute

    assert not lacking_attribute(SimpleNamespace(values=[]), [("attr", "values"), ("index", 3)])  # may be filled later
    assert lacking_attribute(SimpleNamespace(values=[SimpleNamespace(x=1.0)]), [("attr", "values"), ("index", 0), ("attr", "y")])
