"""No-op stand-in for a predictor: the latency floor of rclpy + Fast DDS on this machine.

Subscribes to the predictor's inputs (``/quad/motor_input``, ``/quad/mocap/odom``, ``/quad/imu``) with
the same QoS, executor and DDS profile as the nodes, and answers each motor input at once with an empty
``nav_msgs/Odometry`` carrying its stamp on ``/quad/<TOPIC>``. Whatever a predictor's latency adds to
this node's is the predictor's own cost.

Usage (bench_nodes starts it): python bench/echo_node.py TOPIC [REALTIME_PRIORITY]
"""

from __future__ import annotations

import gc
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from sensor_msgs.msg import Imu, JointState

    from quad_modelling.nodes.common import (
        MATH_THREADS,
        data_qos,
        limit_math_threads,
        make_executor,
        set_realtime_priority,
        spin,
        use_dds_profile,
    )

    topic, priority = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 0
    use_dds_profile()
    rclpy.init()
    node = Node("echo", namespace="/quad")
    qos = data_qos()
    publisher = node.create_publisher(Odometry, topic, qos)
    answer = Odometry()

    def on_motor(msg: JointState) -> None:
        answer.header.stamp = msg.header.stamp
        publisher.publish(answer)

    node.create_subscription(JointState, "motor_input", on_motor, qos)
    node.create_subscription(Odometry, "mocap/odom", lambda msg: None, qos)
    node.create_subscription(Imu, "imu", lambda msg: None, qos)
    executor = make_executor("events", node)
    limit_math_threads(MATH_THREADS)  # as the nodes do by default
    if priority and (refused := set_realtime_priority(priority)):
        print(f"echo_node: {refused}", file=sys.stderr)
        return 1
    gc.freeze()  # as run_node does
    try:
        spin(node, executor)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
