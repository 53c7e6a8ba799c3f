"""Messages of a topic map's topics -> rows of numbers -> a FlightLog: the one conversion for any map.

Used offline by :func:`read_mapped_bag` (messages deserialised with the
definitions stored in the bag) and live by the nodes' ``topic_map`` subscriptions
(:mod:`quad_modelling.nodes.mapping.streams`, rclpy's messages): both call
:class:`TopicReader` per message (attribute access only, so rosbags' and rclpy's messages alike),
:func:`map_commands` and :func:`convert_measurements` (:func:`~quad_modelling.io.field_conversion.convert_field` per field) for the numbers, which
convert units and frames through
:mod:`quad_modelling.core.frames` only. Imports neither rclpy nor rosbags.

Offline assembly (:func:`flight_from_streams`), the rules of streams on their own clocks
(:mod:`quad_modelling.core.alignment`, DESIGN 5a):

- time base: the commands topic's own stamps (the predictors answer at each input); no command is invented;
- every other stream is interpolated onto it with :func:`~quad_modelling.core.alignment.interpolate_at`
  (linear per component, the attitude quaternion a normalised lerp of the sign-aligned pair; exact at equal
  stamps, so streams sharing the commands' stamps are taken as recorded);
- rows outside the span every kinematic stream (position, attitude, velocity, IMU) covers are cut, no
  extrapolation (the notes say how much; a cut over :data:`CUT_WARNING_S` is warned about);
- a step longer than :data:`~quad_modelling.core.alignment.MAX_GAP_S` (the live coverage rule's longest gap)
  of a kinematic stream around kept rows is marked as a measurement gap: windows and training segments
  overlapping it are left out, as the live evaluator marks such windows;
- a stream whose stamps do not overlap the commands' for at least half of the shorter span is on another
  clock (e.g. an on-board ``timestamp`` next to ``header.stamp``): refused in one line;
- the battery (optional, slow) bounds nothing: its readings at 0 V or not finite are skipped (a monitor not
  connected; of a multi-instance topic, the first instance with a usable reading is read), the rest put on the
  rows at the end, held beyond its first and last, a late start, early end or pause noted
  (:func:`~quad_modelling.core.alignment.battery_on_rows`).
"""

from __future__ import annotations

import operator
import math
from pathlib import Path

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.alignment import (MAX_GAP_S, MAX_STAMP_STEP_S, Stamp, StampGate, battery_on_rows, check_one_clock,
                                           interpolate_at, usable_voltage)
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.consistency import consistency_warnings
from quad_modelling.core.preprocess import MeasurementGap, mark_measurement_gaps
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import BagError, ConfigError, DataError, reason
from quad_modelling.io.bag_io import READ_ERRORS, missing_messages, open_reader, stored_typestore
from quad_modelling.io.field_conversion import convert_field, frame_notes, message_frames
from quad_modelling.io.topics import NANOSECONDS
from quad_modelling.io.topic_maps import STAMP_UNITS, FieldSource, TopicMap, TopicSpec, check_map_fields, fields_of_store, parse_path

KINEMATIC_FIELDS = ("position", "attitude", "velocity", "acc", "gyro")
"""Fields whose streams bound the flight's span and whose long gaps are marked (the battery is read apart, module doc)."""

GAP_FIELDS = {"position": ("pos_n",), "attitude": ("euler",), "velocity": ("vel_n",), "acc": ("acc_b",), "gyro": ("gyro_b",)}
"""FlightLog fields of each map field (a marked gap names them)."""

CUT_WARNING_S = 1.0
"""Commands [s] outside the span every kinematic stream covers beyond which the cut is warned about (topics
discovered a moment apart cut a fraction of a second; a stream that stopped mid-flight cuts the rest of it)."""

HOLD_S = 1e6
"""Hold/interpolation limit [s] passed to interpolate_at for values: gaps are marked (not NaN) by the gap rule."""

EMIT_ROWS = 8192
"""Pending command rows aligned in one batch (the buffers of the other streams hold about this span)."""

SAME_STAMP_NS = 1_000
"""Stamps of one stream closer than this [ns] are one stamp (the first message kept): float64 seconds since the epoch
resolve about 0.2 us, and two rows 128 ns apart were one time, refused as 'time is not strictly increasing'."""

MAX_COMMAND_RATE_HZ = 5000.0
"""Fastest engine-input stream read as such: a flight stack commands its motors at tens to hundreds of Hz (PX4
actuator_motors up to about 1 kHz); a faster one is stamps in a unit 1000x coarser than the map's stamp_unit says (us
stamps under a map's ns: 100 kHz, a 40 s flight read as 0.04 s)."""

MAX_PENDING_S = 60.0
"""Longest span [s] of command rows held while a stream has not reached them: then a stream that lags is on another
clock (refused), has ended (the rows after its last message are cut, as at the end) or has not started (the rows
before its first message are cut)."""


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
    """One mapped topic: each message -> (stamp [ns], numbers of every path the map reads from it).

    ``paths``: the message field paths read (in order). With an ``instance`` field, only messages of the first
    instance seen with a ``usable`` reading are kept (:meth:`keep`; :attr:`instances` counts the messages of each
    instance seen; :attr:`chosen` the one read): ``usable`` tells a message's values measure something (a battery
    topic: :func:`~quad_modelling.core.alignment.usable_voltage`, so PX4's unused battery slot at 0 V is not read).
    ``frames``: the frames each message names (:class:`~quad_modelling.io.field_conversion.MessageFrames`), applied
    to the numbers of each kept message (:meth:`keep`).
    """

    def __init__(self, spec: TopicSpec, paths: list[str], where: str, usable=None, frames=None):
        self.spec = spec
        self.paths = list(paths)
        self._stamp = _getter(parse_path(spec.stamp, spec, where))
        self._values = [_getter(parse_path(p, spec, where)) for p in self.paths]
        self._instance = _getter(parse_path(spec.instance, spec, where)) if spec.instance else None
        self._factor = STAMP_UNITS[spec.stamp_unit] if spec.stamp_unit else None
        self.instances: dict = {}
        self.chosen = None
        self.usable = usable
        self.frames = frames
        self._frame_codes = [_getter(parse_path(s.frame_field, spec, where)) for s in frames.sources] if frames else []
        self.where = where
        self.read = 0  # messages whose values were read (the index a fault names)

    def _field(self, read, path: str, msg, index: int):
        """``read(msg)``; DataError naming topic, field and message index when the message lacks it (a JointState with 3
        efforts for ``effort[3]``, a map's stamp or instance path the type does not have: the predictor stopped)."""
        try:
            return read(msg)
        except (IndexError, AttributeError, TypeError, ValueError, KeyError) as err:
            raise DataError(f"{self.where}: topic {self.spec.name} message {index} has no usable field {path} "
                            f"({type(err).__name__}: {err})") from err

    def stamp_ns(self, msg) -> int:
        """The message's stamp [ns] (a builtin_interfaces/Time, or an integer field times its unit)."""
        if self._factor is None:
            return self._field(lambda m: (v := self._stamp(m)).sec * NANOSECONDS + v.nanosec, self.spec.stamp, msg, self.read - 1)
        return self._field(lambda m: int(self._stamp(m)) * self._factor, self.spec.stamp, msg, self.read - 1)

    def values(self, msg) -> list[float]:
        """The numbers of every path, in :attr:`paths` order (:meth:`_field`)."""
        index, self.read = self.read, self.read + 1
        return [self._field(lambda m, get=get: float(get(m)), path, msg, index) for path, get in zip(self.paths, self._values)]

    def keep(self, msg, values: list[float]) -> bool:
        """False for a message of another instance than the first one seen with usable ``values`` (its numbers,
        :meth:`values`; every instance counted in :attr:`instances`). A kept message's numbers are then read in the
        frames it names (:attr:`frames`, ``values`` changed in place): another instance's frame is never checked."""
        if self._instance is not None:
            which = self._field(self._instance, self.spec.instance, msg, self.read - 1)
            self.instances[which] = self.instances.get(which, 0) + 1
            if self.chosen is None and (self.usable is None or self.usable(values)):
                self.chosen = which
            if which != self.chosen:
                return False
        if self.frames is not None:
            self.frames.apply([self._field(get, s.frame_field, msg, self.read - 1) for get, s in zip(self._frame_codes, self.frames.sources)],
                              values, self.read - 1)
        return True


def readers_for(topic_map: TopicMap, sources: dict[str, FieldSource], where: str) -> dict[str, TopicReader]:
    """One :class:`TopicReader` per topic the chosen ``sources`` read, with every path of that topic."""
    paths: dict[str, list[str]] = {}
    for source in sources.values():
        paths.setdefault(source.topic, [])
        paths[source.topic] += [p for p in source.paths if p not in paths[source.topic]]
    battery = battery_topic(sources)
    return {topic: TopicReader(topic_map.topics[topic], wanted, where,
                               usable=(lambda values: all(map(usable_voltage, values))) if topic == battery else None,
                               frames=message_frames(topic_map, sources, topic, wanted, where))
            for topic, wanted in paths.items()}


def battery_topic(sources: dict[str, FieldSource]) -> str | None:
    """The topic of the map's battery when it carries nothing else (read apart, :class:`FlightAssembler`), or None."""
    if "battery" not in sources:
        return None
    topic = sources["battery"].topic
    return topic if all(s.topic != topic for name, s in sources.items() if name != "battery") else None


def instance_notes(readers: dict[str, TopicReader], bag_topics) -> dict:
    """Notes on multi-instance topics (as the ULog reader's): a topic with several instances (the first one read) and
    instance topics ``<topic>_N`` of the bag that are not read."""
    notes: dict = {}
    several = {t: f"{len(r.instances)} instances seen, " + (f"{r.spec.instance} {r.chosen} used" if r.chosen is not None
                                                            else "none with a usable reading")
               for t, r in readers.items() if len(r.instances) > 1}
    if several:
        notes["instances"] = several
    extra = sorted(t for t in bag_topics if any(t.startswith(f"{s}_") and t[len(s) + 1:].isdigit() for s in readers))
    if extra:
        notes["instance_topics"] = f"{', '.join(extra)} not read (instance 0 topics used)"
    return notes


# --- numbers -> internal frames and units ----------------------------------------------------------

def commands_in_vehicle_unit(values: np.ndarray, source: FieldSource, vehicle: VehicleConfig, where: str) -> np.ndarray:
    """Commands as the map gives them -> the vehicle's input unit: as they are when the units agree (or ``unit:
    vehicle``), converted when both are units of one dimension (a pulse width in us for a vehicle in s:
    :func:`~quad_modelling.core.frames.to_si`), else mapped linearly from the map's ``range`` [a, b] onto the
    vehicle's [min, max]: :math:`u = u_{min} + (x - a) (u_{max} - u_{min}) / (b - a)`."""
    if source.unit in ("vehicle", vehicle.input_unit):
        return values
    dimensions = {frames.UNIT_FACTORS.get(unit, (unit,))[0] for unit in (source.unit, vehicle.input_unit)}
    if len(dimensions) == 1 and vehicle.input_unit in frames.UNIT_FACTORS:
        return frames.from_si(frames.to_si(values, source.unit), vehicle.input_unit)
    if source.range is None:
        raise ConfigError(f"{where}: commands of topic {source.topic} are in {source.unit!r}, vehicle {vehicle.name} takes "
                          f"{vehicle.input_unit!r}: give the map's commands a range: [low, high] to map them linearly")
    low, high = source.range
    return vehicle.input_min + (values - low) * ((vehicle.input_max - vehicle.input_min) / (high - low))


def stopped_command(source: FieldSource) -> float:
    """The command a NaN stands for (PX4 actuator_motors: motor stopped): the low end of the map's range (else 0)."""
    return source.range[0] if source.range else 0.0


def map_commands(values: np.ndarray, source: FieldSource, vehicle: VehicleConfig, where: str) -> np.ndarray:
    """(n, 4) commands as the map gives them -> the vehicle's input unit (:func:`commands_in_vehicle_unit`), a NaN
    (motor stopped) read as :func:`stopped_command`, as the ULog reader does. Offline and live alike."""
    values = np.asarray(values, dtype=float)
    stopped = np.isnan(values)
    if stopped.any():
        values = np.where(stopped, stopped_command(source), values)
    return commands_in_vehicle_unit(values, source, vehicle, where)


def convert_measurements(sources: dict[str, FieldSource], aligned: dict[str, np.ndarray],
                         last_yaw: float | None = None) -> dict[str, np.ndarray]:
    """Every non-command field's (n, k) numbers on the same rows (the map's units and frames) -> FlightLog arrays
    by map field name (:func:`~quad_modelling.io.field_conversion.convert_field`): the attitude first (Euler NED/FRD, yaw unwrapped over the rows and
    from ``last_yaw``, the previous row's), then the others (a body-frame velocity rotated by it). Offline
    (:class:`FlightAssembler`) and live (:mod:`quad_modelling.nodes.mapping.streams`) alike."""
    euler = convert_field(sources["attitude"], aligned["attitude"])
    yaw = frames.unwrap_angles(np.concatenate([[last_yaw if last_yaw is not None else euler[0, 2]], euler[:, 2]]))[1:]
    euler[:, 2] = yaw
    out = {"attitude": euler}
    for name, values in aligned.items():
        if name not in ("attitude", "commands"):
            out[name] = convert_field(sources[name], values, euler)
    return out


# --- streams -> FlightLog, streamed ---------------------------------------------------------------

def rate_hz(count: int, first: int, last: int) -> float:
    """Mean rate [Hz] of ``count`` stamps from ``first`` to ``last`` [ns]."""
    return (count - 1) / ((last - first) / 1e9) if count > 1 and last > first else 0.0


class _Stream:
    """One topic while it is read: its recent samples (from the one before the oldest pending row on), its span,
    its message count and the steps longer than :data:`~quad_modelling.core.alignment.MAX_GAP_S`."""

    def __init__(self, topic: str, paths: list[str]):
        self.topic, self.paths = topic, paths
        self.stamps: list[int] = []
        self.values: list[list[float]] = []
        self.first = self.last = None
        self.count = 0
        self.leading_skipped = 0  # messages before the first with every mapped field finite (an estimator not yet valid)
        self.gate = StampGate(int(MAX_STAMP_STEP_S * 1e9))  # the live nodes' stamp rule
        self.outliers = 0  # single stamps off the stream's time, dropped
        self.long_steps: list[tuple[int, int]] = []
        self.ended = False

    def covers(self, ns: int) -> bool:
        return self.last is not None and self.last >= ns


class FlightAssembler:
    """A map's streams -> a FlightLog, message by message in recording order (module doc), in memory that does not
    grow with the recording: the commands wait (at most :data:`MAX_PENDING_S`) until every stream has a message at or
    after them, are aligned in batches of :data:`EMIT_ROWS` (:func:`~quad_modelling.core.alignment.interpolate_at`)
    and converted (:func:`~quad_modelling.io.field_conversion.convert_field`) into FlightLog arrays allocated once for ``capacity`` rows (the commands
    topic's message count); only the samples around the pending rows are kept.
    """

    def __init__(self, topic_map: TopicMap, sources: dict[str, FieldSource], readers: dict[str, TopicReader],
                 vehicle: VehicleConfig, where: str, capacity: int):
        self.topic_map, self.sources, self.vehicle, self.where = topic_map, sources, vehicle, where
        self.base = sources["commands"].topic
        self.streams = {topic: _Stream(topic, reader.paths) for topic, reader in readers.items()}
        self.kinematic = {sources[f].topic for f in KINEMATIC_FIELDS if f in sources}
        self.battery = battery_topic(sources)  # read apart: every reading kept, put on the rows at the end
        self.battery_samples: list[tuple[int, float]] = []
        self.pending: list[tuple[int, list[float]]] = []
        capacity = max(int(capacity), 2)
        self.t_ns = np.empty(capacity, dtype=np.int64)
        self.out = {name: np.empty(capacity if name == "battery" else (capacity, 4 if name == "commands" else 3)) for name in sources}
        self.rows = 0
        self.stopped = 0
        self.cut_warning = ""
        self._next_emit = EMIT_ROWS
        self.last_yaw: float | None = None
        self._column_index = {name: [self.streams[s.topic].paths.index(p) for p in s.paths] for name, s in sources.items()}

    def add(self, topic: str, ns: int, values: list[float]) -> None:
        """One kept message of ``topic``: stamp [ns] and the numbers of its reader's paths. Its stamp passes the live
        nodes' gate (:class:`~quad_modelling.core.alignment.StampGate`, :data:`MAX_STAMP_STEP_S`): a single stamp off
        the stream's time (far ahead, or back) costs that message, counted in the notes, not the flight."""
        stream = self.streams[topic]
        if stream.last is None and topic != self.battery and self._not_finite(stream, values) is not None:
            stream.leading_skipped += 1  # before the stream's first valid message: skipped, as before its first message
            return
        if stream.last is not None and abs(ns - stream.last) < SAME_STAMP_NS:
            return  # a repeated stamp (to the microsecond): the first message is kept
        decision = stream.gate.admit(ns, (ns, values))
        stream.outliers += len(stream.gate.dropped)
        if decision is Stamp.SUSPECT:
            return
        for held_ns, held in stream.gate.confirmed if decision is Stamp.JUMPED else [(ns, values)]:
            self._add(stream, held_ns, held)

    def _add(self, stream: _Stream, ns: int, values: list[float]) -> None:
        topic = stream.topic
        if stream.last is not None:
            if ns < stream.last:
                raise DataError(f"{self.where}: topic {topic} stamps ({self.topic_map.topics[topic].stamp}) go back at message {stream.count}")
            if ns == stream.last:
                return  # a repeated stamp: the first message is kept
            if stream.ended:
                raise DataError(f"{self.where}: topic {topic} resumes after {(ns - stream.last) / 1e9:.1f} s without messages, "
                                f"longer than the {MAX_PENDING_S:g} s held: a restarted publisher or another clock")
            if ns - stream.last > MAX_GAP_S * 1e9:
                stream.long_steps.append((stream.last, ns))
        else:
            stream.first = ns
        if topic == self.battery:  # an unusable reading (0 V: not connected) is counted by battery_on_rows, not refused
            self.battery_samples.append((ns, values[0]))
        else:
            self._check(stream, values)
        stream.last = ns
        stream.count += 1
        if topic == self.battery:
            return
        stream.stamps.append(ns)
        stream.values.append(values)
        if topic == self.base:
            self.pending.append((ns, values))
            if len(self.pending) >= self._next_emit:
                self._emit(final=False)
                self._next_emit = len(self.pending) + EMIT_ROWS  # rows still waiting: not looked at again for a batch

    def _not_finite(self, stream: _Stream, values: list[float]) -> str | None:
        """The first mapped field path of ``stream``'s message ``values`` that is not finite (a command may be NaN:
        motor stopped), or None."""
        for name, source in self.sources.items():
            if source.topic == stream.topic:
                for path, i in zip(source.paths, self._column_index[name]):
                    if math.isinf(values[i]) if name == "commands" else not math.isfinite(values[i]):
                        return path
        return None

    def _check(self, stream: _Stream, values: list[float]) -> None:
        """DataError for a message after the stream's first valid one with a field not finite or an attitude
        quaternion not of norm 1 (its index counts the skipped leading messages)."""
        index = stream.count + stream.leading_skipped
        path = self._not_finite(stream, values)
        if path is not None:
            raise DataError(f"{self.where}: topic {stream.topic} message {index} field {path} is not finite (after "
                            f"{stream.count} valid messages; only messages before a stream's first valid one are skipped)")
        for name, source in self.sources.items():
            if source.topic != stream.topic:
                continue
            numbers = [values[i] for i in self._column_index[name]]
            norm = frames.quaternion_norm_off(numbers) if name == "attitude" else None
            if norm is not None:
                raise DataError(f"{self.where}: topic {stream.topic} message {index} has an attitude quaternion of norm "
                                f"{norm:.3g}, not 1")

    def _lagging(self) -> None:
        """More than :data:`MAX_PENDING_S` of rows wait: decide about each stream silent for that long before the newest."""
        horizon = self.pending[-1][0] - int(MAX_PENDING_S * 1e9)
        for stream in self.streams.values():
            if stream.ended or stream.topic == self.battery or (stream.last is not None and stream.last >= horizon):
                continue
            if stream.last is None:  # not started yet: the rows before its first message are cut, as at the start
                cut = int(np.searchsorted([p[0] for p in self.pending], horizon))
                del self.pending[:cut]
                continue
            check_one_clock(self._spans(), self.base, self.where)
            stream.ended = True  # stopped: the rows after its last message are cut, as at the end

    def _spans(self) -> dict[str, tuple[int, int]]:
        return {t: (s.first, s.last) for t, s in self.streams.items() if s.last is not None}

    def _emit(self, final: bool) -> None:
        """Align the pending rows every stream covers (``final``: all), convert them into the output arrays."""
        if not self.pending:
            return
        if not final and self.pending[-1][0] - self.pending[0][0] > MAX_PENDING_S * 1e9:
            self._lagging()
        live = [s for s in self.streams.values() if not s.ended and s.topic != self.battery]
        limit = None if final else min((s.last for s in live if s.last is not None), default=None)
        if not final and (limit is None or any(s.last is None for s in live)):
            return
        take = len(self.pending) if final else int(np.searchsorted([p[0] for p in self.pending], limit, side="right"))
        if take == 0:
            return
        rows, self.pending = self.pending[:take], self.pending[take:]
        t_ns = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
        keep = np.ones(len(rows), dtype=bool)
        for topic in self.kinematic:  # rows outside the span every kinematic stream covers are cut
            stream = self.streams[topic]
            if stream.last is None:
                keep[:] = False
            else:
                keep &= (t_ns >= stream.first) & (t_ns <= stream.last)
        commands = np.asarray([r[1] for r in rows], dtype=float)[:, self._column_index["commands"]][keep]
        t_ns = t_ns[keep]
        aligned = {}
        for name, source in self.sources.items():
            if name == "commands" or source.topic == self.battery or not len(t_ns):
                continue
            stream = self.streams[source.topic]
            values = np.asarray(stream.values, dtype=float)[:, self._column_index[name]]
            aligned[name] = interpolate_at(np.asarray(stream.stamps, dtype=np.int64), values, t_ns,
                                           quaternion=(0, 4) if name == "attitude" else None, max_gap_s=HOLD_S)
        if len(t_ns):
            self._store(t_ns, commands, aligned)
        last = int(rows[-1][0])
        for stream in self.streams.values():  # keep the samples from the last one at or before the last row on
            start = max(int(np.searchsorted(stream.stamps, last, side="right")) - 1, 0)
            del stream.stamps[:start], stream.values[:start]

    def _store(self, t_ns: np.ndarray, commands: np.ndarray, aligned: dict) -> None:
        n, end = len(t_ns), self.rows + len(t_ns)
        if end > len(self.t_ns):
            raise DataError(f"{self.where}: topic {self.base} holds more messages than its recorded count {len(self.t_ns)}")
        self.stopped += int(np.isnan(commands).sum())
        rows = slice(self.rows, end)
        self.t_ns[rows] = t_ns
        self.out["commands"][rows] = map_commands(commands, self.sources["commands"], self.vehicle, self.where)
        converted = convert_measurements(self.sources, aligned, self.last_yaw)
        self.last_yaw = float(converted["attitude"][-1, 2])
        for name, values in converted.items():
            self.out[name][rows] = values
        self.rows = end

    def _stopped_value(self) -> float:
        return stopped_command(self.sources["commands"])

    def finish(self, notes: dict | None = None) -> FlightLog:
        """Align what is left and build the FlightLog (one-line DataError: a topic without messages, another clock,
        no common span)."""
        for stream in self.streams.values():
            if stream.topic == self.battery:
                continue  # no usable reading: the flight is read without a voltage (noted below)
            if stream.last is None and stream.leading_skipped:
                raise DataError(f"{self.where}: topic {stream.topic}: none of its {stream.leading_skipped} messages has every "
                                f"mapped field ({', '.join(stream.paths)}) finite")
            if stream.last is None:
                raise DataError(f"{self.where}: topic {stream.topic} has no messages")
        for name in (*KINEMATIC_FIELDS, "commands"):  # a stream slower than the gap rule: one marked gap after another
            # (10 Hz actuator_motors printed a warning per step, 309 lines, and a 20 kB error converting to .mat)
            stream = self.streams[self.sources[name].topic] if name in self.sources else None
            if stream is not None and stream.count > 2:
                step_s = (stream.last - stream.first) / (stream.count - 1) / 1e9  # the mean step (the stamps stream by)
                if step_s > MAX_GAP_S:
                    raise DataError(f"{self.where}: topic {stream.topic} ({name}) is sampled at {1 / step_s:.3g} Hz (mean "
                                    f"step {step_s * 1e3:.0f} ms): every step is longer than the {MAX_GAP_S * 1e3:.0f} ms a "
                                    f"measurement may be interpolated over; record it at {1 / MAX_GAP_S:.0f} Hz or more "
                                    f"(or check the map's stamp_unit, {self.topic_map.topics[stream.topic].stamp_unit or 'Time'})")
        check_one_clock(self._spans(), self.base, self.where)
        self._emit(final=True)
        unit = self.topic_map.topics[self.base].stamp_unit or "Time"
        if self.rows < 2:
            raise DataError(f"{self.where}: the topics {', '.join(sorted(self.kinematic | {self.base}))} share no common time span "
                            f"(or their stamps are in a unit finer than the map's stamp_unit, {unit}: every step then "
                            "looks 1000x too long and is dropped)")
        n = self.rows
        t_ns = self.t_ns[:n]
        rate = rate_hz(n, int(t_ns[0]), int(t_ns[-1]))
        if rate > MAX_COMMAND_RATE_HZ:
            raise DataError(f"{self.where}: topic {self.base} read at {rate:.0f} Hz ({n} commands in {(t_ns[-1] - t_ns[0]) / 1e9:.3g} s): "
                            f"its stamps are in a unit 1000x coarser than the map's stamp_unit, {unit} (ms stamps under us, us under ns); "
                            "fix stamp_unit")
        base, kinematic = self.streams[self.base], [self.streams[topic] for topic in self.kinematic]
        notes = {"format": f"bag (topic map {self.topic_map.name})", **(notes or {})}
        for stream in self.streams.values():  # suspects still held at the end: never confirmed by a following message
            stream.outliers += len(stream.gate.suspects)
        outliers = {s.topic: s.outliers for s in self.streams.values() if s.outliers}
        if outliers:
            notes["stamp_outliers"] = "; ".join(f"{topic}: {count} message(s) whose stamp lay off the stream's time dropped"
                                                for topic, count in outliers.items())
        skipped = {s.topic: s.leading_skipped for s in self.streams.values() if s.leading_skipped}
        if skipped:
            notes["leading_not_finite"] = "; ".join(f"{topic}: the first {count} messages skipped (a mapped field not finite: "
                                                    "an estimator not yet valid)" for topic, count in skipped.items())
        if self.stopped:
            notes["motor_nan"] = f"{self.stopped} NaN commands (motor stopped) read as {self._stopped_value():g}"
        cut = (base.last - base.first - (int(t_ns[-1]) - int(t_ns[0]))) / 1e9
        notes["time_base"] = f"{self.base} stamps, {rate_hz(n, int(t_ns[0]), int(t_ns[-1])):.1f} Hz; {cut:.2f} s outside the span all kinematic streams cover cut"
        if cut > CUT_WARNING_S:  # a stream that stopped (or started) far from the commands: said, not only noted
            ends = [(f"{s.topic} starts {(s.first - base.first) / 1e9:.2f} s after", s.first - base.first) for s in kinematic]
            ends += [(f"{s.topic} ends {(base.last - s.last) / 1e9:.2f} s before", base.last - s.last) for s in kinematic]
            self.cut_warning = (f"{self.where}: {cut:.2f} s of the {(base.last - base.first) / 1e9:.2f} s of commands cut: "
                                f"{max(ends, key=lambda e: e[1])[0]} them (rows outside the span every kinematic stream covers)")
        notes["sources"] = {name: f"{s.topic} {', '.join(s.paths)} ({s.unit or s.order}, {s.frame or '-'}), "
                                  f"{rate_hz(self.streams[s.topic].count, self.streams[s.topic].first, self.streams[s.topic].last):.1f} Hz"
                            for name, s in self.sources.items()}
        out = {name: array[:n] for name, array in self.out.items()}
        t = t_ns / 1e9
        if self.battery is not None:
            samples = np.asarray(self.battery_samples, dtype=float).reshape(-1, 2)
            out["battery"], battery_note = battery_on_rows(samples[:, 0] / 1e9, samples[:, 1], t)
            if out["battery"] is None:
                notes["sources"].pop("battery")
            if battery_note:
                notes["battery"] = f"{self.battery}: {battery_note}"
        self.out, self.t_ns = {}, np.empty(0, dtype=np.int64)  # the log holds the arrays; the stamps [ns] go after the gaps
        gaps: dict[tuple[str, int, int], tuple[str, ...]] = {}  # (topic, start, end) -> the FlightLog fields it carries
        for name in KINEMATIC_FIELDS:
            if name in self.sources:
                topic = self.sources[name].topic
                for a, b in self.streams[topic].long_steps:  # a row strictly inside: interpolated through
                    if np.searchsorted(t_ns, b, side="left") > np.searchsorted(t_ns, a, side="right"):
                        gaps[(topic, a, b)] = gaps.get((topic, a, b), ()) + GAP_FIELDS[name]
        for a, b in self.streams[self.base].long_steps:  # a hole in the time base: no row inside, the rows around kept
            if t_ns[0] <= a and b <= t_ns[-1]:
                gaps[(self.base, a, b)] = ("u",)
        log = FlightLog(
            t=t, u=out["commands"], acc_b=out.get("acc"), gyro_b=out.get("gyro"), pos_n=out["position"], vel_n=out["velocity"],
            euler=out["attitude"], vbat=out.get("battery"),
            meta=FlightMeta(vehicle=self.vehicle.name, source=self.where, notes=notes),
        )
        marked = [MeasurementGap(topic, a / 1e9, b / 1e9, fields) for (topic, a, b), fields in gaps.items()]
        mark_measurement_gaps(log, sorted(marked, key=lambda g: (g.start_s, g.topic)), MAX_GAP_S)
        for warning in consistency_warnings(log, self.vehicle.input_min, self.vehicle.input_max):  # order, frame, sign, unit
            log.warn(f"{warning}: topic map {self.topic_map.name}")
        if self.cut_warning:
            log.warn(self.cut_warning)
        return log


# --- any recording through a topic map (users' own topics) ---------------------------------------------------

def read_mapped_bag(path: str | Path, topic_map, vehicle) -> FlightLog:
    """Any rosbag2 bag (MCAP or sqlite3) through a topic map (bound to its robot) into a FlightLog for ``vehicle``.

    Deserialised with the definitions stored in the bag (no px4_msgs/crazyflie_interfaces install), streamed: each
    message becomes numbers as it is read (:class:`~quad_modelling.io.mapped_flight.TopicReader`), then the streams
    are aligned (:func:`~quad_modelling.io.mapped_flight.flight_from_streams`). One-line errors name topic, field, type.
    """
    path, where = Path(path), str(path)
    reader = open_reader(path)
    try:
        counts: dict[str, int] = {}
        for c in reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
        empty = sorted(t for t, n in counts.items() if n == 0 and t in topic_map.topics and topic_map.topics[t].optional)
        present = {c.topic: c.msgtype for c in reader.connections if c.topic not in empty}  # recorded, never received: absent
        missing = topic_map.missing(present)
        if missing:
            raise BagError(f"{path}: topic map {topic_map.name} reads {'; '.join(missing)}: not in the bag, which has {sorted(present)}")
        sources = topic_map.sources(present)
        wrong = next((s.topic for s in sources.values() if present[s.topic] != topic_map.topics[s.topic].msgtype), None)
        if wrong:
            raise BagError(f"{path}: topic {wrong} has type {present[wrong]}, topic map {topic_map.name} reads {topic_map.topics[wrong].msgtype}")
        used = [c for c in reader.connections if c.topic in {s.topic for s in sources.values()}]
        store = stored_typestore(used, path)
        check_map_fields(topic_map, sources, fields_of_store(store), f"{path}: topic map {topic_map.name}")
        readers = readers_for(topic_map, sources, where)
        capacity = sum(c.msgcount for c in used if c.topic == sources["commands"].topic)
        assembler = FlightAssembler(topic_map, sources, readers, vehicle, where, capacity)
        deserialize = store.deserialize_cdr
        read: dict[int, int] = {}
        for connection, _, raw in reader.messages(connections=used):
            read[connection.id] = read.get(connection.id, 0) + 1
            try:
                msg = deserialize(raw, connection.msgtype)
            except READ_ERRORS as err:  # named as the contract reader names it
                raise BagError(f"{path}: topic {connection.topic} message {read[connection.id] - 1}: cannot deserialise "
                               f"({reason(err)})") from err
            topic_reader = readers[connection.topic]
            values = topic_reader.values(msg)
            if topic_reader.keep(msg, values):
                assembler.add(connection.topic, topic_reader.stamp_ns(msg), values)
    except READ_ERRORS as err:
        if isinstance(err, (BagError, ConfigError, DataError)):
            raise
        raise BagError(f"{path}: corrupt or truncated bag ({reason(err)})") from err
    finally:
        reader.close()
    notes, warnings = frame_notes(readers)
    log = assembler.finish({**instance_notes(readers, present), **notes})
    for warning in [*warnings, *missing_messages(path, used, read)]:
        log.warn(warning)
    if empty:  # a QoS mismatch records the topic without a message: read as an optional topic left out
        log.warn(f"{path}: optional topic(s) {', '.join(empty)} recorded with no message: read without them")
    return log
