"""``evaluator``: live windowed RMS/TIC of every predictor against the measurements (DESIGN 5a, 7).

Subscribes (relative names, namespace ``/quad`` unless remapped): ``motor_input``,
``mocap/odom``, ``imu`` and, for each name in ``models``, ``<model>/odom`` and
``<model>/accel`` (``horizon_s`` > 0: ``<model>/horizon/odom`` instead, MAE@h only); ``window_origin`` (transient-local); with ``topic_map`` (not ``quad``), a stack's
own topics instead of the first three (:mod:`~quad_modelling.nodes.mapping.streams`). Publishes
``evaluation`` (diagnostic_msgs/DiagnosticArray, one status per model and span
for each closed window: level OK with ``<variable>.rms``/``<variable>.tic``
values in SI units, or WARN with the reason the window was not scored) and
``evaluation/progress`` (rosgraph_msgs/Clock: the last stamp every stream has
delivered; the replay paces itself on it). Service ``write_results``
(std_srvs/Trigger) writes ``results.json``/``tables.md`` (and figures) into
``output_dir`` now; they are also written at shutdown. ``record``: everything received and
published goes into one MCAP bag (:mod:`~quad_modelling.nodes.recording`), finished at shutdown.
Data subscriptions use the ``qos`` parameter (:func:`~quad_modelling.nodes.common.subscription_qos`);
the vehicle is learned from the replay's ``vehicle`` topic as the predictor's is.

Scoring uses the core code of ``quad-modelling evaluate`` (:mod:`~quad_modelling.nodes.scoring` adapts):
received measurements become a FlightLog, received absolute predictions a
:class:`~quad_modelling.core.models.streaming.RecordedPrediction`, scored with
:func:`~quad_modelling.core.evaluation.windowed.evaluate_window` (trim and smoothing from one
:class:`~quad_modelling.core.windows.EvaluationConfig`) on the windows of the core
:class:`~quad_modelling.core.windows.WindowClock` that lie inside a span (``spans``: ``NAME:A:B`` s from t0).

Closing rule: window k = [t0 + kW, t0 + (k+1)W) closes when every scored stream (``motor_input``,
``mocap/odom``, ``imu``, each model's ``<model>/odom`` and ``<model>/accel``) has delivered a stamp of a
later window, or ``close_grace_s`` [wall s] after the first passed its end (then marked naming the late
stream; a late model: its records). A model silent for ``stale_model_s`` is not waited for. A model whose
prediction topics have several publishers (two predictors under one name) is marked, not scored (a fault, once).

Streams on their own clocks (:mod:`~quad_modelling.core.alignment`, shared with offline; the rules in
docs/nodes.md): the scored rows are the window's engine-input stamps, motion capture, IMU and predictions
interpolated to them (exact where a stamp matches); a window is scored when every stream meets the coverage
rule, else marked naming each failing stream. Receding horizon (``horizon_s`` > 0): ``<model>/horizon/odom``
is scored against the measurements at its stamp with the multi-step group errors (MAE@h). Faults: bad
messages are dropped with one warning per kind; every stream's stamps pass the predictors'
:class:`~quad_modelling.core.alignment.StampGate`; a jump of the engine inputs closes the open windows and
keeps the origin (aligned with the predictors'), unless it lies before it. Timers run on the steady clock.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from quad_modelling.core.alignment import CONFIRM, Stamp, StampGate
from quad_modelling.core.evaluation.windowed import evaluate_window
from quad_modelling.core.models.base import DummyPredictor
from quad_modelling.core.windows import EvaluationConfig, WindowClock, seconds_spans, seconds_to_ns, warm_samples_for
from quad_modelling.errors import QuadModellingError
from quad_modelling.io import topics
from quad_modelling.io.topics import HORIZON_TOPIC
from quad_modelling.nodes import messages
from quad_modelling.nodes.common import (  # the one stream naming and fault vocabulary (stream_fault)
    IMU, MOCAP_ODOM, MOTOR_INPUT, VEHICLE_TOPIC, BadParameter, FaultLog, StreamTally, VehicleSource, adopt_vehicle, data_qos,
    declare_parameters, latched_qos, limit_math_threads, make_executor, prediction_subscription_qos, run_node, say, spin,
    stream_fault, subscription_qos, zero_quaternion,
)
from quad_modelling.nodes.recording import check_output_dir, close_recording, open_recorder, subscribe_recorded
from quad_modelling.nodes.mapping.streams import MEASURED_FIELDS, MappedStreams, live_topic_map, message_class
from quad_modelling.nodes.scoring import (  # noqa: F401  (EVALUATOR_PARAMETERS re-exported)
    EVALUATOR_PARAMETERS, LiveScores, WindowBuffer, WindowRecord, diagnostics_message, late_reason, shared_models,
    shared_reason, score_horizon, score_model, unmatched_models, window_measurements,
)

PROGRESS_REPEAT_S = 0.2
"""The progress acknowledgement is repeated this often [s] even when unchanged (late replays)."""

MAX_OPEN_WINDOWS = 3
"""Windows buffered at once; an older one is closed (and marked if incomplete) when a newer one opens."""


MEASUREMENT_STREAMS = (MOTOR_INPUT, MOCAP_ODOM, IMU)
"""Names of the measurement streams in the closing rule and in the reasons of marked windows."""

class EvaluatorNode(Node):
    """Scores every closed window of every model with core evaluate_window (see module doc)."""

    def __init__(self, **kwargs):
        kwargs.setdefault("namespace", topics.DEFAULT_NAMESPACE)
        super().__init__("evaluator", **kwargs)
        p = declare_parameters(self, EVALUATOR_PARAMETERS)
        if p["warm_s"] >= p["window_s"]:
            raise BadParameter(f"evaluator: parameter warm_s={p['warm_s']} must be shorter than window_s={p['window_s']}")
        self.vehicles = VehicleSource(self.get_name(), p["vehicle"])
        self.models = [str(m).strip() for m in p["models"]]
        self.spans = seconds_spans(p["spans"])
        self.window_s, self.warm_s = p["window_s"], p["warm_s"]
        self.horizon_s = p["horizon_s"]
        self.horizon_ns = seconds_to_ns(self.horizon_s)
        self.output_dir = Path(p["output_dir"]) if p["output_dir"] else None
        vehicle_file = [p["vehicle"]] if p["vehicle"].endswith((".yaml", ".yml")) else []  # an input, never replaced
        check_output_dir("evaluator", self.output_dir, p["force"], vehicle_file)
        self.figures = p["figures"]
        self.executor_kind, self.math_threads = p["executor"], p["math_threads"]
        self.stale_s, self.grace_s, self.ready_timeout_s = p["stale_model_s"], p["close_grace_s"], p["ready_timeout_s"]
        named = {span.name: span.text() for span in self.spans}
        # The one trim/smoothing configuration of every window this node scores (core defaults, as offline).
        self.config = EvaluationConfig(drop_start=0.0, drop_end=0.0, window_s=self.window_s, warm_s=self.warm_s,
                                       train=named.get("train", ""), eval=named.get("eval", ""), horizons=(1,))
        # The zero-predicting dummy (thesis Fig 5.2) is always reported, as offline; it needs no node.
        self.baselines = [] if "dummy" in self.models else ["dummy"]
        self.tally = StreamTally()  # per stream: messages received (results.json live.received), whether one was kept
        self.scores = LiveScores(self.config, self.spans, self.models + self.baselines, horizon_s=self.horizon_s,
                                 received=self.tally.received)
        self.faults = FaultLog(self.get_logger())
        self.clock_ = WindowClock(self.window_s, self.warm_s, p["sample_period_s"])
        self.open: dict[int, WindowBuffer] = {}
        self.previous: WindowBuffer | None = None  # the last closed window: its samples bracket the next one's first rows
        self.closed_below = None  # windows with index < this are closed
        self.time_base, self.base_pending = 0, False  # WindowRecord.time_base; a jump or origin move since the last window
        # Latest stamp [ns] of every stream the node scores (the closing rule); a model's streams also their wall time.
        topic_map = live_topic_map(p["topic_map"], "evaluator")
        self.mapped = None if topic_map is None else MappedStreams(topic_map, MEASURED_FIELDS, 0, 0, f"evaluator: topic_map {topic_map.name}")
        if self.mapped is not None and p["record"]:  # the recorder writes the contract's types, stamped by their headers
            raise BadParameter(f"evaluator: parameter record with topic_map={p['topic_map']!r}: record a stack's own topics "
                               "with ros2 bag record (then quad-modelling evaluate --topic-map reads the bag)")
        self.measurement_streams = MEASUREMENT_STREAMS if self.mapped is None else (MOTOR_INPUT, *self.mapped.measured_topics)
        self.stream_last_ns: dict[str, int | None] = {s: None for s in (*self.measurement_streams, *self.model_streams())}
        self.stamp_gates: dict[str, StampGate] = {}  # one per stream, the predictors' stamp rule (core.alignment)
        self.max_step_ns = seconds_to_ns(p["max_stamp_step_s"])
        self.model_last_wall = {m: None for m in self.models}
        self.ready = False
        self.shared: dict[str, int] = {}  # model -> publishers, for a model several nodes publish (shared_models)
        self.prediction_kinds = (HORIZON_TOPIC,) if self.horizon_s > 0 else ("accel", "odom")  # <model>/<kind> topics
        self.started_wall = time.monotonic()
        self.first_motor_wall: float | None = None
        self.progress_sent = None
        self.progress_wall = 0.0
        self.windows_closed = 0
        qos = subscription_qos(p["qos"], p["qos_depth"])
        self.recorder = open_recorder("evaluator", p["record"], self.output_dir, p["force"], self.vehicle)
        subscribe = self._subscribe
        if self.mapped is None:
            subscribe(JointState, p["motor_input_topic"], self._guarded(MOTOR_INPUT, self.on_motor), qos)
            subscribe(Odometry, p["odom_topic"], self._guarded(MOCAP_ODOM, self.on_odom), qos)
            subscribe(Imu, p["imu_topic"], self._guarded(IMU, self.on_imu), qos)
        else:  # a stack's own topics (nodes.mapping.streams): the offline reader's conversion
            where = f"evaluator: topic_map {topic_map.name} topic"
            for topic, kind in {t: message_class(topic_map.topics[t].msgtype, f"{where} {t}") for t in self.mapped.readers}.items():
                subscribe(kind, topic, self._guarded(topic, lambda msg, t=topic: self.on_mapped(t, msg)), qos)
            self.get_logger().info(f"topic map {topic_map.name} ({topic_map.origin}): {self.mapped.describe()}")
        self.create_subscription(Clock, topics.ORIGIN_TOPIC, self.on_origin, latched_qos(reader=True))
        self.create_subscription(String, VEHICLE_TOPIC, self.on_vehicle, latched_qos())
        qos = prediction_subscription_qos(p["qos"], p["qos_depth"])
        # windowed predictions; in receding-horizon mode the predictors publish <model>/horizon/odom alone
        readers = ((Odometry, HORIZON_TOPIC, "horizon", self.on_horizon),) if self.horizon_s > 0 else \
            ((Odometry, "odom", "odom", self.on_pred_odom), (AccelStamped, "accel", "accel", self.on_pred_accel))
        for model in self.models:
            for kind, topic, stream, callback in readers:
                subscribe(kind, f"{model}/{topic}", self._guarded(f"{model}/{stream}", lambda msg, m=model, c=callback: c(m, msg)), qos)
        self.origin_pub = self.create_publisher(Clock, topics.ORIGIN_TOPIC, latched_qos())
        self.diag_pub = self.create_publisher(DiagnosticArray, "evaluation", data_qos(100))
        self.diag_topic = self.resolve_topic_name("evaluation")
        self.progress_pub = self.create_publisher(Clock, topics.PROGRESS_TOPIC, data_qos(10))
        self.create_service(Trigger, "write_results", self.on_write)
        steady = RosClock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(0.01, self.on_progress_timer, clock=steady)
        self.create_timer(0.25, self.on_close_timer, clock=steady)
        horizon = f", MAE@{self.horizon_s:g} s of <model>/{HORIZON_TOPIC}" if self.horizon_s > 0 else ""
        self.get_logger().info(f"scoring models {self.models} in spans {p['spans']} ({self.window_s:g} s windows{horizon}, "
                               f"{p['qos']} subscriptions{', recording to ' + p['record'] if p['record'] else ''})")
        if p["nice"]:  # last: a node that refuses its parameters leaves its process's niceness as it was
            os.nice(int(p["nice"]))

    @property
    def vehicle(self):
        return self.vehicles.vehicle

    def model_streams(self, model: str | None = None) -> list[str]:
        """Stream names of one model's (or every model's) predictions: ``<model>/odom``, ``<model>/accel``; in
        receding-horizon mode ``<model>/horizon``, whose progress is the last input its forecasts answer (on_horizon)."""
        kinds = ("horizon",) if self.horizon_s > 0 else ("odom", "accel")
        return [f"{m}/{kind}" for m in ([model] if model else self.models) for kind in kinds]

    def _subscribe(self, kind, topic: str, callback, qos) -> None:
        subscribe_recorded(self, self.recorder, kind, topic, callback, qos)

    def _guarded(self, stream: str, callback):
        """``callback`` that counts each message (:class:`StreamTally`) and survives one it cannot use: reported (once
        per stream, counted) and dropped."""

        def guarded(msg):
            try:
                callback(msg)
            except (ValueError, TypeError, IndexError, AttributeError, OverflowError, QuadModellingError) as err:
                self.faults.report(stream_fault("bad", stream), f"unusable {stream} message dropped ({type(err).__name__}: {err})")

        return self.tally.counting(stream, guarded)

    # --- inputs -------------------------------------------------------------------------------

    def on_vehicle(self, msg: String) -> None:
        adopt_vehicle(self, self.vehicles, msg.data, lambda: self.recorder and self.recorder.set_vehicle(self.vehicle.name))

    def on_origin(self, msg: Clock) -> None:
        ns = topics.stamp_ns(msg.clock)
        if self.clock_.origin_ns is None or ns < self.clock_.origin_ns:
            if self.clock_.origin_ns is not None:
                self.faults.report("origin_changed", f"window origin moved {(ns - self.clock_.origin_ns) / 1e9:+.3f} s to an "
                                                     "earlier t0 (a replay restarted earlier): the open windows closed")
                self._end_time_base("the window origin moved to an earlier t0 before the window was complete")
            self.clock_.origin_ns = ns

    def _admit(self, stream: str, ns: int, payload) -> list:
        """The stamp rule of every stream (module doc): the samples ``(ns, payload)`` to use now -- none (a suspect), this
        one (regular; an engine input that confirms a jump), or the confirming run (oldest first) of a new time base."""
        gate = self.stamp_gates.get(stream) or self.stamp_gates.setdefault(stream, StampGate(self.max_step_ns))
        last = gate.last
        verdict = gate.admit(ns, (ns, payload))
        for dropped in gate.dropped:
            self.faults.report(stream_fault("stamp_outlier", stream), f"{stream} stamp t = {dropped / 1e9:.6f} s lies {(dropped - last) / 1e9:+.6f} s "
                                                           "from the stream's time (a duplicate, back in time, or beyond "
                                                           f"max_stamp_step_s={self.max_step_ns / 1e9:g} ahead): dropped")
        if verdict is Stamp.ACCEPTED:
            return [(ns, payload)]
        if verdict is Stamp.SUSPECT:
            return []
        self.faults.report(stream_fault("clock_jump", stream), f"{stream} jumped to stamp t = {ns / 1e9:.6f} s ({CONFIRM} consistent stamps): "
                                                    "publisher restarted, clock reset, or samples lost (a reader that falls behind a keep-last writer loses the "
                                                    "oldest: a replay at --rate > 0 on a busy machine; rate 0 is lossless); following it")
        if stream == MOTOR_INPUT:
            self._restart_clock(ns)
            return [(ns, payload)]  # the windows go on from here, on the predictors' window clock
        self.stream_last_ns[stream] = None
        return gate.confirmed

    def _restart_clock(self, ns: int) -> None:
        """The engine inputs jumped to ``ns`` [ns]: close (score or mark) the open windows and forget every stream's
        position. The window origin stays (the predictors keep theirs: windows stay aligned with the predictions),
        unless ``ns`` lies before it: then ``ns`` is the new origin, published, as a predictor does."""
        self._end_time_base("the engine inputs' clock jumped before the window was complete")
        if self.clock_.origin_ns is not None and ns < self.clock_.origin_ns:
            self.clock_.origin_ns = ns
            self.origin_pub.publish(messages.clock_message(ns))
        self.stream_last_ns = dict.fromkeys(self.stream_last_ns)
        for gate in (g for name, g in self.stamp_gates.items() if name != MOTOR_INPUT):
            gate.reset()

    def _end_time_base(self, reason: str) -> None:
        """Close the open windows (scored if complete, else marked with ``reason``); the windows opened next get the
        next time base (:attr:`WindowRecord.time_base`: their indices may repeat earlier ones)."""
        for k in sorted(self.open):
            self._close(k, reason_if_incomplete=reason)
        self.previous = self.closed_below = None
        self.base_pending = True

    def _window_for(self, ns: int, stream: str) -> WindowBuffer | None:
        if self.clock_.origin_ns is None:
            if stream != MOTOR_INPUT:
                return None  # no origin yet: wait for the first engine input
            self.clock_.origin_ns = ns
            self.origin_pub.publish(messages.clock_message(ns))
        if ns < self.clock_.origin_ns - self.clock_.window_ns:
            return None
        k, _ = self.clock_.locate(ns)
        self.time_base, self.base_pending = self.time_base + self.base_pending, False  # one per jump, however many events
        if self.closed_below is not None and k < self.closed_below:
            self.faults.report(stream_fault("late", stream), f"{stream} message for the already closed window {k}: dropped")
            return None
        if k < 0:
            # Samples within a window before t0 bracket window 0's first rows; they belong to no scored window.
            if self.previous is None:
                self.previous = WindowBuffer(-1, self.models, self.time_base)
            return self.previous
        window = self.open.get(k)
        if window is None:
            window = self.open[k] = WindowBuffer(k, self.models, self.time_base)
            while len(self.open) > MAX_OPEN_WINDOWS:
                self._close(min(self.open), reason_if_incomplete="closed early to bound memory")
        return window

    def _accept(self, stream: str, ns: int, values) -> list:
        """The samples ``(ns, values)`` of a message to use now (:meth:`_admit`); none for a non-finite one."""
        if messages.dropped(self.faults, stream, values, f"{stream} message"):
            return []
        return self._admit(stream, ns, values)

    def on_motor(self, msg: JointState) -> None:
        ns = topics.stamp_ns(msg.header.stamp)
        fields = topics.motor_fields(msg)
        if fields is None:
            self.faults.report(stream_fault("bad", MOTOR_INPUT), f"motor_input message with {len(msg.effort)} efforts (4 expected) dropped")
            return
        if not topics.all_finite(fields[0]):
            self.faults.report(stream_fault("nan", MOTOR_INPUT), "non-finite motor_input message dropped")
            return
        if self.vehicle is not None and messages.admitted_command(self.faults, self.vehicle, fields[0]) is None:
            return
        for ns, (u, omega) in self._admit(MOTOR_INPUT, ns, fields):
            self._motor(ns, u, omega)

    def _motor(self, ns: int, u, omega) -> None:
        """One engine input with a stamp after the previous one (the stamp gate keeps them increasing)."""
        self.clock_.observe(ns)
        window = self._window_for(ns, MOTOR_INPUT)
        if window is None:
            return
        window.motor[ns] = u.tolist()
        window.omega[ns] = None if omega is None else omega.tolist()
        if self.first_motor_wall is None:
            self.first_motor_wall = time.monotonic()
        self._advance(MOTOR_INPUT, ns, window.index)

    def _advance(self, stream: str, ns: int, k: int) -> None:
        """Stream ``stream`` delivered stamp ``ns`` [ns] of window ``k``: note its latest stamp; on entering a new window,
        stamp the wall time on the windows it passed first and try to close them."""
        self.tally.used.add(stream)
        last = self.stream_last_ns[stream]
        if last is not None and ns <= last:
            return
        self.stream_last_ns[stream] = ns
        if k < 0 or (last is not None and self.clock_.locate(last)[0] >= k):
            return
        now = time.monotonic()
        for index, w in self.open.items():
            if index < k and w.passed_at is None:
                w.passed_at = now
        self._try_close()

    def on_mapped(self, topic: str, msg) -> None:
        """A message of a ``topic_map`` topic (:mod:`~quad_modelling.nodes.mapping.streams`): its commands (in the
        vehicle's unit) an engine input, its measured fields kept in the window's ``mapped`` buffer of the topic."""
        read = self.mapped.admit(topic, msg, self.faults)
        if read is None:
            return  # another instance of a multi-instance topic, or a fault (reported)
        ns, fields = read
        measured = {f: v for f, v in fields.items() if f != "commands"}
        if measured:
            self._keep(topic, self._admit(topic, ns, measured), lambda window: window.mapped.setdefault(topic, {}))
        if "commands" not in fields:
            return
        if self.vehicle is None:
            self.faults.report("no_vehicle", f"no vehicle yet: {topic} dropped until a replay announces one on topic "
                                             f"{VEHICLE_TOPIC} (or set parameter vehicle)")
            return
        for ns, u in self._admit(MOTOR_INPUT, ns, self.mapped.command(fields["commands"], self.vehicle)):
            self._motor(ns, u, None)

    def _measurement(self, stream: str, ns: int, fields: list, store: str) -> None:
        """One ``mocap_odom`` or ``imu`` message (``store``: the window's buffer)."""
        self._keep(stream, self._accept(stream, ns, fields), lambda window: getattr(window, store))

    def _keep(self, stream: str, admitted: list, buffer_of) -> None:
        """Store the admitted samples ``(ns, fields)`` of a measurement stream in their window's ``buffer_of(window)``."""
        for ns, fields in admitted:
            window = self._window_for(ns, stream)
            if window is None:
                continue
            buffer = buffer_of(window)
            if ns in buffer:
                self.faults.report(stream_fault("duplicate", stream), f"duplicated {stream} stamp t = {ns / 1e9:.6f} s: later copy dropped")
                continue
            buffer[ns] = fields
            self._advance(stream, ns, window.index)

    def on_odom(self, msg: Odometry) -> None:
        fields = topics.odometry_fields(msg)
        messages.check_odometry_frames(self.faults, msg)
        if topics.all_finite(fields) and zero_quaternion(self.faults, fields):  # dropped as the predictors drop it
            return
        self._measurement(MOCAP_ODOM, topics.stamp_ns(msg.header.stamp), fields, "odom")

    def on_imu(self, msg: Imu) -> None:
        self._measurement(IMU, topics.stamp_ns(msg.header.stamp), topics.imu_fields(msg), "imu")

    def _prediction(self, model: str, ns: int, fields: list, store: str) -> None:
        stream = f"{model}/{'odom' if store == 'pred_odom' else 'accel'}"
        for ns, fields in self._accept(stream, ns, fields):
            window = self._window_for(ns, stream)
            if window is None:
                continue
            buffer = getattr(window, store)[model]
            if ns in buffer:
                # A restarted predictor may re-publish a stamp: keep the first copy.
                self.faults.report(stream_fault("duplicate", stream), f"model {model}: duplicated prediction stamp t = {ns / 1e9:.6f} s: later copy dropped")
                continue
            buffer[ns] = fields
            self.model_last_wall[model] = time.monotonic()
            self._advance(stream, ns, window.index)

    def on_pred_odom(self, model: str, msg: Odometry) -> None:
        self._prediction(model, topics.stamp_ns(msg.header.stamp), topics.predicted_odometry_fields(msg), "pred_odom")

    def on_pred_accel(self, model: str, msg: AccelStamped) -> None:
        self._prediction(model, topics.stamp_ns(msg.header.stamp), topics.accel_fields(msg), "pred_accel")

    def on_horizon(self, model: str, msg: Odometry) -> None:
        """A receding-horizon prediction (stamped at the predicted time): kept in that time's window. Not a closing stream."""
        ns, fields = topics.stamp_ns(msg.header.stamp), topics.predicted_odometry_fields(msg)
        for ns, fields in self._accept(f"{model}/horizon", ns, fields):
            if (self.clock_.origin_ns is not None and self.clock_.locate(ns)[0] not in self.open
                    and len(self.open) >= MAX_OPEN_WINDOWS):
                self.faults.report(f"horizon_ahead_{model}", f"{model}/{HORIZON_TOPIC} stamp t = {ns / 1e9:.6f} s beyond the open windows: dropped")
                continue
            window = self._window_for(ns, f"{model}/horizon")
            if window is not None:
                window.horizon[model].setdefault(ns, fields)
            self.model_last_wall[model] = time.monotonic()
            # The input this forecast answers -- its stream's progress, as a windowed prediction's stamp is: held inputs
            # publish at once, stamped horizon_s ahead of the input; flown ones when the input at the predicted time
            # arrives (stamped at it, so not after the latest input).
            motor = self.stream_last_ns[MOTOR_INPUT]
            answered = ns - self.horizon_ns if motor is None or ns > motor else ns
            if self.clock_.origin_ns is not None:
                self._advance(f"{model}/horizon", answered, self.clock_.locate(answered)[0])

    # --- progress and closing -----------------------------------------------------------------

    def _stale(self, model: str, now: float) -> bool:
        last = self.model_last_wall[model]
        if last is None:
            last = self.first_motor_wall if self.first_motor_wall is not None else now
        return now - last > self.stale_s

    def waited_streams(self, now: float) -> list[str]:
        """The streams progress and window closing wait for: the measurements and every model not stale."""
        return [*self.measurement_streams, *(s for m in self.models if not self._stale(m, now) for s in self.model_streams(m))]

    def progress_ns(self) -> int | None:
        """Last stamp [ns] every measurement stream and every live model has delivered (None: one has delivered nothing)."""
        stamps = [self.stream_last_ns[s] for s in self.waited_streams(time.monotonic())]
        return None if any(ns is None for ns in stamps) else min(stamps)

    def on_progress_timer(self) -> None:
        """Acknowledge progress: on change, and every :data:`PROGRESS_REPEAT_S` for late subscribers."""
        now = time.monotonic()
        if not self.ready:
            missing = unmatched_models(self, self.models, self.prediction_kinds)  # matched: none lost to a late match
            waited = now - self.started_wall
            if missing and waited < self.ready_timeout_s:
                return
            if missing:
                self.faults.report("model_missing", f"no publisher of model(s) {', '.join(missing)} after {waited:.0f} s "
                                                    f"(of {self.models}); going on without")
            self.ready = True
        ns = self.progress_ns()
        ns = 0 if ns is None else ns  # 0 = ready, nothing processed yet
        if ns != self.progress_sent or now - self.progress_wall > PROGRESS_REPEAT_S:
            self.progress_sent, self.progress_wall = ns, now
            self.progress_pub.publish(messages.clock_message(ns))

    def on_close_timer(self) -> None:
        self.shared = shared_models(self.count_publishers, self.models, self.prediction_kinds)
        for model, publishers in self.shared.items():
            self.faults.report(f"shared_{model}", shared_reason(model, publishers))
        self._try_close()

    def late_streams(self, k: int, now: float) -> list[str]:
        """The waited streams (:meth:`waited_streams`) that have not yet delivered a stamp of a window after ``k``."""
        return [s for s in self.waited_streams(now)
                if self.stream_last_ns[s] is None or self.clock_.locate(self.stream_last_ns[s])[0] <= k]

    def _try_close(self) -> None:
        """Close, oldest first, every window all waited streams have passed, or that the first stream passed
        ``close_grace_s`` ago (then marked naming the streams still behind)."""
        now = time.monotonic()
        for k in sorted(self.open):
            window = self.open[k]
            if window.passed_at is None:
                return
            late = self.late_streams(k, now)
            if late and now - window.passed_at < self.grace_s:
                return
            self._close(k, late=late)

    def _late_reason(self, late: list[str]) -> str:
        return late_reason({stream: self.stream_last_ns[stream] for stream in late}, self.clock_.origin_ns, self.grace_s)

    def _close(self, k: int, reason_if_incomplete: str = "", late: list[str] = ()) -> None:
        """Score (or mark) window ``k`` and publish its diagnostics. ``late``: streams that had not passed its end
        (a late measurement stream marks the whole window, a late model stream that model's records)."""
        window = self.open.pop(k)
        neighbours = [w for w in (self.previous, window, self.open.get(k + 1)) if w is not None and abs(w.index - k) <= 1]
        self.previous = window
        self.closed_below = max(self.closed_below or 0, k + 1)
        self.windows_closed += 1
        start_s, end_s = self.clock_.window_start_s(k), self.clock_.window_start_s(k + 1)
        spans = [span.name for span in self.spans if span.covers(start_s, end_s)]
        if not spans:
            return
        records = self._score(window, neighbours, start_s, end_s, spans, reason_if_incomplete, list(late))
        self.scores.records.extend(records)
        horizon = score_horizon(window, neighbours, [m for m in self.models if m not in self.shared], self.vehicle, self.mapped) if self.horizon_s > 0 and self.vehicle else []
        self.scores.horizon.extend(horizon)
        msg = diagnostics_message(records, self.clock_.origin_ns + (window.index + 1) * self.clock_.window_ns, horizon)
        if self.context.ok():  # at shutdown the results still go to results.json (and the recording)
            self.diag_pub.publish(msg)
        if self.recorder is not None:
            self.recorder.add(self.diag_topic, msg)

    def _score(self, window: WindowBuffer, neighbours: list[WindowBuffer], start_s: float, end_s: float, spans: list[str], extra: str,
               late: list[str]) -> list[WindowRecord]:
        def marked(reason: str, models=None) -> list[WindowRecord]:
            return [WindowRecord(m, s, window.index, start_s, end_s, reason=reason, time_base=window.time_base)
                    for m in (models or self.models + self.baselines) for s in spans]

        if any(s in self.measurement_streams for s in late):
            return marked(self._late_reason([s for s in late if s in self.measurement_streams]))
        if self.vehicle is None:
            self.faults.report("no_vehicle", f"no vehicle: window {window.index} marked, not scored; set parameter vehicle "
                                             f"(nothing announces one on topic {VEHICLE_TOPIC} next to a real flight)")
            return marked(f"no vehicle: parameter vehicle is empty and no replay announced one on topic {VEHICLE_TOPIC}")
        lo, hi = self.clock_.stamp_bounds(window.index)
        log, measured, reason = window_measurements(window, neighbours, lo, hi, self.vehicle, self.config, self.mapped)
        if log is None:
            return marked(f"{reason}{'; ' + extra if extra else ''}")
        warm = warm_samples_for(log, self.warm_s)
        records, predicted = [], {}
        for model in self.models if self.horizon_s <= 0 else []:  # receding horizon: the models are scored by MAE@h
            model_late = [s for s in self.model_streams(model) if s in late]
            if model in self.shared:
                records += marked(shared_reason(model, self.shared[model]), [model])
                continue
            if model_late:
                records += marked(self._late_reason(model_late), [model])
                continue
            result, reason = score_model(model, window, neighbours, lo, hi, log, measured, warm, self.config, self.vehicle)
            if result is None:
                records += marked(reason, [model])
                continue
            predicted[model] = result.predicted
            records += [WindowRecord(model, s, window.index, start_s, end_s, result.rms, result.tic, time_base=window.time_base) for s in spans]
        for baseline in self.baselines:
            result = evaluate_window(DummyPredictor(), log, warm, self.config.trim, self.vehicle, self.config.smooth_cutoff_hz, measured)
            records += [WindowRecord(baseline, s, window.index, start_s, end_s, result.rms, result.tic, time_base=window.time_base) for s in spans]
        if predicted and self.figures:
            for s in spans:
                self.scores.add_example(s, log, measured, predicted, warm)
        return records

    # --- results ------------------------------------------------------------------------------

    def write_results(self) -> str:
        """Write results.json, tables.md (and figures) into output_dir; returns a one-line summary."""
        if self.output_dir is None:
            return "output_dir is empty: nothing written"
        self.scores.vehicle = self.vehicle.name if self.vehicle else ""
        return self.scores.write(self.output_dir, "live", self.figures, f"Live evaluation of {', '.join(self.models)} on vehicle "
                                                                          f"{self.vehicle.name if self.vehicle else '(unknown)'}")

    def on_write(self, request, response):
        try:
            response.message = self.write_results()
            response.success = True
        except (QuadModellingError, OSError) as err:
            response.success, response.message = False, str(err)
        return response

    def run(self) -> None:
        executor = make_executor(self.executor_kind, self)
        self.get_logger().info(limit_math_threads(self.math_threads))
        spin(self, executor)

    def finish(self) -> None:
        refused = getattr(self, "fatal", None) is not None  # e.g. another vehicle's flight: its windows are no results
        if refused and self.output_dir is not None:
            say(self, f"results not written to {self.output_dir}: the evaluation was refused")
        for k in sorted(self.open) if not refused else ():
            self._close(k, reason_if_incomplete="input ended before the window was complete")
        if self.output_dir is not None and not refused:
            try:
                say(self, self.write_results())
            except (QuadModellingError, OSError) as err:
                say(self, f"cannot write results: {err}", error=True)
        close_recording(lambda text, error=False: say(self, text, error=error), self.recorder, refused)  # after the last window
        say(self, self.exit_summary())

    def exit_summary(self) -> str:
        """The closing line: windows closed, messages received per stream, faults, and every stream waited for of which
        no sample was kept in a window (nothing received, or nothing usable: every message dropped, or stamped outside
        the flight's windows)."""
        silent = self.tally.unused(self.stream_last_ns)
        return (f"closed {self.windows_closed} windows; {self.tally.received_text()}; faults: {self.faults.summary()}"
                + (f"; nothing usable received on {', '.join(silent)}" if silent else ""))


def main(args=None) -> int:
    return run_node(EvaluatorNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
