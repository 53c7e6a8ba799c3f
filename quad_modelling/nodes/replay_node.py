"""``replay``: plays an MCAP bag's contract topics with their recorded stamps (DESIGN 5a).

The bag is read with :func:`quad_modelling.io.bag_io.read_bag` (one FlightLog on the
``motor_input`` time base; bags written by ``quad-modelling convert`` stamp every
topic with the same sample times) and published through
:mod:`quad_modelling.nodes.messages`: per sample ``/clock`` (rosgraph_msgs/Clock),
``motor_input``, ``mocap/odom``, ``imu`` and ``battery`` when the bag has it, all
reliable keep-last. Before the first sample it publishes ``window_origin``
(transient-local) = the first published stamp, so every node cuts the same windows.

Pacing: ``rate`` > 0 is a real-time factor (1 = as recorded). ``rate`` = 0 plays as
fast as the graph keeps up without loss: the evaluator acknowledges on
``evaluation/progress`` the last stamp every stream has delivered, and the replay
keeps at most ``max_in_flight`` samples unacknowledged (far below the QoS depth, so
no reliable queue overflows). Without an acknowledging node (none within
``startup_timeout_s``, or silent for ``pace_timeout_s``) it warns once and plays in
real time instead. ``loop`` replays forever, shifting stamps by one bag length (+ one
sample period) per pass so time keeps increasing. The node exits when done, after
the acknowledgements reached the last sample (or ``pace_timeout_s``).
"""

from __future__ import annotations

import collections
import time

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import BatteryState, Imu, JointState

from quad_modelling.errors import QuadModellingError
from quad_modelling.io.bag_io import DEFAULT_NAMESPACE as BAG_NAMESPACE
from quad_modelling.io.bag_io import read_bag, stamps_ns
from quad_modelling.nodes import messages
from quad_modelling.nodes.common import (
    DEFAULT_NAMESPACE,
    ORIGIN_TOPIC,
    PROGRESS_TOPIC,
    BadParameter,
    FaultLog,
    Param,
    data_qos,
    declare_parameters,
    executor_param,
    latched_qos,
    make_executor,
    non_empty,
    non_negative,
    positive,
    run_node,
    say,
)

SETTLE_S = 0.5
"""Pause after the subscribers matched, before the first sample [s], so every reader is matched both ways."""

REPLAY_PARAMETERS = [
    Param("bag", "", "MCAP bag directory to play", non_empty),
    Param("bag_namespace", BAG_NAMESPACE, "namespace of the contract topics inside the bag", non_empty),
    Param("vehicle", "", "vehicle config name when the bag names none (empty = the bag's)"),
    Param("rate", 1.0, "real-time factor; 0 = as fast as the acknowledging evaluator keeps up, without loss", non_negative),
    Param("start_s", 0.0, "start offset into the bag [s]", non_negative),
    Param("end_s", -1.0, "end offset into the bag [s] (exclusive); < 0 = to the end"),
    Param("loop", False, "replay forever (stamps shifted by one bag length per pass)"),
    Param("publish_clock", True, "publish /clock with each sample's stamp (for use_sim_time nodes)"),
    Param("wait_for_subscribers", 0, "wait until motor_input has this many matched subscribers before playing", non_negative),
    Param("max_in_flight", 100, "rate 0: samples published but not yet acknowledged at most", positive),
    Param("pace_timeout_s", 10.0, "rate 0: acknowledgements silent this long [wall s] -> play in real time", positive),
    Param("startup_timeout_s", 30.0, "wait this long [wall s] for subscribers and the first acknowledgement", positive),
    Param("qos_depth", 1000, "depth of the reliable keep-last publishers", positive),
    executor_param(),
]


class ReplayNode(Node):
    """Publishes one bag (see module doc); :meth:`run` plays it and returns when done."""

    def __init__(self, **kwargs):
        kwargs.setdefault("namespace", DEFAULT_NAMESPACE)
        super().__init__("replay", **kwargs)
        p = declare_parameters(self, REPLAY_PARAMETERS)
        if p["end_s"] >= 0 and p["end_s"] <= p["start_s"]:
            raise BadParameter(f"replay: parameter end_s={p['end_s']} must be after start_s={p['start_s']} (or < 0 for the end)")
        try:
            log = read_bag(p["bag"], vehicle=p["vehicle"] or None, namespace=p["bag_namespace"])
        except QuadModellingError as err:
            raise BadParameter(f"replay: parameter bag={p['bag']!r}: {err}") from err
        offset = log.t - log.t[0]
        rows = np.flatnonzero((offset >= p["start_s"]) & ((offset < p["end_s"]) if p["end_s"] >= 0 else True))
        if rows.size < 2:
            raise BadParameter(f"replay: start_s={p['start_s']} / end_s={p['end_s']} leave {rows.size} samples of a {log.duration:.2f} s bag")
        self.log = log.slice(int(rows[0]), int(rows[-1]) + 1)
        self.arrays = messages.MeasurementArrays(self.log)
        self.stamps = stamps_ns(self.log.t)
        self.rate = p["rate"]
        self.loop = p["loop"]
        self.publish_clock = p["publish_clock"]
        self.wait_for = p["wait_for_subscribers"]
        self.max_in_flight = p["max_in_flight"]
        self.pace_timeout_s = p["pace_timeout_s"]
        self.startup_timeout_s = p["startup_timeout_s"]
        self.executor_kind = p["executor"]
        self.executor_ = None  # made in run()
        self.faults = FaultLog(self.get_logger())
        qos = data_qos(p["qos_depth"])
        self.motor_pub = self.create_publisher(JointState, "motor_input", qos)
        self.odom_pub = self.create_publisher(Odometry, "mocap/odom", qos)
        self.imu_pub = self.create_publisher(Imu, "imu", qos)
        self.battery_pub = self.create_publisher(BatteryState, "battery", qos) if self.log.vbat is not None else None
        self.clock_pub = self.create_publisher(Clock, "/clock", qos) if self.publish_clock else None
        self.origin_pub = self.create_publisher(Clock, ORIGIN_TOPIC, latched_qos())
        self.acked_ns: int | None = None
        self.ack_wall = time.monotonic()
        self.progress_sub = self.create_subscription(Clock, PROGRESS_TOPIC, self.on_progress, data_qos(10))
        self.in_flight: collections.deque[int] = collections.deque()
        self.published = 0
        self.last_published_ns: int | None = None
        self.passes = 0
        self.play_started: float | None = None
        self.get_logger().info(f"replaying {p['bag']}: {len(self.log)} samples, {self.log.duration:.2f} s, "
                               f"rate {'as fast as acknowledged' if self.rate == 0 else f'{self.rate:g}x'}{', looping' if self.loop else ''}")

    def on_progress(self, msg: Clock) -> None:
        ns = messages.stamp_ns(msg.clock)
        if self.acked_ns is None or ns > self.acked_ns:
            self.acked_ns = ns
            self.ack_wall = time.monotonic()
            while self.in_flight and self.in_flight[0] <= ns:
                self.in_flight.popleft()

    def _spin_once(self, timeout_s: float) -> None:
        self.executor_.spin_once(timeout_sec=timeout_s)

    def _spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while rclpy.ok(context=self.context):
            left = end - time.monotonic()
            if left <= 0:
                return
            self._spin_once(left)

    def _wait_startup(self) -> None:
        deadline = time.monotonic() + self.startup_timeout_s
        while self.motor_pub.get_subscription_count() < self.wait_for and time.monotonic() < deadline:
            self._spin_once(0.05)
        if self.motor_pub.get_subscription_count() < self.wait_for:
            self.faults.report("subscribers", f"only {self.motor_pub.get_subscription_count()} of {self.wait_for} motor_input "
                                              f"subscribers after {self.startup_timeout_s:g} s; playing anyway")
        if self.rate == 0:
            while self.acked_ns is None and time.monotonic() < deadline:
                self._spin_once(0.05)
            if self.acked_ns is None:
                self._unpace(f"no acknowledgement on {PROGRESS_TOPIC} within {self.startup_timeout_s:g} s (is an evaluator running?)")
        self._spin_for(SETTLE_S)

    def _unpace(self, why: str) -> None:
        self.faults.report("unpaced", f"{why}: playing in real time instead of rate 0")
        self.rate = 1.0
        self.in_flight.clear()

    def run(self) -> None:
        self.executor_ = make_executor(self.executor_kind, self)
        self._wait_startup()
        self.play_started = time.monotonic()
        period_ns = int(np.median(np.diff(self.stamps)))
        shift = 0
        self.origin_pub.publish(messages.clock_message(int(self.stamps[0])))
        while rclpy.ok(context=self.context):
            self._play_pass(shift)
            self.passes += 1
            if not self.loop:
                break
            shift += int(self.stamps[-1] - self.stamps[0]) + period_ns
        self._drain()

    def _play_pass(self, shift: int) -> None:
        arrays, stamps = self.arrays, self.stamps
        wall0 = time.monotonic()
        rate = self.rate
        t0 = int(stamps[0])
        for row, ns in enumerate(stamps.tolist()):
            ns += shift
            if self.rate == 0:
                while len(self.in_flight) >= self.max_in_flight:
                    self._spin_once(0.05)
                    if not rclpy.ok(context=self.context):
                        return
                    if self.progress_sub.get_publisher_count() == 0 or time.monotonic() - self.ack_wall > self.pace_timeout_s:
                        self._unpace(f"acknowledgements on {PROGRESS_TOPIC} stopped")
                        wall0 = time.monotonic() - (ns - shift - t0) / 1e9
                        break
                self.in_flight.append(ns)
            else:
                if rate != self.rate:
                    rate = self.rate
                target = wall0 + (ns - shift - t0) / 1e9 / rate
                left = target - time.monotonic()
                if left > 0:
                    self._spin_for(left)
            if not rclpy.ok(context=self.context):
                return
            if self.clock_pub is not None:
                self.clock_pub.publish(messages.clock_message(ns))
            self.motor_pub.publish(arrays.motor(row, ns))
            self.odom_pub.publish(arrays.odometry(row, ns))
            self.imu_pub.publish(arrays.imu(row, ns))
            if self.battery_pub is not None:
                self.battery_pub.publish(arrays.battery(row, ns))
            self.published += 1
            self.last_published_ns = ns
            if self.rate == 0 and row % 8 == 0:
                self._spin_once(0.0)

    def _drain(self) -> None:
        """Wait for the acknowledgement of the last sample (when something acknowledges)."""
        if self.progress_sub.get_publisher_count() == 0 or self.last_published_ns is None:
            self._spin_for(0.5)  # let reliable writers deliver the tail
            return
        while rclpy.ok(context=self.context) and (self.acked_ns is None or self.acked_ns < self.last_published_ns):
            if time.monotonic() - self.ack_wall > self.pace_timeout_s:
                self.faults.report("tail_unacknowledged", "the last samples were not acknowledged in time")
                break
            self._spin_once(0.05)

    def finish(self) -> None:
        took = time.monotonic() - self.play_started if self.play_started else 0.0
        say(self, f"published {self.published} samples in {self.passes} pass(es) in {took:.2f} s "
                  f"({self.published / took if took > 0 else 0:.0f} samples/s); faults: {self.faults.summary()}")


def main(args=None) -> int:
    return run_node(ReplayNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
