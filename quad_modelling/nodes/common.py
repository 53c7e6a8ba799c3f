"""What every node of the suite shares: QoS, parameter declaration, fault reporting.

The window clock and the span grammar are core's (:mod:`quad_modelling.core.windows`).

QoS (DESIGN 5a): data topics are reliable, volatile, keep-last with a bounded
depth (parameter ``qos_depth``, default :data:`DEFAULT_QOS_DEPTH`): the replay
keeps at most ``max_in_flight`` samples unacknowledged, far below the depth, so
nothing is dropped. ``window_origin`` is reliable + transient-local depth 1, so
a node started late (or restarted) learns the window origin t0.
"""

from __future__ import annotations

import gc
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, ParameterException
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from quad_modelling.core.windows import seconds_spans
from quad_modelling.errors import ConfigError
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


def spans_check(value) -> str | None:
    """Parameter validator of named seconds spans (:func:`quad_modelling.core.windows.seconds_spans`)."""
    try:
        seconds_spans([str(v) for v in value])
    except ConfigError as err:
        return str(err)
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
