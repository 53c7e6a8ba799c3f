"""The rclpy binding of the topic contract (:mod:`quad_modelling.io.topics`).

The conversion between FlightLog rows and messages, the field layouts and the frames
are written once in :mod:`quad_modelling.io.topics`, shared with the bag reader and
writer; this module only supplies rclpy's message classes to it and the messages
the bag has no counterpart for (rosgraph_msgs/Clock: ``/clock``, ``window_origin``,
``evaluation/progress``).
"""

from __future__ import annotations

import importlib
import struct

from builtin_interfaces.msg import Time
from rosgraph_msgs.msg import Clock

import numpy as np

from quad_modelling.core.flight_log import (
    ACCEL_FULL_SCALE,
    GYRO_FULL_SCALE,
    POSITION_LIMIT,
    SATURATION_MARGIN,
    VELOCITY_LIMIT,
    FlightLog,
)
from quad_modelling.io import topics
from quad_modelling.nodes.common import IMU, MOCAP_ODOM, MOTOR_INPUT, stream_fault
from quad_modelling.io.topics import (
    NANOSECONDS,
    WORLD_FRAME,
    MeasurementMessages,
    MessageTypes,
    PredictionMessages,
)


def rclpy_message_class(name: str) -> type:
    """``geometry_msgs/msg/Point`` -> rclpy's generated class ``geometry_msgs.msg.Point``."""
    package, _, message = name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), message)


RCLPY_TYPES = MessageTypes.from_lookup(rclpy_message_class)
"""The contract's message classes as rclpy's generated messages."""


def ns_stamp(ns: int) -> Time:
    """Integer nanoseconds -> builtin_interfaces/Time."""
    ns = int(ns)
    return Time(sec=ns // NANOSECONDS, nanosec=ns % NANOSECONDS)


def clock_message(ns: int) -> Clock:
    """rosgraph_msgs/Clock at ``ns`` (also the window origin and the evaluator's progress acknowledgement)."""
    return Clock(clock=ns_stamp(ns))


def measurement_messages(log: FlightLog) -> MeasurementMessages:
    """The measurement messages of ``log`` as rclpy messages (refilled per row)."""
    return MeasurementMessages(log, RCLPY_TYPES)


def prediction_publisher_messages(child_frame: str, world_frame: str = WORLD_FRAME) -> PredictionMessages:
    """One predictor's reusable rclpy (Odometry, AccelStamped) pair."""
    return PredictionMessages(RCLPY_TYPES, child_frame, world_frame)


class SerializedPredictions:
    """One predictor's (Odometry, AccelStamped) pair as serialized CDR bytes, what ``Publisher.publish`` sends as they
    are: rclpy serializes the filled pair (:class:`~quad_modelling.io.topics.PredictionMessages`) once; each
    prediction then writes only its stamp and its 13 + 6 numbers into a copy, at the offsets where the serialization
    put probe values (the frames and covariances never change). They deserialize to the filled pair (test); in the
    node a publication took ~22 us instead of ~65 us with rclpy converting the message in ``publish`` (session 40,
    timed around ``publish`` in ``bench_nodes.forecast_cost``, greybox, three alternated pairs)."""

    def __init__(self, child_frame: str, world_frame: str = WORLD_FRAME):
        from rclpy.serialization import serialize_message

        rng = np.random.default_rng(0)  # probe values: no two alike, none in the messages' other bytes
        ns = 1_234_567_890 * NANOSECONDS + 987_654_321
        odom, accel = rng.uniform(1e3, 2e3, 13), rng.uniform(2e3, 3e3, 6)
        probes = prediction_publisher_messages(child_frame, world_frame).fill(ns, odom, accel)
        stamp = [("i", ns // NANOSECONDS), ("I", ns % NANOSECONDS)]
        self._odom, self._accel = (_Template(serialize_message(message), stamp + [("d", v) for v in values.tolist()])
                                   for message, values in zip(probes, (odom, accel)))

    def fill(self, ns: int, odom: np.ndarray, accel: np.ndarray) -> tuple[bytes, bytes]:
        """One row of prediction fields -> the (Odometry, AccelStamped) bytes stamped ``ns``."""
        sec, nanosec = divmod(int(ns), NANOSECONDS)
        return self._odom.fill([sec, nanosec, *odom.tolist()]), self._accel.fill([sec, nanosec, *accel.tolist()])

    def odometry(self, ns: int, odom: np.ndarray) -> bytes:
        """The Odometry of :meth:`fill` alone (the receding horizon publishes no AccelStamped)."""
        return self._odom.fill([*divmod(int(ns), NANOSECONDS), *odom.tolist()])


class _Template:
    """Serialized bytes and where each of its probed fields lies: contiguous fields written by one struct each."""

    def __init__(self, raw: bytes, probes: list[tuple[str, float]]):
        endian = "<" if raw[1:2] == b"\x01" else ">"  # the CDR encapsulation: 0x0001 little endian, 0x0000 big
        found = []
        for index, (code, value) in enumerate(probes):
            packed = struct.pack(endian + code, value)
            if raw.count(packed) != 1:
                raise RuntimeError(f"serialized prediction: probe {index} found {raw.count(packed)} times")
            found.append((raw.index(packed), len(packed), code, index))
        found.sort()
        self.raw, self.runs = bytearray(raw), []
        for offset, size, code, index in found:  # (offset, struct of the run, value indices)
            last = self.runs[-1] if self.runs else None
            if last is not None and last[0] + last[1].size == offset:
                self.runs[-1] = (last[0], struct.Struct(last[1].format + code), last[2] + [index])
            else:
                self.runs.append((offset, struct.Struct(endian + code), [index]))

    def fill(self, values: list) -> bytes:
        for offset, layout, indices in self.runs:
            layout.pack_into(self.raw, offset, *[values[i] for i in indices])
        return bytes(self.raw)


def prediction_messages(ns: int, odom, accel, child_frame: str, world_frame: str = WORLD_FRAME):
    """One row of prediction fields -> a new rclpy (Odometry, AccelStamped) pair stamped ``ns``."""
    return prediction_publisher_messages(child_frame, world_frame).fill(ns, odom, accel)


# --- intake checks: what a node drops from a stream (one rule for the predictors and the evaluator) ---

SAMPLE_LIMITS = {MOCAP_ODOM: (("position", slice(0, 3), POSITION_LIMIT, "m"), ("velocity", slice(7, 10), VELOCITY_LIMIT, "m/s")),
                 IMU: (("specific force", slice(0, 3), ACCEL_FULL_SCALE, "m/s²"), ("rate", slice(3, 6), GYRO_FULL_SCALE, "rad/s"))}
"""Per stream, the (quantity, fields of its message, bound, unit) a sample may not exceed (flight_log's bounds)."""


def beyond_bounds(stream: str, values) -> str | None:
    """Why a finite measurement message is impossible (a corrupt or wrongly scaled value, e.g. 1e300), or None: the
    bounds a flight log holds (:mod:`quad_modelling.core.flight_log`): position and velocity of ``mocap_odom``
    (:func:`~quad_modelling.io.topics.odometry_fields` order), specific force and rates of ``imu``."""
    for what, part, limit, unit in SAMPLE_LIMITS.get(stream, ()):
        big = [v for v in values[part] if abs(v) > limit]  # NaN (not measured) compares False
        if big:
            return f"{what} {big[0]:.4g} {unit} beyond ±{limit:.4g} {unit}"
    return None


def command_beyond_range(vehicle, u) -> str | None:
    """Why a command (4,) in ``vehicle``'s unit is impossible -- more than ``SATURATION_MARGIN`` of the input range past
    either end, what a flight log refuses (:func:`~quad_modelling.core.flight_log.saturate_commands`) -- or None
    (within the margin the actuator saturates: the caller clips)."""
    low, high = vehicle.input_min, vehicle.input_max
    margin = SATURATION_MARGIN * (high - low)
    if min(u) < low - margin or max(u) > high + margin:
        return f"a command beyond the vehicle's input range [{low:g}, {high:g}] {vehicle.input_unit}"
    return None


def dropped(faults, stream: str, values, what: str) -> bool:
    """Report and True when a measurement message is unusable: a non-finite value (``nan_<stream>``) or an impossible
    one (``range_<stream>``, :func:`beyond_bounds`); ``what`` names the message in the warning."""
    if not topics.all_finite(values):
        faults.report(stream_fault("nan", stream), f"non-finite {what} dropped")
        return True
    if (why := beyond_bounds(stream, values)) is not None:
        faults.report(stream_fault("range", stream), f"{what} dropped: {why}")
        return True
    return False


def admitted_command(faults, vehicle, u):
    """The command (4,) to use, clipped to ``vehicle``'s input range (the actuators saturate), or None (reported,
    ``range_motor_input``) for one beyond it by more than the margin (:func:`command_beyond_range`)."""
    if (why := command_beyond_range(vehicle, u)) is not None:
        faults.report(stream_fault("range", MOTOR_INPUT), f"motor_input dropped: {why}")
        return None
    return np.minimum(np.maximum(u, vehicle.input_min), vehicle.input_max)  # np.clip's numbers at a fraction of its cost


def check_odometry_frames(faults, msg) -> None:
    """Report (not drop) an odometry message whose frames say it is not the contract's (pose in an ENU world frame,
    twist in the FLU ``base_link``): a frame named NED or FRD, or the twist in the pose's own frame. Read as the
    contract either way (a stack in NED/FRD needs a topic map); said once, then counted as fault ``odom_frames``.
    ``map_ned`` / ``base_link_frd`` were read silently as ENU / FLU (review of session 33)."""
    world, child = msg.header.frame_id, msg.child_frame_id
    if any(tag in name.lower() for name in (world, child) for tag in ("ned", "frd")) or (child and child == world):
        faults.report("odom_frames", f"odometry in frames {world!r} / {child!r}, read as the contract's ENU world and FLU "
                                     f"{topics.BODY_FRAME} (a NED/FRD stack needs a topic map: parameter topic_map)")
