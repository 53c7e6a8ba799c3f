"""The one module that converts ROS messages to and from core arrays (DESIGN 2, 4, 5a).

Frames and units are converted only through :mod:`quad_modelling.core.frames`;
this module only moves numbers between message fields and arrays.

=====================  ========================  ==========================================================
topic                  type                      fields used (frames per REP-103/147)
=====================  ========================  ==========================================================
``motor_input``        sensor_msgs/JointState    ``effort`` (4) raw command; ``velocity`` (4) rotor speed
                                                 [rad/s] when present
``mocap/odom``         nav_msgs/Odometry         pose in ``world`` (ENU), twist.linear in body FLU
``imu``                sensor_msgs/Imu           ``linear_acceleration`` specific force [m/s²] and
                                                 ``angular_velocity`` [rad/s], body FLU
``battery``            sensor_msgs/BatteryState  ``voltage`` [V]
``<model>/odom``       nav_msgs/Odometry         predicted pose (``world``, ENU), twist.linear and
                                                 twist.angular in ``<model>/base_link`` (FLU)
``<model>/accel``      geometry_msgs/AccelStamped  predicted linear and angular acceleration in
                                                 ``<model>/base_link`` (FLU) [m/s², rad/s²]
=====================  ========================  ==========================================================

"Fields" arrays are the raw message numbers in message frames, row per
message: odometry fields (10) = position ENU (3), quaternion x, y, z, w (4),
linear twist FLU (3); predicted odometry fields (13) = those plus angular
twist FLU (3); imu fields (6) = specific force FLU (3), gyro FLU (3); accel
fields (6) = linear FLU (3), angular FLU (3). Nodes buffer fields and convert
whole windows at once (:func:`measurement_log`, :func:`predictions_from_fields`),
with the same vectorised frames calls the bag reader uses.
"""

from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import BatteryState, Imu, JointState

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.variables import VARIABLES

WORLD_FRAME = "world"
BODY_FRAME = "base_link"
MOTOR_NAMES = ["motor_1", "motor_2", "motor_3", "motor_4"]
NANOSECONDS = 1_000_000_000

ODOM_FIELDS = 10
PREDICTED_ODOM_FIELDS = 13
IMU_FIELDS = 6
ACCEL_FIELDS = 6

UNKNOWN_ANGULAR_TWIST = [0.0] * 36
for _i in (21, 28, 35):
    UNKNOWN_ANGULAR_TWIST[_i] = -1.0
"""Odometry twist covariance marking the angular twist as not measured (motion capture gives none)."""

NO_ORIENTATION = [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
"""Imu orientation_covariance meaning 'no orientation estimate' (sensor_msgs/Imu doc)."""


# --- stamps -----------------------------------------------------------------------------------

def stamp_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return stamp.sec * NANOSECONDS + stamp.nanosec


def ns_stamp(ns: int) -> Time:
    """Integer nanoseconds -> builtin_interfaces/Time."""
    ns = int(ns)
    return Time(sec=ns // NANOSECONDS, nanosec=ns % NANOSECONDS)


def stamps_to_seconds(stamps_ns: np.ndarray) -> np.ndarray:
    """Nanosecond stamps -> seconds, exactly as the bag reader computes its time base."""
    return np.asarray(stamps_ns, dtype=np.int64) / 1e9


def clock_message(ns: int) -> Clock:
    """rosgraph_msgs/Clock at ``ns`` (also the evaluator's progress acknowledgement)."""
    return Clock(clock=ns_stamp(ns))


# --- measurements: arrays -> messages (replay) -----------------------------------------------

class MeasurementArrays:
    """A flight's measurements in message frames, converted once for publishing.

    position_enu, quat_xyzw, twist_flu: :func:`quad_modelling.core.frames.to_odometry`;
    acc_flu, gyro_flu: :func:`quad_modelling.core.frames.frd_to_flu` of the body FRD signals.

    Each method refills one message of its kind and returns it (valid until the next
    call of that method: publish it, which serialises it, or copy it). Constructing
    rclpy messages costs ~20-70 µs each; the replay publishes four per sample.
    """

    def __init__(self, log: FlightLog):
        self.position_enu, self.quat_xyzw, self.twist_flu = frames.to_odometry(log.pos_n, log.vel_n, log.euler)
        self.acc_flu = frames.frd_to_flu(log.acc_b)
        self.gyro_flu = frames.frd_to_flu(log.gyro_b)
        self.u = log.u
        self.omega = log.omega
        self.vbat = log.vbat
        self._motor = JointState()
        self._motor.header.frame_id = BODY_FRAME
        self._motor.name = MOTOR_NAMES
        self._odometry = Odometry()
        self._odometry.header.frame_id = WORLD_FRAME
        self._odometry.child_frame_id = BODY_FRAME
        self._odometry.twist.covariance = UNKNOWN_ANGULAR_TWIST
        self._imu = Imu()
        self._imu.header.frame_id = BODY_FRAME
        self._imu.orientation.w = 1.0
        self._imu.orientation_covariance = NO_ORIENTATION
        nan = float("nan")  # sensor_msgs/BatteryState: unmeasured fields are NaN
        self._battery = BatteryState(temperature=nan, current=nan, charge=nan, capacity=nan, design_capacity=nan, percentage=nan,
                                     present=True, power_supply_status=BatteryState.POWER_SUPPLY_STATUS_DISCHARGING)
        self._battery.header.frame_id = BODY_FRAME

    @staticmethod
    def _stamp(msg, ns: int) -> None:
        ns = int(ns)
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns // NANOSECONDS, ns % NANOSECONDS

    def motor(self, row: int, ns: int) -> JointState:
        msg = self._motor
        self._stamp(msg, ns)
        msg.effort = self.u[row].tolist()
        if self.omega is not None:
            msg.velocity = self.omega[row].tolist()
        return msg

    def odometry(self, row: int, ns: int) -> Odometry:
        msg = self._odometry
        self._stamp(msg, ns)
        p, q, v = self.position_enu[row].tolist(), self.quat_xyzw[row].tolist(), self.twist_flu[row].tolist()
        position, orientation, linear = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
        position.x, position.y, position.z = p
        orientation.x, orientation.y, orientation.z, orientation.w = q
        linear.x, linear.y, linear.z = v
        return msg

    def imu(self, row: int, ns: int) -> Imu:
        msg = self._imu
        self._stamp(msg, ns)
        a, w = self.acc_flu[row].tolist(), self.gyro_flu[row].tolist()
        msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = a
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = w
        return msg

    def battery(self, row: int, ns: int) -> BatteryState | None:
        if self.vbat is None:
            return None
        msg = self._battery
        self._stamp(msg, ns)
        msg.voltage = float(self.vbat[row])
        return msg


# --- measurements: messages -> fields -> FlightLog (predictor, evaluator) ----------------------

def motor_fields(msg: JointState) -> tuple[np.ndarray, np.ndarray | None] | None:
    """(command (4,), rotor speed (4,) or None); None when the message has no 4 finite efforts."""
    if len(msg.effort) != 4:
        return None
    u = np.array(msg.effort, dtype=float)
    omega = np.array(msg.velocity, dtype=float) if len(msg.velocity) == 4 else None
    if omega is not None and not np.isfinite(omega).all():
        omega = None
    return u, omega


def odometry_fields(msg: Odometry) -> list[float]:
    """Odometry -> position ENU, quaternion xyzw, linear twist FLU (10 numbers)."""
    p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
    return [p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z]


def predicted_odometry_fields(msg: Odometry) -> list[float]:
    """Odometry -> the 10 odometry fields plus angular twist FLU (13 numbers)."""
    w = msg.twist.twist.angular
    return odometry_fields(msg) + [w.x, w.y, w.z]


def imu_fields(msg: Imu) -> list[float]:
    """Imu -> specific force FLU, gyro FLU (6 numbers)."""
    a, w = msg.linear_acceleration, msg.angular_velocity
    return [a.x, a.y, a.z, w.x, w.y, w.z]


def accel_fields(msg: AccelStamped) -> list[float]:
    """AccelStamped -> linear FLU, angular FLU (6 numbers)."""
    a, w = msg.accel.linear, msg.accel.angular
    return [a.x, a.y, a.z, w.x, w.y, w.z]


def all_finite(values) -> bool:
    """True when every number is finite (a NaN/inf message is dropped by the nodes)."""
    return all(map(math.isfinite, values))  # a few numbers per message: no numpy array needed


def measurement_log(
    stamps_ns: np.ndarray,
    u: np.ndarray,
    odometry: np.ndarray,
    imu: np.ndarray,
    vehicle: str,
    source: str,
    omega: np.ndarray | None = None,
    vbat: np.ndarray | None = None,
) -> FlightLog:
    """Rows of received measurements -> FlightLog (internal frames), as the bag reader builds one.

    ``odometry`` (N, 10) and ``imu`` (N, 6) hold message fields (module docstring).
    Raises DataError (from FlightLog validation) for unusable rows.
    """
    odometry = np.asarray(odometry, dtype=float).reshape(-1, ODOM_FIELDS)
    imu = np.asarray(imu, dtype=float).reshape(-1, IMU_FIELDS)
    pos_n, vel_n, euler = frames.from_odometry(odometry[:, 0:3], odometry[:, 3:7], odometry[:, 7:10])
    euler[:, 2] = np.unwrap(euler[:, 2])
    return FlightLog(
        t=stamps_to_seconds(stamps_ns),
        u=np.asarray(u, dtype=float).reshape(-1, 4),
        acc_b=frames.flu_to_frd(imu[:, 0:3]),
        gyro_b=frames.flu_to_frd(imu[:, 3:6]),
        pos_n=pos_n,
        vel_n=vel_n,
        euler=euler,
        vbat=vbat,
        omega=omega,
        meta=FlightMeta(vehicle=vehicle, source=source),
    )


# --- predictions: (18,) <-> Odometry + AccelStamped -------------------------------------------

def prediction_fields(prediction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 18) predictions (VARIABLES order, internal frames) -> (N, 13) odometry and (N, 6) accel fields.

    Odometry: pose ENU and quaternion of R_ENU←FLU, linear twist rotated into
    the predicted body FLU, angular twist = rates FLU. Accel: the predicted N
    acceleration rotated into the predicted body FLU, angular acceleration FLU.
    """
    y = np.atleast_2d(np.asarray(prediction, dtype=float))
    pos, vel, acc, euler, rates, angular_acc = (y[:, i:i + 3] for i in range(0, 18, 3))
    position_enu, quat, twist_flu = frames.to_odometry(pos, vel, euler)
    odom = np.hstack([position_enu, quat, twist_flu, frames.frd_to_flu(rates)])
    accel = np.hstack([frames.frd_to_flu(frames.nav_to_body(acc, euler)), frames.frd_to_flu(angular_acc)])
    return odom, accel


def predictions_from_fields(odom: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """Inverse of :func:`prediction_fields`: (N, 13) and (N, 6) fields -> (N, 18) predictions.

    Yaw is unwrapped over the rows (as the measurement's yaw in
    :func:`~quad_modelling.core.preprocess.measured_variables`).
    """
    odom = np.asarray(odom, dtype=float).reshape(-1, PREDICTED_ODOM_FIELDS)
    accel = np.asarray(accel, dtype=float).reshape(-1, ACCEL_FIELDS)
    pos_n, vel_n, euler = frames.from_odometry(odom[:, 0:3], odom[:, 3:7], odom[:, 7:10])
    euler[:, 2] = np.unwrap(euler[:, 2])
    acc_n = frames.body_to_nav(frames.flu_to_frd(accel[:, 0:3]), euler)
    out = np.empty((len(odom), len(VARIABLES)))
    out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:12] = pos_n, vel_n, acc_n, euler
    out[:, 12:15] = frames.flu_to_frd(odom[:, 10:13])
    out[:, 15:18] = frames.flu_to_frd(accel[:, 3:6])
    return out


class PredictionMessages:
    """The Odometry and AccelStamped of one predictor, filled row by row and reused.

    A fresh Odometry costs ~70 µs to construct in rclpy (nested messages, two
    covariance arrays); the publisher serialises a message inside ``publish``, so
    one pair, refilled for every prediction, is safe and takes that off the
    per-input path.
    """

    def __init__(self, child_frame: str, world_frame: str = WORLD_FRAME):
        self.odom = Odometry()
        self.odom.header.frame_id = world_frame
        self.odom.child_frame_id = child_frame
        self.accel = AccelStamped()
        self.accel.header.frame_id = child_frame

    def fill(self, ns: int, odom: np.ndarray, accel: np.ndarray) -> tuple[Odometry, AccelStamped]:
        """One row of prediction fields -> the (Odometry, AccelStamped) pair stamped ``ns`` (valid until the next fill)."""
        o = odom.tolist()
        a = accel.tolist()
        ns = int(ns)
        sec, nanosec = ns // NANOSECONDS, ns % NANOSECONDS
        msg, out = self.odom, self.accel
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        out.header.stamp.sec, out.header.stamp.nanosec = sec, nanosec
        position, orientation = msg.pose.pose.position, msg.pose.pose.orientation
        linear, angular = msg.twist.twist.linear, msg.twist.twist.angular
        position.x, position.y, position.z = o[0], o[1], o[2]
        orientation.x, orientation.y, orientation.z, orientation.w = o[3], o[4], o[5], o[6]
        linear.x, linear.y, linear.z = o[7], o[8], o[9]
        angular.x, angular.y, angular.z = o[10], o[11], o[12]
        out.accel.linear.x, out.accel.linear.y, out.accel.linear.z = a[0], a[1], a[2]
        out.accel.angular.x, out.accel.angular.y, out.accel.angular.z = a[3], a[4], a[5]
        return msg, out


def prediction_messages(ns: int, odom: np.ndarray, accel: np.ndarray, child_frame: str, world_frame: str = WORLD_FRAME) -> tuple[Odometry, AccelStamped]:
    """One row of prediction fields -> a new (Odometry, AccelStamped) pair stamped ``ns``."""
    return PredictionMessages(child_frame, world_frame).fill(ns, odom, accel)
