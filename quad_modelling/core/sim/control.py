"""Per-channel PID stabiliser of the truth simulator (thesis Fig 1.10), with the mixer.

Each channel is a PID loop tuned for a closed-loop natural frequency ω and
damping ζ: :math:`k_p = \\omega^2,\\ k_d = 2 \\zeta \\omega,\\ k_i = f_i \\omega k_p`
(``ControlParams.integral_fraction`` = f_i). Angular accelerations asked of the
roll, pitch and yaw channels become torques through the inertia; the altitude
channel asks for a vertical acceleration:

.. math::

    \\tau_\\phi = I_{xx} (k_p e_\\phi + k_i \\textstyle\\int e_\\phi - k_d p), \\ \\dots \\qquad
    T = m (g + \\ddot h_{ref} + k_p e_h + k_i \\textstyle\\int e_h + k_d (\\dot z + \\dot h_{ref})) / (\\cos\\phi \\cos\\theta)

(:math:`e_h` = height error, :math:`\\dot z` = NED down speed). With ``ControlParams.height_feedforward`` (the
Crazyflie's) :math:`\\dot h_{ref}, \\ddot h_{ref}` are the rate and acceleration of the pilot's smooth height
references (:meth:`~quad_modelling.core.sim.pilot.PilotScript.height_feedforward`), else 0: with the damping on the
measured speed alone, the integral of the error over a height change is zero, so a descent of A metres lags by about
:math:`A k_d / k_p` metre-seconds and then undershoots by as much, about :math:`2 \\zeta f_i A` = 0.27 A at the
bottom (the LinkQuad's low passes touch down on some seeds; the Crazyflie's did on every seed before session 34).
The mixer inverts
the allocation :math:`[T, \\tau_\\phi, \\tau_\\theta, \\tau_\\psi]^T = M [T_1 \\dots T_4]^T`
whose columns are :math:`(1, -y_i, x_i, s_i d/a)` (motor positions and spin
signs from the vehicle config), and maps each thrust to an engine command
through the nominal ESC curve
:math:`u_i = u_0 + \\sqrt{T_i / a} / k_u` (no battery sag, no imbalance: the
stabiliser does not know them; its integrators absorb them).

The pilot holds position (human-like, slow): it adds roll/pitch references
:math:`\\theta_{hold} = -a_{fwd}/g,\\ \\phi_{hold} = a_{right}/g` with
:math:`a = -k_p p_{N,xy} - k_d v_{N,xy}` rotated into the heading frame, and a
stick trim :math:`(\\phi_{trim}, \\theta_{trim})` that balances a body-fixed side
force in hover (a bent arm's; zero otherwise, :meth:`Stabiliser.set_trim`).
"""

from __future__ import annotations

import math

import numpy as np

from quad_modelling.core.physics.rigid_body import allocation_matrix
from quad_modelling.core.physics.rotors import command_for_rotor_speed, rotor_speed_for_thrust, rotor_thrusts, steady_rotor_speed
from quad_modelling.core.sim.params import SimParams
from quad_modelling.core.physics.rigid_body import GRAVITY

INTEGRAL_AUTHORITY = (30.0, 30.0, 30.0, 0.4 * GRAVITY)
"""Anti-windup: largest output of the roll, pitch, yaw [rad/s²] and altitude [m/s²]
integral terms (covers a 1 cm CG offset, 5 % motor spread, a 30 % battery sag)."""


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def euler_from_quaternion(q0: float, q1: float, q2: float, q3: float) -> tuple[float, float, float]:
    """(φ, θ, ψ) ZYX [rad] of R_N<-B given as a unit quaternion (scalar first)."""
    roll = math.atan2(2.0 * (q0 * q1 + q2 * q3), 1.0 - 2.0 * (q1 * q1 + q2 * q2))
    sin_pitch = 2.0 * (q0 * q2 - q3 * q1)
    pitch = math.asin(max(-1.0, min(1.0, sin_pitch)))
    yaw = math.atan2(2.0 * (q0 * q3 + q1 * q2), 1.0 - 2.0 * (q2 * q2 + q3 * q3))
    return roll, pitch, yaw


class Stabiliser:
    """PID per channel + mixer; call :meth:`flying` once per control tick."""

    def __init__(self, params: SimParams):
        self.params = params
        vehicle = params.vehicle
        control = params.control
        self.dt = 1.0 / control.rate
        self.mass = vehicle.mass
        self.inertia = tuple(float(v) for v in vehicle.inertia)

        def gains(bandwidth: float) -> tuple[float, float, float]:
            kp = bandwidth**2
            return kp, 2.0 * control.damping * bandwidth, control.integral_fraction * bandwidth * kp

        self.attitude_gains = gains(control.attitude_bandwidth)
        self.yaw_gains = gains(control.yaw_bandwidth)
        self.altitude_gains = gains(control.altitude_bandwidth)
        ki = (self.attitude_gains[2], self.attitude_gains[2], self.yaw_gains[2], self.altitude_gains[2])
        self.integral_limits = tuple(limit / k for limit, k in zip(INTEGRAL_AUTHORITY, ki))
        pos_w = control.position_bandwidth
        self.hold_gains = (pos_w**2, 2.0 * control.damping * pos_w)
        a = vehicle.value("rotor_thrust_constant")
        allocation = allocation_matrix(vehicle.motor_positions, vehicle.yaw_signs, vehicle.value("rotor_torque_constant") / a)
        self.allocation = allocation
        self.mix = tuple(tuple(float(v) for v in row) for row in np.linalg.inv(allocation))
        self.thrust_constant = a
        esc = params.esc
        self.esc = esc
        self.u0 = esc.zero_speed_input
        self.k_u = esc.speed_gain
        hover = vehicle.hover_rotor_speed
        self.u_idle = float(command_for_rotor_speed(esc.idle_speed_fraction * hover, self.k_u, esc.speed_offset))
        self.u_max = vehicle.input_max
        self.u_off = vehicle.input_min
        self.max_tilt = control.max_tilt
        self.max_thrust = 4.0 * float(rotor_thrusts(a, steady_rotor_speed(esc, self.u_max)))
        self.trim_integrals = (0.0, 0.0, 0.0, 0.0)
        self.trim_tilt = (0.0, 0.0)
        self.reset()

    def reset(self) -> None:
        """Integrators back to the pilot's trim (on the ground)."""
        self.integrals = list(self.trim_integrals)

    def set_trim(self, commands, tilt: tuple[float, float] = (0.0, 0.0)) -> None:
        r"""Trim like a pilot who flew this airframe before: start the integrators where
        they settle in a steady hover flown with ``commands``. The nominal mixer reads
        those commands as the wrench :math:`W = M T_{nom}(u)`; the integrators then hold
        :math:`k_i I_h = W_0/m - g` and :math:`k_i I_\phi = W_1/I_{xx}` etc. ``tilt``:
        the roll/pitch stick trim [rad] added to every reference (a hover attitude that
        is not level, :meth:`QuadDynamics.hover_tilt <quad_modelling.core.sim.dynamics.QuadDynamics.hover_tilt>`)."""
        self.trim_tilt = (float(tilt[0]), float(tilt[1]))
        wrench = self.allocation @ rotor_thrusts(self.thrust_constant, steady_rotor_speed(self.esc, commands))
        needed = (wrench[1] / self.inertia[0], wrench[2] / self.inertia[1], wrench[3] / self.inertia[2], wrench[0] / self.mass - GRAVITY)
        ki = (self.attitude_gains[2], self.attitude_gains[2], self.yaw_gains[2], self.altitude_gains[2])
        self.trim_integrals = tuple(max(-lim, min(lim, n / k)) for n, k, lim in zip(needed, ki, self.integral_limits))
        self.reset()

    def hold_position(self, s) -> tuple[float, float]:
        """Pilot's roll and pitch corrections [rad] towards the origin of N."""
        kp, kd = self.hold_gains
        ax = -kp * s[0] - kd * s[3]
        ay = -kp * s[1] - kd * s[4]
        _, _, yaw = euler_from_quaternion(*s[6:10])
        forward = math.cos(yaw) * ax + math.sin(yaw) * ay
        right = -math.sin(yaw) * ax + math.cos(yaw) * ay
        return right / GRAVITY, -forward / GRAVITY

    def flying(self, s, refs, gyro, airborne: bool, height_rate: float = 0.0, height_acceleration: float = 0.0) -> list[float]:
        """Engine commands [input unit] for state ``s`` (truth attitude, height and
        velocity), references (roll, pitch, yaw [rad], height [m]) and measured
        body rates ``gyro`` [rad/s]; integrators run only when ``airborne``.
        ``height_rate`` [m/s], ``height_acceleration`` [m/s²]: the smooth height references' (up), fed forward
        (module docstring)."""
        roll, pitch, yaw = euler_from_quaternion(*s[6:10])
        lim = self.max_tilt
        roll_hold, pitch_hold = self.hold_position(s) if airborne else (0.0, 0.0)
        roll_ref = max(-lim, min(lim, refs[0] + roll_hold + self.trim_tilt[0]))
        pitch_ref = max(-lim, min(lim, refs[1] + pitch_hold + self.trim_tilt[1]))
        errors = (roll_ref - roll, pitch_ref - pitch, _wrap(refs[2] - yaw), refs[3] + s[2])
        if airborne:
            for i in range(4):
                value = self.integrals[i] + errors[i] * self.dt
                self.integrals[i] = max(-self.integral_limits[i], min(self.integral_limits[i], value))
        kp, kd, ki = self.attitude_gains
        ixx, iyy, izz = self.inertia
        tau_x = ixx * (kp * errors[0] + ki * self.integrals[0] - kd * gyro[0])
        tau_y = iyy * (kp * errors[1] + ki * self.integrals[1] - kd * gyro[1])
        kp, kd, ki = self.yaw_gains
        tau_z = izz * (kp * errors[2] + ki * self.integrals[2] - kd * gyro[2])
        kp, kd, ki = self.altitude_gains
        tilt = max(0.5, math.cos(roll) * math.cos(pitch))
        thrust = self.mass * (GRAVITY + height_acceleration + kp * errors[3] + ki * self.integrals[3] + kd * (s[5] + height_rate)) / tilt
        thrust = max(0.0, min(self.max_thrust, thrust))
        wrench = (thrust, tau_x, tau_y, tau_z)
        commands = []
        for row in self.mix:
            t_i = row[0] * wrench[0] + row[1] * wrench[1] + row[2] * wrench[2] + row[3] * wrench[3]
            u_i = command_for_rotor_speed(rotor_speed_for_thrust(self.thrust_constant, t_i), self.k_u, self.esc.speed_offset) if t_i > 0.0 else self.u0
            commands.append(max(self.u_idle, min(self.u_max, u_i)))
        return commands
