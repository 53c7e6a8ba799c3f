"""Recordings of other flight stacks, written from a FlightLog as those stacks publish them (tests and benchmarks).

PX4 (uXRCE-DDS bridge, px4_msgs) and crazyswarm2 (crazyflie_interfaces) messages built with the real message
definitions copied into ``test/data/ros_msgs`` (px4_msgs BSD-3, crazyflie_interfaces MIT, licences there):
float32 fields as the firmware fills them, PX4 stamps in integer microseconds since boot. The messages come
from generators of ``(topic, stamp_ns, message)`` (:func:`px4_messages`, :func:`crazyswarm2_messages`) so a
live test can publish the same messages it would record; :func:`write_stack_bag` records them into a rosbag2
bag (MCAP or sqlite3) with the definitions stored, as ``ros2 bag record`` of Jazzy does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.io.bag_io import ForeignBagWriter
from quad_modelling.io.topics import stamps_ns

ROS_MSGS = Path(__file__).resolve().parent / "data" / "ros_msgs"
BOOT_US = 5_000_000
"""PX4 stamps: microseconds since boot; the flight's first sample 5 s after boot."""


def definitions() -> dict[str, str]:
    """Message type -> .msg text of every px4_msgs and crazyflie_interfaces message in test/data/ros_msgs."""
    return {f"{package.name}/msg/{msg.stem}": msg.read_text() for package in sorted(ROS_MSGS.iterdir()) if package.is_dir()
            for msg in sorted((package / "msg").glob("*.msg"))}


def px4_stamps_us(t: np.ndarray) -> np.ndarray:
    """Sample times [s] -> PX4 stamps: integer microseconds since boot (rounded), first sample at :data:`BOOT_US`."""
    return BOOT_US + np.round((np.asarray(t) - t[0]) * 1e6).astype(np.int64)


def _f32(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float32)


PWM_RANGE_US = (900.0, 2000.0)
"""actuator_outputs pulse widths of the stopped and the full motor: PX4's defaults (config/topic_maps/px4.yaml)."""


def px4_messages(writer: ForeignBagWriter, log: FlightLog, input_range: tuple[float, float], pwm: bool = False,
                 battery_ids: tuple[int, ...] = (1,), stamps_us: np.ndarray | None = None):
    """The PX4 messages of ``log``, one of each topic per sample, in time order: ``(topic, bag ns, message)``.

    vehicle_odometry (NED position and velocity, q = (w, x, y, z) of R_NED<-FRD), actuator_motors (control[0..3] =
    the commands mapped linearly from ``input_range`` onto 0..1, the other 8 channels NaN as PX4 leaves unused
    ones) or, with ``pwm``, actuator_outputs (output[0..3] = those 0..1 as pulse widths on :data:`PWM_RANGE_US`),
    sensor_combined (FRD) and
    battery_status (one message per id of ``battery_ids`` per sample: a multi-instance topic).
    """
    us = px4_stamps_us(log.t) if stamps_us is None else stamps_us
    quat_xyzw = frames.euler_ned_to_rotation(log.euler).as_quat()
    q_wxyz = _f32(quat_xyzw[:, [3, 0, 1, 2]])
    position, velocity = _f32(log.pos_n), _f32(log.vel_n)
    low, high = input_range
    control = _f32((log.u - low) / (high - low))
    pulse = _f32(PWM_RANGE_US[0] + (log.u - low) / (high - low) * (PWM_RANGE_US[1] - PWM_RANGE_US[0]))
    acc = _f32(log.acc_b) if log.acc_b is not None else None
    gyro = _f32(log.gyro_b) if log.gyro_b is not None else None
    unused = np.full(8, np.nan, dtype=np.float32)
    for i, stamp in enumerate(us.tolist()):
        ns = stamp * 1000
        yield "/fmu/out/vehicle_odometry", ns, writer.new(
            "px4_msgs/msg/VehicleOdometry", timestamp=stamp, timestamp_sample=stamp, pose_frame=1, velocity_frame=1,
            position=position[i], q=q_wxyz[i], velocity=velocity[i],
            angular_velocity=gyro[i] if gyro is not None else np.full(3, np.nan, dtype=np.float32))
        if pwm:
            yield "/fmu/out/actuator_outputs", ns, writer.new(
                "px4_msgs/msg/ActuatorOutputs", timestamp=stamp, noutputs=4,
                output=np.concatenate([pulse[i], np.zeros(12, dtype=np.float32)]))
        else:
            yield "/fmu/out/actuator_motors", ns, writer.new(
                "px4_msgs/msg/ActuatorMotors", timestamp=stamp, timestamp_sample=stamp, control=np.concatenate([control[i], unused]))
        if acc is not None and gyro is not None:
            yield "/fmu/out/sensor_combined", ns, writer.new(
                "px4_msgs/msg/SensorCombined", timestamp=stamp, gyro_rad=gyro[i], accelerometer_m_s2=acc[i],
                gyro_integral_dt=4000, accelerometer_integral_dt=4000)
        if log.vbat is not None:
            for k, battery in enumerate(battery_ids):
                yield "/fmu/out/battery_status", ns, writer.new(
                    "px4_msgs/msg/BatteryStatus", timestamp=stamp, connected=True, id=battery, cell_count=1,
                    voltage_v=np.float32(log.vbat[i] + k))


def crazyswarm2_messages(writer: ForeignBagWriter, log: FlightLog, robot: str = "cf231", stamps: np.ndarray | None = None):
    """The crazyswarm2 messages of ``log``: ``/<robot>/pose`` (PoseStamped, world ENU, orientation of R_ENU<-FLU) and
    the LogDataGeneric blocks of config/topic_maps/crazyswarm2.yaml: log_motors (PWM), log_velocity (world ENU m/s),
    log_imu (acc in g, gyro in deg/s, body FLU) and log_battery (V), float32 values as the firmware logs them.
    Header stamps: ``stamps`` [ns] (default: the log's times in ns); the on-board ``timestamp`` in ms since the first."""
    ns_all = stamps_ns(log.t) if stamps is None else stamps
    position, quat_xyzw, _ = frames.to_odometry(log.pos_n, log.vel_n, log.euler)
    velocity = _f32(frames.ned_to_enu(log.vel_n))
    motors = _f32(log.u)
    imu = None
    if log.acc_b is not None and log.gyro_b is not None:
        imu = _f32(np.hstack([frames.from_si(frames.frd_to_flu(log.acc_b), "g"), frames.from_si(frames.frd_to_flu(log.gyro_b), "deg/s")]))
    t0 = int(ns_all[0])

    def header(ns: int, frame: str):
        return writer.new("std_msgs/msg/Header", stamp=writer.new("builtin_interfaces/msg/Time", sec=ns // 10**9, nanosec=ns % 10**9),
                          frame_id=frame)

    def block(ns: int, values):
        return writer.new("crazyflie_interfaces/msg/LogDataGeneric", header=header(ns, "world"), timestamp=(ns - t0) // 10**6,
                          values=_f32(values))

    for i, ns in enumerate(ns_all.tolist()):
        p, q = position[i], quat_xyzw[i]
        pose = writer.new("geometry_msgs/msg/Pose", position=writer.new("geometry_msgs/msg/Point", x=p[0], y=p[1], z=p[2]),
                          orientation=writer.new("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))
        yield f"/{robot}/pose", ns, writer.new("geometry_msgs/msg/PoseStamped", header=header(ns, "world"), pose=pose)
        yield f"/{robot}/log_motors", ns, block(ns, motors[i])
        yield f"/{robot}/log_velocity", ns, block(ns, velocity[i])
        if imu is not None:
            yield f"/{robot}/log_imu", ns, block(ns, imu[i])
        if log.vbat is not None:
            yield f"/{robot}/log_battery", ns, block(ns, [log.vbat[i]])


def write_stack_bag(path: Path, messages, storage: str = "mcap", store_definitions: bool = True, skip=(), empty=()) -> Path:
    """Record ``messages(writer)`` (a generator function of this module, bound with its arguments) into a bag at ``path``.

    ``skip``: topics left out (a recording that lacks them); ``empty``: topics recorded without a message (a publisher
    whose QoS the recorder's did not match)."""
    with ForeignBagWriter(path, definitions(), storage=storage, store_definitions=store_definitions) as writer:
        for topic, ns, msg in messages(writer):
            if topic in empty:
                writer.connection(topic, msg.__msgtype__)
            elif topic not in skip:
                writer.write(topic, ns, msg)
    return Path(path)
