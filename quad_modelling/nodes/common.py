"""What every node of the suite shares: QoS, parameter declaration, fault reporting.

The window clock and the span grammar are core's (:mod:`quad_modelling.core.windows`).

QoS (DESIGN 5a): every node *publishes* its data reliable, volatile, keep-last with
a bounded depth (parameter ``qos_depth``, default :data:`DEFAULT_QOS_DEPTH`); a
reliable writer serves reliable and best-effort readers alike. Every data
*subscription* takes the profile of the parameter ``qos`` (:func:`subscription_qos`):
``best_effort`` (default) matches both reliable publishers (our replay) and
best-effort ones (MAVROS, the PX4 uXRCE-DDS bridge, crazyswarm2 publish with the
sensor-data profile), ``reliable`` matches only reliable publishers but never loses
a sample (``run-bag`` uses it: its replay keeps at most ``max_in_flight`` samples
unacknowledged, far below the depth, so nothing is dropped), ``sensor_data`` is
rclpy's ``qos_profile_sensor_data`` (best effort, depth 5). ``window_origin`` and
``vehicle`` are reliable + transient-local depth 1, so a node started late (or
restarted) learns the window origin t0 and the vehicle.

Parameters (:func:`declare_parameters`): an integer given for a float parameter
(``rate:=2``) is taken as that float; a parameter given (file or command line) that
the node does not declare is one warning naming it and the closest declared name
(:func:`unknown_parameters`).
"""

from __future__ import annotations

import difflib
import gc
import math
import signal
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, ParameterException
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from quad_modelling.core.alignment import CONFIRM, MAX_STAMP_STEP_S
from quad_modelling.node_entry import EXIT_INTERRUPTED
from quad_modelling.core.windows import MIN_SAMPLE_PERIOD_S, seconds_spans
from quad_modelling.errors import ConfigError, QuadModellingError, reason
from quad_modelling.io import topics
from quad_modelling.io.reports.evaluation import received_text
from quad_modelling.nodes.domains import DDS_PROFILE_ENV, use_dds_profile  # noqa: F401  (re-exported)
from quad_modelling.nodes.executors import (  # noqa: F401  (re-exported for the nodes)
    MATH_THREADS, executor_kind, interrupt, limit_math_threads, make_executor, set_realtime_priority, spin, spin_once,
)

DEFAULT_QOS_DEPTH = 1000
"""Depth of data topics [messages]: 10 s at 100 Hz, 2.5 s at 400 Hz."""

EXIT_BAD_PARAMETER = 2
"""Exit code of a node started with an invalid parameter (as the CLI's bad-input code)."""

def data_qos(depth: int = DEFAULT_QOS_DEPTH) -> QoSProfile:
    """Reliable, volatile, keep-last ``depth``: measurements, commands, predictions."""
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
                      history=HistoryPolicy.KEEP_LAST, depth=depth)


QOS_KINDS = ("best_effort", "reliable", "sensor_data", "replay")
"""Values of the ``qos`` parameter of every subscribing node (:func:`subscription_qos`)."""


def qos_kind(value) -> str | None:
    return None if value in QOS_KINDS else f"must be one of {', '.join(QOS_KINDS)}"


def qos_param() -> Param:
    return Param("qos", "best_effort", "QoS of the data subscriptions: best_effort (default; matches reliable and "
                                       "best-effort publishers), reliable (reliable publishers only, lossless), sensor_data "
                                       "(rclpy's qos_profile_sensor_data: best effort, depth 5), replay (reliable and "
                                       "transient-local: our replay's topics, none lost to a late match; run-bag sets it)",
                 qos_kind)


def subscription_qos(kind: str, depth: int = DEFAULT_QOS_DEPTH) -> QoSProfile:
    """The data subscriptions' profile for the ``qos`` parameter value ``kind`` (:data:`QOS_KINDS`).

    ``best_effort``: best effort, volatile, keep-last ``depth``. A best-effort reader
    matches reliable and best-effort writers (DDS request/offer rule: the offer must be at
    least as strong as the request), so it is the default. ``reliable``: :func:`data_qos`;
    it matches reliable writers only (a best-effort publisher and a reliable reader are
    incompatible: nothing is delivered). ``sensor_data``: rclpy's ``qos_profile_sensor_data``
    as is (best effort, volatile, keep-last 5). ``replay``: :func:`history_qos`, for topics of our own
    replay (which offers them transient-local): lossless, and what was published before the replay's writer
    matched this reader (discovery repaired late over a lossy link) is delivered too; a volatile publisher
    (another stack's) does not match it.
    """
    if kind == "reliable":
        return data_qos(depth)
    if kind == "replay":
        return history_qos(depth)
    if kind == "best_effort":
        return QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE,
                          history=HistoryPolicy.KEEP_LAST, depth=depth)
    if kind == "sensor_data":
        return qos_profile_sensor_data
    raise BadParameter(f"parameter qos={kind!r}: {qos_kind(kind)}")


def history_qos(depth: int = DEFAULT_QOS_DEPTH) -> QoSProfile:
    """Reliable, transient-local, keep-last ``depth``: what our nodes publish as data (the predictor's predictions,
    the replay's measurements).

    Transient-local so that a reader the writer matches late (discovery repaired over a lossy link after the data
    began) still receives the last ``depth`` samples instead of losing them (``test/ros/test_two_hosts.py`` lost the
    first 0.3-1 s of a stream that way). Any reader matches it (a volatile reader gets only new samples); a reader
    asks for the history with ``qos:=replay`` (measurements) or ``reliable`` / ``replay`` (predictions,
    :func:`prediction_subscription_qos`)."""
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                      history=HistoryPolicy.KEEP_LAST, depth=depth)


def prediction_subscription_qos(kind: str, depth: int = DEFAULT_QOS_DEPTH) -> QoSProfile:
    """The evaluator's subscriptions to predictions (always ours, offered with :func:`history_qos`):
    :func:`subscription_qos`, with the history when ``reliable`` or ``replay``."""
    return history_qos(depth) if kind in ("reliable", "replay") else subscription_qos(kind, depth)


LATCHED_READER_DEPTH = 64
"""A latched topic's reader history: every writer's sample and the node's own (depth 1 kept the last to arrive only: a
late joiner's own window origin replaced the graph's earlier one, and it cut unaligned windows)."""
def latched_qos(reader: bool = False) -> QoSProfile:
    """Reliable, transient-local, for late joiners: a writer keeps its last sample, a ``reader`` :data:`LATCHED_READER_DEPTH`."""
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                      history=HistoryPolicy.KEEP_LAST, depth=LATCHED_READER_DEPTH if reader else 1)


class BadParameter(ValueError):
    """A node parameter is invalid; the message names it, its value and the rule."""


@dataclass(frozen=True)
class Param:
    """One declared parameter: default, description, validator (value -> reason or None), read-only."""

    name: str
    default: object
    description: str
    check: Callable[[object], str | None] | None = None
    read_only: bool = True


MAX_PARAMETER = 1.0e6
"""Largest value a numeric parameter takes (seconds, rates, depths): 11.6 days as a time; beyond it (or inf) a
time would overflow the nanosecond stamps it is turned into, a depth or a count exhaust memory -- a typo, refused."""


def _bounded(value) -> str | None:
    if not math.isfinite(value) or value > MAX_PARAMETER:
        return f"must be finite and at most {MAX_PARAMETER:g}"
    return None


def positive(value) -> str | None:
    return _bounded(value) or (None if value > 0 else "must be > 0")


def non_negative(value) -> str | None:
    return _bounded(value) or (None if value >= 0 else "must be >= 0")


MIN_TIME_SPAN_S = 1.0e-6
"""Shortest window, warm start or stamp step a parameter sets [s]: stamps are whole nanoseconds, and 1e-12 s rounded to
0 ns (a division by zero on the first message, or a gate that dropped every message)."""


def time_span(value) -> str | None:
    return _bounded(value) or (None if value >= MIN_TIME_SPAN_S else f"must be at least {MIN_TIME_SPAN_S:g} s")


def sample_period(value) -> str | None:
    """0 (measured from the first steps) or a period of at least :data:`MIN_SAMPLE_PERIOD_S` [s]."""
    return non_negative(value) or (None if value == 0 or value >= MIN_SAMPLE_PERIOD_S else
                                   f"must be 0 (measured) or at least {MIN_SAMPLE_PERIOD_S:g} s")


def topic_name(value) -> str | None:
    """A ROS 2 topic name (relative or absolute), as rclpy validates it."""
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_topic_name import validate_topic_name

    if not str(value).strip():
        return "must not be empty"
    try:
        validate_topic_name(str(value))
    except InvalidTopicNameException as err:
        return f"not a ROS 2 topic name ({str(err).splitlines()[0].rstrip(':')})"
    return None


def model_name_check(value) -> str | None:
    """Empty (the spec's kind) or one topic-name token: the predictions are <model_name>/odom (``a/b`` or ``/x`` make
    topics the evaluator's ``models`` cannot name)."""
    if not str(value):
        return None
    bad = topic_name(f"{value}/odom") or "/" in str(value)
    return f"{value!r} cannot prefix a topic: use letters, digits and '_'" if bad else None


def niceness(value) -> str | None:
    return None if 0 <= value <= 19 else "must be a niceness increment from 0 to 19"


def realtime_priority_range(value) -> str | None:
    return None if 0 <= value <= 99 else "must be 0 (normal scheduling) or a SCHED_FIFO priority from 1 to 99"


def non_negative_int(value) -> str | None:
    return None if value >= 0 else "must be >= 0"


def math_threads_param() -> Param:
    return Param("math_threads", MATH_THREADS, "threads of the math libraries' pools (OpenBLAS, OpenMP, torch) in this node; "
                                               "0 = as the libraries start them (one per core)", non_negative_int)


def realtime_param() -> Param:
    return Param("realtime_priority", 0, "0 = normal scheduling; 1-99 = run every thread of this node under SCHED_FIFO at "
                                         "this priority (needs CAP_SYS_NICE or rtprio in limits.conf; a warning if refused). "
                                         "For predictors next to a flight: keeps other processes from delaying an answer",
                 realtime_priority_range)


def executor_param() -> Param:
    return Param("executor", "events", "rclpy executor: events (EventsExecutor, less overhead per message) or single "
                                       "(SingleThreadedExecutor)", executor_kind)


def non_empty(value) -> str | None:
    return None if str(value).strip() else "must not be empty"


AUTOMATIC_PARAMETERS = ("use_sim_time", "start_type_description_service")
"""Parameters rclpy declares on every node itself (Jazzy): never reported as unknown."""

QOS_OVERRIDE_PREFIX = "qos_overrides."
"""rclpy's publisher/subscription QoS override parameters: not the node's own, never reported as unknown."""


def unknown_parameters(given: Iterable[str], declared: Iterable[str]) -> list[str]:
    """One warning per name in ``given`` that is not in ``declared``, naming the closest declared name.

    ``given``: the parameters set from files or the command line; rclpy's own
    (:data:`AUTOMATIC_PARAMETERS`, ``qos_overrides.*``) are never unknown. The closest name is
    :func:`difflib.get_close_matches` (ratio >= 0.6), else the declared names are listed.
    """
    declared = list(declared)
    warnings = []
    for name in sorted(given):
        if name in declared or name in AUTOMATIC_PARAMETERS or name.startswith(QOS_OVERRIDE_PREFIX):
            continue
        close = difflib.get_close_matches(name, declared, n=1)
        hint = f"did you mean {close[0]!r}?" if close else f"declared: {', '.join(sorted(declared))}"
        warnings.append(f"unknown parameter {name!r} ignored; {hint}")
    return warnings


def integers_as_floats(overrides: dict, params: list[Param]) -> list[str]:
    """Turn every integer override of a float parameter into that float, in place (``rate:=2`` = ``rate:=2.0``).

    ``overrides``: rclpy's {name: Parameter} the node was given (``Node._parameter_overrides``,
    resolved from the command line and the params files for this node). Returns the names converted.
    """
    converted = []
    for p in params:
        given = overrides.get(p.name)
        if (isinstance(p.default, float) and given is not None and given.type_ == Parameter.Type.INTEGER):
            overrides[p.name] = Parameter(p.name, Parameter.Type.DOUBLE, float(given.value))
            converted.append(p.name)
    return converted


def declare_parameters(node, params: list[Param]) -> dict:
    """Declare ``params`` with descriptors, validating every value (also later set requests).

    Returns {name: value}. Raises :class:`BadParameter` with the reason when a
    value given at start (``--ros-args -p`` or a params file) is invalid; at run
    time, invalid or read-only changes are rejected with the reason. Integers
    given for float parameters are taken as floats (:func:`integers_as_floats`);
    parameters given but not declared are warned about (:func:`unknown_parameters`).
    """
    checks = {p.name: p.check for p in params}
    floats = {p.name for p in params if isinstance(p.default, float)}
    overrides = node._parameter_overrides  # rclpy keeps them there; there is no public accessor (rclpy 7.1)
    integers_as_floats(overrides, params)
    for warning in unknown_parameters(overrides, [p.name for p in params]):
        node.get_logger().warning(f"{node.get_name()}: {warning}")

    refused: dict[str, str] = {}  # name -> the reason validate() gave: the one line a refused start value prints

    def validate(parameters) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name in floats and parameter.type_ == Parameter.Type.INTEGER:
                refused[parameter.name] = f"parameter {parameter.name}={parameter.value!r}: give a float ({float(parameter.value)!r})"
                return SetParametersResult(successful=False, reason=refused[parameter.name])
            check = checks.get(parameter.name)
            if check is None:
                continue
            reason = check(parameter.value)
            if reason:
                shown = "[] (empty: rclpy reads an empty list as no value)" if parameter.value is None else repr(parameter.value)
                refused[parameter.name] = f"parameter {parameter.name}={shown}: {reason}"
                return SetParametersResult(successful=False, reason=refused[parameter.name])
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(validate)
    values = {}
    for p in params:
        descriptor = ParameterDescriptor(description=p.description, read_only=p.read_only)
        if isinstance(p.default, list):
            descriptor.type = ParameterType.PARAMETER_STRING_ARRAY
        try:
            value = node.declare_parameter(p.name, p.default, descriptor).value
        except (ParameterException, InvalidParameterTypeException) as err:  # value rejected by validate(), wrong type
            raise BadParameter(f"{node.get_name()}: {refused.get(p.name, err)}") from err
        values[p.name] = value
    return values


MOTOR_INPUT, MOCAP_ODOM, IMU, BATTERY = "motor_input", "mocap_odom", "imu", "battery"
STREAMS = (MOTOR_INPUT, MOCAP_ODOM, IMU, BATTERY)
"""The measurement streams of every node, named after their topics (``mocap/odom`` is ``mocap_odom``): in the logs,
the fault kinds (:func:`stream_fault`) and the reasons of marked windows. A model's prediction streams are
``<model>/odom``, ``<model>/accel`` and ``<model>/horizon``."""

STREAM_FAULTS = {
    "stamp_outlier": "a stamp off the stream's time (a duplicate, back in time, or beyond max_stamp_step_s ahead): dropped",
    "clock_jump": "the stamps jumped to a new time base (restarted publisher, clock reset, end of a long silence): followed",
    "nan": "a message with a non-finite value: dropped",
    "range": "a message beyond what a flight can hold (a sensor's full scale, 100 km, 200 m/s; flight_log's bounds): dropped",
    "bad": "a message that cannot be decoded or used (e.g. not 4 efforts): dropped",
    "duplicate": "a second message with a stamp already stored: dropped",
    "late": "a message for a window the evaluator already closed: dropped",
    "stopped_motor": "(topic map) a NaN command, PX4's stopped motor: kept, read as the map's lowest command as offline"}
"""The one vocabulary of per-stream faults of every node: ``<kind>_<stream>`` (:func:`stream_fault`), kind -> meaning
(the table in docs/nodes.md)."""


def stream_fault(kind: str, stream: str) -> str:
    """The fault kind ``<kind>_<stream>`` of a stream (e.g. ``stamp_outlier_imu``, ``clock_jump_motor_input``); ``kind``
    must be one of :data:`STREAM_FAULTS` (ValueError otherwise: a new name belongs in the vocabulary first)."""
    if kind not in STREAM_FAULTS:
        raise ValueError(f"fault kind {kind!r} is not in the vocabulary {sorted(STREAM_FAULTS)}")
    return f"{kind}_{stream}"


class FaultLog:
    """One clear warning per kind of fault (not per message), with counts for the summary."""

    def __init__(self, logger):
        self.logger = logger
        self.counts: dict[str, int] = {}

    def report(self, kind: str, message: str) -> None:
        count = self.counts.get(kind, 0)
        self.counts[kind] = count + 1
        if count == 0:
            self.logger.warning(f"{message} (fault '{kind}': reported once, further ones are counted)")

    def summary(self) -> str:
        return ", ".join(f"{k} x{n}" for k, n in sorted(self.counts.items())) or "none"


class StreamTally:
    """Per stream, the messages its subscription delivered (:attr:`received`, counted on arrival, before any check:
    ``run-bag`` compares them with the samples sent, docs/nodes.md "Sample loss") and whether a sample of it was used
    (kept for scoring): the exit summary names the streams a node waited for of which none was (:meth:`unused`). A
    message received is not a sample used: a stream whose stamps are all zero, or off the flight's time, delivers
    messages that pass no window (the evaluator judged a stream by its stamp gate, which the first message of valid
    numbers creates whatever its stamp: a zero-stamped IMU went unnamed)."""

    def __init__(self):
        self.received: dict[str, int] = {}
        self.used: set[str] = set()

    def counting(self, stream: str, callback: Callable) -> Callable:
        """``callback`` of a subscription to ``stream`` that counts each message delivered, first."""
        self.received.setdefault(stream, 0)

        def counted(*args):
            self.received[stream] += 1
            return callback(*args)

        return counted

    def unused(self, streams: Iterable[str]) -> list[str]:
        """Those of ``streams`` of which no sample was used, in their order."""
        return [s for s in streams if s not in self.used]

    def received_text(self) -> str:
        """The exit summary's ``received motor_input 4227, mocap_odom 4227, imu 4227``
        (:func:`~quad_modelling.io.reports.evaluation.received_text`, which run-bag reads back)."""
        return received_text(self.received)


def zero_quaternion(faults: FaultLog, fields) -> bool:
    """True, with the fault ``zero_quaternion`` reported, for motion-capture ``fields`` whose attitude quaternion is
    zero (not a rotation): every node drops such a message (the predictors and the evaluator alike)."""
    if not topics.invalid_odometry_quaternion(fields):
        return False
    faults.report("zero_quaternion", "motion-capture message with a zero (non-unit) quaternion dropped; its neighbours "
                                     "are interpolated across it")
    return True


VEHICLE_TOPIC = "vehicle"
"""std_msgs/String, reliable + transient-local: the vehicle (config name or YAML path) of the flight the replay plays."""


class VehicleSource:
    """A node's vehicle: its ``vehicle`` parameter, or (parameter empty) what the replay announces on
    :data:`VEHICLE_TOPIC`. A parameter naming another vehicle than the announced one is refused.

    ``requested``: the parameter value ('' = learn it). :meth:`announce` takes an announced
    vehicle and returns the vehicle newly learned (None when nothing changed), or raises
    :class:`BadParameter` in one line on a mismatch or an announced vehicle this host cannot load.
    """

    def __init__(self, node_name: str, requested: str):
        from quad_modelling.core.vehicle import load_vehicle

        self.node_name = node_name
        self.requested = requested.strip()
        self.announced: str | None = None
        self.vehicle = None
        if self.requested:
            try:
                self.vehicle = load_vehicle(self.requested)
            except QuadModellingError as err:
                raise BadParameter(f"{node_name}: parameter vehicle={self.requested!r}: {err}") from err

    def announce(self, announced: str):
        from quad_modelling.core.vehicle import load_vehicle

        announced = announced.strip()
        if not announced or announced == self.announced:
            return None
        self.announced = announced
        try:
            vehicle = load_vehicle(announced)
        except QuadModellingError as err:
            if self.vehicle is not None and Path(announced).stem == self.vehicle.name:
                return None  # the same vehicle by name, its file elsewhere (another host)
            if self.vehicle is not None:  # set by the parameter: the flight is another vehicle's
                raise BadParameter(f"{self.node_name}: parameter vehicle={self.requested!r} ({self.vehicle.name}) but the "
                                   f"replay plays a flight of vehicle {announced!r} (topic {VEHICLE_TOPIC}), which this host "
                                   "cannot load either: replay this vehicle's flights") from err
            raise BadParameter(f"{self.node_name}: the replay announces vehicle {announced!r} on topic {VEHICLE_TOPIC}, "
                               f"which this host cannot load: {err}; set parameter vehicle") from err
        if self.vehicle is None:
            self.vehicle = vehicle
            return vehicle
        if vehicle.name != self.vehicle.name:
            raise BadParameter(f"{self.node_name}: parameter vehicle={self.requested!r} ({self.vehicle.name}) but the replay "
                               f"plays a flight of vehicle {vehicle.name!r} (topic {VEHICLE_TOPIC}); set vehicle:={announced} "
                               "or leave it empty to learn it")
        return None


def vehicle_param() -> Param:
    return Param("vehicle", "", "vehicle config name (config/vehicles) or YAML path; empty = the one the replay announces "
                                "on topic vehicle (a set one must match it)")


def stamp_step_param() -> Param:
    """``max_stamp_step_s``: the one stamp rule of every node (:class:`~quad_modelling.core.alignment.StampGate`)."""
    return Param("max_stamp_step_s", MAX_STAMP_STEP_S, "longest regular step of a stream's stamps [s]; a stamp beyond it, back in time or "
                                          f"repeated is dropped as an outlier, {CONFIRM} consistent ones are a new time base "
                                          "(restarted publisher, clock jump, end of a longer silence)", time_span)


def adopt_vehicle(node, vehicles: VehicleSource, announced: str, learned: Callable[[], None] = lambda: None) -> None:
    """A node's handler of :data:`VEHICLE_TOPIC`: ``learned()`` once a vehicle is newly learned; a mismatch
    stops the node (:func:`refuse`, exit 2)."""
    try:
        if vehicles.announce(announced) is not None:
            learned()
            node.get_logger().info(f"vehicle {vehicles.vehicle.name} learned from topic {VEHICLE_TOPIC}")
    except BadParameter as err:
        refuse(node, err)


def refuse(node, error: BadParameter) -> None:
    """Stop ``node`` from a callback because of ``error``: :func:`run_node` prints it (its one line) and exits 2."""
    node.fatal = error
    import rclpy

    rclpy.try_shutdown(context=node.context)


def spans_check(value) -> str | None:
    """Parameter validator of named seconds spans (:func:`quad_modelling.core.windows.seconds_spans`)."""
    if not value:  # spans:=[] arrives as None (a traceback in the list below)
        return "give at least one span, e.g. spans:=[live:0:inf]"
    try:
        seconds_spans([str(v) for v in value])
    except ConfigError as err:
        return str(err)
    return None


def say(node, text: str, error: bool = False) -> None:
    """Log through the node while ROS runs; after shutdown (final summaries) print to stderr."""
    if node.context.ok():  # two call sites: rclpy refuses a severity change between calls from one line
        if error:
            node.get_logger().error(text)
        else:
            node.get_logger().info(text)
    else:
        print(f"[{'ERROR' if error else 'INFO'}] [{node.get_namespace().strip('/')}.{node.get_name()}]: {text}", file=sys.stderr, flush=True)


def run_node(factory, args=None) -> int:
    """Create the node with ``factory()``, spin it, shut down cleanly; exit code.

    A :class:`BadParameter` or a package error raised while building the node is
    printed as one line on stderr and gives :data:`EXIT_BAD_PARAMETER`.
    """
    # Ours from the start (a parent's SIG_IGN of a background job included): a Ctrl-C while rclpy loads or starts
    # ends the process with 130, not a traceback, and is not lost. rclpy's own handlers shut the context down from
    # their signal thread while this thread may be inside a wait on it: a rare RCLError ("context is not valid") or
    # a segfault at Ctrl-C. The signals stay Python's here: Ctrl-C and SIGTERM raise KeyboardInterrupt in this thread
    # when the spin's wait returns (<= SPIN_TIMEOUT_S).
    previous = {signum: signal.signal(signum, _interrupt) for signum in (signal.SIGINT, signal.SIGTERM)}
    signal.pthread_sigmask(signal.SIG_UNBLOCK, set(previous))  # whatever the parent ignored or blocked
    try:
        import rclpy
        from rclpy.executors import ExternalShutdownException
        from rclpy.signals import SignalHandlerOptions

        use_dds_profile()
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except QuadModellingError as err:
        print(f"error: {err}", file=sys.stderr, flush=True)
        return _restored(previous, EXIT_BAD_PARAMETER)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM before the node existed: nothing to summarise
        return _restored(previous, EXIT_INTERRUPTED)
    except Exception as err:  # rclpy's RCLError: an unreadable --params-file, a malformed -p override
        if type(err).__name__ != "RCLError":
            raise
        print(f"error: cannot start ROS 2 with these arguments: {reason(err)} (check --params-file and -p NAME:=VALUE)",
              file=sys.stderr, flush=True)
        return _restored(previous, EXIT_BAD_PARAMETER)
    node = None
    code = 0
    try:
        node = factory()
        # Everything built so far lives as long as the node: move it out of the cyclic GC's reach, so a
        # full collection scans only objects made while running (one took 75 ms at 400 Hz; gc.freeze docs).
        gc.freeze()
        try:
            node.run()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass  # Ctrl-C, SIGTERM (both KeyboardInterrupt: _interrupt) or refuse(): the end of a node
        if getattr(node, "fatal", None) is not None:  # a callback refused to go on (refuse())
            raise node.fatal
    except (BadParameter, QuadModellingError) as err:
        print(f"error: {err}", file=sys.stderr, flush=True)
        code = EXIT_BAD_PARAMETER
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0  # Ctrl-C while the node was being built
    finally:
        if node is not None:  # the end is decided: a second Ctrl-C or a SIGTERM after it may not cut the results short
            for signum in previous:
                signal.signal(signum, signal.SIG_IGN)
            node.finish()
            node.destroy_node()
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return code




def _restored(previous: dict, code: int) -> int:
    """Put back the signal handlers ``previous`` held; ``code``."""
    for signum, handler in previous.items():
        signal.signal(signum, handler)
    return code


def _interrupt(signum, frame):
    """SIGINT and SIGTERM handler of a node process: KeyboardInterrupt, which ends it cleanly (summary, exit code 0);
    inside an executor's spin (a callback may be running) raised when the spin returns (:func:`executors.interrupt`)."""
    interrupt(signal.Signals(signum).name)
