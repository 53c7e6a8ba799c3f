"""ROS test helpers: a DDS domain of this test process, in-process nodes, message capture."""

from __future__ import annotations

import os

import numpy as np
import pytest

from quad_modelling.nodes.domains import claim_domain

# Each test process talks in a domain no other process on this machine holds (a lock file per domain),
# on loopback only (DESIGN 3). Subprocesses started by the tests inherit it.
os.environ["ROS_DOMAIN_ID"] = str(claim_domain())
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


@pytest.fixture
def ros():
    """rclpy initialised for one test (in-process nodes); shut down after it."""
    import rclpy

    rclpy.init()
    yield rclpy
    rclpy.try_shutdown()


def in_process_evaluator(**values):
    """An EvaluatorNode built in this test process with ``values`` as its parameters, at niceness increment 0 unless
    given: the node raises its own process's niceness (parameter ``nice``, default 10) and in process that is the
    pytest worker's, for every later test on it (one of the two workers ran at nice 19 and yielded the CPU to the
    other's node subprocesses)."""
    from rclpy.parameter import Parameter

    from quad_modelling.nodes.evaluator_node import EvaluatorNode

    return EvaluatorNode(parameter_overrides=[Parameter(k, value=v) for k, v in {"nice": 0, **values}.items()])


class Capture:
    """Stands in for a publisher: keeps what a node publishes, by stamp.

    Keeps a serialised round trip of each message, as a real publisher sends the
    message's contents at ``publish`` (nodes may refill one message object), and
    reads serialized bytes, which a real publisher sends as they are, as
    ``message_type`` (the replaced publisher's ``msg_type``).
    """

    def __init__(self, message_type: type | None = None):
        self.messages, self.message_type = [], message_type

    def publish(self, msg) -> None:
        from rclpy.serialization import deserialize_message, serialize_message

        if isinstance(msg, bytes):
            self.messages.append(deserialize_message(msg, self.message_type))
        else:
            self.messages.append(deserialize_message(serialize_message(msg), type(msg)))

    def by_stamp(self) -> dict:
        from quad_modelling.io.topics import stamp_ns

        return {stamp_ns(m.header.stamp): m for m in self.messages}


def feed(node, log, rows, arrays=None, skip_odom=(), predictions=None, skip_imu=()):
    """Call the node's callbacks with the messages of ``log`` rows, as the replay publishes them
    (``skip_odom``/``skip_imu``: rows whose mocap/IMU message is left out)."""
    from quad_modelling.io.topics import stamps_ns
    from quad_modelling.nodes import messages

    arrays = arrays or messages.measurement_messages(log)
    stamps = stamps_ns(log.t)
    for row in rows:
        ns = int(stamps[row])
        node.on_motor(arrays.motor(row, ns))
        if row not in skip_odom:
            node.on_odom(arrays.odometry(row, ns))
        if row not in skip_imu:
            node.on_imu(arrays.imu(row, ns))
        if predictions is not None:
            for name, (odom, accel) in predictions.items():
                o, a = messages.prediction_messages(ns, odom[row], accel[row], f"{name}/base_link")
                node.on_pred_odom(name, o)
                node.on_pred_accel(name, a)
    return stamps


def hover_log(n: int = 2500, rate: float = 100.0, seed: int = 3):
    """A smooth synthetic flight (test.conftest.synthetic_log) long enough for 10 s windows."""
    from test.conftest import synthetic_log

    return synthetic_log(n=n, rate=rate, seed=seed)


__all__ = ["Capture", "feed", "hover_log", "np"]


def interrupted_node(module: str, params: list[str], ready: str, settle_s: float, timeout_s: float = 20.0) -> tuple[int, str]:
    """Run node ``module`` (``python -m``) with ``--ros-args`` ``params`` until a line holds ``ready``, let it spin
    ``settle_s``, send SIGINT; (exit code, everything it printed)."""
    import signal
    import subprocess
    import sys
    import time

    node = subprocess.Popen([sys.executable, "-m", module, "--ros-args", *params], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines = []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = node.stdout.readline()
        lines.append(line)
        if ready in line or not line:
            break
    time.sleep(settle_s)
    node.send_signal(signal.SIGINT)
    out = node.communicate(timeout=timeout_s)[0]
    return node.returncode, "".join(lines) + out
