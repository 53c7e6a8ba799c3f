"""Nodes as a ROS user starts them, over real DDS: best-effort publishers, parameter files in another
namespace, misspelt and integer parameters, the vehicle announced by a replay, SIGTERM."""

import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String

from quad_modelling.io import topics
from quad_modelling.nodes import messages
from quad_modelling.nodes.common import data_qos, latched_qos
from test.conftest import REPO
from test.ros.conftest import hover_log


def start(module: str, args: list[str], log_path):
    """A node process whose output goes to ``log_path`` (read with :func:`wait_for_line`)."""
    handle = open(log_path, "w")  # noqa: SIM115 -- closed by the process's end
    return subprocess.Popen([sys.executable, "-m", f"quad_modelling.nodes.{module}", "--ros-args", *args],
                            stdout=handle, stderr=subprocess.STDOUT, text=True)


def wait_for_line(log_path, text: str, node=None, timeout: float = 60.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        content = log_path.read_text()
        if text in content:
            return content
        if node is not None:
            rclpy.spin_once(node, timeout_sec=0.05)
        else:
            time.sleep(0.05)
    raise AssertionError(f"{text!r} not in the log within {timeout:g} s:\n{log_path.read_text()}")


def stop(proc, signum=signal.SIGTERM, timeout: float = 30.0) -> int:
    proc.send_signal(signum)
    return proc.wait(timeout)


def spin_until(node, condition, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    assert condition(), "condition not met in time"


@pytest.mark.slow
@pytest.mark.exclusive  # 100 Hz in real time, >= 99 % must arrive: the machine to itself under xdist
def test_a_sensor_data_publisher_feeds_a_default_predictor_and_not_a_reliable_one(ros, tmp_path):
    """MAVROS, the PX4 uXRCE-DDS bridge and crazyswarm2 publish best effort: the default qos receives it."""
    log = hover_log(300)  # 3 s at 100 Hz: window 0 (2 s) whole, window 1 partly
    common = ["-p", "vehicle:=crazyflie21", "-p", "window_s:=2", "-p", "sample_period_s:=0.01"]  # window_s:=2 an integer
    default = start("predictor_node", common, tmp_path / "default.log")
    strict = start("predictor_node", [*common, "-r", "__node:=strict", "-p", "model_name:=strict", "-p", "qos:=reliable"],
                   tmp_path / "strict.log")
    node = Node("flight_stack", namespace="/quad")
    try:
        pubs = {key: node.create_publisher(kind, key, qos_profile_sensor_data)
                for key, kind in (("motor_input", JointState), ("mocap/odom", Odometry), ("imu", Imu))}
        got = {"naive": [], "strict": []}
        for name in got:
            node.create_subscription(Odometry, f"{name}/odom", lambda m, n=name: got[n].append(m), data_qos())
        wait_for_line(tmp_path / "default.log", "best_effort subscriptions", node)
        wait_for_line(tmp_path / "strict.log", "reliable subscriptions", node)
        spin_until(node, lambda: pubs["motor_input"].get_subscription_count() >= 1
                   and node.count_publishers("naive/odom") >= 1 and node.count_publishers("strict/odom") >= 1)
        time.sleep(0.5)
        arrays = messages.measurement_messages(log)
        stamps = topics.stamps_ns(log.t)
        t0 = time.monotonic()
        for row, ns in enumerate(stamps.tolist()):
            pubs["motor_input"].publish(arrays.motor(row, ns))
            pubs["mocap/odom"].publish(arrays.odometry(row, ns))
            pubs["imu"].publish(arrays.imu(row, ns))
            while time.monotonic() < t0 + (row + 1) * 0.01:  # 100 Hz, as the flight
                rclpy.spin_once(node, timeout_sec=max(0.0, t0 + (row + 1) * 0.01 - time.monotonic()))
        spin_until(node, lambda: len(got["naive"]) >= 295, timeout=10)
        predicted = {topics.stamp_ns(m.header.stamp): m for m in got["naive"]}
        assert set(predicted) <= set(stamps.tolist())  # each prediction carries its input's stamp
        assert len(predicted) >= 0.99 * len(stamps)
        # naive = the state measured at the last warm row (row 19 of window 0), held: a real prediction, not an echo
        streamed = [predicted[ns] for ns in stamps[20:200].tolist() if ns in predicted]
        held = topics.predictions_from_fields([topics.predicted_odometry_fields(m) for m in streamed],
                                              [[0.0] * 6] * len(streamed))
        assert np.allclose(held[:, 3:6], log.vel_n[19], atol=1e-9)
        assert got["strict"] == []  # a reliable subscription does not match a best-effort publisher
        assert stop(default) == 0 and stop(strict) == 0
    finally:
        for proc in (default, strict):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        node.destroy_node()
    out = (tmp_path / "default.log").read_text()
    assert "published" in out and "over 2 windows" in out
    assert "windows 2 s, warm start 0.2 s" in out  # window_s:=2, an integer, taken as 2.0
    assert "incompatible QoS" in (tmp_path / "strict.log").read_text()  # rclpy says why nothing arrives


def test_shipped_params_file_applies_in_another_namespace_and_sigterm_writes_results(tmp_path):
    out = tmp_path / "results"
    proc = start("evaluator_node", ["-r", "__ns:=/cf1", "--params-file", str(REPO / "config" / "evaluator.yaml"),
                                    "-p", "windw_s:=3.0", "-p", "window_s:=4", "-p", "nice:=0", "-p", "vehicle:=crazyflie21",
                                    "-p", f"output_dir:={out}"], tmp_path / "eval.log")
    try:
        text = wait_for_line(tmp_path / "eval.log", "scoring models")
        time.sleep(0.5)  # spinning
        code = stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = (tmp_path / "eval.log").read_text()
    assert "[cf1.evaluator]" in text  # running in /cf1 ...
    assert "scoring models ['greybox', 'narx']" in text  # ... with the file's models (keyed /**), not the default [naive]
    assert "(4 s windows" in text  # window_s:=4, an integer, taken as 4.0
    assert "unknown parameter 'windw_s' ignored; did you mean 'window_s'?" in text
    assert code == 0, text  # SIGTERM: a normal end ...
    assert (out / "results.json").is_file() and "closed 0 windows" in text  # ... that wrote the results


@pytest.mark.slow
def test_nodes_learn_the_replayed_vehicle_or_refuse_another_in_one_line(ros, tmp_path):
    node = Node("replay_stand_in", namespace="/quad")
    announcer = node.create_publisher(String, "vehicle", latched_qos())
    announcer.publish(String(data="linkquad"))  # transient-local: nodes started later receive it
    learner = start("predictor_node", ["--params-file", str(REPO / "config" / "greybox_predictor.yaml")], tmp_path / "learner.log")
    refuser = start("predictor_node", ["-r", "__node:=refuser", "-p", "vehicle:=crazyflie21"], tmp_path / "refuser.log")
    evaluator = start("evaluator_node", ["-p", "vehicle:=crazyflie21", "-p", f"output_dir:={tmp_path / 'out'}"],
                      tmp_path / "evaluator.log")
    try:
        learned = wait_for_line(tmp_path / "learner.log", "vehicle linkquad learned from topic vehicle", node)
        assert "predicting with 'greybox'" in learned  # the params file (keyed /**) gave the model
        code = refuser.wait(60)
        refused = (tmp_path / "refuser.log").read_text()
        assert code == 2, refused
        errors = [line for line in refused.splitlines() if line.startswith("error:")]
        assert errors == ["error: refuser: parameter vehicle='crazyflie21' (crazyflie21) but the replay plays a flight of "
                          "vehicle 'linkquad' (topic vehicle); set vehicle:=linkquad or leave it empty to learn it"]
        assert refused.count("but the replay plays a flight of") == 1  # one line, not a log line and the error
        assert stop(learner) == 0
        assert evaluator.wait(60) == 2  # refused: no results of another vehicle's windows are written
        text = (tmp_path / "evaluator.log").read_text()
        assert f"results not written to {tmp_path / 'out'}: the evaluation was refused" in text and not (tmp_path / "out").exists()
    finally:
        for proc in (learner, refuser, evaluator):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        node.destroy_node()


@pytest.mark.parametrize("kind", ["evaluator", "predictor"])
def test_a_keep_last_subscription_that_overflows_counts_only_what_it_delivered(ros, tmp_path, kind):
    """A reliable keep-last reader of depth 2 that takes nothing while 50 IMU messages arrive keeps the last 2: the
    other 48 are lost, as a node that falls behind a replay at --rate > 0 loses them. The node counts the 2 it got
    (its exit summary's ``received``, and the evaluator's results.json ``live.received``), what run-bag compares with
    the 50 replayed."""
    import json

    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from quad_modelling.nodes.evaluator_node import EvaluatorNode
    from quad_modelling.nodes.predictor_node import PredictorNode

    params = {"vehicle": "crazyflie21", "qos": "reliable", "qos_depth": 2}
    if kind == "evaluator":
        params.update(models=["m"], figures=False, output_dir=str(tmp_path / "out"), nice=0)  # in process: the worker's
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    node = EvaluatorNode(parameter_overrides=overrides) if kind == "evaluator" else PredictorNode(parameter_overrides=overrides)
    source = Node("imu_source", namespace="/quad")
    try:
        pub = source.create_publisher(Imu, "imu", data_qos(100))  # reliable: every message sent is delivered or lost to depth
        spin_until(source, lambda: pub.get_subscription_count() >= 1)
        log = hover_log(50)
        arrays = messages.measurement_messages(log)
        for row, ns in enumerate(topics.stamps_ns(log.t).tolist()):
            pub.publish(arrays.imu(row, ns))
        assert pub.wait_for_all_acked(Duration(seconds=10))  # all 50 in the reader's 2-deep history, in turn
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        for _ in range(20):
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
        assert node.tally.received["imu"] == 2 and node.tally.received["motor_input"] == 0
        if kind == "evaluator":
            node.finish()
            assert json.loads((tmp_path / "out" / "results.json").read_text())["live"]["received"] == \
                {"motor_input": 0, "mocap_odom": 0, "imu": 2, "m/odom": 0, "m/accel": 0}
            assert "; received motor_input 0, mocap_odom 0, imu 2, m/odom 0, m/accel 0; " in node.exit_summary()
    finally:
        source.destroy_node()
        node.destroy_node()
