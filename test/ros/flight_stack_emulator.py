"""A flight-stack emulator: a real NanoBench flight published as a flight stack does (DESIGN 5a).

Each stream on its own clock, from one seeded :class:`Schedule`:

* ``motor_input`` ~100 Hz, each stamp jittered uniformly by +-2 ms around its nominal time;
* ``mocap/odom`` ~120 Hz (+-0.3 ms), ``imu`` ~500 Hz (+-0.1 ms), phases offset so no stamp is shared;

values are the flight's 100 Hz rows interpolated to each stream's stamps (:func:`log_at`; the IMU is the
flight's noise-free onboard values interpolated, not a noise model). Publishers use best-effort
sensor-data QoS (``qos_profile_sensor_data``) in any namespace (e.g. ``/cf1``); the emulator also
publishes ``/clock`` (sim time) and sends every message whose stamp the sim clock has passed, at
``rate`` x real time (:meth:`FlightStackEmulator.run`). ``log_at`` and :func:`schedule` serve the
in-process tests as well, so both feed the same streams.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.io import topics


@dataclass(frozen=True)
class Schedule:
    """Stamps [ns] of each stream (sorted, unique, no stamp shared between streams)."""

    motor: np.ndarray
    mocap: np.ndarray
    imu: np.ndarray


def _stream(start_s: float, end_s: float, rate_hz: float, jitter_s: float, phase_s: float, rng) -> np.ndarray:
    nominal = start_s + phase_s + np.arange(int((end_s - start_s - phase_s) * rate_hz)) / rate_hz
    return topics.stamps_ns(nominal + rng.uniform(-jitter_s, jitter_s, len(nominal)))


def schedule(start_s: float, end_s: float, seed: int = 0, motor_hz: float = 100.0, motor_jitter_s: float = 0.002,
             mocap_hz: float = 120.0, imu_hz: float = 500.0) -> Schedule:
    """The seeded stamps of the three streams over [start_s, end_s) [s] (module doc)."""
    rng = np.random.default_rng(seed)
    motor = _stream(start_s, end_s, motor_hz, motor_jitter_s, 0.0, rng)
    mocap = _stream(start_s, end_s, mocap_hz, 0.0003, 0.0013, rng)
    imu = _stream(start_s, end_s, imu_hz, 0.0001, 0.0007, rng)
    mocap = mocap[~np.isin(mocap, motor)]
    imu = imu[~np.isin(imu, np.concatenate([motor, mocap]))]
    return Schedule(motor, mocap, imu)


def log_at(log: FlightLog, stamps_ns: np.ndarray) -> FlightLog:
    """The flight at other stamps [ns]: every channel linearly interpolated (yaw unwrapped first)."""
    t = topics.stamps_to_seconds(np.asarray(stamps_ns, dtype=np.int64))

    def at(values):
        if values is None:
            return None
        values = np.asarray(values, dtype=float)
        if values.ndim == 1:
            return np.interp(t, log.t, values)
        return np.column_stack([np.interp(t, log.t, values[:, i]) for i in range(values.shape[1])])

    euler = log.euler.copy()
    euler[:, 2] = np.unwrap(euler[:, 2])
    return FlightLog(t=t, u=at(log.u), acc_b=at(log.acc_b), gyro_b=at(log.gyro_b), pos_n=at(log.pos_n), vel_n=at(log.vel_n),
                     euler=at(euler), vbat=at(log.vbat), omega=at(log.omega), meta=log.meta)


def events(plan: Schedule) -> list[tuple[int, str, int]]:
    """(stamp [ns], stream, row in that stream) of every message, in stamp order."""
    out = [(int(ns), stream, i) for stream, stamps in (("motor", plan.motor), ("mocap", plan.mocap), ("imu", plan.imu))
           for i, ns in enumerate(stamps)]
    return sorted(out)


def run_emulator(log: FlightLog, plan: Schedule, namespace: str, rate: float = 1.0, lead_s: float = 2.0) -> dict:
    """Publish ``log`` on ``plan``'s stamps in ``namespace`` (best-effort sensor-data QoS) with ``/clock``, at ``rate``
    x real time, after waiting ``lead_s`` [wall s] for subscribers; returns the counts published per stream."""
    import time

    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, JointState

    from quad_modelling.nodes import messages

    streams = {"motor": log_at(log, plan.motor), "mocap": log_at(log, plan.mocap), "imu": log_at(log, plan.imu)}
    arrays = {name: messages.measurement_messages(part) for name, part in streams.items()}
    node = rclpy.create_node("flight_stack_emulator", namespace=namespace)
    pubs = {"motor": node.create_publisher(JointState, "motor_input", qos_profile_sensor_data),
            "mocap": node.create_publisher(Odometry, "mocap/odom", qos_profile_sensor_data),
            "imu": node.create_publisher(Imu, "imu", qos_profile_sensor_data)}
    clock_pub = node.create_publisher(Clock, "/clock", 10)
    build = {"motor": lambda i, ns: arrays["motor"].motor(i, ns), "mocap": lambda i, ns: arrays["mocap"].odometry(i, ns),
             "imu": lambda i, ns: arrays["imu"].imu(i, ns)}
    counts = {name: 0 for name in pubs}
    try:
        end = time.monotonic() + lead_s
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        plan_events = events(plan)
        first = plan_events[0][0]
        started = time.monotonic()
        for ns, stream, row in plan_events:
            due = started + (ns - first) / 1e9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            clock_pub.publish(messages.clock_message(ns))
            pubs[stream].publish(build[stream](row, ns))
            counts[stream] += 1
    finally:
        node.destroy_node()
    return counts
