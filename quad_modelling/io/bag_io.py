"""MCAP bags (rosbag2 layout) with the topic contract of DESIGN 5a — the only rosbags user.

Written with rosbags' MCAP storage and the ROS 2 Jazzy type store, readable by
``ros2 bag info``, Foxglove and PlotJuggler. Topics under a namespace
(default ``/quad``):

=================  ========================  ===============================================
topic              type                      content (frames per REP-103/147)
=================  ========================  ===============================================
motor_input        sensor_msgs/JointState    names motor_1..4, effort = raw command,
                                             velocity = rotor speed [rad/s] when known
mocap/odom         nav_msgs/Odometry         pose in ``world`` (ENU), twist in ``base_link`` (FLU)
imu                sensor_msgs/Imu           gyro [rad/s] and specific force [m/s²], FLU;
                                             no orientation (covariance[0] = -1)
battery            sensor_msgs/BatteryState  voltage [V] (only when the log has it)
=================  ========================  ===============================================

The flight's metadata (vehicle, source, notes) is kept in the bag's
``custom_data`` under ``quad_modelling.*`` keys. Reading puts every topic on the
``motor_input`` time base (linear interpolation when stamps differ; exact when
they coincide, as in bags written here).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.typesys import Stores, get_typestore

from quad_modelling.atomic import atomic_output
from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.errors import BagError, DataError

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
DEFAULT_NAMESPACE = "/quad"
WORLD_FRAME = "world"
BODY_FRAME = "base_link"
MOTOR_NAMES = ("motor_1", "motor_2", "motor_3", "motor_4")

TOPIC_TYPES = {
    "motor_input": "sensor_msgs/msg/JointState",
    "mocap/odom": "nav_msgs/msg/Odometry",
    "imu": "sensor_msgs/msg/Imu",
    "battery": "sensor_msgs/msg/BatteryState",
}
REQUIRED_TOPICS = ("motor_input", "mocap/odom", "imu")

_T = TYPESTORE.types
Header, Time = _T["std_msgs/msg/Header"], _T["builtin_interfaces/msg/Time"]
JointState, Odometry, Imu, BatteryState = (_T[TOPIC_TYPES[k]] for k in ("motor_input", "mocap/odom", "imu", "battery"))
Point, Quaternion, Vector3 = _T["geometry_msgs/msg/Point"], _T["geometry_msgs/msg/Quaternion"], _T["geometry_msgs/msg/Vector3"]
Pose, PoseWithCovariance = _T["geometry_msgs/msg/Pose"], _T["geometry_msgs/msg/PoseWithCovariance"]
Twist, TwistWithCovariance = _T["geometry_msgs/msg/Twist"], _T["geometry_msgs/msg/TwistWithCovariance"]

UNKNOWN_ANGULAR_TWIST = np.zeros(36)
UNKNOWN_ANGULAR_TWIST[[21, 28, 35]] = -1.0
"""Odometry twist covariance marking the angular twist as not measured (mocap gives none)."""

NO_ORIENTATION = np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0])
"""Imu orientation_covariance meaning 'no orientation estimate' (sensor_msgs/Imu doc)."""


def topic_name(namespace: str, relative: str) -> str:
    """``/quad`` + ``imu`` -> ``/quad/imu``."""
    return f"{namespace.rstrip('/')}/{relative}"


def stamps_ns(t: np.ndarray) -> np.ndarray:
    """Sample times [s] -> integer nanoseconds (rounded)."""
    return np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def _header(ns: int, frame: str):
    return Header(stamp=Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)), frame_id=frame)


def _vec(v) -> object:
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def write_bag(log: FlightLog, path: str | Path, force: bool = False, namespace: str = DEFAULT_NAMESPACE, progress=None) -> Path:
    """Write ``log`` as an MCAP bag directory at ``path``, atomically.

    ``progress``: optional callable(n_samples_done) for a progress bar.
    """
    path = Path(path)
    stamps = stamps_ns(log.t)
    if np.any(np.diff(stamps) <= 0):
        raise DataError(f"{log.meta.source}: sample times collapse at nanosecond resolution")
    position_enu, quat, twist_flu = frames.to_odometry(log.pos_n, log.vel_n, log.euler)
    acc_flu = frames.frd_to_flu(log.acc_b)
    gyro_flu = frames.frd_to_flu(log.gyro_b)
    serialize = TYPESTORE.serialize_cdr
    with atomic_output(path, force) as tmp:
        writer = Writer(tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        try:
            writer.open()
            connections = {
                key: writer.add_connection(topic_name(namespace, key), msgtype, typestore=TYPESTORE)
                for key, msgtype in TOPIC_TYPES.items()
                if key != "battery" or log.vbat is not None
            }
            writer.set_custom_data("quad_modelling.vehicle", log.meta.vehicle)
            writer.set_custom_data("quad_modelling.source", Path(log.meta.source).name)
            writer.set_custom_data("quad_modelling.notes", json.dumps(log.meta.notes))
            empty = np.zeros(0)
            for i, ns in enumerate(stamps.tolist()):
                motor = JointState(
                    header=_header(ns, BODY_FRAME),
                    name=list(MOTOR_NAMES),
                    position=empty,
                    velocity=log.omega[i] if log.omega is not None else empty,
                    effort=log.u[i],
                )
                writer.write(connections["motor_input"], ns, serialize(motor, JointState.__msgtype__))
                odom = Odometry(
                    header=_header(ns, WORLD_FRAME),
                    child_frame_id=BODY_FRAME,
                    pose=PoseWithCovariance(
                        pose=Pose(
                            position=Point(x=float(position_enu[i, 0]), y=float(position_enu[i, 1]), z=float(position_enu[i, 2])),
                            orientation=Quaternion(x=float(quat[i, 0]), y=float(quat[i, 1]), z=float(quat[i, 2]), w=float(quat[i, 3])),
                        ),
                        covariance=np.zeros(36),
                    ),
                    twist=TwistWithCovariance(
                        twist=Twist(linear=_vec(twist_flu[i]), angular=Vector3(x=0.0, y=0.0, z=0.0)),
                        covariance=UNKNOWN_ANGULAR_TWIST,
                    ),
                )
                writer.write(connections["mocap/odom"], ns, serialize(odom, Odometry.__msgtype__))
                imu = Imu(
                    header=_header(ns, BODY_FRAME),
                    orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=NO_ORIENTATION,
                    angular_velocity=_vec(gyro_flu[i]),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=_vec(acc_flu[i]),
                    linear_acceleration_covariance=np.zeros(9),
                )
                writer.write(connections["imu"], ns, serialize(imu, Imu.__msgtype__))
                if log.vbat is not None:
                    writer.write(connections["battery"], ns, serialize(_battery(ns, float(log.vbat[i])), BatteryState.__msgtype__))
                if progress is not None and i % 1000 == 999:
                    progress(1000)
            writer.close()
        except WriterError as err:
            raise BagError(f"{path}: cannot write bag: {err}") from err
    return path


def _battery(ns: int, voltage: float):
    nan = float("nan")  # sensor_msgs/BatteryState: unmeasured fields are NaN
    return BatteryState(
        header=_header(ns, BODY_FRAME), voltage=voltage, temperature=nan, current=nan, charge=nan,
        capacity=nan, design_capacity=nan, percentage=nan,
        power_supply_status=BatteryState.POWER_SUPPLY_STATUS_DISCHARGING,
        power_supply_health=BatteryState.POWER_SUPPLY_HEALTH_UNKNOWN,
        power_supply_technology=BatteryState.POWER_SUPPLY_TECHNOLOGY_UNKNOWN,
        present=True, cell_voltage=np.zeros(0, dtype=np.float32), cell_temperature=np.zeros(0, dtype=np.float32),
        location="", serial_number="",
    )


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


def _open_reader(path: Path) -> Reader:
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError, ValueError, KeyError) as err:
        raise BagError(f"{path}: not a readable rosbag2 bag ({err})") from err
    return reader


def summarize_bag(path: str | Path) -> BagSummary:
    """Topics, types, counts, time spans and rates of a bag (reads every message header)."""
    path = Path(path)
    reader = _open_reader(path)
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
    except (ReaderError, OSError, ValueError, KeyError, EOFError) as err:
        raise BagError(f"{path}: corrupt or truncated bag ({type(err).__name__}: {err})") from err
    finally:
        reader.close()


def _custom_data(path: Path) -> dict:
    import yaml

    try:
        doc = yaml.safe_load((path / "metadata.yaml").read_text())
        return dict(doc["rosbag2_bagfile_information"].get("custom_data") or {})
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return {}


def read_bag(path: str | Path, vehicle: str | None = None, namespace: str = DEFAULT_NAMESPACE) -> FlightLog:
    """Read a contract bag into a FlightLog on the ``motor_input`` time base.

    Raises BagError for an unreadable/corrupt bag or a missing topic (naming
    it and what was found), DataError naming topic and message index for
    non-finite values or stamps that do not increase.
    """
    path = Path(path)
    reader = _open_reader(path)
    try:
        wanted = {topic_name(namespace, key): key for key in TOPIC_TYPES}
        present = {c.topic for c in reader.connections}
        missing = [topic_name(namespace, k) for k in REQUIRED_TOPICS if topic_name(namespace, k) not in present]
        if missing:
            raise BagError(f"{path}: missing required topic(s) {missing}; found: {sorted(present)}")
        for c in reader.connections:
            key = wanted.get(c.topic)
            if key and c.msgtype != TOPIC_TYPES[key]:
                raise BagError(f"{path}: topic {c.topic} has type {c.msgtype}, expected {TOPIC_TYPES[key]}")
        columns: dict[str, list] = {key: [] for key in TOPIC_TYPES}
        stamps: dict[str, list] = {key: [] for key in TOPIC_TYPES}
        connections = [c for c in reader.connections if c.topic in wanted]
        deserialize = TYPESTORE.deserialize_cdr
        for connection, _, raw in reader.messages(connections=connections):
            key = wanted[connection.topic]
            msg = deserialize(raw, connection.msgtype)
            stamps[key].append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            if key == "motor_input":
                if len(msg.effort) != 4:
                    raise DataError(f"{path}: topic {connection.topic} message {len(stamps[key]) - 1} has {len(msg.effort)} efforts, expected 4")
                velocity = msg.velocity if len(msg.velocity) == 4 else np.full(4, np.nan)
                columns[key].append(np.concatenate([msg.effort, velocity]))
            elif key == "mocap/odom":
                p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
                columns[key].append((p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z))
            elif key == "imu":
                a, w = msg.linear_acceleration, msg.angular_velocity
                columns[key].append((a.x, a.y, a.z, w.x, w.y, w.z))
            else:
                columns[key].append((msg.voltage,))
    except (ReaderError, OSError, ValueError, KeyError, EOFError, AssertionError, IndexError) as err:
        raise BagError(f"{path}: corrupt or truncated bag ({type(err).__name__}: {err})") from err
    finally:
        reader.close()
    return _to_flight_log(path, namespace, columns, stamps, vehicle)


def _to_flight_log(path: Path, namespace: str, columns: dict, stamps: dict, vehicle: str | None) -> FlightLog:
    arrays = {}
    times = {}
    for key in TOPIC_TYPES:
        if not columns[key]:
            if key in REQUIRED_TOPICS:
                raise BagError(f"{path}: topic {topic_name(namespace, key)} has no messages")
            continue
        arrays[key] = np.asarray(columns[key], dtype=float)
        times[key] = np.asarray(stamps[key], dtype=np.int64)
        steps = np.diff(times[key])
        if np.any(steps <= 0):
            k = int(np.argmax(steps <= 0)) + 1
            raise DataError(f"{path}: topic {topic_name(namespace, key)} header stamps do not increase at message {k}")
        data = arrays[key] if key != "motor_input" else arrays[key][:, :4]
        bad = ~np.isfinite(data)
        if bad.any():
            k = int(np.argmax(bad.any(axis=1)))
            raise DataError(f"{path}: topic {topic_name(namespace, key)} message {k} holds a non-finite value")
    t_ns = times["motor_input"]
    t = t_ns / 1e9

    def on_motor_time(key: str) -> np.ndarray:
        data, when = arrays[key], times[key]
        if when.shape == t_ns.shape and np.array_equal(when, t_ns):
            return data
        return np.column_stack([np.interp(t_ns, when, column) for column in data.T])

    mocap = on_motor_time("mocap/odom")
    imu = on_motor_time("imu")
    pos_n, vel_n, euler = frames.from_odometry(mocap[:, 0:3], mocap[:, 3:7], mocap[:, 7:10])
    euler[:, 2] = np.unwrap(euler[:, 2])
    omega = arrays["motor_input"][:, 4:8]
    custom = _custom_data(path)
    notes = json.loads(custom.get("quad_modelling.notes", "{}") or "{}")
    vehicle_name = vehicle or custom.get("quad_modelling.vehicle")
    if not vehicle_name:
        raise DataError(f"{path}: the bag names no vehicle (custom_data quad_modelling.vehicle); pass --vehicle NAME")
    return FlightLog(
        t=t,
        u=arrays["motor_input"][:, :4],
        acc_b=frames.flu_to_frd(imu[:, 0:3]),
        gyro_b=frames.flu_to_frd(imu[:, 3:6]),
        pos_n=pos_n,
        vel_n=vel_n,
        euler=euler,
        vbat=on_motor_time("battery")[:, 0] if "battery" in arrays else None,
        omega=omega if np.isfinite(omega).all() else None,
        meta=FlightMeta(vehicle=vehicle_name, source=str(path), notes=notes),
    )
