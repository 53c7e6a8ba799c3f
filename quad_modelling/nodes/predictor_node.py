"""``predictor``: a streaming model run live on engine inputs (DESIGN 5a).

Subscribes (relative names, namespace ``/quad`` unless remapped):
``motor_input`` (sensor_msgs/JointState), ``mocap/odom`` (nav_msgs/Odometry),
``imu`` (sensor_msgs/Imu), optionally ``battery`` (sensor_msgs/BatteryState),
``window_origin`` (rosgraph_msgs/Clock, transient-local); with ``topic_map`` (not ``quad``), a stack's own
topics instead (:mod:`~quad_modelling.nodes.mapping.streams`, docs/nodes.md).
Publishes ``<model>/odom`` (nav_msgs/Odometry: pose in ``world`` ENU, twist in
``<model>/base_link`` FLU) and ``<model>/accel`` (geometry_msgs/AccelStamped in
``<model>/base_link`` FLU), one of each per engine input, stamped with the input's stamp.
Data subscriptions follow the ``qos`` parameter (best effort by default: reliable and
best-effort publishers both deliver). The vehicle is the ``vehicle`` parameter or, when
it is empty, the one a replay announces on ``vehicle`` (transient-local); the model is
built once it is known, and inputs before are dropped with one warning; a set vehicle
that differs from the announced one stops the node (exit 2).

Streams on their own clocks (issue #15; parameters and warnings: docs/nodes.md): motion capture, IMU and
battery are kept in :class:`~quad_modelling.core.alignment.MeasurementTrack` buffers and read at any command
stamp (exact, else interpolated, else the nearest within ``measurement_tolerance_s``); every stream's stamps
pass a :class:`~quad_modelling.core.alignment.StampGate` (single outliers dropped, a confirmed new time base
resets the stream; for motor inputs the windows, and one back before t0 moves the origin).

Windows (:class:`~quad_modelling.core.windows.WindowClock`, the offline evaluation's clock): window k starts at
t0 + kW, t0 = the first motor-input stamp (or the ``window_origin`` another node published). The commands of
the first ``warm_s`` are the warm rows, their measurements read from the tracks at the commands' stamps; every
later command is pushed (``push_at``: the model steps over the real interval) and its prediction published at
once. A window starts once every track holds a sample at or after its last warm row (else after
:data:`MEASUREMENT_WAIT_S`); the warm rows' predictions are then published in stamp order, so stamps strictly
increase on every output topic. A node that joins mid-window waits for the next window start. A prediction
beyond the vehicle's :class:`~quad_modelling.core.models.bounds.PhysicalBounds` abandons the window
(``out_of_bounds``): nothing beyond them, and nothing non-finite, is published.

Receding-horizon mode (``horizon_s`` > 0, instead of windows): h = round(horizon_s / dt) steps; anchor s gets
the model's multi-step form (:func:`~quad_modelling.core.evaluation.multistep.multistep_form`) over the rows up to
s, h steps ahead, on ``<model>/horizon/odom`` (:class:`~quad_modelling.core.models.streaming.RecedingHorizon`):
its anchor carried from input to input (:func:`~quad_modelling.core.live.forms.carried_forecast`), or for a
model without a carried form re-run over the last ``horizon_history_s`` of rows. ``horizon_inputs``: ``hold`` (default, the
forecast) flies u_s held, published at input s, stamped t_s + h dt; ``flown`` flies the recorded commands,
published at input s+h, stamped t_{s+h}: equal to the offline multi-step prediction, too late to be a forecast.

Faults (one warning per kind, then counted; per stream ``<kind>_<stream>`` of the one vocabulary
:data:`~quad_modelling.nodes.common.STREAM_FAULTS`, as the evaluator's): non-finite or malformed messages and zero
quaternions are dropped; warm rows without a measurement within tolerance are left out (fewer than 2: the window is
not predicted); a model error or a non-finite prediction stops the window."""

from __future__ import annotations

import time
from collections import deque

import numpy as np
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import BatteryState, Imu, JointState
from std_msgs.msg import String

from quad_modelling.core.alignment import MeasurementTrack, Stamp, StampGate, usable_voltage
from quad_modelling.core.evaluation.multistep import multistep_form
from quad_modelling.core.live.forms import carried_forecast, compiled_window_stream, prepare_compiled_step
from quad_modelling.core.models.bounds import PhysicalBounds
from quad_modelling.core.models.registry import baseline_name_clash
from quad_modelling.core.models.streaming import MAX_LIVE_HORIZON_STEPS, RecedingHorizon, prime, push_sample
from quad_modelling.core.windows import WindowClock, seconds_to_ns
from quad_modelling.errors import QuadModellingError
from quad_modelling.io import topics
from quad_modelling.nodes import messages
from quad_modelling.nodes.common import (  # the one stream naming and fault vocabulary (stream_fault)
    BATTERY, IMU, MOCAP_ODOM, MOTOR_INPUT, STREAMS, VEHICLE_TOPIC, BadParameter, FaultLog, StreamTally, VehicleSource,
    adopt_vehicle, declare_parameters, history_qos, latched_qos, limit_math_threads, make_executor, run_node, say,
    set_realtime_priority, spin, stream_fault, subscription_qos, zero_quaternion,
)
from quad_modelling.nodes.mapping.streams import MEASURED_FIELDS, MappedStreams, live_topic_map, subscribe
from quad_modelling.nodes.model_factory import (  # noqa: F401  (predictor_parameters re-exported)
    check_spec_without_vehicle,
    make_streaming_predictor,
    model_name,
    predictor_parameters,
)

MEASUREMENT_WAIT_S = 0.5
"""A window start waits for every track to hold a sample at or after its last warm row (each topic is
delivered on its own) for at most this long [wall s] after the warm start closed; then it starts from
the rows the tracks give (nearest within tolerance, or left out: a motion-capture/IMU gap)."""

WAIT_TIMER_PERIOD_S = 0.01
"""Period [wall s] of the timer that re-checks a waiting window start when no message arrives."""

MAX_DEFERRED_COMMANDS = 4096
"""Commands held back while a window start waits (bounded memory)."""


PRIME_SAMPLE_PERIOD_S = 0.01
"""Sample period [s] of the priming window when ``sample_period_s`` is 0 (unknown until data flows);
the one-time costs it pays do not depend on the rate."""


MAX_PENDING_MEASUREMENTS = 64
"""Serialised measurements held before decoding without waiting for a command (bounds memory when no
commands flow)."""

TRACK_CAPACITY = 4096
"""Samples kept per measurement stream (4 s of a 1 kHz IMU)."""

class PredictorNode(Node):
    """Generic live predictor; the model comes from the ``model`` parameter."""

    def __init__(self, node_name: str = "predictor", default_model: str = "naive", **kwargs):
        kwargs.setdefault("namespace", topics.DEFAULT_NAMESPACE)
        super().__init__(node_name, **kwargs)
        p = declare_parameters(self, predictor_parameters(default_model))
        if p["warm_s"] >= p["window_s"]:
            raise BadParameter(f"{node_name}: parameter warm_s={p['warm_s']} must be shorter than window_s={p['window_s']}")
        if p["sample_period_s"] and p["horizon_s"] / p["sample_period_s"] > MAX_LIVE_HORIZON_STEPS:
            raise BadParameter(f"{node_name}: parameters horizon_s={p['horizon_s']} and sample_period_s={p['sample_period_s']} "
                               f"make {p['horizon_s'] / p['sample_period_s']:.0f} steps, more than {MAX_LIVE_HORIZON_STEPS}")
        spec = f"{p['model']}:{p['model_file']}" if p["model_file"] else p["model"]
        self.name_ = p["model_name"] or model_name(spec)
        clash = baseline_name_clash(self.name_, p["model"])  # a naive predictor named dummy filled the zero baseline's rows
        if clash:
            raise BadParameter(f"{node_name}: parameter model_name={self.name_!r}: {clash}")
        self.spec = spec
        self.sample_period_s, self.warm_s = p["sample_period_s"], p["warm_s"]
        self.horizon_s, self.horizon_history_s = p["horizon_s"], p["horizon_history_s"]
        self.horizon_inputs = p["horizon_inputs"]
        self.model = None
        self.bounds = None
        self.horizon = None  # receding-horizon mode, built with the model (it needs the model's multi-step form)
        self.use_battery = bool(p["battery_topic"])
        self.vehicles = VehicleSource(self.get_name(), p["vehicle"])
        if self.vehicles.vehicle is not None:
            self._build_model()
        else:
            try:
                check_spec_without_vehicle(spec)
            except QuadModellingError as err:
                raise BadParameter(f"{node_name}: parameter model={spec!r}: {err}") from err
        self.executor_kind = p["executor"]
        self.realtime_priority, self.math_threads = p["realtime_priority"], p["math_threads"]
        self.faults = FaultLog(self.get_logger())
        self.tally = StreamTally()  # messages received per stream, in the exit summary (run-bag reads them)
        self.clock_ = WindowClock(p["window_s"], p["warm_s"], p["sample_period_s"])
        self.child_frame = f"{self.name_}/base_link"
        self.world_frame = p["world_frame"]
        self.out = messages.SerializedPredictions(self.child_frame, self.world_frame)  # bytes rclpy publishes as they are
        out_qos, qos = history_qos(p["qos_depth"]), subscription_qos(p["qos"], p["qos_depth"])
        if self.horizon_s > 0:
            self.horizon_pub = self.create_publisher(Odometry, f"{self.name_}/horizon/odom", out_qos)
        else:
            self.odom_pub = self.create_publisher(Odometry, f"{self.name_}/odom", out_qos)
            self.accel_pub = self.create_publisher(AccelStamped, f"{self.name_}/accel", out_qos)
        self.origin_pub = self.create_publisher(Clock, topics.ORIGIN_TOPIC, latched_qos())
        self.create_subscription(String, VEHICLE_TOPIC, self.on_vehicle, latched_qos())
        # Measurement streams, each on its own clock: read at any command stamp (core.alignment).
        self.tolerance_ns = seconds_to_ns(p["measurement_tolerance_s"])
        gap_ns, step_ns = seconds_to_ns(p["measurement_gap_s"]), seconds_to_ns(p["max_stamp_step_s"])
        self.pending: deque[tuple] = deque()  # serialised measurements not decoded yet (handler, type, bytes)
        self.odom = MeasurementTrack(topics.ODOM_FIELDS, gap_ns, TRACK_CAPACITY, quaternion=topics.ODOM_QUATERNION)
        self.imu = MeasurementTrack(topics.IMU_FIELDS, gap_ns, TRACK_CAPACITY)
        self.battery = MeasurementTrack(1, gap_ns, TRACK_CAPACITY)
        self.tracks = [self.odom, self.imu] + ([self.battery] if self.use_battery else [])
        self.track_of = {MOCAP_ODOM: self.odom, IMU: self.imu, BATTERY: self.battery}
        self.gates = {name: StampGate(step_ns) for name in STREAMS}
        topic_map, self.mapped = live_topic_map(p["topic_map"], node_name), None
        if topic_map is None:  # the contract; each message counted as it arrives (self.tally)
            count = self.tally.counting
            self.create_subscription(JointState, p["motor_input_topic"], count(MOTOR_INPUT, self.on_motor), qos)
            # measurements arrive serialised and are decoded after the answer to the next command (_decode_pending)
            self.create_subscription(Odometry, p["odom_topic"], count(MOCAP_ODOM, lambda data: self._receive(self.on_odom, Odometry, MOCAP_ODOM, data)), qos, raw=True)
            self.create_subscription(Imu, p["imu_topic"], count(IMU, lambda data: self._receive(self.on_imu, Imu, IMU, data)), qos, raw=True)
            if self.use_battery:
                self.create_subscription(BatteryState, p["battery_topic"], count(BATTERY, self.on_battery), qos)
        else:  # a stack's own topics (nodes.mapping.streams): the offline reader's conversion
            fields = [*MEASURED_FIELDS, *(["battery"] if self.use_battery else [])]
            self.mapped = MappedStreams(topic_map, fields, gap_ns, TRACK_CAPACITY, f"{node_name}: topic_map {topic_map.name}")
            subscribe(self, self.mapped, qos, self.on_mapped, self.tally.counting)
            self.tracks = list(self.mapped.tracks.values())
            self.gates.update({topic: StampGate(step_ns) for topic in self.mapped.readers})
            self.get_logger().info(f"topic map {topic_map.name} ({topic_map.origin}): {self.mapped.describe()}")
        self.create_subscription(Clock, topics.ORIGIN_TOPIC, self.on_origin, latched_qos(reader=True))
        self.window = None  # current window index
        self.state = "idle"  # idle | warm | stream | skip
        self.warm_rows: list[tuple[int, np.ndarray, np.ndarray | None]] = []
        self.deferred: list[tuple[int, np.ndarray]] = []
        self.warm_closed = False  # the warm start of the current window is over (its last row is known)
        self.stream = None
        self.anchor: tuple[int, np.ndarray] | None = None  # (stamp, prediction) of the window's anchor row
        # runs only while a window start waits for measurements (a periodic timer would also be what Ctrl-C interrupts)
        self.timer = self.create_timer(WAIT_TIMER_PERIOD_S, self._on_timer, clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self.timer.cancel()
        self.deferred_since = 0.0
        self.last_published_ns = None
        self.published = 0
        self.windows_started = 0
        mode = (f"receding horizon {self.horizon_s:g} s ({self.horizon_inputs} inputs) on {self.name_}/horizon/odom"
                if self.horizon_s > 0
                else f"windows {p['window_s']:g} s, warm start {p['warm_s']:g} s")
        self.get_logger().info(f"predicting with {self.spec!r} as '{self.name_}' on vehicle "
                               f"{f'{self.vehicle.name} ({self.vehicle.path})' if self.vehicle else '(from the replay, topic ' + VEHICLE_TOPIC + ')'}; "
                               f"{mode}, {p['qos']} subscriptions")

    @property
    def vehicle(self):
        return self.vehicles.vehicle

    def _build_model(self) -> None:
        """The streaming model of the spec on the vehicle, primed (one-time costs paid now, not in the first window)."""
        try:
            self.model = make_streaming_predictor(self.spec, self.vehicle)
            self.bounds = PhysicalBounds.from_vehicle(self.vehicle)
        except QuadModellingError as err:
            raise BadParameter(f"{self.get_name()}: parameter model={self.spec!r} vehicle={self.vehicle.name!r}: {err}") from err
        period = self.sample_period_s or PRIME_SAMPLE_PERIOD_S
        prime(self.model, self.vehicle, period, int(round(self.warm_s / period)))
        prepare_compiled_step(self.model, self.vehicle, self.horizon_s > 0)  # the compiled step: built now, not live
        if self.horizon_s > 0:
            self.horizon = RecedingHorizon(lambda warm: multistep_form(self.model, warm), self._rows_log, self.horizon_s,
                                           self.warm_s, self.horizon_history_s, self.sample_period_s, MEASUREMENT_WAIT_S,
                                           self.horizon_inputs,
                                           lambda period, steps: carried_forecast(self.model, self.vehicle, period, steps),
                                           ends_only=True)

    # --- inputs -------------------------------------------------------------------------------

    def on_vehicle(self, msg: String) -> None:
        adopt_vehicle(self, self.vehicles, msg.data, self._build_model)

    def on_origin(self, msg: Clock) -> None:
        ns = topics.stamp_ns(msg.clock)
        if self.clock_.origin_ns is None or ns < self.clock_.origin_ns:
            if self.clock_.origin_ns is not None:
                self.faults.report("origin_changed", f"window origin moved to an earlier t0 (t = {ns / 1e9:.6f} s): re-aligning windows")
                self.state, self.window = "idle", None
            self.clock_.origin_ns = ns

    def _gate(self, stream: str, ns: int, fields=None) -> bool:
        """Pass a stamp through the stream's gate (core.alignment); False when the sample is not to be used.
        A measurement stream's jump keeps the run of samples that confirmed it (stored here, ``fields`` last)."""
        gate = self.gates[stream]
        verdict = gate.admit(ns, (ns, fields))
        for dropped in gate.dropped:
            self.faults.report(stream_fault("stamp_outlier", stream), f"{stream} stamp t = {dropped / 1e9:.6f} s off the stream's time (a duplicate, "
                                                          "back in time, or beyond max_stamp_step_s ahead): dropped")
        if verdict is Stamp.SUSPECT:
            return False
        if verdict is Stamp.JUMPED:
            self.faults.report(stream_fault("clock_jump", stream), f"{stream} stamps jumped to a new time base at t = {ns / 1e9:.6f} s "
                                                          "(restarted publisher, clock jump or a long gap): its buffer restarts")
            if stream == MOTOR_INPUT:
                self._reset_time_base(ns)
            elif self.mapped is not None:
                self.mapped.clear(stream)
                for stamp, values in gate.confirmed[:-1]:
                    self.mapped.store(stamp, values)
            else:
                track = self.track_of[stream]
                track.clear()
                for stamp, values in gate.confirmed[:-1]:
                    track.add(stamp, values)
        return True

    def _reset_time_base(self, ns: int) -> None:
        """Motor-input stamps jumped: forget the windows, the buffers and the last published stamp; a jump back
        before t0 makes the new stamp the origin (published on ``window_origin``)."""
        self._finish_window(force=False)
        self.state, self.window, self.warm_rows, self.deferred = "idle", None, [], []
        self.last_published_ns = None
        if self.horizon is not None:
            self.horizon.reset()
        for track in self.tracks:
            track.clear()
        if self.clock_.origin_ns is not None and ns < self.clock_.origin_ns:
            self.clock_.origin_ns = ns
            self.origin_pub.publish(messages.clock_message(ns))

    def _receive(self, handler, kind, stream: str, data: bytes) -> None:
        self.pending.append((handler, kind, stream, data))
        if len(self.pending) > MAX_PENDING_MEASUREMENTS or (self.state == "warm" and self.warm_closed) or \
                (self.horizon is not None and self.horizon.waiting()):
            self._decode_pending()  # no commands to answer (or a start or horizon anchor waits on them): decode now

    def _decode_pending(self) -> None:
        """Decode and store the measurements received since the last call (each checked as ``on_odom``/``on_imu``).

        Motion capture and IMU are needed only for the warm rows of the next window, so their
        deserialisation (Odometry ~55 µs, Imu ~27 µs here) waits until the current command is
        answered; it runs before any window start, after every command, and on the timer.
        """
        while self.pending:
            handler, kind, stream, data = self.pending.popleft()
            try:
                msg = deserialize_message(data, kind)
            except Exception as err:  # noqa: BLE001 -- rclpy raises a bare RuntimeError/TypeError on bad CDR
                self.faults.report(stream_fault("bad", stream), f"undecodable {kind.__name__} message dropped: {err}")
                continue
            handler(msg)

    def _measured(self) -> None:
        """A measurement was stored: a waiting window start or horizon anchor may proceed."""
        if self.state == "warm" and self.warm_closed and not self.pending:
            self._maybe_start()
        if self.horizon is not None and not self.pending:
            self._publish_horizons()

    def on_odom(self, msg: Odometry) -> None:
        fields = topics.odometry_fields(msg)
        messages.check_odometry_frames(self.faults, msg)
        if messages.dropped(self.faults, MOCAP_ODOM, fields, "motion-capture message") or zero_quaternion(self.faults, fields):
            return
        ns = topics.stamp_ns(msg.header.stamp)
        if self._gate(MOCAP_ODOM, ns, fields):
            self._store(self.odom, ns, fields, MOCAP_ODOM)
            self._measured()

    def on_imu(self, msg: Imu) -> None:
        fields = topics.imu_fields(msg)
        if messages.dropped(self.faults, IMU, fields, "IMU message"):
            return
        ns = topics.stamp_ns(msg.header.stamp)
        if self._gate(IMU, ns, fields):
            self._store(self.imu, ns, fields, IMU)
            self._measured()

    def on_battery(self, msg: BatteryState) -> None:
        if not usable_voltage(msg.voltage):
            kind, what = ("nan", "non-finite") if not np.isfinite(msg.voltage) else ("range", "at or below 0 V (not connected)")
            self.faults.report(stream_fault(kind, BATTERY), f"battery voltage {what} dropped")
            return
        ns = topics.stamp_ns(msg.header.stamp)
        if self._gate(BATTERY, ns, [msg.voltage]):
            self._store(self.battery, ns, [msg.voltage], BATTERY)
            self._measured()

    def _store(self, track: MeasurementTrack, ns: int, fields, stream: str) -> None:
        if not track.add(ns, fields):
            self.faults.report(stream_fault("duplicate", stream), f"duplicated {stream} stamp t = {ns / 1e9:.6f} s: later copy dropped")

    def on_mapped(self, topic: str, msg) -> None:
        """A message of a ``topic_map`` topic (:mod:`~quad_modelling.nodes.mapping.streams`): its measurements stored,
        its commands (in the vehicle's unit) handled as a ``motor_input``."""
        read = self.mapped.admit(topic, msg, self.faults)
        if read is None:
            return  # another instance of a multi-instance topic, or a fault (reported)
        ns, fields = read
        measured = {f: v for f, v in fields.items() if f != "commands"}
        if measured and self._gate(topic, ns, measured):
            if not self.mapped.store(ns, measured):
                self.faults.report(stream_fault("duplicate", topic), f"duplicated {topic} stamp t = {ns / 1e9:.6f} s: later copy dropped")
            self._measured()
        if "commands" in fields:
            self.on_command(ns, self.mapped.command(fields["commands"], self.vehicle) if self.model else None, None)

    def on_motor(self, msg: JointState) -> None:
        fields = topics.motor_fields(msg)
        if self.model is not None and (fields is None or not np.isfinite(fields[0]).all()):
            self.faults.report(stream_fault("bad" if fields is None else "nan", MOTOR_INPUT), "motor_input without 4 finite efforts dropped")
            return
        self.on_command(topics.stamp_ns(msg.header.stamp), *(fields or (None, None)))

    def on_command(self, ns: int, u: np.ndarray, omega: np.ndarray | None) -> None:
        """One engine input: stamp [ns], command (4,) in the vehicle's unit, rotor speeds (4,) or None."""
        if self.model is None:
            self.faults.report("no_vehicle", f"no vehicle yet: motor_input dropped until a replay announces one on topic "
                                             f"{VEHICLE_TOPIC} (or set parameter vehicle)")
            return
        if u is not None and (u := messages.admitted_command(self.faults, self.vehicle, u)) is None:  # clipped, or impossible
            return
        if not self._gate(MOTOR_INPUT, ns):
            return
        if self.clock_.origin_ns is None:
            self.clock_.origin_ns = ns
            self.origin_pub.publish(messages.clock_message(ns))
        self.clock_.observe(ns)
        if ns < self.clock_.origin_ns:
            self.faults.report("before_origin", "motor_input stamped before the window origin: dropped")
            return
        if self.horizon is not None:
            fault = self.horizon.add(ns, u, omega)
            if fault and fault[0] == "no_multistep_form":
                self.faults.report("no_multistep_form", f"model {self.name_} {fault[1]}")
            elif fault:  # a period too short or an h too long (a burst of inputs): measured again
                self.faults.report("horizon_period", fault[1])
            if self.horizon.inputs == "hold":
                self._decode_pending()  # this input is the anchor: the measurements received before it are needed now
            self._publish_horizons()
            self._decode_pending()
            return
        k, position = self.clock_.locate(ns)
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

    def _finish_window(self, force: bool = True) -> None:
        if force and self.state == "warm" and self.warm_rows:
            self._maybe_start(force=True)
        self.stream = None

    def _row_measurements(self, ns: int):
        """(odometry fields, imu fields, battery voltage or None) at a command stamp, or None when a stream has none;
        with a topic map, every field's numbers (:meth:`~quad_modelling.nodes.mapping.streams.MappedStreams.at`)."""
        if self.mapped is not None:
            return self.mapped.at(ns, self.tolerance_ns)
        odom, imu = self.odom.at(ns, self.tolerance_ns), self.imu.at(ns, self.tolerance_ns)
        battery = self.battery.at(ns, self.tolerance_ns) if self.use_battery else None
        if odom is None or imu is None or (self.use_battery and battery is None):
            return None
        return odom, imu, None if battery is None else float(battery[0])

    def _rows_log(self, stamps: np.ndarray, rows: list, measured: list, source: str = "live receding horizon"):
        """Command rows (stamp, command, rotor speeds) and their measurements (:meth:`_row_measurements`) -> FlightLog."""
        omegas = [row[2] for row in rows]
        if self.mapped is not None:
            return self.mapped.rows_log(stamps, np.array([row[1] for row in rows]), measured, self.vehicle.name, source)
        return topics.measurement_log(
            stamps, np.array([row[1] for row in rows]), np.array([m[0] for m in measured]), np.array([m[1] for m in measured]),
            self.vehicle.name, source, omega=np.array(omegas) if all(o is not None for o in omegas) else None,
            vbat=np.array([m[2] for m in measured]) if self.use_battery else None,
        )

    def _maybe_start(self, force: bool = False) -> None:
        """Start the window once every track covers its last warm row (or too long a wait)."""
        self._decode_pending()
        if self.state != "warm":  # a decoded measurement started it meanwhile
            return
        last = self.warm_rows[-1][0] if self.warm_rows else None
        covered = last is None or all(track.covers(last) for track in self.tracks)
        waited = time.monotonic() - self.deferred_since if self.warm_closed else 0.0
        if not covered and waited < MEASUREMENT_WAIT_S and len(self.deferred) <= MAX_DEFERRED_COMMANDS and not force:
            return
        rows = [(row, self._row_measurements(row[0])) for row in self.warm_rows]
        complete = [(row, m) for row, m in rows if m is not None]
        if len(complete) < len(rows):  # name the streams without a sample near the first such row (a gap, or none yet)
            ns = next(row[0] for row, m in rows if m is None)
            tracks = self.mapped.tracks if self.mapped is not None else {n: t for n, t in self.track_of.items() if n != BATTERY or self.use_battery}
            empty = ", ".join(f"{name} ({'nothing received yet' if not t.stamps else 'a gap'})" for name, t in tracks.items() if t.at(ns, self.tolerance_ns) is None)
            self.faults.report("warm_gap", f"window {self.window}: {len(rows) - len(complete)} warm-start rows have no measurement "
                                           f"within tolerance ({empty or 'a motion-capture/IMU gap'}); starting from the others")
        deferred, self.deferred = self.deferred, []
        self.state = "skip"
        if len(complete) < 2:
            self.faults.report("warm_empty", f"window {self.window}: fewer than 2 measured warm-start rows; window not predicted")
            return
        stamps = np.array([row[0] for row, _ in complete], dtype=np.int64)
        try:
            warm = self._rows_log(stamps, [row for row, _ in complete], [m for _, m in complete], f"live window {self.window}")
            predictions, self.stream = self.model.start_window(warm)
            self.stream = compiled_window_stream(self.model, self.vehicle, self.stream)
        except (QuadModellingError, ValueError) as err:
            self.faults.report("model_error", f"window {self.window}: model {self.name_} cannot start: {err}")
            return
        predictions = np.atleast_2d(predictions)
        self.anchor = (int(stamps[-1]), predictions[-1].copy())
        if not self._publish(stamps.tolist(), predictions):
            return
        self.state = "stream"
        self.windows_started += 1
        for ns, u in deferred:
            if self.state == "stream":
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

    def _publish(self, stamps: list[int], predictions: np.ndarray) -> bool:
        """Publish predictions (N, 18) for ``stamps`` (increasing) now; False (window abandoned, nothing published)
        when one is non-finite or beyond the vehicle's physical bounds."""
        predictions = np.atleast_2d(predictions)
        if not np.isfinite(predictions).all():
            self.faults.report("nan_prediction", f"window {self.window}: model {self.name_} predicted a non-finite value; "
                                                 "window abandoned (nothing non-finite is published)")
            return False
        anchor_ns, anchor = self.anchor
        elapsed = (np.asarray(stamps, dtype=np.int64) - anchor_ns) / 1e9
        violation = self.bounds.violation(predictions, elapsed, anchor)
        if violation is not None:
            self.faults.report("out_of_bounds", f"window {self.window}: model {self.name_} predicted {violation}; window "
                                                "abandoned (nothing beyond the physical bounds is published)")
            return False
        odom, accel = topics.prediction_fields(predictions)
        for i, ns in enumerate(stamps):
            self._send(ns, odom[i], accel[i])
        return True

    def _on_timer(self) -> None:
        """While a window start waits for warm-row measurements (else cancelled)."""
        self._decode_pending()
        if self.state == "warm" and self.warm_closed:
            self._maybe_start()
        if not (self.state == "warm" and self.warm_closed):
            self.timer.cancel()

    def _monotonic(self, ns: int) -> bool:
        """True (and remembered) when ``ns`` is after the last published stamp: output stamps strictly increase."""
        if self.last_published_ns is not None and ns <= self.last_published_ns:
            self.faults.report("stamp_not_increasing", f"prediction stamped t = {ns / 1e9:.6f} s is not after the last published one "
                                                       f"(t = {self.last_published_ns / 1e9:.6f} s): not published")
            return False
        self.last_published_ns = ns
        return True

    def _send(self, ns: int, odom: np.ndarray, accel: np.ndarray) -> None:
        if not self._monotonic(ns):
            return
        o, a = self.out.fill(ns, odom, accel)
        self.odom_pub.publish(o)
        self.accel_pub.publish(a)
        self.published += 1

    # --- receding horizon -----------------------------------------------------------------------

    def _publish_horizons(self) -> None:
        """Publish every anchor that is ready (:class:`~quad_modelling.core.models.streaming.RecedingHorizon`), checked as
        the window mode's predictions: finite, inside the physical bounds, stamps strictly increasing."""
        for event in self.horizon.ready(lambda ns: all(track.covers(ns) for track in self.tracks), self._row_measurements):
            if event[0] == "fault":
                self.faults.report(event[1], f"receding horizon: model {self.name_}: {event[2]}")
                continue
            _, ns, prediction, elapsed = event  # rows 0 (the anchor) and h
            if not np.isfinite(prediction).all():
                self.faults.report("nan_prediction", f"receding horizon: model {self.name_} predicted a non-finite value: "
                                                     "not published")
                continue
            violation = self.bounds.violation(prediction[1], elapsed, prediction[0])
            if violation is not None:
                self.faults.report("out_of_bounds", f"receding horizon: model {self.name_} predicted {violation}: not published")
                continue
            if not self._monotonic(ns):
                continue
            odom, _ = topics.prediction_fields(prediction[1])
            self.horizon_pub.publish(self.out.odometry(ns, odom[0]))
            self.published += 1

    # --- lifecycle ----------------------------------------------------------------------------

    def run(self) -> None:
        executor = make_executor(self.executor_kind, self)
        self.get_logger().info(limit_math_threads(self.math_threads))  # before SCHED_FIFO moves every thread
        if self.realtime_priority:
            refused = set_realtime_priority(self.realtime_priority)
            (self.get_logger().warning if refused else self.get_logger().info)(
                f"parameter realtime_priority={self.realtime_priority}: {refused}" if refused else f"running under SCHED_FIFO priority {self.realtime_priority}")
        spin(self, executor)

    def finish(self) -> None:
        where = f"over {self.windows_started} windows" if self.horizon_s == 0 else f"{self.horizon_s:g} s ahead (receding horizon)"
        say(self, f"published {self.published} predictions {where}; {self.tally.received_text()}; faults: {self.faults.summary()}")


def main(args=None) -> int:
    return run_node(lambda: PredictorNode("predictor", "naive"), args)


if __name__ == "__main__":
    raise SystemExit(main())
