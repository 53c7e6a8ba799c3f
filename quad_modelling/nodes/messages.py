"""The rclpy binding of the topic contract (:mod:`quad_modelling.io.topics`).

The conversion between FlightLog rows and messages, the field layouts and the frames
are written once in :mod:`quad_modelling.io.topics`, shared with the bag reader and
writer; this module only supplies rclpy's message classes to it and the messages
the bag has no counterpart for (rosgraph_msgs/Clock: ``/clock``, ``window_origin``,
``evaluation/progress``).
"""

from __future__ import annotations

import importlib

from builtin_interfaces.msg import Time
from rosgraph_msgs.msg import Clock

from quad_modelling.core.flight_log import FlightLog
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


def prediction_messages(ns: int, odom, accel, child_frame: str, world_frame: str = WORLD_FRAME):
    """One row of prediction fields -> a new rclpy (Odometry, AccelStamped) pair stamped ``ns``."""
    return prediction_publisher_messages(child_frame, world_frame).fill(ns, odom, accel)
