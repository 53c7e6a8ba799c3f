"""MCAP bags (rosbag2 layout) with the topic contract of DESIGN 5a — the only rosbags user.

Written with rosbags' MCAP storage and the ROS 2 Jazzy type store, readable by
``ros2 bag info``, Foxglove and PlotJuggler. The topics, types, frames and the
FlightLog <-> message conversion are :mod:`quad_modelling.io.topics` (shared with the
nodes); this module holds the rosbags calls: the type store's classes
(:data:`BAG_TYPES`), CDR (de)serialisation, the bag files.

The flight's metadata (vehicle, source, notes) is kept in the bag's ``custom_data``
under ``quad_modelling.*`` keys (:func:`read_bag_metadata` reads it without a
message). :func:`read_bag` puts every topic on the ``motor_input`` time base (linear
interpolation when stamps differ; exact when they coincide, as in bags written here);
:func:`read_recorded` gives the serialised messages as recorded (the replay's input).
:func:`quad_modelling.io.mapped_flight.read_mapped_bag` reads any stack's bag through a topic map (:mod:`quad_modelling.io.topic_maps`).
"""

from __future__ import annotations

import contextlib
import json
import stat
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.serde import SerdeError

try:  # the zstd module rosbags decompresses MCAP chunks with (Python 3.14 stdlib, else its backport)
    from compression.zstd import ZstdError
except ImportError:  # pragma: no cover - Python < 3.14
    from backports.zstd import ZstdError
from rosbags.typesys import Stores, get_typestore

from quad_modelling.atomic import atomic_output
from quad_modelling.core.flight_log import FlightLog, chosen_vehicle
from quad_modelling.core.input_files import input_path_mode, read_yaml
from quad_modelling.errors import BagError, ConfigError, DataError, reason
from quad_modelling.io.topics import (
    DEFAULT_NAMESPACE,
    GAP_FIELDS,
    LIVE_TOPICS,
    MEASUREMENT_TOPICS,
    REQUIRED_TOPICS,
    MeasurementMessages,
    MessageTypes,
    cdr_stamp_ns,
    check_namespace,
    contract_flight_log,
    gap_rows_by_topic,
    imu_fields,
    motor_fields,
    odometry_fields,
    stamp_ns,
    stamps_ns,
    topic_name,
)

VEHICLE_KEY = "quad_modelling.vehicle"
SOURCE_KEY = "quad_modelling.source"
NOTES_KEY = "quad_modelling.notes"
"""custom_data keys of the flight's metadata (vehicle config name, source file name, JSON notes)."""

READ_ERRORS = (ReaderError, OSError, ValueError, KeyError, EOFError, MemoryError, OverflowError, struct.error, TypeError,
               AssertionError, IndexError, ZstdError, SerdeError)
"""What rosbags, the MCAP and zstd layers and the deserialiser raise on a corrupt or truncated bag (our BagError, an
OSError, is re-raised as it is by every reader)."""

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
BAG_TYPES = MessageTypes.from_lookup(TYPESTORE.types.__getitem__)
"""The contract's message classes in rosbags' Jazzy type store (keyword construction, attribute access)."""


def _mcap_writer(path: Path, compress: bool = True) -> Writer:
    """A rosbag2 MCAP writer (version 9, as Jazzy's) whose chunks are zstd-compressed.

    rosbags' MCAP storage compresses each chunk (~1 MiB of messages) with zstd when asked for
    storage-level compression (``CompressionMode.STORAGE``): the bag stays one ``.mcap`` file that
    ``ros2 bag``, the mcap library, Foxglove and PlotJuggler read as is (chunk compression is part of
    MCAP), and metadata.yaml records no file/message compression. The bundled 42 s flight (itself written so): 6.1 MB
    uncompressed, 1.08 MB with zstd chunks (docs/formats.md).
    """
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    return writer


_NUMPY_TYPES = {"byte": "uint8", "char": "uint8", "octet": "uint8", "bool": "bool"}
"""numpy dtypes of the ROS base types whose names are not numpy's (float64, int32, ... are)."""


def _bag_message(msg, msgtype: str):
    """Any message object with the fields of ``msgtype`` (e.g. an rclpy message) as the type store's message.

    Field by field through the type store's definitions: nested messages recursively, numeric
    sequences/arrays as numpy arrays of the field's dtype, ``byte`` fields as their integer.
    """
    from rosbags.typesys.store import Nodetype

    fields = {}
    for name, (kind, detail) in TYPESTORE.fielddefs[msgtype][1]:
        value = getattr(msg, name)
        if kind == Nodetype.NAME:
            value = _bag_message(value, detail)
        elif kind in (Nodetype.SEQUENCE, Nodetype.ARRAY):
            (element, element_detail), _ = detail
            if element == Nodetype.NAME:
                value = [_bag_message(v, element_detail) for v in value]
            elif element_detail[0] == "string":
                value = list(value)
            else:
                value = np.asarray(value, dtype=_NUMPY_TYPES.get(element_detail[0], element_detail[0]))
        elif detail[0] in ("byte", "char") and isinstance(value, bytes):
            value = value[0]
        fields[name] = value
    return TYPESTORE.types[msgtype](**fields)


def serialize_as(msg, msgtype: str) -> bytes:
    """CDR bytes of ``msg`` (any object with the fields of ``msgtype``), as a bag stores them.

    rclpy's ``serialize_message`` (rclpy 7.1, rmw_fastrtps) returned 8 bytes past the message and
    uninitialised alignment padding here: rosbags refused such bytes ("CDR message size mismatch").
    """
    return bytes(TYPESTORE.serialize_cdr(_bag_message(msg, msgtype), msgtype))


class BagRecorder:
    """A bag recorded from serialised messages as they arrive (the evaluator's ``record``).

    MCAP with zstd chunks (:func:`_mcap_writer`), written at a staging path next to ``path``
    (:func:`~quad_modelling.atomic.atomic_output`) and renamed onto it by :meth:`close`; :meth:`abort`
    leaves nothing. Each message's bag time is the ``ns`` given (the nodes give the header stamp, so
    measured and predicted samples of one instant line up in Foxglove/PlotJuggler); messages may
    come out of time order (MCAP readers order them by the chunk indexes).
    """

    def __init__(self, path: str | Path, force: bool = False, custom_data: dict[str, str] | None = None):
        self.path = Path(path)
        self._stack = contextlib.ExitStack()
        tmp = self._stack.enter_context(atomic_output(self.path, force))
        self._writer = _mcap_writer(tmp)
        self._connections: dict[str, object] = {}
        self.count = 0
        try:
            self._writer.open()
            for key, value in (custom_data or {}).items():
                self._writer.set_custom_data(key, value)
        except (WriterError, OSError) as err:
            self.abort()
            raise BagError(f"{self.path}: cannot record: {err}") from err

    def set_custom_data(self, key: str, value: str) -> None:
        """A ``custom_data`` entry of metadata.yaml (written at :meth:`close`)."""
        self._writer.set_custom_data(key, value)

    def write(self, topic: str, msgtype: str, ns: int, raw: bytes) -> None:
        """Add one CDR message of ``msgtype`` (``pkg/msg/Name``) on ``topic`` (absolute name) at bag time ``ns``."""
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._connections[topic] = self._writer.add_connection(topic, msgtype, typestore=TYPESTORE)
        self._writer.write(connection, int(ns), raw)
        self.count += 1

    def close(self) -> Path:
        """Finish the bag and move it to ``path``."""
        try:
            self._writer.close()
        except (WriterError, OSError) as err:
            self.abort()
            raise BagError(f"{self.path}: cannot finish the recording: {err}") from err
        self._stack.close()
        return self.path

    def abort(self) -> None:
        """Drop the recording (the staging path is removed)."""
        with contextlib.suppress(Exception):
            self._writer.close()
        with contextlib.suppress(BagError):
            self._stack.__exit__(BagError, BagError(f"{self.path}: recording aborted"), None)


MAX_STAMP_NS = 2**31 * 1_000_000_000
"""The first time a bag cannot stamp [ns]: builtin_interfaces/Time holds int32 seconds (2038-01-19 as epoch time)."""


def write_bag(log: FlightLog, path: str | Path, force: bool = False, namespace: str = DEFAULT_NAMESPACE, progress=None,
              compress: bool = True) -> Path:
    """Write ``log`` as an MCAP bag directory at ``path`` (zstd chunks, :func:`_mcap_writer`), atomically.

    Every topic's message of sample i is stamped (header and bag time) ``stamps_ns(log.t)[i]``, except the
    mocap/odom and imu messages of rows strictly inside a marked measurement gap of their fields
    (:func:`gap_rows_by_topic`): the gap stays a gap, the notes say where it is.
    ``progress``: optional callable(n_samples_done) for a progress bar. ``compress=False``: chunks stored
    uncompressed (as before zstd; the same messages byte for byte).
    """
    path = Path(path)
    check_namespace(namespace)
    stamps = stamps_ns(log.t)
    if len(stamps) and (stamps[0] < 0 or stamps[-1] >= MAX_STAMP_NS):  # the writer's uint64 / the header's int32 raised
        raise DataError(f"{log.meta.source}: sample times {log.t[0]:.6g}..{log.t[-1]:.6g} s cannot be bag stamps (ROS times "
                        f"0..2^31 s, builtin_interfaces/Time int32 seconds): "
                        + ("shift the time column to start at or after 0" if stamps[0] < 0 else
                           "check the time column's unit (microseconds or nanoseconds read as seconds?)"))
    if np.any(np.diff(stamps) <= 0):
        raise DataError(f"{log.meta.source}: sample times collapse at nanosecond resolution")
    measurements = MeasurementMessages(log, BAG_TYPES)
    serialize = TYPESTORE.serialize_cdr
    with atomic_output(path, force) as tmp:
        writer = _mcap_writer(tmp, compress)
        try:
            writer.open()
            connections = {
                key: writer.add_connection(topic_name(namespace, key), msgtype, typestore=TYPESTORE)
                for key, msgtype in MEASUREMENT_TOPICS.items()
                if key in measurements.topics
            }
            writer.set_custom_data(VEHICLE_KEY, log.meta.vehicle)
            writer.set_custom_data(SOURCE_KEY, Path(log.meta.source).name)
            writer.set_custom_data(NOTES_KEY, json.dumps(log.meta.notes))
            skip = gap_rows_by_topic(log)
            for i, ns in enumerate(stamps.tolist()):
                for key, msg in measurements.row(i, ns).items():
                    if key not in skip or not skip[key][i]:
                        writer.write(connections[key], ns, serialize(msg, MEASUREMENT_TOPICS[key]))
                if progress is not None and i % 1000 == 999:
                    progress(1000)
            writer.close()
        except WriterError as err:
            raise BagError(f"{path}: cannot write bag: {err}") from err
    return path


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag, as ``quad-modelling info`` shows it."""

    name: str
    msgtype: str
    count: int
    start_s: float
    end_s: float

    @property
    def rate_hz(self) -> float:
        span = self.end_s - self.start_s
        return (self.count - 1) / span if self.count > 1 and span > 0 else 0.0


@dataclass(frozen=True)
class BagSummary:
    path: str
    storage: str
    duration_s: float
    start_s: float
    end_s: float
    message_count: int
    topics: tuple[TopicSummary, ...]
    custom_data: dict


def open_reader(path: Path) -> Reader:
    """An opened rosbags Reader of the bag directory ``path``; BagError (one line) for no bag or an unreadable one."""
    if (mode := input_path_mode(path, "bag", BagError)) is None:
        raise BagError(f"{path}: no such bag")
    if not stat.S_ISDIR(mode):
        raise BagError(f"{path}: not a bag directory (a rosbag2 bag is a directory with metadata.yaml)")
    if not (path / "metadata.yaml").exists() and not any(path.glob("*.mcap")) and not any(path.glob("*.db3")):
        raise BagError(f"{path}: not a bag: the directory holds no metadata.yaml and no .mcap or .db3 file")
    try:  # bounded first: rosbags' own YAML read has no limits
        _ = (path / "metadata.yaml").exists() and read_yaml(path / "metadata.yaml", "bag metadata")
    except ConfigError as err:
        raise BagError(f"{path}: not a readable rosbag2 bag: {err}") from err
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError, ValueError, KeyError, TypeError, SerdeError, MemoryError, OverflowError, struct.error,
            ZstdError) as err:  # a corrupt record size: MemoryError
        raise BagError(f"{path}: not a readable rosbag2 bag ({reason(err)})") from err
    check_mcap_crcs(path)
    return reader


def check_mcap_crcs(path: Path) -> None:
    """BagError naming the file when an MCAP file of the bag ``path`` fails a CRC its writer stored: the data
    section's and each chunk's (rosbag2 stores them; rosbags reads without checking, so a damaged byte in an
    uncompressed chunk read as other numbers). Checked with the mcap library (its StreamReader and chunk reader) in a
    pass over the raw chunks, decompressing only those with a stored CRC; files without CRCs (this project's own
    bags: rosbags writes none) pass at the cost of reading their bytes. Any other damage is left to the reader's
    own error."""
    from mcap.exceptions import McapError
    from mcap.records import Chunk
    from mcap.stream_reader import CRCValidationError, StreamReader, get_chunk_data_stream

    for file in sorted(path.glob("*.mcap")):
        try:
            with open(file, "rb") as stream:
                for record in StreamReader(stream, validate_crcs=True, emit_chunks=True).records:
                    if isinstance(record, Chunk) and record.uncompressed_crc != 0:
                        get_chunk_data_stream(record, validate_crc=True)
        except CRCValidationError as err:
            raise BagError(f"{path}: {file.name} is damaged: {err} (a byte changed since it was recorded)") from err
        except (McapError, *READ_ERRORS):  # truncated or malformed: the reader's error says so
            return


def summarize_bag(path: str | Path) -> BagSummary:
    """Topics, types, counts, time spans and rates of a bag (reads every message header)."""
    path = Path(path)
    reader = open_reader(path)
    try:
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        counts: dict[str, int] = {}
        for connection, timestamp, _ in reader.messages():
            topic = connection.topic
            first.setdefault(topic, timestamp)
            last[topic] = timestamp
            counts[topic] = counts.get(topic, 0) + 1
        topics = tuple(
            TopicSummary(name, info.msgtype or "?", counts.get(name, 0), first.get(name, 0) / 1e9, last.get(name, 0) / 1e9)
            for name, info in sorted(reader.topics.items())
        )
        custom = _custom_data(path)
        storage = "mcap" if any(p.suffix == ".mcap" for p in path.iterdir()) else "sqlite3"
        start = min(first.values(), default=0) / 1e9
        end = max(last.values(), default=0) / 1e9
        return BagSummary(str(path), storage, end - start, start, end, sum(counts.values()), topics, custom)
    except BagError:  # a missing topic or a wrong type, named (a BagError is an OSError: not "corrupt")
        raise
    except (ReaderError, OSError, ValueError, KeyError, EOFError, MemoryError, OverflowError, struct.error, TypeError,
            ZstdError) as err:  # a corrupt zstd chunk: ZstdError
        raise BagError(f"{path}: corrupt or truncated bag ({reason(err)})") from err
    finally:
        reader.close()


def _custom_data(path: Path) -> dict:
    """The text entries of the bag's ``custom_data`` ({} when it has none)."""
    try:
        doc = read_yaml(path / "metadata.yaml", "bag metadata")
        custom = doc["rosbag2_bagfile_information"].get("custom_data") or {}
        return {str(key): value for key, value in dict(custom).items() if isinstance(value, str)}
    except (ConfigError, KeyError, TypeError, ValueError, AttributeError):
        return {}


@dataclass(frozen=True)
class BagMetadata:
    """What a bag's ``metadata.yaml`` says, read without touching a message."""

    path: str
    vehicle: str | None
    """The vehicle config name recorded at conversion (custom_data ``quad_modelling.vehicle``)."""
    source: str | None
    duration_s: float
    """Time from the first to the last message (bag receive times) [s]."""
    message_count: int
    topics: tuple[str, ...] = ()
    """Every topic the bag records (absolute names)."""

    def require_live_topics(self, namespace: str = DEFAULT_NAMESPACE) -> None:
        """BagError naming the topics the live nodes need (:data:`~quad_modelling.io.topics.LIVE_TOPICS`) that the bag lacks."""
        missing = [topic_name(namespace, key) for key in LIVE_TOPICS if topic_name(namespace, key) not in self.topics]
        if missing:
            raise BagError(f"{self.path}: run-bag needs topic(s) {missing}, which the bag does not have (the live predictor and "
                           "evaluator nodes start from imu messages); evaluate it offline with quad-modelling evaluate")


def read_bag_metadata(path: str | Path) -> BagMetadata:
    """The bag's recorded vehicle and source, duration and message count from ``metadata.yaml`` only.

    Raises BagError for a path that is not a readable rosbag2 bag.
    """
    path = Path(path)
    reader = open_reader(path)
    try:
        span_ns = max(reader.end_time - 1 - reader.start_time, 0) if reader.message_count else 0  # end_time is after the last message
        count = reader.message_count
        topics = tuple(sorted(reader.topics))
    finally:
        reader.close()
    custom = _custom_data(path)
    return BagMetadata(str(path), custom.get(VEHICLE_KEY) or None, custom.get(SOURCE_KEY) or None, span_ns / 1e9, count, topics)


def _contract_connections(reader: Reader, path: Path, namespace: str) -> dict:
    """The bag's contract connections by relative topic; BagError for a missing required topic or a wrong type."""
    wanted = {topic_name(namespace, key): key for key in MEASUREMENT_TOPICS}
    present = {c.topic for c in reader.connections}
    missing = [topic_name(namespace, k) for k in REQUIRED_TOPICS if topic_name(namespace, k) not in present]
    if missing:
        raise BagError(f"{path}: missing required topic(s) {missing}; found: {sorted(present)}")
    connections = {}
    for c in reader.connections:
        key = wanted.get(c.topic)
        if key and c.msgtype != MEASUREMENT_TOPICS[key]:
            raise BagError(f"{path}: topic {c.topic} has type {c.msgtype}, expected {MEASUREMENT_TOPICS[key]}")
        if key:
            connections.setdefault(key, []).append(c)
    return connections


@dataclass(frozen=True)
class RecordedMessage:
    """One contract message as recorded: relative topic, header stamp [ns], CDR bytes."""

    topic: str
    stamp_ns: int
    raw: bytes


def read_recorded(path: str | Path, namespace: str = DEFAULT_NAMESPACE) -> list[RecordedMessage]:
    """Every contract-topic message of a bag, serialised as recorded, in header-stamp order.

    Messages of one stamp keep the order of :data:`~quad_modelling.io.topics.MEASUREMENT_TOPICS`
    (motor_input, mocap/odom, imu, battery), the order ``replay`` publishes a sample in.
    Nothing is deserialised: the stamp is read from the CDR header
    (:func:`~quad_modelling.io.topics.cdr_stamp_ns`). Raises BagError for an
    unreadable bag, a missing required topic, a wrong type or a message without a header.
    """
    path = Path(path)
    reader = open_reader(path)
    try:
        by_topic = _contract_connections(reader, path, namespace)
        key_of = {c.id: key for key, connections in by_topic.items() for c in connections}
        rank = {key: i for i, key in enumerate(MEASUREMENT_TOPICS)}
        recorded = []
        for connection, _, raw in reader.messages(connections=[c for cs in by_topic.values() for c in cs]):
            key = key_of[connection.id]
            recorded.append(RecordedMessage(key, cdr_stamp_ns(raw), bytes(raw)))
    except BagError:  # a missing topic or a wrong type, named (a BagError is an OSError: not "corrupt")
        raise
    except (ReaderError, OSError, ValueError, KeyError, EOFError, MemoryError, OverflowError, struct.error, TypeError,
            ZstdError) as err:  # a corrupt zstd chunk: ZstdError
        raise BagError(f"{path}: corrupt or truncated bag ({reason(err)})") from err
    finally:
        reader.close()
    recorded.sort(key=lambda m: (m.stamp_ns, rank[m.topic]))
    return recorded


def read_bag(path: str | Path, vehicle: str | None = None, namespace: str = DEFAULT_NAMESPACE) -> FlightLog:
    """Read a contract bag into a FlightLog on the ``motor_input`` time base.

    Raises BagError for an unreadable/corrupt bag or a missing topic (naming
    it and what was found), DataError naming topic and message index for
    non-finite values or stamps that do not increase.
    """
    path = Path(path)
    reader = open_reader(path)
    try:
        by_topic = _contract_connections(reader, path, namespace)
        key_of = {c.id: key for key, connections in by_topic.items() for c in connections}
        columns: dict[str, list] = {key: [] for key in MEASUREMENT_TOPICS}
        stamps: dict[str, list] = {key: [] for key in MEASUREMENT_TOPICS}
        deserialize = TYPESTORE.deserialize_cdr
        read: dict[int, int] = {}
        for connection, _, raw in reader.messages(connections=[c for cs in by_topic.values() for c in cs]):
            read[connection.id] = read.get(connection.id, 0) + 1
            key = key_of[connection.id]
            msg = deserialize(raw, connection.msgtype)
            stamps[key].append(stamp_ns(msg.header.stamp))
            if key == "motor_input":
                motor = motor_fields(msg)
                if motor is None:
                    raise DataError(f"{path}: topic {connection.topic} message {len(stamps[key]) - 1} has {len(msg.effort)} efforts, expected 4")
                columns[key].append(np.concatenate([motor[0], motor[1] if motor[1] is not None else np.full(4, np.nan)]))
            elif key == "mocap/odom":
                columns[key].append(odometry_fields(msg))
            elif key == "imu":
                columns[key].append(imu_fields(msg))
            else:
                columns[key].append((msg.voltage,))
    except (BagError, DataError):  # a missing topic, a wrong type, a message short of a field: named, not "corrupt"
        raise
    except (ReaderError, OSError, ValueError, KeyError, EOFError, MemoryError, OverflowError, struct.error, TypeError, AssertionError,
            IndexError, ZstdError) as err:
        raise BagError(f"{path}: corrupt or truncated bag ({reason(err)})") from err
    except SerdeError as err:
        raise BagError(f"{path}: topic {connection.topic} message {len(stamps[key])}: cannot deserialise ({reason(err)})") from err
    finally:
        reader.close()

    def flight_meta() -> tuple[str, dict]:
        custom = _custom_data(path)
        vehicle_name = chosen_vehicle(vehicle, custom.get(VEHICLE_KEY), str(path))
        if not vehicle_name:
            raise DataError(f"{path}: the bag names no vehicle (custom_data {VEHICLE_KEY}); pass --vehicle NAME")
        try:
            notes = json.loads(custom.get(NOTES_KEY) or "{}")
        except json.JSONDecodeError as err:
            raise BagError(f"{path}: custom_data {NOTES_KEY} is not valid JSON ({err.msg} at character {err.pos})") from err
        except RecursionError as err:
            raise BagError(f"{path}: custom_data {NOTES_KEY} nests deeper than JSON can be read") from err
        if not isinstance(notes, dict):
            raise BagError(f"{path}: custom_data {NOTES_KEY} must hold a JSON object, got {type(notes).__name__}")
        return vehicle_name, notes
    log = contract_flight_log(path, namespace, columns, stamps, flight_meta)
    for warning in missing_messages(path, [c for cs in by_topic.values() for c in cs], read):
        log.warn(warning)
    return log


def missing_messages(path: Path, connections, read: dict[int, int]) -> list[str]:
    """One warning per connection of which fewer messages were read (``read``: connection id -> count) than the bag's
    metadata counts: a damaged file rosbags reads past without an error (a bag without CRCs, 4 KB zeroed, lost 341
    messages per topic without a word)."""
    return [f"{path}: topic {c.topic}: {read.get(c.id, 0)} of the {c.msgcount} messages the bag's metadata counts were "
            "read: the file is damaged or was cut" for c in connections if c.msgcount and read.get(c.id, 0) < c.msgcount]


class ForeignBagWriter:
    """A rosbag2 bag (``storage`` mcap or sqlite3) of any types, ``definitions`` (type -> ``.msg`` text; standard types
    from the Jazzy store) stored in it as ``ros2 bag record`` of Jazzy does (``store_definitions=False``: empty, as an
    older rosbag2): the test and benchmark recordings of other stacks. A context manager; :meth:`new`, :meth:`write`."""

    def __init__(self, path: str | Path, definitions: dict[str, str], storage: str = "mcap", store_definitions: bool = True):
        from rosbags.typesys import get_types_from_msg

        self.store = get_typestore(Stores.ROS2_JAZZY)
        for msgtype, text in definitions.items():
            self.store.register(get_types_from_msg(text, msgtype))
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = Writer(Path(path), version=9, storage_plugin=plugin)
        self._store_definitions = store_definitions
        self._connections: dict[str, object] = {}

    def __enter__(self) -> ForeignBagWriter:
        self._writer.open()
        return self

    def __exit__(self, *exc) -> None:
        self._writer.close()

    def new(self, msgtype: str, **fields):
        """A message of ``msgtype`` (``pkg/msg/Name``) with ``fields``; the fields not given are zero (numbers), empty
        (strings, sequences), zero-filled (arrays) or such messages (nested)."""
        from rosbags.typesys.store import Nodetype

        def zero(kind, detail):
            if kind == Nodetype.NAME:
                return self.new(detail)
            if kind == Nodetype.BASE:
                return "" if detail[0] == "string" else False if detail[0] == "bool" else 0.0 if detail[0].startswith("float") else 0
            (element_kind, element_detail), size = detail
            if element_kind == Nodetype.BASE and element_detail[0] != "string":
                dtype = _NUMPY_TYPES.get(element_detail[0], element_detail[0])
                return np.zeros(size if kind == Nodetype.ARRAY else 0, dtype=dtype)
            return [zero(element_kind, element_detail) for _ in range(size if kind == Nodetype.ARRAY else 0)]

        values = {name: fields[name] if name in fields else zero(kind, detail)
                  for name, (kind, detail) in self.store.fielddefs[msgtype][1]}
        return self.store.types[msgtype](**values)

    def connection(self, topic: str, msgtype: str):
        """The bag's connection of ``topic`` (added at the first call): a topic with no message written stays in the bag
        with a count of 0, as ``ros2 bag record`` leaves one whose publisher never matched (a QoS mismatch)."""
        if topic not in self._connections:
            extra = {} if self._store_definitions else {"msgdef": "", "rihs01": "RIHS01_" + "0" * 64}
            self._connections[topic] = self._writer.add_connection(topic, msgtype, typestore=self.store, **extra)
        return self._connections[topic]

    def write(self, topic: str, ns: int, msg) -> None:
        """Serialise ``msg`` and add it on ``topic`` at bag time ``ns``."""
        msgtype = msg.__msgtype__
        self._writer.write(self.connection(topic, msgtype), int(ns), self.store.serialize_cdr(msg, msgtype))


def stored_typestore(connections, path: Path):
    """A type store of the definitions the bag stores for ``connections`` (MCAP schemas, sqlite3 message_definitions);
    BagError naming the topic and type when the bag stores none or an unreadable one."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    types: dict = {}
    for c in connections:
        if c.msgdef.format == MessageDefinitionFormat.NONE or not c.msgdef.data.strip():
            raise BagError(f"{path}: topic {c.topic} ({c.msgtype}): the bag stores no message definition (recorded by a "
                           "rosbag2 older than Jazzy?); re-record it with ros2 bag record of Jazzy or later (MCAP or sqlite3)")
        try:
            if c.msgdef.format == MessageDefinitionFormat.MSG:
                types.update(get_types_from_msg(c.msgdef.data, c.msgtype))
            else:  # IDL: one or more "IDL: name" sections after a line of 80 '='
                for part in filter(str.strip, c.msgdef.data.split("=" * 80 + "\n")):
                    types.update(get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part))
        except Exception as err:  # rosbags' definition parsers raise their own and bare errors on bad text
            raise BagError(f"{path}: topic {c.topic} ({c.msgtype}): unreadable stored message definition ({reason(err)})") from err
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(types)
    except Exception as err:
        raise BagError(f"{path}: the bag's stored message definitions do not fit together ({reason(err)})") from err
    return store
