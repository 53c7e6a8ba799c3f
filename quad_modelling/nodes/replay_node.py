"""``replay``: plays an MCAP bag's contract topics as recorded (DESIGN 5a).

The bag's serialised messages (:func:`quad_modelling.io.bag_io.read_recorded`:
``motor_input``, ``mocap/odom``, ``imu`` and ``battery`` when the bag has it) are
published unchanged, as CDR bytes (rclpy ``Publisher.publish(bytes)``), in header-stamp
order, all reliable keep-last: what a consumer receives is the recorded message, never a
conversion of it. A ``/clock`` (rosgraph_msgs/Clock) carrying the stamp precedes the
messages of every new stamp. Before the first message it publishes ``window_origin``
(transient-local) = the first played ``motor_input`` stamp, so every node cuts the
same windows (the offline reader's time base is the ``motor_input`` stamps too), and
``vehicle`` (std_msgs/String, transient-local) = the bag's vehicle (or the ``vehicle``
parameter), which nodes with an empty ``vehicle`` parameter adopt and others check.

Pacing: ``rate`` > 0 is a real-time factor (1 = as recorded). ``rate`` = 0 plays as
fast as the graph keeps up without loss: the evaluator acknowledges on
``evaluation/progress`` the last stamp every stream has delivered, and the replay
keeps at most ``max_in_flight`` stamps unacknowledged (far below the QoS depth, so
no reliable queue overflows). Without an acknowledging node (none within
``startup_timeout_s``, or silent for ``pace_timeout_s``) it warns once and plays in
real time instead. ``start_s``/``end_s`` select the messages whose stamps lie in
[t0 + start_s, t0 + end_s), t0 = the bag's first ``motor_input`` stamp.

``loop`` replays forever, shifting stamps by one bag length (+ one ``motor_input``
period) per pass so time keeps increasing. A shifted pass publishes the recorded bytes
with only the header stamp rewritten (:func:`quad_modelling.io.topics.cdr_restamped`:
the 8 stamp bytes after the CDR encapsulation header); the first pass is byte for byte
the bag. The node exits when done, after the acknowledgements reached the last stamp
(or ``pace_timeout_s``), announcing the end on ``replay/done`` (transient-local: the last
stamp played) and waiting up to :data:`DONE_ACK_S` for its readers' acknowledgements, so a
``run-bag`` on another host learns it even over a lossy link.
"""

from __future__ import annotations

import collections
import time

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

from quad_modelling.errors import QuadModellingError
from quad_modelling.io import topics
from quad_modelling.io.bag_io import read_bag_metadata, read_recorded
from quad_modelling.nodes import messages
from quad_modelling.nodes.common import (
    VEHICLE_TOPIC,
    BadParameter,
    FaultLog,
    Param,
    data_qos,
    history_qos,
    declare_parameters,
    executor_param,
    latched_qos,
    make_executor,
    non_empty,
    non_negative,
    positive,
    run_node,
    say,
    spin_once,
)

DONE_ACK_S = 5.0
"""How long [wall s] the replay waits for its ``replay/done`` readers to acknowledge the end before exiting."""

WAITED_TOPICS = ("motor_input", "mocap/odom", "imu")
"""The topics every predictor and the evaluator read: ``wait_for_subscribers`` counts each (the battery has fewer)."""

SETTLE_S = 0.5
"""Pause after the subscribers matched, before the first sample [s], so every reader is matched both ways."""

REPLAY_PARAMETERS = [
    Param("bag", "", "MCAP bag directory to play", non_empty),
    Param("bag_namespace", topics.DEFAULT_NAMESPACE, "namespace of the contract topics inside the bag", non_empty),
    Param("vehicle", "", "vehicle announced on topic vehicle (config name or YAML path); empty = the one the bag names"),
    Param("rate", 1.0, "real-time factor; 0 = as fast as the acknowledging evaluator keeps up, without loss", non_negative),
    Param("start_s", 0.0, "start offset into the bag [s]", non_negative),
    Param("end_s", -1.0, "end offset into the bag [s] (exclusive); < 0 = to the end"),
    Param("loop", False, "replay forever (stamps shifted by one bag length per pass)"),
    Param("publish_clock", True, "publish /clock with each sample's stamp (for use_sim_time nodes)"),
    Param("wait_for_subscribers", 0, "wait until motor_input, mocap/odom and imu each have this many matched subscribers "
          "before playing", non_negative),
    Param("max_in_flight", 100, "rate 0: samples published but not yet acknowledged at most", positive),
    Param("pace_timeout_s", 10.0, "rate 0: acknowledgements silent this long [wall s] -> play in real time", positive),
    Param("startup_timeout_s", 30.0, "wait this long [wall s] for subscribers and the first acknowledgement", positive),
    Param("qos_depth", 1000, "depth of the reliable keep-last publishers", positive),
    executor_param(),
]


def played_messages(recorded: list, start_s: float = 0.0, end_s: float = -1.0) -> list:
    """The messages of ``recorded`` (:func:`~quad_modelling.io.bag_io.read_recorded`, stamp order) one pass plays: those
    stamped in [t0 + start_s, t0 + end_s), t0 = the first ``motor_input`` stamp (``end_s`` < 0: to the end). What
    stamps before t0 (an IMU that started first) is not played."""
    t0 = next((m.stamp_ns for m in recorded if m.topic == "motor_input"), None)
    if t0 is None:
        return []
    start_ns = t0 + topics.stamps_ns(start_s).item()
    end_ns = t0 + topics.stamps_ns(end_s).item() if end_s >= 0 else None
    return [m for m in recorded if m.stamp_ns >= start_ns and (end_ns is None or m.stamp_ns < end_ns)]


def played_counts(bag: str, namespace: str = topics.DEFAULT_NAMESPACE) -> dict[str, int]:
    """Samples one pass of the whole ``bag`` plays per stream (``motor_input``, ``mocap_odom``, ``imu``, ``battery``,
    :data:`~quad_modelling.nodes.common.STREAMS`): what ``run-bag``'s replay sends, to compare with what its nodes
    received (docs/nodes.md, "Sample loss")."""
    counts = collections.Counter(m.topic for m in played_messages(read_recorded(bag, namespace=namespace)))
    return {key.replace("/", "_"): counts[key] for key in topics.MEASUREMENT_TOPICS if counts[key]}


class ReplayNode(Node):
    """Publishes one bag (see module doc); :meth:`run` plays it and returns when done."""

    def __init__(self, **kwargs):
        kwargs.setdefault("namespace", topics.DEFAULT_NAMESPACE)
        super().__init__("replay", **kwargs)
        p = declare_parameters(self, REPLAY_PARAMETERS)
        if p["end_s"] >= 0 and p["end_s"] <= p["start_s"]:
            raise BadParameter(f"replay: parameter end_s={p['end_s']} must be after start_s={p['start_s']} (or < 0 for the end)")
        try:
            recorded = read_recorded(p["bag"], namespace=p["bag_namespace"])
            self.vehicle = p["vehicle"].strip() or read_bag_metadata(p["bag"]).vehicle
        except QuadModellingError as err:
            raise BadParameter(f"replay: parameter bag={p['bag']!r}: {err}") from err
        motor_stamps = np.array([m.stamp_ns for m in recorded if m.topic == "motor_input"], dtype=np.int64)
        if motor_stamps.size == 0:
            raise BadParameter(f"replay: parameter bag={p['bag']!r}: topic motor_input has no messages")
        self.recorded = played_messages(recorded, p["start_s"], p["end_s"])
        played = np.array([m.stamp_ns for m in self.recorded if m.topic == "motor_input"], dtype=np.int64)
        duration_s = (motor_stamps[-1] - motor_stamps[0]) / 1e9
        if played.size < 2:
            raise BadParameter(f"replay: start_s={p['start_s']} / end_s={p['end_s']} leave {played.size} samples of a {duration_s:.2f} s bag")
        self.first_ns, self.last_ns = int(played[0]), max(m.stamp_ns for m in self.recorded)
        self.period_ns = int(np.median(np.diff(played)))
        self.stamp_count = len({m.stamp_ns for m in self.recorded})
        present = {m.topic for m in self.recorded}
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
        types = {key: messages.rclpy_message_class(msgtype) for key, msgtype in topics.MEASUREMENT_TOPICS.items()}
        self.publishers_ = {key: self.create_publisher(types[key], key, history_qos(p["qos_depth"]))  # qos:=replay readers
                            for key in topics.MEASUREMENT_TOPICS if key in present}
        self.motor_pub = self.publishers_["motor_input"]
        self.clock_pub = self.create_publisher(Clock, "/clock", qos) if self.publish_clock else None
        self.origin_pub = self.create_publisher(Clock, topics.ORIGIN_TOPIC, latched_qos())
        self.vehicle_pub = self.create_publisher(String, VEHICLE_TOPIC, latched_qos())
        self.done_pub = self.create_publisher(Clock, topics.DONE_TOPIC, latched_qos())
        if self.vehicle:
            self.vehicle_pub.publish(String(data=self.vehicle))  # latched: nodes started later learn it too
        else:
            self.faults.report("no_vehicle", f"the bag names no vehicle and parameter vehicle is empty: nothing announced on "
                                             f"topic {VEHICLE_TOPIC}; set the nodes' vehicle parameter")
        self.acked_ns: int | None = None
        self.ack_wall = time.monotonic()
        self.progress_sub = self.create_subscription(Clock, topics.PROGRESS_TOPIC, self.on_progress, data_qos(10))
        self.in_flight: collections.deque[int] = collections.deque()
        self.published = 0
        self.last_published_ns: int | None = None
        self.passes = 0
        self.completed_passes = 0
        self.play_started: float | None = None
        self.get_logger().info(f"replaying {p['bag']}: {len(self.recorded)} messages at {self.stamp_count} stamps, "
                               f"{(self.last_ns - self.first_ns) / 1e9:.2f} s, "
                               f"rate {'as fast as acknowledged' if self.rate == 0 else f'{self.rate:g}x'}{', looping' if self.loop else ''}")

    def on_progress(self, msg: Clock) -> None:
        ns = topics.stamp_ns(msg.clock)
        if self.acked_ns is None or ns > self.acked_ns:
            self.acked_ns = ns
            self.ack_wall = time.monotonic()
            while self.in_flight and self.in_flight[0] <= ns:
                self.in_flight.popleft()

    def _spin_once(self, timeout_s: float) -> None:
        spin_once(self.executor_, timeout_s)

    def _spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while rclpy.ok(context=self.context):
            left = end - time.monotonic()
            if left <= 0:
                return
            self._spin_once(left)

    def _unmatched(self) -> dict[str, int]:
        """The waited-for topics (:data:`WAITED_TOPICS` the bag has) with fewer than ``wait_for_subscribers`` matched
        subscribers, with their count: a reader matched late misses the first samples (volatile durability)."""
        counts = {key: self.publishers_[key].get_subscription_count() for key in WAITED_TOPICS if key in self.publishers_}
        return {key: n for key, n in counts.items() if n < self.wait_for}

    def _wait_startup(self) -> None:
        deadline = time.monotonic() + self.startup_timeout_s
        while self._unmatched() and time.monotonic() < deadline:
            self._spin_once(0.05)
        unmatched = self._unmatched()
        if unmatched:
            counts = ", ".join(f"{key} {n}" for key, n in unmatched.items())
            self.faults.report("subscribers", f"only {counts} of {self.wait_for} subscribers after "
                                              f"{self.startup_timeout_s:g} s; playing anyway")
        if self.rate == 0:
            while self.acked_ns is None and time.monotonic() < deadline:
                self._spin_once(0.05)
            if self.acked_ns is None:
                self._unpace(f"no acknowledgement on {topics.PROGRESS_TOPIC} within {self.startup_timeout_s:g} s (is an evaluator running?)")
        self._spin_for(SETTLE_S)

    def _unpace(self, why: str) -> None:
        self.faults.report("unpaced", f"{why}: playing in real time instead of rate 0")
        self.rate = 1.0
        self.in_flight.clear()

    def run(self) -> None:
        self.executor_ = make_executor(self.executor_kind, self)
        self._wait_startup()
        self.play_started = time.monotonic()
        shift = 0
        self.origin_pub.publish(messages.clock_message(self.first_ns))
        while rclpy.ok(context=self.context):
            self.passes += 1  # counted when started: an interrupted pass is one, said as such in finish()
            self._play_pass(shift)
            if rclpy.ok(context=self.context):  # not cut short by a shutdown (a signal raises out of it)
                self.completed_passes += 1
            if not self.loop:
                break
            shift += self.last_ns - self.first_ns + self.period_ns
        self._drain()
        if rclpy.ok(context=self.context) and self.last_published_ns is not None:
            self.done_pub.publish(messages.clock_message(self.last_published_ns))
            if self.done_pub.get_subscription_count() and not self.done_pub.wait_for_all_acked(Duration(seconds=DONE_ACK_S)):
                self.faults.report("done_unacknowledged", f"{topics.DONE_TOPIC} not acknowledged within {DONE_ACK_S:g} s")

    def _play_pass(self, shift: int) -> None:
        """Publish every recorded message once, stamps shifted by ``shift`` [ns] (restamped bytes when > 0)."""
        wall0 = time.monotonic()
        t0 = self.first_ns
        previous = None
        for message in self.recorded:
            recorded_ns = message.stamp_ns
            if recorded_ns != previous:  # a new stamp: pace, then /clock
                previous = recorded_ns
                ns = recorded_ns + shift
                if self.rate == 0:
                    while len(self.in_flight) >= self.max_in_flight:
                        self._spin_once(0.05)
                        if not rclpy.ok(context=self.context):
                            return
                        if self.progress_sub.get_publisher_count() == 0 or time.monotonic() - self.ack_wall > self.pace_timeout_s:
                            self._unpace(f"acknowledgements on {topics.PROGRESS_TOPIC} stopped")
                            wall0 = time.monotonic() - (recorded_ns - t0) / 1e9
                            break
                    self.in_flight.append(ns)
                else:
                    left = wall0 + (recorded_ns - t0) / 1e9 / self.rate - time.monotonic()
                    if left > 0:
                        self._spin_for(left)
                if not rclpy.ok(context=self.context):
                    return
                if self.clock_pub is not None:
                    self.clock_pub.publish(messages.clock_message(ns))
                self.published += 1
                self.last_published_ns = ns
                if self.rate == 0 and self.published % 8 == 0:
                    self._spin_once(0.0)
            self.publishers_[message.topic].publish(message.raw if shift == 0 else topics.cdr_restamped(message.raw, ns))

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
        interrupted = " (the last interrupted)" if self.passes > self.completed_passes else ""
        say(self, f"published {self.published} stamps in {self.passes} pass(es){interrupted} in {took:.2f} s "
                  f"({self.published / took if took > 0 else 0:.0f} samples/s); faults: {self.faults.summary()}")


def main(args=None) -> int:
    return run_node(ReplayNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
