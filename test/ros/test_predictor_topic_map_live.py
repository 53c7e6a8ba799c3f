"""Live through a topic map, the standard-type half (issue #27 item 3), over real DDS.

A user's stack publishing standard types on its own topics (commands sensor_msgs/JointState, the pose
geometry_msgs/PoseStamped and the body velocity geometry_msgs/TwistStamped on /user/..., the IMU sensor_msgs/Imu),
each stream at its own rate and phase, read by a predictor started with ``topic_map:=<user map YAML>``, gives the
predictions a predictor reading the project's contract gives for the same flight, published alongside.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import AccelStamped, PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, JointState

from quad_modelling.io import topics
from quad_modelling.io.bag_io import read_bag
from quad_modelling.nodes import messages
from quad_modelling.nodes.predictor_node import PredictorNode
from test.ros.test_predictor_live_streams import BAG, CHUNK_S, resampled, stream_stamps

XYZ = ("x", "y", "z")
USER_MAP = {
    "name": "user",
    "topics": {"/user/motors": {"type": "sensor_msgs/msg/JointState", "stamp": "header.stamp"},
               "/user/pose": {"type": "geometry_msgs/msg/PoseStamped", "stamp": "header.stamp"},
               "/user/twist": {"type": "geometry_msgs/msg/TwistStamped", "stamp": "header.stamp"},
               "/user/imu": {"type": "sensor_msgs/msg/Imu", "stamp": "header.stamp"}},
    "fields": {"commands": {"topic": "/user/motors", "fields": [f"effort[{i}]" for i in range(4)], "unit": "vehicle"},
               "position": {"topic": "/user/pose", "fields": [f"pose.position.{c}" for c in XYZ], "unit": "m", "frame": "ENU"},
               "attitude": {"topic": "/user/pose", "fields": [f"pose.orientation.{c}" for c in "xyzw"], "order": "xyzw",
                            "frame": "ENU/FLU"},
               "velocity": {"topic": "/user/twist", "fields": [f"twist.linear.{c}" for c in XYZ], "unit": "m/s", "frame": "FLU"},
               "acc": {"topic": "/user/imu", "fields": [f"linear_acceleration.{c}" for c in XYZ], "unit": "m/s2", "frame": "FLU"},
               "gyro": {"topic": "/user/imu", "fields": [f"angular_velocity.{c}" for c in XYZ], "unit": "rad/s", "frame": "FLU"}},
}
SAME_BOUND = 1e-9
"""Largest difference [m, m/s, rad/s] allowed between the two predictors' outputs: the same numbers through two frame
conversions (contract: quaternion rotation of the body twist; map: the Euler angles); measured: 0.0 (bit-identical)."""


def user_messages(kind: str, contract_msg):
    """The user's standard-type message(s) of one contract message: Odometry -> PoseStamped + TwistStamped."""
    if kind == "odom":
        return [("/user/pose", PoseStamped(header=contract_msg.header, pose=contract_msg.pose.pose)),
                ("/user/twist", TwistStamped(header=contract_msg.header, twist=contract_msg.twist.twist))]
    return [({"motor": "/user/motors", "imu": "/user/imu"}[kind], contract_msg)]


@pytest.mark.exclusive  # two predictors on their own real-time streams: the machine to itself under xdist
def test_a_user_map_of_standard_types_predicts_what_the_contract_predicts(ros, tmp_path):
    map_file = tmp_path / "user_map.yaml"
    map_file.write_text(yaml.safe_dump(USER_MAP))
    log = read_bag(BAG)
    rng = np.random.default_rng(27)
    t0, t1 = log.t[300], log.t[300] + 1.9  # two 0.8 s windows and the start of a third
    stamps = {"motor": stream_stamps(t0, t1, 100.0, 0.0, 0.002, rng), "odom": stream_stamps(t0 - 0.05, t1 + 0.05, 120.0, 0.00137, 0.0, rng),
              "imu": stream_stamps(t0 - 0.05, t1 + 0.05, 250.0, 0.00071, 0.0, rng)}
    arrays = {kind: messages.measurement_messages(resampled(log, t)) for kind, t in stamps.items()}
    make = {"motor": lambda i, s: arrays["motor"].motor(i, s), "odom": lambda i, s: arrays["odom"].odometry(i, s),
            "imu": lambda i, s: arrays["imu"].imu(i, s)}
    events = sorted((int(s), kind, i) for kind, t in stamps.items() for i, s in enumerate(topics.stamps_ns(t)))

    common = {"vehicle": "crazyflie21", "model": "greybox", "window_s": 0.8, "qos": "reliable"}
    contract = PredictorNode(parameter_overrides=[Parameter(k, value=v) for k, v in common.items()])
    mapped = PredictorNode(namespace="/mapped", parameter_overrides=[Parameter(k, value=v) for k, v in
                                                                      {**common, "topic_map": str(map_file)}.items()])
    stack = ros.create_node("user_stack")
    reliable = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=10000)
    types = {"motor_input": JointState, "mocap/odom": Odometry, "imu": Imu, "/user/motors": JointState,
             "/user/pose": PoseStamped, "/user/twist": TwistStamped, "/user/imu": Imu}
    pubs = {name: stack.create_publisher(kind, name if name.startswith("/") else f"/quad/{name}", reliable) for name, kind in types.items()}
    received = {"/quad": [], "/mapped": []}
    for ns in received:
        stack.create_subscription(Odometry, f"{ns}/greybox/odom", received[ns].append, reliable)
        stack.create_subscription(AccelStamped, f"{ns}/greybox/accel", received[ns].append, reliable)
    executor = SingleThreadedExecutor()
    for node in (stack, contract, mapped):
        executor.add_node(node)

    def spin(quiet: int = 8) -> None:
        idle = 0
        for _ in range(3000):
            before = len(received["/quad"]) + len(received["/mapped"]) + contract.published + mapped.published + len(contract.pending)
            executor.spin_once(timeout_sec=0.001)
            after = len(received["/quad"]) + len(received["/mapped"]) + contract.published + mapped.published + len(contract.pending)
            idle = idle + 1 if after == before else 0
            if idle >= quiet:
                return

    try:
        for _ in range(2000):
            if all(pub.get_subscription_count() > 0 for pub in pubs.values()) and \
                    all(stack.count_publishers(s.topic_name) > 0 for s in stack.subscriptions):
                break
            executor.spin_once(timeout_sec=0.005)
        contract_topic = {"motor": "motor_input", "odom": "mocap/odom", "imu": "imu"}
        start = 0
        while start < len(events):
            end = start
            while end < len(events) and events[end][0] - events[start][0] < CHUNK_S * 1e9:
                end += 1
            for s, kind, i in events[start:end]:
                msg = make[kind](i, s)
                pubs[contract_topic[kind]].publish(msg)
                for topic, user_msg in user_messages(kind, msg):
                    pubs[topic].publish(user_msg)
            spin()
            start = end
        deadline = time.monotonic() + 20.0  # under load the last messages can stall longer than a quiet spin
        while min(contract.windows_started, mapped.windows_started) < 3 and time.monotonic() < deadline:
            spin(quiet=30)
        spin(quiet=30)
    finally:
        executor.shutdown()
        for node in (stack, contract, mapped):
            node.destroy_node()

    def outputs(ns):
        odom = {topics.stamp_ns(m.header.stamp): topics.predicted_odometry_fields(m) for m in received[ns] if isinstance(m, Odometry)}
        accel = {topics.stamp_ns(m.header.stamp): topics.accel_fields(m) for m in received[ns] if isinstance(m, AccelStamped)}
        assert sorted(odom) == sorted(accel)
        return sorted(odom), np.array([odom[s] + accel[s] for s in sorted(odom)])

    (want_stamps, want), (got_stamps, got) = outputs("/quad"), outputs("/mapped")
    print(f"contract {len(want_stamps)} predictions, mapped {len(got_stamps)}; faults {contract.faults.summary()} / "
          f"{mapped.faults.summary()}; largest difference {np.abs(got - want).max() if got_stamps == want_stamps else 'n/a'}")
    assert contract.windows_started == mapped.windows_started == 3
    assert len(want_stamps) > 150 and got_stamps == want_stamps
    assert np.abs(got - want).max() <= SAME_BOUND
