"""``predictor``: a streaming model run live on engine inputs (DESIGN 5a).

Subscribes (relative names, namespace ``/quad`` unless remapped):
``motor_input`` (sensor_msgs/JointState), ``mocap/odom`` (nav_msgs/Odometry),
``imu`` (sensor_msgs/Imu), optionally ``battery`` (sensor_msgs/BatteryState),
``window_origin`` (rosgraph_msgs/Clock, transient-local).
Publishes ``<model>/odom`` (nav_msgs/Odometry: pose in ``world`` ENU, twist in
``<model>/base_link`` FLU) and ``<model>/accel`` (geometry_msgs/AccelStamped in
``<model>/base_link`` FLU), one of each per engine input, stamped with the input's stamp.

Windows (:class:`~quad_modelling.core.windows.WindowClock`, the offline evaluation's clock): window k starts at
t0 + kW, t0 = the first motor-input stamp (or the ``window_origin`` another node
published). The first ``warm_s`` of each window are the warm start: those rows
(command + measurements with the same stamp) become a FlightLog, ``start_window``
gives their predictions, and every later command is ``push``-ed and its
prediction published immediately. The window starts as soon as the warm start
is over: at its last row by the clock (the next row, one sample period later,
falls past ``warm_s``), once that row's measurements are in -- so the start's
cost (1-3 ms) is paid between two inputs instead of delaying the first streamed
answer -- or at the first row past ``warm_s`` when the period is unknown or the
clock's guess was early (a warm row arriving after the start is reported and
predicted as a streamed one). The warm rows' predictions (0.2 s of rows,
available only once the warm start is complete) go to a backlog that is
published behind the live ones: :data:`WARM_BACKLOG_PER_INPUT` after each live
prediction, :data:`WARM_BACKLOG_PER_TICK` per timer tick in a pause of the inputs. Published
at once, 80 rows at 400 Hz held the next live inputs back by ~20-35 ms. A node that joins mid-window
(late start, restart, gap) waits for the next window start.

Faults (one warning per kind): non-finite or malformed messages are dropped;
out-of-order/duplicated stamps are dropped; warm rows without a measurement
(motion-capture gap) are left out, and a window without any is not predicted;
a model error or a non-finite prediction stops that window; nothing non-finite
is ever published.
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque

import numpy as np
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import BatteryState, Imu, JointState

from quad_modelling.core.models.streaming import prime, push_sample
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import WindowClock
from quad_modelling.errors import QuadModellingError
from quad_modelling.io import topics
from quad_modelling.nodes import messages
from quad_modelling.nodes.common import (
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
    realtime_param,
    run_node,
    say,
    set_realtime_priority,
    spin,
)
from quad_modelling.nodes.model_factory import make_streaming_predictor, model_name

WARM_BACKLOG_PER_INPUT = 1
"""Warm-start predictions published after each live prediction while a backlog remains (at 400 Hz, 2 per
input saturated the 2-core machine for the ~40 inputs of the drain: live latency rose to 11-18 ms)."""

WARM_BACKLOG_PER_TICK = 4
"""... and per tick of the backlog timer (every :data:`WARM_BACKLOG_PERIOD_S`) in a pause of the inputs."""

WARM_BACKLOG_PERIOD_S = 0.01

MEASUREMENT_WAIT_S = 0.5
"""Commands after the warm start are held back while warm rows' measurements are still in flight
(each topic is delivered on its own) for at most this long [wall s] after the first held command;
then the window starts from the complete rows (a motion-capture/IMU gap). A count bound of 10
commands was not enough: a replay at rate 0 with 200 samples in flight delivered motor inputs 20
rows ahead of the IMU, and a window went unpredicted."""

MAX_DEFERRED_COMMANDS = 4096
"""... and for at most this many commands (bounded memory)."""


def predictor_parameters(default_model: str) -> list[Param]:
    return [
        Param("model", default_model, "model spec: naive, greybox, greybox:euler, narx:PATH, hybrid:PATH", non_empty),
        Param("model_file", "", "model file appended to the spec as MODEL:FILE (e.g. the NARX .npz); empty = none"),
        Param("model_name", "", "topic prefix and name of the predictions (<model_name>/odom); empty = the spec's kind"),
        Param("vehicle", "crazyflie21", "vehicle config name (config/vehicles) or YAML path", non_empty),
        Param("window_s", 10.0, "window length W [s]; windows [t0 + kW, t0 + (k+1)W) from the first motor input", positive),
        Param("warm_s", 0.2, "warm start at each window start [s] (thesis 0.2 s)", positive),
        Param("sample_period_s", 0.0, "nominal sample period [s]; 0 = median of the first motor-input steps", non_negative),
        Param("motor_input_topic", "motor_input", "engine inputs (sensor_msgs/JointState)", non_empty),
        Param("odom_topic", "mocap/odom", "motion capture (nav_msgs/Odometry)", non_empty),
        Param("imu_topic", "imu", "IMU (sensor_msgs/Imu)", non_empty),
        Param("battery_topic", "", "battery voltage (sensor_msgs/BatteryState) for models that use it; empty = not subscribed"),
        Param("world_frame", topics.WORLD_FRAME, "frame_id of the predicted pose", non_empty),
        Param("qos_depth", 1000, "depth of the reliable keep-last subscriptions and publishers", positive),
        executor_param(),
        realtime_param(),
    ]


PRIME_SAMPLE_PERIOD_S = 0.01
"""Sample period [s] of the priming window when ``sample_period_s`` is 0 (unknown until data flows);
the one-time costs it pays do not depend on the rate."""


MAX_PENDING_MEASUREMENTS = 64
"""Serialised measurements held before decoding without waiting for a command (bounds memory when no
commands flow)."""


class PredictorNode(Node):
    """Generic live predictor; the model comes from the ``model`` parameter."""

    def __init__(self, node_name: str = "predictor", default_model: str = "naive", **kwargs):
        kwargs.setdefault("namespace", topics.DEFAULT_NAMESPACE)
        super().__init__(node_name, **kwargs)
        p = declare_parameters(self, predictor_parameters(default_model))
        if p["warm_s"] >= p["window_s"]:
            raise BadParameter(f"{node_name}: parameter warm_s={p['warm_s']} must be shorter than window_s={p['window_s']}")
        spec = f"{p['model']}:{p['model_file']}" if p["model_file"] else p["model"]
        self.name_ = p["model_name"] or model_name(spec)
        try:
            self.vehicle = load_vehicle(p["vehicle"])
            self.model = make_streaming_predictor(spec, self.vehicle)
        except QuadModellingError as err:
            raise BadParameter(f"{node_name}: parameter model={spec!r} vehicle={p['vehicle']!r}: {err}") from err
        self.spec = spec
        # pay the model's one-time costs now, not in the first window (streaming.prime)
        prime(self.model, self.vehicle, p["sample_period_s"] or PRIME_SAMPLE_PERIOD_S,
              int(round(p["warm_s"] / (p["sample_period_s"] or PRIME_SAMPLE_PERIOD_S))))
        self.executor_kind = p["executor"]
        self.realtime_priority = p["realtime_priority"]
        self.faults = FaultLog(self.get_logger())
        self.clock_ = WindowClock(p["window_s"], p["warm_s"], p["sample_period_s"])
        self.child_frame = f"{self.name_}/base_link"
        self.world_frame = p["world_frame"]
        self.out = messages.prediction_publisher_messages(self.child_frame, self.world_frame)
        qos = data_qos(p["qos_depth"])
        self.odom_pub = self.create_publisher(Odometry, f"{self.name_}/odom", qos)
        self.accel_pub = self.create_publisher(AccelStamped, f"{self.name_}/accel", qos)
        self.origin_pub = self.create_publisher(Clock, topics.ORIGIN_TOPIC, latched_qos())
        self.create_subscription(JointState, p["motor_input_topic"], self.on_motor, qos)
        # measurements arrive serialised and are decoded after the answer to the next command (_decode_pending)
        self.create_subscription(Odometry, p["odom_topic"], lambda data: self._receive(self.on_odom, Odometry, data), qos, raw=True)
        self.create_subscription(Imu, p["imu_topic"], lambda data: self._receive(self.on_imu, Imu, data), qos, raw=True)
        self.create_subscription(Clock, topics.ORIGIN_TOPIC, self.on_origin, latched_qos())
        self.use_battery = bool(p["battery_topic"])
        if self.use_battery:
            self.create_subscription(BatteryState, p["battery_topic"], self.on_battery, qos)
        # Bounded buffers: measurements by stamp for the warm rows, the warm rows themselves.
        self.pending: deque[tuple] = deque()  # serialised measurements not decoded yet (handler, type, bytes)
        self.measurement_capacity = 4096
        self.odom: OrderedDict[int, list] = OrderedDict()
        self.imu: OrderedDict[int, list] = OrderedDict()
        self.battery: OrderedDict[int, float] = OrderedDict()
        self.window = None  # current window index
        self.state = "idle"  # idle | warm | stream | skip
        self.warm_rows: list[tuple[int, np.ndarray, np.ndarray | None]] = []
        self.deferred: list[tuple[int, np.ndarray]] = []
        self.warm_closed = False  # the warm start of the current window is over (its last row is known)
        self.stream = None
        self.backlog: deque[tuple[int, np.ndarray, np.ndarray]] = deque()
        # runs only while a backlog or a held-back window start waits (a periodic timer would also be
        # what Ctrl-C interrupts)
        self.timer = self.create_timer(WARM_BACKLOG_PERIOD_S, self._on_timer, clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self.timer.cancel()
        self.deferred_since = 0.0
        self.last_motor_ns = None
        self.last_input_wall = 0.0
        self.published = 0
        self.windows_started = 0
        self.get_logger().info(f"predicting with {self.spec!r} as '{self.name_}' on vehicle {self.vehicle.name}; "
                               f"windows {p['window_s']:g} s, warm start {p['warm_s']:g} s")

    # --- inputs -------------------------------------------------------------------------------

    def on_origin(self, msg: Clock) -> None:
        ns = topics.stamp_ns(msg.clock)
        if self.clock_.origin_ns is None or ns < self.clock_.origin_ns:
            if self.clock_.origin_ns is not None:
                self.faults.report("origin_changed", f"window origin moved to an earlier t0 ({ns} ns): re-aligning windows")
                self.state, self.window = "idle", None
            self.clock_.origin_ns = ns

    def _store(self, buffer: OrderedDict, ns: int, value, kind: str) -> None:
        if ns in buffer:
            self.faults.report(f"duplicate_{kind}", f"duplicated {kind} stamp {ns} ns: later copy dropped")
            return
        buffer[ns] = value
        if len(buffer) > self.measurement_capacity:
            buffer.popitem(last=False)

    def _receive(self, handler, kind, data: bytes) -> None:
        self.pending.append((handler, kind, data))
        if len(self.pending) > MAX_PENDING_MEASUREMENTS or (self.state == "warm" and self.warm_closed):
            self._decode_pending()  # no commands to answer (or a start waits on them): decode now

    def _decode_pending(self) -> None:
        """Decode and store the measurements received since the last call (each checked as ``on_odom``/``on_imu``).

        Motion capture and IMU are needed only for the warm rows of the next window, so their
        deserialisation (Odometry ~55 µs, Imu ~27 µs here) waits until the current command is
        answered; it runs before any window start, after every command, and on the timer.
        """
        while self.pending:
            handler, kind, data = self.pending.popleft()
            try:
                msg = deserialize_message(data, kind)
            except Exception as err:  # noqa: BLE001 -- rclpy raises a bare RuntimeError/TypeError on bad CDR
                self.faults.report(f"bad_{kind.__name__.lower()}", f"undecodable {kind.__name__} message dropped: {err}")
                continue
            handler(msg)

    def on_odom(self, msg: Odometry) -> None:
        fields = topics.odometry_fields(msg)
        if not topics.all_finite(fields):
            self.faults.report("nan_odom", "non-finite motion-capture message dropped")
            return
        self._store(self.odom, topics.stamp_ns(msg.header.stamp), fields, "odom")
        if self.state == "warm" and self.warm_closed and not self.pending:
            self._maybe_start()

    def on_imu(self, msg: Imu) -> None:
        fields = topics.imu_fields(msg)
        if not topics.all_finite(fields):
            self.faults.report("nan_imu", "non-finite IMU message dropped")
            return
        self._store(self.imu, topics.stamp_ns(msg.header.stamp), fields, "imu")
        if self.state == "warm" and self.warm_closed and not self.pending:
            self._maybe_start()

    def on_battery(self, msg: BatteryState) -> None:
        if not np.isfinite(msg.voltage):
            self.faults.report("nan_battery", "non-finite battery voltage dropped")
            return
        self._store(self.battery, topics.stamp_ns(msg.header.stamp), float(msg.voltage), "battery")

    def on_motor(self, msg: JointState) -> None:
        ns = topics.stamp_ns(msg.header.stamp)
        fields = topics.motor_fields(msg)
        if fields is None or not np.isfinite(fields[0]).all():
            self.faults.report("bad_motor", "motor_input without 4 finite efforts dropped")
            return
        if self.last_motor_ns is not None and ns <= self.last_motor_ns:
            kind = "duplicate_motor" if ns == self.last_motor_ns else "out_of_order_motor"
            self.faults.report(kind, f"motor_input stamp {ns} ns is not after the previous one ({self.last_motor_ns} ns): dropped")
            return
        self.last_motor_ns = ns
        self.last_input_wall = time.monotonic()
        if self.clock_.origin_ns is None:
            self.clock_.origin_ns = ns
            self.origin_pub.publish(messages.clock_message(ns))
        self.clock_.observe(ns)
        if ns < self.clock_.origin_ns:
            self.faults.report("before_origin", "motor_input stamped before the window origin: dropped")
            return
        k, position = self.clock_.locate(ns)
        u, omega = fields
        if k != self.window:
            self._finish_window()
            self.window = k
            if self.clock_.is_warm(position):
                self.state, self.warm_rows, self.deferred, self.warm_closed = "warm", [], [], False
            else:
                self.state = "skip"
                self.faults.report("joined_mid_window", f"joined window {k} after its warm start: waiting for the next window")
        if self.state == "warm":
            if self.clock_.is_warm(position):
                self.warm_rows.append((ns, u, omega))
                if self.clock_.is_last_warm(position):
                    self._close_warm()
            else:
                self.deferred.append((ns, u))
                self._close_warm()
        elif self.state == "stream":
            if self.clock_.is_warm(position):
                self.faults.report("late_warm_row", f"window {self.window}: a warm-start row (t0 + {position / 1e9:.4f} s) came "
                                                    "after the window started (irregular sampling?): predicted as a streamed row")
            self._push(ns, u)
        self._decode_pending()

    # --- windows ------------------------------------------------------------------------------

    def _close_warm(self) -> None:
        """The warm start is over: start the window now, or once its rows' measurements are in."""
        if not self.warm_closed:
            self.warm_closed = True
            self.deferred_since = time.monotonic()
            self.timer.reset()  # re-checks the wait even if no message arrives
        self._maybe_start()

    def _finish_window(self) -> None:
        if self.state == "warm" and self.warm_rows:
            self._maybe_start(force=True)
        self.stream = None

    def _maybe_start(self, force: bool = False) -> None:
        """Start the window once every warm row has its measurements (or too long a wait)."""
        self._decode_pending()
        if self.state != "warm":  # a decoded measurement started it meanwhile
            return
        complete = [row for row in self.warm_rows if row[0] in self.odom and row[0] in self.imu
                    and (not self.use_battery or row[0] in self.battery)]
        waited = time.monotonic() - self.deferred_since if self.warm_closed else 0.0
        if len(complete) < len(self.warm_rows) and waited < MEASUREMENT_WAIT_S and len(self.deferred) <= MAX_DEFERRED_COMMANDS \
                and not force:
            return
        if len(complete) < len(self.warm_rows):
            self.faults.report("warm_gap", f"window {self.window}: {len(self.warm_rows) - len(complete)} warm-start rows have no "
                                           "measurement (motion-capture/IMU gap); starting from the complete ones")
        deferred, self.deferred = self.deferred, []
        self.state = "skip"
        if len(complete) < 2:
            self.faults.report("warm_empty", f"window {self.window}: fewer than 2 measured warm-start rows; window not predicted")
            return
        stamps = np.array([row[0] for row in complete], dtype=np.int64)
        omegas = [row[2] for row in complete]
        try:
            warm = topics.measurement_log(
                stamps, np.array([row[1] for row in complete]), np.array([self.odom[s] for s in stamps.tolist()]),
                np.array([self.imu[s] for s in stamps.tolist()]), self.vehicle.name, f"live window {self.window}",
                omega=np.array(omegas) if all(o is not None for o in omegas) else None,
                vbat=np.array([self.battery[s] for s in stamps.tolist()]) if self.use_battery else None,
            )
            predictions, self.stream = self.model.start_window(warm)
        except (QuadModellingError, ValueError) as err:
            self.faults.report("model_error", f"window {self.window}: model {self.name_} cannot start: {err}")
            return
        if not self._publish(stamps.tolist(), predictions, backlog=True):
            return
        self.state = "stream"
        self.windows_started += 1
        for ns, u in deferred:
            self._push(ns, u)

    def _push(self, ns: int, u: np.ndarray) -> None:
        try:
            prediction = push_sample(self.stream, u, float(topics.stamps_to_seconds(np.array([ns], dtype=np.int64))[0]))
        except (QuadModellingError, ValueError) as err:
            self.faults.report("model_error", f"window {self.window}: model {self.name_} failed: {err}")
            self.state = "skip"
            return
        if not self._publish([ns], prediction):
            self.state = "skip"
        self._publish_backlog(WARM_BACKLOG_PER_INPUT)

    def _publish(self, stamps: list[int], predictions: np.ndarray, backlog: bool = False) -> bool:
        """Publish predictions (N, 18) for ``stamps`` now, or queue them behind the live ones (``backlog``)."""
        predictions = np.atleast_2d(predictions)
        if not np.isfinite(predictions).all():
            self.faults.report("nan_prediction", f"window {self.window}: model {self.name_} predicted a non-finite value; "
                                                 "window abandoned (nothing non-finite is published)")
            return False
        odom, accel = topics.prediction_fields(predictions)
        if backlog:
            self.backlog.extend(zip(stamps, odom, accel))
            self.timer.reset()
            return True
        for i, ns in enumerate(stamps):
            self._send(ns, odom[i], accel[i])
        return True

    def _on_timer(self) -> None:
        """While a window waits for warm-row measurements or a warm backlog remains (else cancelled)."""
        self._decode_pending()
        if self.state == "warm" and self.warm_closed:
            self._maybe_start()
        if time.monotonic() - self.last_input_wall >= WARM_BACKLOG_PERIOD_S:  # else inputs are flowing: each drains its share
            self._publish_backlog(WARM_BACKLOG_PER_TICK)
        if not self.backlog and not (self.state == "warm" and self.warm_closed):
            self.timer.cancel()

    def _publish_backlog(self, count: int) -> None:
        for _ in range(min(count, len(self.backlog))):
            self._send(*self.backlog.popleft())

    def _send(self, ns: int, odom: np.ndarray, accel: np.ndarray) -> None:
        o, a = self.out.fill(ns, odom, accel)
        self.odom_pub.publish(o)
        self.accel_pub.publish(a)
        self.published += 1

    # --- lifecycle ----------------------------------------------------------------------------

    def run(self) -> None:
        executor = make_executor(self.executor_kind, self)
        if self.realtime_priority:
            refused = set_realtime_priority(self.realtime_priority)
            if refused:
                self.get_logger().warning(f"parameter realtime_priority={self.realtime_priority}: {refused}")
            else:
                self.get_logger().info(f"running under SCHED_FIFO priority {self.realtime_priority}")
        spin(self, executor)

    def finish(self) -> None:
        if self.context.ok():
            self._publish_backlog(len(self.backlog))
        say(self, f"published {self.published} predictions over {self.windows_started} windows; faults: {self.faults.summary()}")


def main(args=None) -> int:
    return run_node(lambda: PredictorNode("predictor", "naive"), args)


if __name__ == "__main__":
    raise SystemExit(main())
