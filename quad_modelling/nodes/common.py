"""What every node of the suite shares: QoS, parameter declaration, fault reporting, windows.

No math here: windows are bookkeeping on integer nanosecond stamps.

QoS (DESIGN 5a): data topics are reliable, volatile, keep-last with a bounded
depth (parameter ``qos_depth``, default :data:`DEFAULT_QOS_DEPTH`): the replay
keeps at most ``max_in_flight`` samples unacknowledged, far below the depth, so
nothing is dropped. ``window_origin`` is reliable + transient-local depth 1, so
a node started late (or restarted) learns the window origin t0.
"""

from __future__ import annotations

import gc
import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, ParameterException
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from quad_modelling.nodes.executors import executor_kind, make_executor, spin  # noqa: F401  (re-exported for the nodes)

DEFAULT_QOS_DEPTH = 1000
"""Depth of data topics [messages]: 10 s at 100 Hz, 2.5 s at 400 Hz."""

EXIT_BAD_PARAMETER = 2
"""Exit code of a node started with an invalid parameter (as the CLI's bad-input code)."""

def data_qos(depth: int = DEFAULT_QOS_DEPTH) -> QoSProfile:
    """Reliable, volatile, keep-last ``depth``: measurements, commands, predictions."""
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
                      history=HistoryPolicy.KEEP_LAST, depth=depth)


def latched_qos() -> QoSProfile:
    """Reliable, transient-local, depth 1: the window origin, delivered to late joiners."""
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                      history=HistoryPolicy.KEEP_LAST, depth=1)


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


def positive(value) -> str | None:
    return None if value > 0 else "must be > 0"


def non_negative(value) -> str | None:
    return None if value >= 0 else "must be >= 0"


def niceness(value) -> str | None:
    return None if 0 <= value <= 19 else "must be a niceness increment from 0 to 19"


def realtime_priority_range(value) -> str | None:
    return None if 0 <= value <= 99 else "must be 0 (normal scheduling) or a SCHED_FIFO priority from 1 to 99"


def set_realtime_priority(priority: int) -> str | None:
    """Put every thread of this process under SCHED_FIFO at ``priority`` (1-99), or back under normal
    scheduling (SCHED_OTHER) for 0; None, or why not.

    Every thread, not just the caller: Fast DDS delivers samples on its own
    threads, which wake the executor; one of them preempted by an ordinary
    process delays the answer as much as the executor itself being preempted.
    Call it once the node and its executor exist (threads created later inherit
    the policy). Needs CAP_SYS_NICE or an RLIMIT_RTPRIO of at least
    ``priority`` (``ulimit -r``; ``rtprio`` in /etc/security/limits.conf).
    """
    policy, param = (os.SCHED_FIFO if priority else os.SCHED_OTHER), os.sched_param(priority)
    try:
        for tid in sorted(int(t) for t in os.listdir("/proc/self/task")):
            os.sched_setscheduler(tid, policy, param)
    except PermissionError:
        return (f"SCHED_FIFO priority {priority} not permitted (needs CAP_SYS_NICE or rtprio >= {priority} in "
                "/etc/security/limits.conf); running with normal scheduling")
    except (ProcessLookupError, FileNotFoundError):  # a thread ended meanwhile / no /proc: best effort
        return None
    return None


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


def declare_parameters(node, params: list[Param]) -> dict:
    """Declare ``params`` with descriptors, validating every value (also later set requests).

    Returns {name: value}. Raises :class:`BadParameter` with the reason when a
    value given at start (``--ros-args -p`` or a params file) is invalid; at run
    time, invalid or read-only changes are rejected with the reason.
    """
    checks = {p.name: p.check for p in params}

    def validate(parameters) -> SetParametersResult:
        for parameter in parameters:
            check = checks.get(parameter.name)
            if check is None:
                continue
            reason = check(parameter.value)
            if reason:
                return SetParametersResult(successful=False, reason=f"parameter {parameter.name}={parameter.value!r}: {reason}")
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
            raise BadParameter(f"{node.get_name()}: {err}") from err
        values[p.name] = value
    return values


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


class WindowClock:
    """Window k = [t0 + kW, t0 + (k+1)W) on integer nanosecond stamps (DESIGN 5a).

    Stamps jitter (real logs: microseconds), so a sample belongs to the window
    of its stamp shifted by half a sample period dt/2, as offline windows are
    cut on row boundaries (``evaluation.span_windows`` searches at ``a - 0.5/rate``):
    ``k = floor((t - t0 + dt/2) / W)``, position ``p = t - t0 + dt/2 - kW``;
    the sample is a warm-start row when ``p < warm_s``. dt is the median of the
    first :data:`PERIOD_SAMPLES` motor-input steps (or the parameter
    ``sample_period_s``), then frozen.
    """

    PERIOD_SAMPLES = 5

    def __init__(self, window_s: float, warm_s: float, sample_period_s: float = 0.0):
        self.window_ns = int(round(window_s * 1e9))
        self.warm_ns = int(round(warm_s * 1e9))
        self.origin_ns: int | None = None
        self.half_period_ns = int(round(sample_period_s * 0.5e9)) if sample_period_s > 0 else None
        self._steps: list[int] = []
        self._last: int | None = None

    @property
    def period_s(self) -> float | None:
        return None if self.half_period_ns is None else 2 * self.half_period_ns / 1e9

    def observe(self, ns: int) -> None:
        """Feed each accepted motor-input stamp (estimates dt while unknown)."""
        if self.half_period_ns is None and self._last is not None and ns > self._last:
            self._steps.append(ns - self._last)
            if len(self._steps) >= self.PERIOD_SAMPLES:
                self._steps.sort()
                self.half_period_ns = self._steps[len(self._steps) // 2] // 2
        self._last = ns

    def locate(self, ns: int) -> tuple[int, int]:
        """(window index k, position in window [ns]) of a stamp; the origin must be set."""
        shifted = ns - self.origin_ns + (self.half_period_ns or 0)
        k = shifted // self.window_ns
        return int(k), int(shifted - k * self.window_ns)

    def is_warm(self, position_ns: int) -> bool:
        return position_ns < self.warm_ns

    def is_last_warm(self, position_ns: int) -> bool:
        """A warm row whose successor, one period dt later, is not: ``p < warm_s <= p + dt`` (False while dt is
        unknown). Positions carry the dt/2 shift, so stamp jitter below dt/2 does not change the answer."""
        return self.half_period_ns is not None and position_ns < self.warm_ns <= position_ns + 2 * self.half_period_ns

    def window_start_s(self, k: int) -> float:
        """Start of window k in seconds from t0."""
        return k * self.window_ns / 1e9


def parse_span(text: str) -> tuple[str, float, float]:
    """``name:A:B`` (seconds from t0; B may be ``inf``) -> (name, A, B); BadParameter when invalid."""
    parts = str(text).split(":")
    if len(parts) != 3 or not parts[0].strip():
        raise BadParameter(f"span {text!r}: expected NAME:START:END in seconds from t0, e.g. eval:20:40 or live:0:inf")
    try:
        start, end = float(parts[1]), float(parts[2])
    except ValueError as err:
        raise BadParameter(f"span {text!r}: START and END must be numbers of seconds (END may be inf)") from err
    if not (math.isfinite(start) and 0.0 <= start < end):
        raise BadParameter(f"span {text!r}: need 0 <= START < END")
    return parts[0].strip(), start, end


def spans_check(value) -> str | None:
    try:
        names = [parse_span(s)[0] for s in value]
    except BadParameter as err:
        return str(err)
    if not names:
        return "give at least one span NAME:START:END"
    if len(set(names)) != len(names):
        return f"span names must be unique, got {names}"
    return None


def say(node, text: str, error: bool = False) -> None:
    """Log through the node while ROS runs; after shutdown (final summaries) print to stderr."""
    if node.context.ok():
        (node.get_logger().error if error else node.get_logger().info)(text)
    else:
        print(f"[{'ERROR' if error else 'INFO'}] [{node.get_namespace().strip('/')}.{node.get_name()}]: {text}", file=sys.stderr, flush=True)


DDS_PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
"""Environment variable Fast DDS 2.x reads its XML profiles from (at participant creation)."""


def use_dds_profile() -> str:
    """Point Fast DDS at ``config/fastdds.xml`` (50 ms writer heartbeat) unless the environment names a profile.

    Call before ``rclpy.init``. Returns the profile file in use.
    """
    import os

    from quad_modelling.core.vehicle import config_dir

    return os.environ.setdefault(DDS_PROFILE_ENV, str(config_dir() / "fastdds.xml"))


def run_node(factory, args=None) -> int:
    """Create the node with ``factory()``, spin it, shut down cleanly; exit code.

    A :class:`BadParameter` or a package error raised while building the node is
    printed as one line on stderr and gives :data:`EXIT_BAD_PARAMETER`.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from quad_modelling.errors import QuadModellingError

    use_dds_profile()
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = factory()
        # Everything built so far lives as long as the node: move it out of the cyclic GC's reach, so a
        # full collection scans only objects made while running (one took 75 ms at 400 Hz; gc.freeze docs).
        gc.freeze()
        node.run()
    except (BadParameter, QuadModellingError) as err:
        print(f"error: {err}", file=sys.stderr, flush=True)
        code = EXIT_BAD_PARAMETER
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0  # Ctrl-C or a shutdown request: the normal end of a node
    finally:
        if node is not None:
            node.finish()
            node.destroy_node()
        rclpy.try_shutdown()
    return code
