"""The replay node over real DDS: every sample, recorded stamps, frames, /clock, clean exit."""

import subprocess
import sys
import time

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String

from quad_modelling.io import topics
from quad_modelling.io.bag_io import write_bag
from quad_modelling.io.topics import stamps_ns
from quad_modelling.nodes.common import data_qos, latched_qos
from test.conftest import synthetic_log


def drain_received(node, got, quiet_s: float = 1.0) -> None:
    """Take every message already delivered to ``node``: spin until none arrived for ``quiet_s``.

    spin_once runs one callback; the replay plays the bag in a fraction of a second at
    rate 20, so on a loaded machine hundreds of messages still wait in the readers when it exits.
    """
    quiet_until = time.monotonic() + quiet_s
    while time.monotonic() < quiet_until:
        before = sum(map(len, got.values()))
        rclpy.spin_once(node, timeout_sec=0.05)
        if sum(map(len, got.values())) > before:
            quiet_until = time.monotonic() + quiet_s


@pytest.mark.parametrize("executor", ["events", "single"])
def test_replay_publishes_every_sample_with_its_stamp_and_exits(ros, tmp_path, executor):
    log = synthetic_log(n=300)
    bag = write_bag(log, tmp_path / "bag")
    node = Node("listener", namespace="/quad")
    got = {"motor": [], "odom": [], "imu": [], "clock": [], "origin": [], "vehicle": []}
    node.create_subscription(JointState, "motor_input", lambda m: got["motor"].append(m), data_qos())
    node.create_subscription(Odometry, "mocap/odom", lambda m: got["odom"].append(m), data_qos())
    node.create_subscription(Imu, "imu", lambda m: got["imu"].append(m), data_qos())
    node.create_subscription(Clock, "/clock", lambda m: got["clock"].append(m), data_qos())
    node.create_subscription(Clock, "window_origin", lambda m: got["origin"].append(m), latched_qos())
    node.create_subscription(String, "vehicle", lambda m: got["vehicle"].append(m), latched_qos())
    replay = subprocess.Popen(
        [sys.executable, "-m", "quad_modelling.nodes.replay_node", "--ros-args", "-p", f"bag:={bag}", "-p", "rate:=20.0",
         "-p", "start_s:=0.5", "-p", "wait_for_subscribers:=1", "-p", f"executor:={executor}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 60
    while replay.poll() is None and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    drain_received(node, got)
    out = replay.communicate(timeout=10)[0]
    assert replay.returncode == 0, out
    expected = stamps_ns(log.t)[50:]  # start_s 0.5 s at 100 Hz
    for key in ("motor", "odom", "imu", "clock"):
        stamps = [topics.stamp_ns(m.clock if key == "clock" else m.header.stamp) for m in got[key]]
        assert stamps == expected.tolist(), key
    assert topics.stamp_ns(got["origin"][0].clock) == expected[0]
    assert [m.data for m in got["vehicle"]] == [log.meta.vehicle]  # the bag's vehicle, announced once (transient-local)
    odom = got["odom"][10]
    assert (odom.header.frame_id, odom.child_frame_id) == ("world", "base_link")
    # ENU position of row 60 = (east, north, up) of the NED log
    assert np.allclose([odom.pose.pose.position.x, odom.pose.pose.position.y, odom.pose.pose.position.z],
                       log.pos_n[60, [1, 0, 2]] * [1, 1, -1])
    assert np.allclose(got["motor"][10].effort, log.u[60])
    node.destroy_node()


def test_replay_waits_for_a_reader_of_every_measurement_topic_not_only_the_engine_inputs(ros, tmp_path):
    """A pose reader that matches after the engine-input reader (a lossy link delays its discovery) still gets the
    first sample: the replay waits for wait_for_subscribers readers on motor_input, mocap/odom and imu each."""
    log = synthetic_log(n=60)
    bag = write_bag(log, tmp_path / "bag")
    node = Node("late_listener", namespace="/quad")
    got = {"motor": [], "odom": [], "imu": []}
    node.create_subscription(JointState, "motor_input", lambda m: got["motor"].append(m), data_qos())
    replay = subprocess.Popen(
        [sys.executable, "-m", "quad_modelling.nodes.replay_node", "--ros-args", "-p", f"bag:={bag}", "-p", "rate:=20.0",
         "-p", "wait_for_subscribers:=1"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        until = time.monotonic() + 3.0  # the replay is up and matched on motor_input well within this
        while time.monotonic() < until:
            rclpy.spin_once(node, timeout_sec=0.05)
        assert got["motor"] == []  # still waiting for the other topics' readers
        node.create_subscription(Odometry, "mocap/odom", lambda m: got["odom"].append(m), data_qos())
        node.create_subscription(Imu, "imu", lambda m: got["imu"].append(m), data_qos())
        deadline = time.monotonic() + 60
        while replay.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        drain_received(node, got)
    finally:
        replay.terminate()
        out = replay.communicate(timeout=10)[0]
    assert replay.returncode == 0, out
    for key in ("motor", "odom", "imu"):
        assert [topics.stamp_ns(m.header.stamp) for m in got[key]] == stamps_ns(log.t).tolist(), key
    assert "playing anyway" not in out
    node.destroy_node()


def test_missing_bag_exits_with_code_2_naming_it(tmp_path):
    run = subprocess.run([sys.executable, "-m", "quad_modelling.nodes.replay_node", "--ros-args", "-p", f"bag:={tmp_path}/nope"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "nope" in run.stderr and "no such bag" in run.stderr


def test_loop_passes_restamp_the_recorded_messages_by_one_bag_length(ros, tmp_path):
    log = synthetic_log(n=30)
    bag = write_bag(log, tmp_path / "bag")
    node = Node("loop_listener", namespace="/quad")
    got = {"motor": [], "odom": [], "imu": [], "clock": []}
    node.create_subscription(JointState, "motor_input", lambda m: got["motor"].append(m), data_qos())
    node.create_subscription(Odometry, "mocap/odom", lambda m: got["odom"].append(m), data_qos())
    node.create_subscription(Imu, "imu", lambda m: got["imu"].append(m), data_qos())
    node.create_subscription(Clock, "/clock", lambda m: got["clock"].append(m), data_qos())
    replay = subprocess.Popen(
        [sys.executable, "-m", "quad_modelling.nodes.replay_node", "--ros-args", "-p", f"bag:={bag}", "-p", "rate:=5.0",
         "-p", "loop:=true", "-p", "wait_for_subscribers:=1"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while min(map(len, got.values())) < 75 and replay.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        replay.terminate()
        replay.communicate(timeout=10)
    recorded = stamps_ns(log.t)
    pass_ns = int(recorded[-1] - recorded[0]) + 10_000_000  # one bag length + one 100 Hz period
    expected = [int(recorded[i % 30]) + (i // 30) * pass_ns for i in range(75)]
    assert [topics.stamp_ns(m.header.stamp) for m in got["motor"][:75]] == expected
    assert [topics.stamp_ns(m.header.stamp) for m in got["odom"][:75]] == expected
    assert [topics.stamp_ns(m.clock) for m in got["clock"][:75]] == expected
    for i in (0, 31, 64):  # later passes carry the recorded contents unchanged
        assert topics.odometry_fields(got["odom"][i]) == topics.odometry_fields(got["odom"][i % 30])
        assert list(got["motor"][i].effort) == log.u[i % 30].tolist()
    node.destroy_node()


def test_an_interrupted_replay_says_its_pass_was_cut_short(ros, tmp_path):
    """SIGINT in the middle of the bag: exit 0 and the summary counts the pass it was in, marked interrupted
    (it said "0 pass(es)": passes were counted only when finished)."""
    from test.ros.conftest import interrupted_node

    bag = write_bag(synthetic_log(n=1000), tmp_path / "bag")  # 10 s at 100 Hz, played in real time
    code, out = interrupted_node("quad_modelling.nodes.replay_node", ["-p", f"bag:={bag}", "-p", "rate:=1.0"],
                                 "replaying", settle_s=2.0)
    assert code == 0, out
    assert "in 1 pass(es) (the last interrupted)" in out, out
    published = int(out.split("published ")[1].split(" stamps")[0])
    assert 0 < published < 1000, out
