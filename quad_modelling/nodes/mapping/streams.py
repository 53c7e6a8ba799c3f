"""A node's subscriptions through a topic map: a stack's own messages -> the node's stream buffers (issue #27).

With the ``topic_map`` parameter set to a map other than the contract (``px4``, ``crazyswarm2:ROBOT``, a YAML
file; docs/formats.md), a node subscribes to each topic the map reads with the map's message type: standard
types (geometry_msgs, nav_msgs, sensor_msgs, ...) through rclpy's classes; custom types (px4_msgs,
crazyflie_interfaces) when their package is importable (the user's workspace sourced), else the node refuses
to start in one line naming the package to source (:func:`message_class`).

Every message goes through the conversion the offline reader uses
(:func:`quad_modelling.io.mapped_flight.read_mapped_bag`): :class:`~quad_modelling.io.mapped_flight.TopicReader`
(message -> stamp [ns] and numbers), then :func:`~quad_modelling.io.mapped_flight.map_commands` for the
commands and :func:`~quad_modelling.io.mapped_flight.convert_measurements` for the rest (units and frames
through :mod:`quad_modelling.core.frames`). Between the two, each field's numbers wait in a
:class:`~quad_modelling.core.alignment.MeasurementTrack` (in the map's units and frames, the attitude
quaternion interpolated as a quaternion) and are read at the command stamps, as the contract's streams are.
"""

from __future__ import annotations

import importlib
import math

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.alignment import MeasurementTrack, usable_voltage
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.errors import DataError, QuadModellingError
from quad_modelling.io import topics
from quad_modelling.io.mapped_flight import TopicReader, convert_measurements, map_commands, readers_for
from quad_modelling.io.topic_maps import CONTRACT_MAP, TopicMap, load_topic_map, parse_path
from quad_modelling.nodes.common import BadParameter, Param, stream_fault

MEASURED_FIELDS = ("position", "attitude", "velocity", "acc", "gyro")
"""Map fields a node reads besides the commands (``battery`` too when the node reads a battery)."""


def topic_map_param() -> Param:
    return Param("topic_map", CONTRACT_MAP, "the topics to read: quad (the project's contract, the *_topic parameters), a "
                                            "built-in map of another stack (px4, crazyswarm2:ROBOT) or a YAML map "
                                            "(docs/formats.md, docs/nodes.md)")


def live_topic_map(value: str, node_name: str) -> TopicMap | None:
    """The map the ``topic_map`` parameter names, None for the contract; BadParameter in one line otherwise."""
    try:
        topic_map = load_topic_map(value)
    except QuadModellingError as err:  # the loader speaks of the CLI's --topic-map; here it is the parameter
        raise BadParameter(f"{node_name}: parameter topic_map={value!r}: {str(err).removeprefix(f'--topic-map {value}: ')}") from err
    if topic_map.is_contract:
        return None
    if topic_map.has_robot:
        raise BadParameter(f"{node_name}: parameter topic_map={value!r}: the map reads one robot's topics; name it, "
                           f"e.g. topic_map:={value}:cf231")
    return topic_map


def message_class(msgtype: str, where: str) -> type:
    """rclpy's class of ``pkg/msg/Name``; BadParameter naming the package to source when it is not importable."""
    package, _, name = msgtype.split("/")
    try:
        module = importlib.import_module(f"{package}.msg")
    except ImportError as err:
        raise BadParameter(f"{where}: {package} is not importable: source the workspace that builds {package} "
                           f"(docs/nodes.md)") from err
    if not hasattr(module, name):
        raise BadParameter(f"{where}: {package} has no message {name} (the sourced {package} is another version?)")
    return getattr(module, name)


class MappedStreams:
    """The fields a node reads through ``topic_map`` (the first source of each field), message by message.

    ``fields``: the map fields besides the commands to read (those the map gives; :data:`MEASURED_FIELDS`);
    ``gap_ns``, ``capacity``: the :class:`~quad_modelling.core.alignment.MeasurementTrack` rules of the node.
    Imports no rclpy: fed with rclpy messages live, or any object with the same attributes in tests.
    """

    def __init__(self, topic_map: TopicMap, fields, gap_ns: int, capacity: int, where: str):
        self.topic_map, self.where = topic_map, where
        first = topic_map.sources(topic_map.topics)
        self.sources = {f: first[f] for f in ("commands", *fields) if f in first}
        self.readers: dict[str, TopicReader] = readers_for(topic_map, self.sources, where)
        self.command_topic = self.sources["commands"].topic
        self.tracks = {f: MeasurementTrack(len(s.paths), gap_ns, capacity, quaternion=(0, 4) if f == "attitude" else None)
                       for f, s in self.sources.items() if f != "commands"}
        self.columns = {f: [self.readers[s.topic].paths.index(p) for p in s.paths] for f, s in self.sources.items()}
        self.fields_of = {t: [f for f, s in self.sources.items() if s.topic == t] for t in self.readers}

    def describe(self) -> str:
        return "; ".join(f"{t} ({self.topic_map.topics[t].msgtype}): {', '.join(fs)}" for t, fs in self.fields_of.items())

    def read(self, topic: str, msg) -> tuple[int, dict[str, list[float]]] | None:
        """(stamp [ns], numbers of each field the topic gives) of a message; None for another instance's message."""
        reader = self.readers[topic]
        values = reader.values(msg)
        if not reader.keep(msg, values):
            return None
        return reader.stamp_ns(msg), {f: [values[i] for i in self.columns[f]] for f in self.fields_of[topic]}

    @staticmethod
    def fault(fields: dict[str, list[float]]) -> str | None:
        """Why a message's numbers are unusable (a fault kind), or None: ``nan``, a non-finite number (an infinite
        command: a NaN command is a stopped motor); ``zero_quaternion``, an attitude quaternion of norm off 1;
        ``range``, a battery reading at or below 0 V (not connected, :func:`~quad_modelling.core.alignment.usable_voltage`)."""
        for name, values in fields.items():
            if any(math.isinf(v) if name == "commands" else not math.isfinite(v) for v in values):
                return "nan"
        if not all(map(usable_voltage, fields.get("battery", ()))):
            return "range"
        attitude = fields.get("attitude")
        if attitude is not None and frames.quaternion_norm_off(attitude) is not None:
            return "zero_quaternion"
        return None

    def admit(self, topic: str, msg, faults) -> tuple[int, dict[str, list[float]]] | None:
        """(stamp [ns], fields) of a message both nodes may use, or None: another instance of a multi-instance topic
        (silently), or a fault reported to ``faults`` (the nodes' fault log: ``zero_quaternion``, ``nan_<topic>`` or
        ``range_<topic>``) and the message dropped. A NaN command (a stopped motor) is kept and reported
        (``stopped_motor_<topic>``), so the log says what the offline reader's notes count. A message the map cannot
        read (a JointState short of an effort, a PX4 odometry in a frame the map does not list) is ``bad_<topic>``: the
        predictor, unguarded, stopped on the first."""
        try:
            read = self.read(topic, msg)
        except DataError as err:
            faults.report(stream_fault("bad", topic), f"unusable {topic} message dropped ({err})")
            return None
        if read is None:
            return None
        fault = self.fault(read[1])
        if fault == "zero_quaternion":
            faults.report("zero_quaternion", f"{topic} message with a zero (non-unit) quaternion dropped")
            return None
        if fault:
            what = "non-finite" if fault == "nan" else "battery reading at or below 0 V (not connected):"
            faults.report(stream_fault(fault, topic), f"{what} {topic} message dropped")
            return None
        if any(math.isnan(v) for v in read[1].get("commands", ())):  # kept: a stopped motor, read as offline
            faults.report(stream_fault("stopped_motor", topic), f"{topic} message with a NaN command: read as a stopped motor "
                                                                 "(the map's lowest command), as the offline reader does")
        return read

    def command(self, values: list[float], vehicle) -> np.ndarray:
        """One message's commands -> the vehicle's input unit (:func:`~quad_modelling.io.mapped_flight.map_commands`)."""
        return map_commands(np.array([values], dtype=float), self.sources["commands"], vehicle, self.where)[0]

    def store(self, ns: int, fields: dict[str, list[float]]) -> bool:
        """Keep a message's measured numbers; False when its stamp is already held."""
        stored = [self.tracks[f].add(ns, v) for f, v in fields.items() if f in self.tracks]
        return all(stored)

    def clear(self, topic: str | None = None) -> None:
        for f, track in self.tracks.items():
            if topic is None or self.sources[f].topic == topic:
                track.clear()

    def covers(self, ns: int) -> bool:
        return all(track.covers(ns) for track in self.tracks.values())

    def at(self, ns: int, tolerance_ns: int) -> dict[str, np.ndarray] | None:
        """Every field's numbers at ``ns`` (exact, interpolated, nearest within tolerance), None when one has none."""
        out = {}
        for f, track in self.tracks.items():
            value = track.at(ns, tolerance_ns)
            if value is None:
                return None
            out[f] = value
        return out

    @property
    def measured_topics(self) -> list[str]:
        """The topics giving measured fields (each one a stream of the evaluator's closing and coverage rules)."""
        return list(dict.fromkeys(self.sources[f].topic for f in self.tracks))

    def field_samples(self, buffers: dict[str, dict[int, dict]], field: str) -> dict[int, list[float]]:
        """One field's samples (stamp [ns] -> numbers) out of per-topic buffers of messages' fields (the evaluator's)."""
        return {ns: fields[field] for ns, fields in buffers.get(self.sources[field].topic, {}).items()}

    def rows_log(self, stamps: np.ndarray, u: np.ndarray, measured: list[dict], vehicle: str, source: str,
                 omega: np.ndarray | None = None) -> FlightLog:
        """Command rows (stamps [ns], commands in the vehicle's unit) and their fields (:meth:`at`) -> FlightLog."""
        aligned = {f: np.array([m[f] for m in measured], dtype=float) for f in self.tracks}
        return self.flight_log(stamps, u, aligned, vehicle, source, omega)

    def flight_log(self, stamps: np.ndarray, u: np.ndarray, aligned: dict[str, np.ndarray], vehicle: str, source: str,
                   omega: np.ndarray | None = None) -> FlightLog:
        """Rows (stamps [ns], commands in the vehicle's unit, each field's (n, k) numbers in the map's units and frames
        on those rows) -> FlightLog (:func:`~quad_modelling.io.mapped_flight.convert_measurements`)."""
        arrays = convert_measurements(self.sources, aligned)
        return FlightLog(t=topics.stamps_to_seconds(np.asarray(stamps, dtype=np.int64)), u=np.asarray(u, dtype=float).reshape(-1, 4),
                         acc_b=arrays.get("acc"), gyro_b=arrays.get("gyro"), pos_n=arrays["position"], vel_n=arrays["velocity"],
                         euler=arrays["attitude"], vbat=arrays.get("battery"), omega=omega,
                         meta=FlightMeta(vehicle=vehicle, source=source, notes={}))


def lacking_attribute(msg, steps) -> bool:
    """Whether the path ``steps`` (:func:`~quad_modelling.io.topic_maps.parse_path`) names an attribute ``msg`` (a
    default message of its type) lacks; an index into an empty sequence is not judged (a message may fill it)."""
    for kind, step in steps:
        if kind == "attr":
            if not hasattr(msg, step):
                return True
            msg = getattr(msg, step)
        elif isinstance(step, int) and hasattr(msg, "__len__") and -len(msg) <= step < len(msg):
            msg = msg[step]
        else:
            return False
    return False


def subscribe(node, streams: MappedStreams, qos, handler, counting=None) -> None:
    """Subscribe ``node`` to every topic of ``streams`` with the map's message types, ``handler(topic, msg)`` per
    message (wrapped in ``counting(topic, callback)`` when given: the node's message count per topic). Every class is
    resolved before the first subscription (a missing package: one line, nothing subscribed)."""
    classes = {t: message_class(streams.topic_map.topics[t].msgtype, f"{node.get_name()}: topic_map {streams.topic_map.name} topic {t}")
               for t in streams.readers}
    for topic, kind in classes.items():  # a path the type lacks read nothing, message after message, without a word
        spec = streams.topic_map.topics[topic]
        for path in (spec.stamp, *([spec.instance] if spec.instance else []), *streams.readers[topic].paths):
            if lacking_attribute(kind(), parse_path(path, spec, streams.where)):
                raise BadParameter(f"{node.get_name()}: topic_map {streams.topic_map.name} topic {topic}: {spec.msgtype} "
                                   f"has no field {path}")
    for topic, kind in classes.items():
        def callback(msg, topic=topic):
            handler(topic, msg)

        node.create_subscription(kind, topic, counting(topic, callback) if counting else callback, qos)
