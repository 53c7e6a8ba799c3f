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
  :math:`b_k = b_{k-1} + N(0, σ_d^2 Δt)` and white noise N(0, σ_n²).
* **Engine commands**: the last command the stabiliser sent at or before each
  log time (zero-order hold), in the vehicle's input unit.
* **Battery voltage**: the pack voltage at the last control tick + ADC noise.
* **Rotor speeds**: the true Ω_i at the log time (FlightLog.omega).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

from quad_modelling.core import frames
from quad_modelling.core.sim.params import SensorParams
from quad_modelling.core.vehicle import GRAVITY


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


def imu(
    quat_wxyz: np.ndarray, accel_n: np.ndarray, rates_b: np.ndarray, steps: int, log_dt: float,
    sensors: SensorParams, rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(acc_b, gyro_b, true specific force, true rates) at the log rate, from physics-rate
    quaternions, translational accelerations in N and body rates."""
    rotations = quaternion_rotations(quat_wxyz)
    specific = rotations.apply(accel_n - np.array([0.0, 0.0, GRAVITY]), inverse=True)
    true_acc = period_average(specific, steps)
    true_gyro = period_average(rates_b, steps)
    n = len(true_acc)

    def corrupt(true: np.ndarray, noise: float, bias: float, drift: float) -> np.ndarray:
        walk = np.cumsum(rng.standard_normal((n, 3)) * drift * np.sqrt(log_dt), axis=0)
        return true + rng.standard_normal(3) * bias + walk + rng.standard_normal((n, 3)) * noise

    acc_b = corrupt(true_acc, sensors.acc_noise, sensors.acc_bias, sensors.acc_drift)
    gyro_b = corrupt(true_gyro, sensors.gyro_noise, sensors.gyro_bias, sensors.gyro_drift)
    return acc_b, gyro_b, true_acc, true_gyro


def motion_capture(
    t_mocap: np.ndarray, pos_n: np.ndarray, quat_wxyz: np.ndarray, t_log: np.ndarray,
    sensors: SensorParams, rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pos_n, vel_n, euler) at ``t_log`` from true mocap-rate samples."""
    noisy_pos = pos_n + rng.standard_normal(pos_n.shape) * sensors.mocap_position_noise
    perturb = Rotation.from_rotvec(rng.standard_normal(pos_n.shape) * sensors.mocap_attitude_noise)
    attitude = quaternion_rotations(quat_wxyz) * perturb
    euler = np.unwrap(frames.rotation_to_euler_ned(attitude), axis=0)
    vel = savgol_filter(noisy_pos, sensors.mocap_velocity_window, 2, deriv=1, delta=1.0 / sensors.mocap_rate, axis=0, mode="interp")

    def resample(values: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t_log, t_mocap, values[:, i]) for i in range(values.shape[1])])

    euler_log = resample(euler)
    euler_log[:, :2] = (euler_log[:, :2] + np.pi) % (2 * np.pi) - np.pi
    return resample(noisy_pos), resample(vel), euler_log
