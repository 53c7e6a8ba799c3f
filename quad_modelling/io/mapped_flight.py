"""Messages of a topic map's topics -> rows of numbers -> a FlightLog: the one conversion for any map.

Used offline by :func:`quad_modelling.io.bag_io.read_mapped_bag` (messages deserialised with the
definitions stored in the bag) and meant for a live node subscribing through a map: both call
:class:`TopicReader` per message (attribute access only, so rosbags' and rclpy's messages alike) and
:func:`convert_field` for the numbers, which converts units and frames through
:mod:`quad_modelling.core.frames` only. Imports neither rclpy nor rosbags.

Offline assembly (:func:`flight_from_streams`), the rules of streams on their own clocks
(:mod:`quad_modelling.core.alignment`, DESIGN 5a):

- time base: the commands topic's own stamps (the predictors answer at each input); no command is invented;
- every other stream is interpolated onto it with :func:`~quad_modelling.core.alignment.interpolate_at`
  (linear per component, the attitude quaternion a normalised lerp of the sign-aligned pair; exact at equal
  stamps, so streams sharing the commands' stamps are taken as recorded);
- rows outside the span every kinematic stream (position, attitude, velocity, IMU) covers are cut, no
  extrapolation (the notes say how much);
- a step longer than :data:`~quad_modelling.core.alignment.MAX_GAP_S` (the live coverage rule's longest gap)
  of a kinematic stream around kept rows is marked as a measurement gap: windows and training segments
  overlapping it are left out, as the live evaluator marks such windows;
- a stream whose stamps do not overlap the commands' for at least half of the shorter span is on another
  clock (e.g. an on-board ``timestamp`` next to ``header.stamp``): refused in one line.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass, field

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.alignment import MAX_GAP_S, interpolate_at
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.preprocess import MeasurementGap, interpolation_gaps, mark_measurement_gaps
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError, DataError
from quad_modelling.io.topic_maps import STAMP_UNITS, FieldSource, TopicMap, TopicSpec, parse_path

NANOSECONDS = 1_000_000_000
KINEMATIC_FIELDS = ("position", "attitude", "velocity", "acc", "gyro")
"""Fields whose streams bound the flight's span and whose long gaps are marked (battery is held and interpolated)."""

GAP_FIELDS = {"position": ("pos_n",), "attitude": ("euler",), "velocity": ("vel_n",), "acc": ("acc_b",), "gyro": ("gyro_b",)}
"""FlightLog fields of each map field (a marked gap names them)."""

SAME_CLOCK_OVERLAP = 0.5
"""Fraction of the shorter span two streams on one clock overlap at least (a late-discovered topic is fine)."""

HOLD_S = 1e6
"""Hold/interpolation limit [s] passed to interpolate_at for values: gaps are marked (not NaN) by the gap rule."""

CHUNK_ROWS = 65536
"""Rows per chunk a stream's numbers are collected in (memory grows with the rows kept, not with message objects)."""


# --- static check of a map against the message definitions ------------------------------------

@dataclass(frozen=True)
class FieldType:
    """One message field as a definition gives it: a nested message type, or a base type; array length or sequence."""

    nested: str | None
    base: str | None
    length: int | None = None
    sequence: bool = False


NUMERIC = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "octet"}
TIME_TYPE = "builtin_interfaces/msg/Time"


def check_path(path: str, spec: TopicSpec, fields_of, where: str, stamp: bool = False) -> None:
    """ConfigError naming the field, the topic and its message type unless ``path`` reaches a number (``stamp``: a
    number or a builtin_interfaces/Time) in ``spec.msgtype``; ``fields_of(msgtype)`` -> {name: FieldType}."""
    msgtype = spec.msgtype
    current: FieldType | None = None
    what = f"{where}: field {path!r} of topic {spec.name} ({spec.msgtype})"
    steps = parse_path(path, spec, where)
    for kind, value in steps:
        if kind == "attr":
            if current is not None:
                if current.nested is None or current.length is not None or current.sequence:
                    raise ConfigError(f"{what}: {value!r} follows a field that is not a message")
                msgtype = current.nested
            known = fields_of(msgtype)
            if value not in known:
                raise ConfigError(f"{what}: {msgtype} has no field {value!r} (fields: {', '.join(known)})")
            current = known[value]
        else:
            if current is None or (current.length is None and not current.sequence):
                raise ConfigError(f"{what}: [{value}] indexes a field that is not an array")
            if current.length is not None and value >= current.length:
                raise ConfigError(f"{what}: index {value} is beyond the field's {current.length} elements")
            current = FieldType(current.nested, current.base)
    if current is None or current.length is not None or current.sequence:
        raise ConfigError(f"{what}: does not name one number")
    if current.base in NUMERIC and not (stamp and spec.stamp_unit is None):
        return
    if stamp and spec.stamp_unit is None and current.nested == TIME_TYPE:
        return
    expected = "a builtin_interfaces/Time (or give stamp_unit for an integer stamp)" if stamp and spec.stamp_unit is None else "a number"
    raise ConfigError(f"{what}: is {current.base or current.nested}, not {expected}")


def check_map_fields(topic_map: TopicMap, sources: dict[str, FieldSource], fields_of, where: str) -> None:
    """Every stamp, instance and field path the ``sources`` read exists in the topics' message definitions."""
    for topic in dict.fromkeys(s.topic for s in sources.values()):
        spec = topic_map.topics[topic]
        check_path(spec.stamp, spec, fields_of, where, stamp=True)
        if spec.instance:
            check_path(spec.instance, spec, fields_of, where)
    for source in sources.values():
        for path in source.paths:
            check_path(path, topic_map.topics[source.topic], fields_of, where)


# --- message -> numbers -------------------------------------------------------------------------

def _getter(steps):
    """A callable msg -> value following parsed path steps (attributes and indexes)."""
    ops = [operator.attrgetter(v) if k == "attr" else operator.itemgetter(v) for k, v in steps]

    def get(msg):
        for op in ops:
            msg = op(msg)
        return msg
    return get


class TopicReader:
    """One mapped topic: each message -> (stamp [ns], numbers of every path the map reads from it); collects rows.

    ``paths``: the message field paths read (in order). With an ``instance`` field, only messages of the first
    instance seen are kept (:attr:`instances` counts the instances seen).
    """

    def __init__(self, spec: TopicSpec, paths: list[str], where: str):
        self.spec = spec
        self.paths = list(paths)
        self._stamp = _getter(parse_path(spec.stamp, spec, where))
        self._values = [_getter(parse_path(p, spec, where)) for p in self.paths]
        self._instance = _getter(parse_path(spec.instance, spec, where)) if spec.instance else None
        self._factor = STAMP_UNITS[spec.stamp_unit] if spec.stamp_unit else None
        self.instances: dict = {}
        self.count = 0
        self._chunks: list[np.ndarray] = []
        self._stamps: list[np.ndarray] = []
        self._rows = np.empty((CHUNK_ROWS, len(self.paths)))
        self._row_stamps = np.empty(CHUNK_ROWS, dtype=np.int64)
        self._filled = 0

    def stamp_ns(self, msg) -> int:
        """The message's stamp [ns] (a builtin_interfaces/Time, or an integer field times its unit)."""
        value = self._stamp(msg)
        if self._factor is None:
            return value.sec * NANOSECONDS + value.nanosec
        return int(value) * self._factor

    def values(self, msg) -> list[float]:
        """The numbers of every path, in :attr:`paths` order."""
        return [float(get(msg)) for get in self._values]

    def keep(self, msg) -> bool:
        """False for a message of another instance than the first one seen (counted in :attr:`instances`)."""
        if self._instance is None:
            return True
        which = self._instance(msg)
        self.instances[which] = self.instances.get(which, 0) + 1
        return which == next(iter(self.instances))

    def add(self, msg) -> None:
        """Convert and keep one message (streamed: rows go into fixed-size numpy chunks)."""
        if not self.keep(msg):
            return
        if self._filled == CHUNK_ROWS:
            self._flush()
        self._row_stamps[self._filled] = self.stamp_ns(msg)
        self._rows[self._filled] = self.values(msg)
        self._filled += 1
        self.count += 1

    def _flush(self) -> None:
        self._chunks.append(self._rows[:self._filled].copy())
        self._stamps.append(self._row_stamps[:self._filled].copy())
        self._filled = 0

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (n,) [ns], values (n, len(paths))) of every kept message, in arrival order."""
        self._flush()
        stamps = np.concatenate(self._stamps) if self._stamps else np.zeros(0, dtype=np.int64)
        values = np.concatenate(self._chunks) if self._chunks else np.zeros((0, len(self.paths)))
        self._chunks, self._stamps = [], []
        return stamps, values


def readers_for(topic_map: TopicMap, sources: dict[str, FieldSource], where: str) -> dict[str, TopicReader]:
    """One :class:`TopicReader` per topic the chosen ``sources`` read, with every path of that topic."""
    paths: dict[str, list[str]] = {}
    for source in sources.values():
        paths.setdefault(source.topic, [])
        paths[source.topic] += [p for p in source.paths if p not in paths[source.topic]]
    return {topic: TopicReader(topic_map.topics[topic], wanted, where) for topic, wanted in paths.items()}


# --- numbers -> internal frames and units ----------------------------------------------------------

def commands_in_vehicle_unit(values: np.ndarray, source: FieldSource, vehicle: VehicleConfig, where: str) -> np.ndarray:
    """Commands as the map gives them -> the vehicle's input unit: as they are when the units agree (or ``unit:
    vehicle``), else mapped linearly from the map's ``range`` [a, b] onto the vehicle's [min, max]:
    :math:`u = u_{min} + (x - a) (u_{max} - u_{min}) / (b - a)`."""
    if source.unit in ("vehicle", vehicle.input_unit):
        return values
    if source.range is None:
        raise ConfigError(f"{where}: commands of topic {source.topic} are in {source.unit!r}, vehicle {vehicle.name} takes "
                          f"{vehicle.input_unit!r}: give the map's commands a range: [low, high] to map them linearly")
    low, high = source.range
    return vehicle.input_min + (values - low) * ((vehicle.input_max - vehicle.input_min) / (high - low))


def attitude_euler(quat: np.ndarray, source: FieldSource) -> np.ndarray:
    """(n, 4) quaternions in the map's order and frame -> Euler (φ, θ, ψ) NED/FRD [rad], yaw not unwrapped."""
    xyzw = quat if source.order == "xyzw" else quat[:, [1, 2, 3, 0]]
    if source.frame == "ENU/FLU":
        return frames.quat_enu_to_euler_ned(xyzw)
    return frames.quat_ned_to_euler_ned(xyzw)


def convert_field(source: FieldSource, values: np.ndarray, euler: np.ndarray | None = None) -> np.ndarray:
    """(n, k) numbers of one non-command field, as the map gives them -> the FlightLog field (NED/FRD, SI).

    position -> pos_n [m]; velocity -> vel_n [m/s] (a body-frame velocity rotated by ``euler``, the attitude at
    the same rows); attitude -> euler [rad]; acc -> acc_b [m/s²]; gyro -> gyro_b [rad/s]; battery -> vbat [V].
    """
    if source.field == "attitude":
        return attitude_euler(values, source)
    si = frames.to_si(values, source.unit)
    if source.field == "battery":
        return si[:, 0]
    if source.frame == "ENU":
        return frames.enu_to_ned(si)
    if source.frame == "FLU":
        si = frames.flu_to_frd(si)
    if source.field == "velocity" and source.frame in ("FLU", "FRD"):
        return frames.body_to_nav(si, euler)
    return si


# --- streams -> FlightLog ---------------------------------------------------------------------------

@dataclass
class Stream:
    """One topic's kept messages: stamps [ns], the numbers of each path, its reader (for the notes)."""

    topic: str
    stamps: np.ndarray
    values: np.ndarray
    paths: list[str]
    instances: dict = field(default_factory=dict)

    def columns(self, source: FieldSource) -> np.ndarray:
        return self.values[:, [self.paths.index(p) for p in source.paths]]


def checked_stream(reader: TopicReader, where: str) -> Stream:
    """The reader's rows as a :class:`Stream`; DataError for no message or stamps going back (naming topic and
    message); exact repeats of a stamp keep the first message."""
    stamps, values = reader.finish()
    topic = reader.spec.name
    if len(stamps) == 0:
        raise DataError(f"{where}: topic {topic} has no messages")
    steps = np.diff(stamps)
    if np.any(steps < 0):
        k = int(np.argmax(steps < 0)) + 1
        raise DataError(f"{where}: topic {topic} stamps ({reader.spec.stamp}) go back at message {k}")
    keep = np.concatenate([[True], steps > 0])
    return Stream(topic, stamps[keep], values[keep], reader.paths, dict(reader.instances))


def check_same_clock(streams: dict[str, Stream], base: str, where: str) -> None:
    """DataError when a stream's stamps do not overlap the base stream's for at least :data:`SAME_CLOCK_OVERLAP` of
    the shorter span: stamps from another clock (module doc)."""
    b0, b1 = streams[base].stamps[0], streams[base].stamps[-1]
    for topic, stream in streams.items():
        s0, s1 = stream.stamps[0], stream.stamps[-1]
        overlap = min(b1, s1) - max(b0, s0)
        shorter = min(b1 - b0, s1 - s0)
        if overlap < SAME_CLOCK_OVERLAP * shorter or (shorter == 0 and not b0 <= s0 <= b1):
            raise DataError(
                f"{where}: topic {topic} stamps span {s0 / 1e9:.3f}..{s1 / 1e9:.3f} s, topic {base} {b0 / 1e9:.3f}..{b1 / 1e9:.3f} s: "
                "stamps from another clock; stamp every topic of the map on one clock (e.g. header.stamp everywhere)")


def _finite(stream: Stream, source: FieldSource, columns: np.ndarray, where: str) -> None:
    bad = ~np.isfinite(columns)
    if bad.any():
        k = int(np.argmax(bad.any(axis=1)))
        raise DataError(f"{where}: topic {stream.topic} message {k} field {source.paths[int(np.argmax(bad[k]))]} is not finite")


def rate_hz(stamps: np.ndarray) -> float:
    span = (stamps[-1] - stamps[0]) / 1e9 if len(stamps) > 1 else 0.0
    return (len(stamps) - 1) / span if span > 0 else 0.0


def flight_from_streams(topic_map: TopicMap, sources: dict[str, FieldSource], streams: dict[str, Stream], vehicle: VehicleConfig,
                        where: str, notes: dict | None = None) -> FlightLog:
    """The FlightLog of a map's streams (module doc), commands in ``vehicle``'s input unit."""
    base = sources["commands"].topic
    check_same_clock(streams, base, where)
    kinematic = {sources[f].topic for f in KINEMATIC_FIELDS if f in sources}
    start = max(streams[t].stamps[0] for t in kinematic | {base})
    end = min(streams[t].stamps[-1] for t in kinematic | {base})
    t_all = streams[base].stamps
    inside = (t_all >= start) & (t_all <= end)
    if inside.sum() < 2:
        raise DataError(f"{where}: the topics {', '.join(sorted(kinematic | {base}))} share no common time span")
    t_ns = t_all[inside]
    commands = streams[base].columns(sources["commands"])[inside]
    stopped = np.isnan(commands)
    notes = {"format": f"bag (topic map {topic_map.name})", **(notes or {})}
    if stopped.any():  # PX4 actuator_motors: NaN = motor stopped, read as the range's low end (as the ULog reader)
        low = sources["commands"].range[0] if sources["commands"].range else 0.0
        commands = np.where(stopped, low, commands)
        notes["motor_nan"] = f"{int(stopped.sum())} NaN commands (motor stopped) read as {low:g}"
    _finite(streams[base], sources["commands"], commands, where)
    at = {}
    for name, source in sources.items():
        if name == "commands":
            continue
        stream = streams[source.topic]
        columns = stream.columns(source)
        _finite(stream, source, columns, where)
        if name == "attitude":
            bad = frames.non_unit_quaternion(columns)
            if bad:
                raise DataError(f"{where}: topic {source.topic} message {bad[0]} has an attitude quaternion of norm {bad[1]:.3g}, not 1")
        quaternion = (0, 4) if name == "attitude" else None
        at[name] = interpolate_at(stream.stamps, columns, t_ns, quaternion=quaternion, max_gap_s=HOLD_S)
    euler = convert_field(sources["attitude"], at["attitude"])
    euler[:, 2] = np.unwrap(euler[:, 2])
    t = t_ns / 1e9
    gaps = {MeasurementGap(sources[f].topic, a, b, GAP_FIELDS[f])
            for f in KINEMATIC_FIELDS if f in sources
            for a, b in interpolation_gaps(streams[sources[f].topic].stamps / 1e9, t, MAX_GAP_S)}
    cut = (t_all[-1] - t_all[0] - (t_ns[-1] - t_ns[0])) / 1e9
    notes["time_base"] = f"{base} stamps, {rate_hz(t_ns):.1f} Hz; {cut:.2f} s outside the span all kinematic streams cover cut"
    notes["sources"] = {name: f"{s.topic} {', '.join(s.paths)} ({s.unit or s.order}, {s.frame or '-'}), "
                              f"{rate_hz(streams[s.topic].stamps):.1f} Hz" for name, s in sources.items()}
    instances = {t: f"{len(s.instances)} instances seen, {topic_map.topics[t].instance} {next(iter(s.instances))} used"
                 for t, s in streams.items() if len(s.instances) > 1}
    if instances:
        notes["instances"] = instances
    log = FlightLog(
        t=t,
        u=commands_in_vehicle_unit(commands, sources["commands"], vehicle, where),
        acc_b=convert_field(sources["acc"], at["acc"]) if "acc" in at else None,
        gyro_b=convert_field(sources["gyro"], at["gyro"]) if "gyro" in at else None,
        pos_n=convert_field(sources["position"], at["position"]),
        vel_n=convert_field(sources["velocity"], at["velocity"], euler),
        euler=euler,
        vbat=convert_field(sources["battery"], at["battery"]) if "battery" in at else None,
        meta=FlightMeta(vehicle=vehicle.name, source=where, notes=notes),
    )
    mark_measurement_gaps(log, sorted(gaps, key=lambda g: (g.start_s, g.topic)), MAX_GAP_S)
    return log
