"""The topic contract (DESIGN 5a) and the one conversion between FlightLog rows and its messages.

One module for both message bindings: the bag writer and reader use rosbags' Jazzy
type store (:mod:`quad_modelling.io.bag_io`), the nodes rclpy's generated messages
(:mod:`quad_modelling.nodes.messages`). Both accept keyword construction and
attribute access, so every message is built and read here once, parameterised by a
:class:`MessageTypes` of the binding's classes. This module imports neither rclpy nor
rosbags. Frames and units are converted only through :mod:`quad_modelling.core.frames`.

Topics are relative to a namespace (default ``/quad``):

=====================  ==========================  =====================================================
topic                  type                        content (frames per REP-103/147)
=====================  ==========================  =====================================================
``motor_input``        sensor_msgs/JointState      names motor_1..4, ``effort`` (4) = raw command,
                                                   ``velocity`` (4) = rotor speed [rad/s] when known
``mocap/odom``         nav_msgs/Odometry           pose in ``world`` (ENU), twist.linear in
                                                   ``base_link`` (FLU) [m/s]; angular twist not measured
``imu``                sensor_msgs/Imu             ``linear_acceleration`` specific force [m/s²] and
                                                   ``angular_velocity`` [rad/s], body FLU; no orientation;
                                                   only when the log has an accelerometer or gyro (one
                                                   missing: its covariance element 0 is -1, REP-145)
``battery``            sensor_msgs/BatteryState    ``voltage`` [V] (only when the log has it)
``<model>/odom``       nav_msgs/Odometry           predicted pose (``world``, ENU), twist.linear and
                                                   twist.angular in ``<model>/base_link`` (FLU)
``<model>/accel``      geometry_msgs/AccelStamped  predicted specific force [m/s²] (the IMU's convention:
                                                   gravity included, at rest level (0, 0, +g) FLU) and
                                                   angular acceleration [rad/s²], ``<model>/base_link`` (FLU)
``<model>/horizon/     nav_msgs/Odometry           receding-horizon mode: the state ``horizon_s`` ahead
odom``                                             of an anchor, frames as ``<model>/odom``
=====================  ==========================  =====================================================

Every header stamp is the sample time: integer nanoseconds ``ns = round(t · 1e9)``,
``t = ns / 1e9`` (:func:`stamps_ns`, :func:`stamps_to_seconds`).

"Fields" arrays are the raw message numbers in message frames, one row per message:
odometry fields (10) = position ENU (3), quaternion x, y, z, w of R_ENU←FLU (4),
linear twist FLU (3); predicted odometry fields (13) = those plus angular twist FLU
(3); imu fields (6) = specific force FLU (3), gyro FLU (3); accel fields (6) = linear
FLU (3), angular FLU (3). Whole windows convert at once (:func:`measurement_log`,
:func:`predictions_from_fields`) with vectorised frames calls.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from typing import Callable

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.preprocess import (MeasurementGap, check_same_clock, interpolation_gaps, mark_measurement_gaps, marked_gaps,
                                           recorded_gap_rule)
from quad_modelling.errors import BagError, ConfigError, DataError

DEFAULT_NAMESPACE = "/quad"
"""Namespace of the contract topics in a bag and of every node unless remapped (``--ros-args -r __ns:=/other``)."""

ORIGIN_TOPIC = "window_origin"
"""rosgraph_msgs/Clock, transient-local: the window origin t0 (first sample stamp), so every node cuts the same windows."""

PROGRESS_TOPIC = "evaluation/progress"
"""rosgraph_msgs/Clock: the last stamp every measurement stream delivered to the evaluator (the replay's rate-0 pacing)."""

DONE_TOPIC = "replay/done"
"""rosgraph_msgs/Clock, transient-local: the last stamp the replay played, published once it has finished (after the
acknowledgements reached it); ``run-bag`` on a host without the replay ends its nodes on it."""

HORIZON_TOPIC = "horizon/odom"
"""``<model>/horizon/odom`` (nav_msgs/Odometry, frames as ``<model>/odom``): receding-horizon mode, the state
``horizon_s`` ahead of each input re-anchored on the latest measurement, stamped at the predicted time."""

WORLD_FRAME = "world"
BODY_FRAME = "base_link"
MOTOR_NAMES = ("motor_1", "motor_2", "motor_3", "motor_4")
NANOSECONDS = 1_000_000_000

MEASUREMENT_TOPICS = {
    "motor_input": "sensor_msgs/msg/JointState",
    "mocap/odom": "nav_msgs/msg/Odometry",
    "imu": "sensor_msgs/msg/Imu",
    "battery": "sensor_msgs/msg/BatteryState",
}
"""Relative measurement topic -> message type, in the order a sample's messages are published."""

REQUIRED_TOPICS = ("motor_input", "mocap/odom")
"""Measurement topics a flight must have (``imu`` and ``battery`` are optional: a pose-only flight has no imu)."""

GAP_FIELDS = {"mocap/odom": ("pos_n", "vel_n", "euler"), "imu": ("acc_b", "gyro_b")}
"""The FlightLog fields each kinematic topic carries: a marked gap of the topic covers them (reader and writer)."""

LIVE_TOPICS = ("motor_input", "mocap/odom", "imu")
"""Measurement topics the live nodes need (the predictor and evaluator nodes wait for imu messages)."""

ODOM_FIELDS = 10
ODOM_QUATERNION = (3, 7)
"""Columns [start, stop) of the quaternion x, y, z, w inside the odometry fields."""
PREDICTED_ODOM_FIELDS = 13
IMU_FIELDS = 6
ACCEL_FIELDS = 6

UNKNOWN_ANGULAR_TWIST = np.zeros(36)
UNKNOWN_ANGULAR_TWIST[[21, 28, 35]] = -1.0
"""Odometry twist covariance marking the angular twist as not measured (motion capture gives none)."""

NO_ORIENTATION = np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0])
"""Imu orientation_covariance meaning 'no orientation estimate' (sensor_msgs/Imu doc)."""


_NAME_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def check_namespace(namespace: str) -> str:
    """``namespace`` if ROS 2 accepts it as a topic namespace: absolute (``/``), tokens of letters, digits and
    ``_`` not starting with a digit, no empty token, no ``__``, no trailing ``/`` (``/`` alone is the root);
    ConfigError naming the first fault otherwise (ROS 2 design article "Topic and Service name mapping")."""
    text = str(namespace)
    if text == "/":
        return text
    problem = None
    if not text.startswith("/"):
        problem = "must start with '/'"
    elif text.endswith("/"):
        problem = "must not end with '/'"
    elif "__" in text:
        problem = "must not contain '__'"
    else:
        bad = next((token for token in text[1:].split("/") if not _NAME_TOKEN.match(token)), None)
        if bad is not None:
            problem = (f"token {bad!r} must be letters, digits and '_', not starting with a digit" if bad
                       else "must not contain an empty token ('//')")
    if problem:
        raise ConfigError(f"--namespace {text!r}: not a valid ROS 2 namespace: {problem} (e.g. /quad or /drone_1)")
    return text


def topic_name(namespace: str, relative: str) -> str:
    """``/quad`` + ``imu`` -> ``/quad/imu``."""
    return f"{namespace.rstrip('/')}/{relative}"


# --- stamps -----------------------------------------------------------------------------------

def stamps_ns(t: np.ndarray) -> np.ndarray:
    """Sample times [s] -> integer nanoseconds (rounded)."""
    return np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def stamps_to_seconds(stamps: np.ndarray) -> np.ndarray:
    """Nanosecond stamps -> sample times [s], the time base of every FlightLog read from messages."""
    return np.asarray(stamps, dtype=np.int64) / 1e9


def stamp_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return stamp.sec * NANOSECONDS + stamp.nanosec


def set_stamp(msg, ns: int) -> None:
    """Set ``msg.header.stamp`` to ``ns`` nanoseconds (sec, nanosec)."""
    ns = int(ns)
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // NANOSECONDS, ns % NANOSECONDS


_CDR_STAMP = {b"\x00\x00": struct.Struct(">iI"), b"\x00\x01": struct.Struct("<iI")}
"""builtin_interfaces/Time (int32 sec, uint32 nanosec) by CDR encapsulation id (big, little endian)."""


def _cdr_stamp_layout(raw: bytes) -> struct.Struct:
    layout = _CDR_STAMP.get(bytes(raw[:2]))
    if layout is None or len(raw) < 12:
        raise ValueError(f"not a plain CDR message with a header ({len(raw)} bytes, encapsulation {bytes(raw[:2])!r})")
    return layout


def cdr_stamp_ns(raw: bytes) -> int:
    """Header stamp [ns] of a serialised contract message, read without deserialising it.

    CDR layout: a 4-byte encapsulation header (``00 01`` little-endian, ``00 00``
    big-endian), then the fields in order; every contract message starts with
    std_msgs/Header, whose first field is the stamp: bytes 4-8 ``sec`` (int32),
    8-12 ``nanosec`` (uint32).
    """
    sec, nanosec = _cdr_stamp_layout(raw).unpack_from(raw, 4)
    return sec * NANOSECONDS + nanosec


def cdr_restamped(raw: bytes, ns: int) -> bytes:
    """A copy of the serialised message ``raw`` with header stamp ``ns``; every other byte as recorded."""
    out = bytearray(raw)
    _cdr_stamp_layout(raw).pack_into(out, 4, int(ns) // NANOSECONDS, int(ns) % NANOSECONDS)
    return bytes(out)


# --- message classes of one binding -----------------------------------------------------------

@dataclass(frozen=True)
class MessageTypes:
    """The message classes of one binding (rosbags' type store or rclpy), by ROS type name."""

    Time: type
    Header: type
    Point: type
    Quaternion: type
    Vector3: type
    Pose: type
    PoseWithCovariance: type
    Twist: type
    TwistWithCovariance: type
    Accel: type
    JointState: type
    Odometry: type
    Imu: type
    BatteryState: type
    AccelStamped: type

    NAMES = {
        "Time": "builtin_interfaces/msg/Time", "Header": "std_msgs/msg/Header",
        "Point": "geometry_msgs/msg/Point", "Quaternion": "geometry_msgs/msg/Quaternion",
        "Vector3": "geometry_msgs/msg/Vector3", "Pose": "geometry_msgs/msg/Pose",
        "PoseWithCovariance": "geometry_msgs/msg/PoseWithCovariance", "Twist": "geometry_msgs/msg/Twist",
        "TwistWithCovariance": "geometry_msgs/msg/TwistWithCovariance", "Accel": "geometry_msgs/msg/Accel",
        "JointState": "sensor_msgs/msg/JointState", "Odometry": "nav_msgs/msg/Odometry", "Imu": "sensor_msgs/msg/Imu",
        "BatteryState": "sensor_msgs/msg/BatteryState", "AccelStamped": "geometry_msgs/msg/AccelStamped",
    }

    @classmethod
    def from_lookup(cls, lookup: Callable[[str], type]) -> MessageTypes:
        """``lookup("geometry_msgs/msg/Point")`` -> that binding's class, for every class above."""
        return cls(**{field: lookup(name) for field, name in cls.NAMES.items()})

    def header(self, frame: str, ns: int = 0):
        return self.Header(stamp=self.Time(sec=int(ns) // NANOSECONDS, nanosec=int(ns) % NANOSECONDS), frame_id=frame)

    def vector3(self, v=(0.0, 0.0, 0.0)):
        return self.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quaternion(self, q=(0.0, 0.0, 0.0, 1.0)):
        return self.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def odometry(self, frame: str, child_frame: str, twist_covariance: np.ndarray = UNKNOWN_ANGULAR_TWIST):
        """An Odometry at the origin, identity attitude, zero twist; every field given (rosbags needs all)."""
        return self.Odometry(
            header=self.header(frame),
            child_frame_id=child_frame,
            pose=self.PoseWithCovariance(pose=self.Pose(position=self.Point(x=0.0, y=0.0, z=0.0), orientation=self.quaternion()),
                                         covariance=np.zeros(36)),
            twist=self.TwistWithCovariance(twist=self.Twist(linear=self.vector3(), angular=self.vector3()),
                                           covariance=np.array(twist_covariance, dtype=float)),
        )

    def joint_state(self, effort=np.zeros(4), velocity=np.zeros(0), ns: int = 0):
        """A motor_input JointState: names motor_1..4, no positions."""
        return self.JointState(header=self.header(BODY_FRAME, ns), name=list(MOTOR_NAMES), position=np.zeros(0),
                               velocity=np.asarray(velocity, dtype=float), effort=np.asarray(effort, dtype=float))

    def imu(self, acc_flu=(0.0, 0.0, 0.0), gyro_flu=(0.0, 0.0, 0.0), ns: int = 0):
        """An Imu with specific force and gyro (FLU) and no orientation estimate."""
        return self.Imu(header=self.header(BODY_FRAME, ns), orientation=self.quaternion(), orientation_covariance=NO_ORIENTATION.copy(),
                        angular_velocity=self.vector3(gyro_flu), angular_velocity_covariance=np.zeros(9),
                        linear_acceleration=self.vector3(acc_flu), linear_acceleration_covariance=np.zeros(9))

    def battery(self, voltage: float = 0.0, ns: int = 0):
        """A BatteryState with ``voltage`` [V]; unmeasured fields NaN (sensor_msgs/BatteryState)."""
        nan, b = float("nan"), self.BatteryState
        return b(header=self.header(BODY_FRAME, ns), voltage=float(voltage), temperature=nan, current=nan, charge=nan,
                 capacity=nan, design_capacity=nan, percentage=nan,
                 power_supply_status=b.POWER_SUPPLY_STATUS_DISCHARGING, power_supply_health=b.POWER_SUPPLY_HEALTH_UNKNOWN,
                 power_supply_technology=b.POWER_SUPPLY_TECHNOLOGY_UNKNOWN, present=True,
                 cell_voltage=np.zeros(0, dtype=np.float32), cell_temperature=np.zeros(0, dtype=np.float32),
                 location="", serial_number="")

    def accel_stamped(self, frame: str):
        return self.AccelStamped(header=self.header(frame), accel=self.Accel(linear=self.vector3(), angular=self.vector3()))


# --- measurements: FlightLog rows -> messages (bag writer; node tests and benchmarks) ---------

class MeasurementMessages:
    """A flight's measurement messages, converted once to message frames and filled row by row.

    position_enu, quat_xyzw, twist_flu: :func:`quad_modelling.core.frames.to_odometry`;
    acc_flu, gyro_flu: :func:`quad_modelling.core.frames.frd_to_flu` of the body FRD signals.

    Each method refills one message of its kind and returns it, valid until the next
    call of that method: serialise it (a bag writer, an rclpy publisher) or copy it.
    Building a message costs ~20-70 µs in rclpy; refilling one costs a few.
    """

    def __init__(self, log: FlightLog, types: MessageTypes):
        self.position_enu, self.quat_xyzw, self.twist_flu = frames.to_odometry(log.pos_n, log.vel_n, log.euler)
        self.has_imu = log.acc_b is not None or log.gyro_b is not None
        self.acc_flu = np.zeros((len(log), 3)) if log.acc_b is None else frames.frd_to_flu(log.acc_b)
        self.gyro_flu = np.zeros((len(log), 3)) if log.gyro_b is None else frames.frd_to_flu(log.gyro_b)
        self.u, self.omega, self.vbat = log.u, log.omega, log.vbat
        self._motor = types.joint_state()
        self._odometry = types.odometry(WORLD_FRAME, BODY_FRAME)
        self._imu = types.imu()
        if log.acc_b is None:  # sensor_msgs/Imu: covariance element 0 = -1 means "no such data"
            self._imu.linear_acceleration_covariance = NO_ORIENTATION.copy()
        if log.gyro_b is None:
            self._imu.angular_velocity_covariance = NO_ORIENTATION.copy()
        self._battery = types.battery() if log.vbat is not None else None

    def motor(self, row: int, ns: int):
        msg = self._motor
        set_stamp(msg, ns)
        msg.effort = self.u[row]
        if self.omega is not None:
            msg.velocity = self.omega[row]
        return msg

    def odometry(self, row: int, ns: int):
        msg = self._odometry
        set_stamp(msg, ns)
        p, q, v = self.position_enu[row].tolist(), self.quat_xyzw[row].tolist(), self.twist_flu[row].tolist()
        position, orientation, linear = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
        position.x, position.y, position.z = p
        orientation.x, orientation.y, orientation.z, orientation.w = q
        linear.x, linear.y, linear.z = v
        return msg

    def imu(self, row: int, ns: int):
        msg = self._imu
        set_stamp(msg, ns)
        a, w = self.acc_flu[row].tolist(), self.gyro_flu[row].tolist()
        msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = a
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = w
        return msg

    def battery(self, row: int, ns: int):
        """The BatteryState of ``row``; None when the log has no voltage."""
        msg = self._battery
        if msg is None:
            return None
        set_stamp(msg, ns)
        msg.voltage = float(self.vbat[row])
        return msg

    @property
    def topics(self) -> tuple[str, ...]:
        """The relative topics this flight has messages on (imu and battery only when measured)."""
        return tuple(key for key, present in (("motor_input", True), ("mocap/odom", True), ("imu", self.has_imu),
                                              ("battery", self._battery is not None)) if present)

    def row(self, row: int, ns: int) -> dict:
        """Every measurement message of one sample, by relative topic, in :data:`MEASUREMENT_TOPICS` order."""
        out = {"motor_input": self.motor(row, ns), "mocap/odom": self.odometry(row, ns)}
        if self.has_imu:
            out["imu"] = self.imu(row, ns)
        if self._battery is not None:
            out["battery"] = self.battery(row, ns)
        return out


# --- measurements: messages -> fields -> FlightLog (bag reader, predictor, evaluator) -----------

def motor_fields(msg) -> tuple[np.ndarray, np.ndarray | None] | None:
    """(command (4,), rotor speed (4,) or None) in motor order; None when the message does not hold 4 efforts. Names
    ``motor_1..4`` in another order are put in motor order; other or no names: the efforts in the order sent."""
    if len(msg.effort) != 4:
        return None
    names = [str(n) for n in msg.name]
    order = [names.index(m) for m in MOTOR_NAMES] if len(names) == 4 and sorted(names) == list(MOTOR_NAMES) else [0, 1, 2, 3]
    u = np.array(msg.effort, dtype=float)[order]
    omega = np.array(msg.velocity, dtype=float)[order] if len(msg.velocity) == 4 else None
    if omega is not None and not np.isfinite(omega).all():
        omega = None
    return u, omega


def odometry_fields(msg) -> list[float]:
    """Odometry -> position ENU, quaternion xyzw, linear twist FLU (10 numbers)."""
    p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
    return [p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z]


def predicted_odometry_fields(msg) -> list[float]:
    """Odometry -> the 10 odometry fields plus angular twist FLU (13 numbers)."""
    w = msg.twist.twist.angular
    return odometry_fields(msg) + [w.x, w.y, w.z]


def imu_fields(msg) -> list[float]:
    """Imu -> specific force FLU, gyro FLU (6 numbers); NaN for a vector whose covariance element 0 is -1 (not measured)."""
    a, w = msg.linear_acceleration, msg.angular_velocity
    nan = float("nan")
    acc = [nan] * 3 if msg.linear_acceleration_covariance[0] == -1 else [a.x, a.y, a.z]
    gyro = [nan] * 3 if msg.angular_velocity_covariance[0] == -1 else [w.x, w.y, w.z]
    return acc + gyro


def accel_fields(msg) -> list[float]:
    """AccelStamped -> linear FLU, angular FLU (6 numbers)."""
    a, w = msg.accel.linear, msg.accel.angular
    return [a.x, a.y, a.z, w.x, w.y, w.z]


def invalid_odometry_quaternion(fields) -> bool:
    """True when odometry fields carry a quaternion whose norm is off 1 beyond
    :data:`~quad_modelling.core.frames.QUATERNION_NORM_TOLERANCE` (a zero quaternion has no attitude)."""
    return frames.quaternion_norm_off(fields[ODOM_QUATERNION[0]:ODOM_QUATERNION[1]]) is not None


def all_finite(values) -> bool:
    """True when every number is finite (a NaN/inf message is dropped by the nodes)."""
    return all(map(math.isfinite, values))  # a few numbers per message: no numpy array needed


def measurement_log(
    stamps: np.ndarray,
    u: np.ndarray,
    odometry: np.ndarray,
    imu: np.ndarray | None,
    vehicle: str,
    source: str,
    omega: np.ndarray | None = None,
    vbat: np.ndarray | None = None,
    notes: dict | None = None,
) -> FlightLog:
    """Rows of measurement fields on one time base -> FlightLog (internal NED/FRD frames).

    ``stamps`` (N,) [ns]; ``odometry`` (N, 10) and ``imu`` (N, 6) hold message fields
    (module docstring); ``imu`` None (no imu topic) or a vector NaN in every row (not
    measured) gives a log without that sensor. Yaw is unwrapped over the rows. Raises
    DataError (from FlightLog validation) for unusable rows.
    """
    odometry = np.asarray(odometry, dtype=float).reshape(-1, ODOM_FIELDS)
    imu = np.full((len(odometry), IMU_FIELDS), np.nan) if imu is None else np.asarray(imu, dtype=float).reshape(-1, IMU_FIELDS)
    acc, gyro = imu[:, 0:3], imu[:, 3:6]
    pos_n, vel_n, euler = frames.from_odometry(odometry[:, 0:3], odometry[:, 3:7], odometry[:, 7:10])
    euler[:, 2] = frames.unwrap_angles(euler[:, 2])
    return FlightLog(
        t=stamps_to_seconds(stamps),
        u=np.asarray(u, dtype=float).reshape(-1, 4),
        acc_b=None if np.isnan(acc).all() else frames.flu_to_frd(acc),
        gyro_b=None if np.isnan(gyro).all() else frames.flu_to_frd(gyro),
        pos_n=pos_n,
        vel_n=vel_n,
        euler=euler,
        vbat=vbat,
        omega=omega,
        meta=FlightMeta(vehicle=vehicle, source=source, notes=notes if notes is not None else {}),
    )


# --- predictions: (N, 18) <-> Odometry + AccelStamped -----------------------------------------

def prediction_fields(prediction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 18) predictions (VARIABLES order, internal frames) -> (N, 13) odometry and (N, 6) accel fields.

    Odometry: pose ENU and quaternion of R_ENU←FLU, linear twist rotated into
    the predicted body FLU, angular twist = rates FLU. Accel: the **specific force** of the
    predicted N acceleration in the predicted body FLU, as an IMU measures it,
    :math:`f_B = R^T (a_N - g e_z)` (:func:`~quad_modelling.core.frames.specific_force`, g =
    :data:`~quad_modelling.core.physics.rigid_body.GRAVITY`; hovering level: (0, 0, +g) FLU), and the angular
    acceleration FLU. A subscriber compares ``<model>/accel`` with ``imu`` directly.
    """
    y = np.atleast_2d(np.asarray(prediction, dtype=float))
    if len(y) == 1:  # the live predictor's case: one row per input, in floats (frames.prediction_row_to_ros)
        odom, accel = frames.prediction_row_to_ros(*(y[0, i:i + 3].tolist() for i in range(0, 18, 3)), GRAVITY)
        return np.array([odom]), np.array([accel])
    pos, vel, acc, euler, rates, angular_acc = (y[:, i:i + 3] for i in range(0, 18, 3))
    position_enu, quat, twist_flu = frames.to_odometry(pos, vel, euler)
    odom = np.hstack([position_enu, quat, twist_flu, frames.frd_to_flu(rates)])
    accel = np.hstack([frames.frd_to_flu(frames.specific_force(acc, euler, GRAVITY)), frames.frd_to_flu(angular_acc)])
    return odom, accel


def predictions_from_fields(odom: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """Inverse of :func:`prediction_fields`: (N, 13) and (N, 6) fields -> (N, 18) predictions.

    Yaw is unwrapped over the rows (as the measurement's yaw in
    :func:`~quad_modelling.core.preprocess.measured_variables`).
    """
    odom = np.asarray(odom, dtype=float).reshape(-1, PREDICTED_ODOM_FIELDS)
    accel = np.asarray(accel, dtype=float).reshape(-1, ACCEL_FIELDS)
    pos_n, vel_n, euler = frames.from_odometry(odom[:, 0:3], odom[:, 3:7], odom[:, 7:10])
    euler[:, 2] = frames.unwrap_angles(euler[:, 2])
    acc_n = frames.kinematic_acceleration(frames.flu_to_frd(accel[:, 0:3]), euler, GRAVITY)
    out = np.empty((len(odom), len(VARIABLES)))
    out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:12] = pos_n, vel_n, acc_n, euler
    out[:, 12:15] = frames.flu_to_frd(odom[:, 10:13])
    out[:, 15:18] = frames.flu_to_frd(accel[:, 3:6])
    return out


class PredictionMessages:
    """The Odometry and AccelStamped of one predictor, filled row by row and reused.

    A fresh Odometry costs ~70 µs to construct in rclpy (nested messages, two
    covariance arrays); a publisher serialises a message inside ``publish``, so
    one pair, refilled for every prediction, is safe and takes that off the
    per-input path.
    """

    def __init__(self, types: MessageTypes, child_frame: str, world_frame: str = WORLD_FRAME):
        self.odom = types.odometry(world_frame, child_frame, twist_covariance=np.zeros(36))
        self.accel = types.accel_stamped(child_frame)

    def fill(self, ns: int, odom: np.ndarray, accel: np.ndarray):
        """One row of prediction fields -> the (Odometry, AccelStamped) pair stamped ``ns`` (valid until the next fill)."""
        o = odom.tolist()
        a = accel.tolist()
        msg, out = self.odom, self.accel
        set_stamp(msg, ns)
        set_stamp(out, ns)
        position, orientation = msg.pose.pose.position, msg.pose.pose.orientation
        linear, angular = msg.twist.twist.linear, msg.twist.twist.angular
        position.x, position.y, position.z = o[0], o[1], o[2]
        orientation.x, orientation.y, orientation.z, orientation.w = o[3], o[4], o[5], o[6]
        linear.x, linear.y, linear.z = o[7], o[8], o[9]
        angular.x, angular.y, angular.z = o[10], o[11], o[12]
        out.accel.linear.x, out.accel.linear.y, out.accel.linear.z = a[0], a[1], a[2]
        out.accel.angular.x, out.accel.angular.y, out.accel.angular.z = a[3], a[4], a[5]
        return msg, out


def contract_flight_log(path, namespace: str, columns: dict, stamps: dict, flight_meta: Callable[[], tuple[str, dict]]) -> FlightLog:
    """The contract topics' rows (``columns``, ``stamps`` [ns] by relative topic, as read from a bag) -> a FlightLog on the
    ``motor_input`` time base (:func:`quad_modelling.io.bag_io.read_bag`): other topics interpolated linearly (exact when
    the stamps coincide), a kinematic topic on another clock refused, its dropouts marked. ``flight_meta()`` -> (vehicle
    name, notes), asked once the rows are checked. DataError/BagError naming the topic and message at fault."""
    arrays = {}
    times = {}
    for key in MEASUREMENT_TOPICS:
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
        if key == "imu":  # a vector the imu does not measure is NaN in every message (covariance -1)
            data = data[:, ~np.isnan(data).all(axis=0)]
        bad = ~np.isfinite(data)
        if bad.any():
            k = int(np.argmax(bad.any(axis=1)))
            raise DataError(f"{path}: topic {topic_name(namespace, key)} message {k} holds a non-finite value")
    t_ns = times["motor_input"]
    bad_quaternion = frames.non_unit_quaternion(arrays["mocap/odom"][:, 3:7])
    if bad_quaternion:
        k, norm = bad_quaternion
        raise DataError(f"{path}: topic {topic_name(namespace, 'mocap/odom')} message {k} has an orientation quaternion of norm {norm:.3g}, not 1")
    gaps: list[MeasurementGap] = []

    def on_motor_time(key: str) -> np.ndarray:
        data, when = arrays[key], times[key]
        if when.shape == t_ns.shape and np.array_equal(when, t_ns):
            return data
        if key != "battery":  # kinematic streams: a clock offset is refused, a dropout marked (never used)
            topic = topic_name(namespace, key)
            check_same_clock(topic, (when - t_ns[0]) * 1e-9, topic_name(namespace, "motor_input"), (t_ns - t_ns[0]) * 1e-9, str(path))
            gaps.extend(MeasurementGap(topic, a, b, GAP_FIELDS[key])
                        for a, b in interpolation_gaps(stamps_to_seconds(when), stamps_to_seconds(t_ns), rule))
        return np.column_stack([np.interp(t_ns, when, column) for column in data.T])

    omega = arrays["motor_input"][:, 4:8]
    vehicle_name, notes = flight_meta()
    rule = recorded_gap_rule(notes)
    base_s = stamps_to_seconds(t_ns)  # a hole of the time base itself: marked, no row inside (resampling fills it)
    gaps.extend(MeasurementGap(topic_name(namespace, "motor_input"), float(base_s[i]), float(base_s[i + 1]), ("u",))
                for i in np.flatnonzero(np.diff(base_s) > rule))
    log = measurement_log(
        t_ns, arrays["motor_input"][:, :4], on_motor_time("mocap/odom"), on_motor_time("imu") if "imu" in arrays else None,
        vehicle_name, str(path),
        omega=omega if np.isfinite(omega).all() else None,
        vbat=on_motor_time("battery")[:, 0] if "battery" in arrays else None,
        notes=notes,
    )
    mark_measurement_gaps(log, gaps, rule)
    return log


def gap_rows_by_topic(log: FlightLog) -> dict[str, np.ndarray]:
    """Per kinematic topic with a marked gap (``meta.notes['measurement_gaps']``) of its fields (:data:`GAP_FIELDS`;
    a gap naming no fields covers both): the (N,) mask of rows strictly inside such a gap, whose messages are not written."""
    masks = {}
    for key, fields in GAP_FIELDS.items():
        inside = np.zeros(len(log), dtype=bool)
        for gap in marked_gaps(log):
            if not gap.fields or set(gap.fields) & set(fields):
                inside |= (log.t > gap.start_s) & (log.t < gap.end_s)
        if inside.any():
            masks[key] = inside
    return masks
