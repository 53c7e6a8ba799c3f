"""Sensor models of the truth simulator: motion capture, IMU, battery voltage.

From the 1 kHz truth (states and translational accelerations) to the logged
channels at the log rate (100 Hz):

* **Motion capture** at ``mocap_rate`` (250 Hz): position + white noise
  (σ_p, mm level), attitude perturbed by a random rotation vector (σ_a);
  velocity = Savitzky-Golay derivative (quadratic, ``mocap_velocity_window``
  samples) of the noisy positions, as tracking software does; all linearly
  interpolated to the log times (yaw unwrapped first).
* **IMU**: specific force :math:`f_B = R^T(\\dot v_N - g e_z)` (≈ (0, 0, -g) at
  hover) and body rates, each averaged over the log period (the sensor's
  anti-alias filter), plus turn-on bias b_0 ~ N(0, σ_b), bias random walk
  :math:`b_k = b_{k-1} + N(0, σ_d^2 Δt)` and white noise N(0, σ_n²). An IMU at
  :math:`r` from the CoM (``com_offset``) measures
  :math:`f_{imu} = f_B + \\dot\\omega \\times r + \\omega \\times (\\omega \\times r)`
  (:func:`lever_arm_acceleration`) before the averaging. :func:`imu` also returns
  the output without the white noise (same draws).
* **Engine commands**: the last command the stabiliser sent at or before each
  log time (zero-order hold), in the vehicle's input unit.
* **Battery voltage**: the pack voltage at the last control tick + ADC noise.
* **Rotor speeds**: the true Ω_i at the log time (FlightLog.omega).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

from quad_modelling.core import frames
from quad_modelling.core.sim.params import SensorParams
from quad_modelling.core.physics.rigid_body import GRAVITY


def quaternion_rotations(quat_wxyz: np.ndarray) -> Rotation:
    """Rotations R_N<-B from (N, 4) scalar-first unit quaternions."""
    return Rotation.from_quat(np.column_stack([quat_wxyz[:, 1:4], quat_wxyz[:, 0]]))


def period_average(values: np.ndarray, steps: int) -> np.ndarray:
    """Mean over each log period: row j = mean of rows (j-1)*steps+1 .. j*steps of
    ``values`` (row 0 = values[0]); ``values`` has n*steps rows for n log samples."""
    n = len(values) // steps
    csum = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    out = np.empty((n, values.shape[1]))
    out[0] = values[0]
    idx = np.arange(1, n) * steps
    out[1:] = (csum[idx + 1] - csum[idx + 1 - steps]) / steps
    return out


class ImuSamples(NamedTuple):
    """IMU channels at the log rate, (n, 3) each, in B."""

    acc_b: np.ndarray  # accelerometer as logged [m/s²]
    gyro_b: np.ndarray  # gyro as logged [rad/s]
    specific_force_b: np.ndarray  # period-averaged specific force at the CoM [m/s²]
    rates_b: np.ndarray  # period-averaged body rates [rad/s]
    noise_free_acc_b: np.ndarray  # acc_b without its white noise: averaged f_imu + bias + bias walk [m/s²]
    noise_free_gyro_b: np.ndarray  # gyro_b without its white noise [rad/s]
    lever_arm_acc_b: np.ndarray  # period-averaged lever-arm part of f_imu (zeros for an IMU at the CoM) [m/s²]


def lever_arm_acceleration(angular_accel_b: np.ndarray, rates_b: np.ndarray, position_b) -> np.ndarray:
    """What an accelerometer at ``position_b`` r [m] from the CoM reads on top of the CoM's specific force,
    rows of :math:`\\dot\\omega \\times r + \\omega \\times (\\omega \\times r)` [m/s²] (rigid body, all in B)."""
    r = np.asarray(position_b, dtype=float)
    return np.cross(angular_accel_b, r) + np.cross(rates_b, np.cross(rates_b, r))


def imu(
    quat_wxyz: np.ndarray, accel_n: np.ndarray, rates_b: np.ndarray, steps: int, log_dt: float,
    sensors: SensorParams, rng: np.random.Generator, angular_accel_b: np.ndarray | None = None, position_b=None,
) -> ImuSamples:
    """The IMU at the log rate, from physics-rate quaternions, translational accelerations in N and body
    rates; an IMU ``position_b`` r off the CoM (None: at the CoM) adds the lever-arm terms, which need the
    physics-rate angular accelerations ``angular_accel_b`` [rad/s²].

    Draws, in this order (the streams of an IMU at the CoM are those of earlier versions): accelerometer
    bias walk, turn-on bias, white noise, then the same for the gyro."""
    rotations = quaternion_rotations(quat_wxyz)
    specific = rotations.apply(accel_n - np.array([0.0, 0.0, GRAVITY]), inverse=True)
    true_acc = period_average(specific, steps)
    true_gyro = period_average(rates_b, steps)
    n = len(true_acc)
    if position_b is None:
        lever = np.zeros_like(true_acc)
        measured_acc = true_acc
    else:
        lever_fast = lever_arm_acceleration(angular_accel_b, rates_b, position_b)
        lever = period_average(lever_fast, steps)
        measured_acc = period_average(specific + lever_fast, steps)

    def corrupt(true: np.ndarray, noise: float, bias: float, drift: float) -> tuple[np.ndarray, np.ndarray]:
        walk = np.cumsum(rng.standard_normal((n, 3)) * drift * np.sqrt(log_dt), axis=0)
        noise_free = true + rng.standard_normal(3) * bias + walk
        return noise_free + rng.standard_normal((n, 3)) * noise, noise_free

    acc_b, noise_free_acc = corrupt(measured_acc, sensors.acc_noise, sensors.acc_bias, sensors.acc_drift)
    gyro_b, noise_free_gyro = corrupt(true_gyro, sensors.gyro_noise, sensors.gyro_bias, sensors.gyro_drift)
    return ImuSamples(acc_b, gyro_b, true_acc, true_gyro, noise_free_acc, noise_free_gyro, lever)


def motion_capture(
    t_mocap: np.ndarray, pos_n: np.ndarray, quat_wxyz: np.ndarray, t_log: np.ndarray,
    sensors: SensorParams, rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pos_n, vel_n, euler) at ``t_log`` from true mocap-rate samples."""
    noisy_pos = pos_n + rng.standard_normal(pos_n.shape) * sensors.mocap_position_noise
    perturb = Rotation.from_rotvec(rng.standard_normal(pos_n.shape) * sensors.mocap_attitude_noise)
    attitude = quaternion_rotations(quat_wxyz) * perturb
    euler = frames.unwrap_angles(frames.rotation_to_euler_ned(attitude))
    vel = savgol_filter(noisy_pos, sensors.mocap_velocity_window, 2, deriv=1, delta=1.0 / sensors.mocap_rate, axis=0, mode="interp")

    def resample(values: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t_log, t_mocap, values[:, i]) for i in range(values.shape[1])])

    euler_log = resample(euler)
    euler_log[:, :2] = (euler_log[:, :2] + np.pi) % (2 * np.pi) - np.pi
    return resample(noisy_pos), resample(vel), euler_log
