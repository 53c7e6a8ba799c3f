"""Nonlinear 6-DoF quadrotor dynamics of the truth simulator, and its RK4 step.

State (17 floats, a plain list for speed), internal convention (N = NED, B = FRD):

    s = [x, y, z, vx, vy, vz, q0, q1, q2, q3, p, q, r, Ω1, Ω2, Ω3, Ω4]

position and velocity of the CG in N [m, m/s]; unit quaternion
:math:`q = (q_0, q_1, q_2, q_3)` of :math:`R_{N \\leftarrow B}` (scalar first);
body rates :math:`\\omega = (p, q, r)` [rad/s]; rotor speeds Ω_i [rad/s].

Rotor i sits at :math:`r_i = (x_i - c_x, y_i - c_y, z_r - d_z)` from the CG (config
position, CG offset c when ``motor_imbalance`` is on, hub height z_r, CoM depth d_z when
``com_offset`` is on) and spins with sign s_i (+1 = counter-clockwise seen from above).
Wrench in B (every thrust along :math:`-e_z`; ``bent_arm`` tilts rotor 1's, below):

.. math::

    T_i = a \\Omega_i^2 \\, k_{GE}(h_i), \\qquad Q_i = d \\Omega_i^2

    F_B = (0, 0, -\\textstyle\\sum_i T_i) + F_{drag}, \\qquad
    \\tau_B = \\sum_i r_i \\times (0, 0, -T_i) + (0, 0, \\sum_i s_i Q_i + I_p \\sum_i s_i \\dot\\Omega_i)
              + \\tau_{drag} - \\omega \\times (I \\omega + h_r)

with the rotor angular momentum :math:`h_r = (0, 0, -I_p \\sum_i s_i \\Omega_i)`
(a counter-clockwise rotor's momentum points up, -z in FRD). Motion:

.. math::

    \\dot p_N = v_N, \\quad m \\dot v_N = R F_B + m g e_z + F_{wind} + F_{ground}, \\quad
    \\dot q = \\tfrac12 q \\otimes (0, \\omega), \\quad I \\dot\\omega = \\tau_B + \\tau_{ground}

Effects (names of :data:`quad_modelling.core.effect_names.SIM_EFFECTS`):

* ``motor_lag``: :math:`\\dot\\Omega_i = (\\Omega_{c,i} - \\Omega_i)/\\tau_m`, :math:`\\tau_m = -1/A_m`;
  off: Ω_i = Ω_c,i at once (the simulator then applies the rotor reaction
  impulse :math:`\\Delta r = I_p \\sum_i s_i \\Delta\\Omega_i / I_{zz}`).
* ``rotor_drag``: :math:`F_i = -\\Omega_i K v_{air,B}`, K = diag(k_h, k_h, k_v), acting at the
  hub, so :math:`F_{drag} = \\sum_i F_i`, :math:`\\tau_{drag} = \\sum_i r_i \\times F_i`;
  :math:`v_{air,B} = R^T (v_N - w_N)`.
* ``ground_effect``: Cheeseman & Bennett (1955),
  :math:`k_{GE}(h) = 1 / (1 - (R_p / (4 h))^2)`, h = hub height above the ground
  (z = 0), clamped to h >= c R_p; off: k_GE = 1.
* ``gyroscopic``: the propellers' gyroscopic torque :math:`-\\omega \\times h_r`; off: dropped (h_r = 0).
  The body's own :math:`-\\omega \\times I\\omega` is rigid-body physics and always acts (until
  2026-11-26 the effect switched both, so an "effect-free" flight lacked Euler's equations' own term,
  which the physics model always has: the cause of most of its angular-velocity gap to ``truth``).
* ``wind``: air moves with :math:`w_N`; airframe drag
  :math:`F_{wind} = -\\tfrac12 \\rho C_D A \\, |v_N - w_N| (v_N - w_N)`; rotor drag then sees
  the relative air. Off: w = 0 and no airframe drag.
* ``motor_imbalance``: CG offset c (here) and per-ESC gain spread (in :meth:`QuadDynamics.omega_command`).
* ``com_offset`` (disturbance): the CoM sits d_z below the IMU and geometric centre (a battery hung
  under the frame). Hubs and feet are d_z higher above it (:math:`z_r \\to z_r - d_z`): the moment
  arm of rotor drag (and of the bent arm's side force) grows, the hubs are d_z higher above the
  ground at a given CoM height. Thrust along body z and gravity have no moment about a CoM on the
  thrust line, so a purely vertical offset adds no torque in hover. The accelerometer, now at
  :math:`r = (0, 0, -d_z)` from the CoM, reads
  :math:`f_{imu} = f_{cm} + \\dot\\omega \\times r + \\omega \\times (\\omega \\times r)`
  (:mod:`quad_modelling.core.sim.sensors`; :attr:`QuadDynamics.imu_position`). The inertia stays
  the config's, taken about the true CoM; the horizontal CG offset of ``motor_imbalance`` is not
  applied to the IMU position (logs of the catalogue effects stay as they were).
* ``bent_arm`` (disturbance): rotor 1's thrust axis is turned by γ about its arm direction
  :math:`a = (x_1, y_1, 0)/l_1` (config position, :math:`l_1` its distance from the geometric
  centre) to :math:`e_1 = -\\cos\\gamma\\, e_z + \\sin\\gamma\\, t`, :math:`t = e_z \\times a`. Its force
  is :math:`T_1 e_1`: a side force :math:`T_1 \\sin\\gamma` along t (fixed in B) and a lift
  :math:`T_1\\cos\\gamma`; its moment :math:`r_1 \\times T_1 e_1` has the yaw part
  :math:`T_1 \\sin\\gamma\\, l_1` (without a CG offset) and a roll/pitch part
  :math:`z_r T_1 \\sin\\gamma` from the hub height. The rotor's drag and acceleration torque
  :math:`-s_1 (Q_1 + I_p \\dot\\Omega_1) e_1` and momentum :math:`I_p s_1 \\Omega_1 e_1` turn with it.
  Rotor drag of rotor 1 and the reaction impulse without ``motor_lag`` stay along z (a 3° tilt
  changes them by 0.1 %).
* ``battery``, ``input_delay``: act on the command path (:mod:`quad_modelling.core.sim.simulate`).

Written once (:meth:`QuadDynamics._build_derivative`) on the numbers of a :class:`Backend`: Python floats (the live
truth model, :attr:`QuadDynamics.derivative`), numpy arrays (the truth model's batches,
:attr:`QuadDynamics.batch_derivative`) and CasADi expressions, from which :meth:`QuadDynamics.compiled_steps` builds
the simulator's integration of a control tick (its 4 RK4 steps: 16 derivative evaluations in one call of ~30 us
instead of ~250 us of Python; the same numbers to ~1e-12 relative, ``test/core/sim/test_dynamics.py``).

Ground contact (always on): each landing-gear foot below z = 0 gets a
spring-damper normal force and regularised Coulomb friction
:math:`F_t = -\\mu N v_t / \\sqrt{|v_t|^2 + \\epsilon^2}`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from quad_modelling.core.effect_names import SIMULATOR, normalise_effect_names
from quad_modelling.core.physics.rotors import command_for_rotor_speed, hover_rotor_speed, rotor_speed_for_thrust
from quad_modelling.core.sim.params import SimParams
from quad_modelling.core.physics.rigid_body import GRAVITY

@dataclass(frozen=True)
class Backend:
    """The four operations of the derivative that are not arithmetic, on one kind of number: Python floats
    (:data:`SCALAR`, one state), numpy arrays (:data:`ARRAYS`, a batch of states) or CasADi ``SX`` expressions
    (:func:`symbolic`, compiled to the simulator's steps, :meth:`QuadDynamics.compiled_steps`). The same
    arithmetic on each gives the same numbers: IEEE-754 rounds +, -, *, / and √ alike in Python, numpy and CasADi."""

    sqrt: Callable
    maximum: Callable
    """maximum(x, low) element-wise."""
    where: Callable
    """where(condition, a, b) element-wise."""
    anywhere: Callable
    """anywhere(condition): whether any member may hold it (True for a symbol: both branches are built)."""


SCALAR = Backend(math.sqrt, lambda x, low: x if x > low else low, lambda c, a, b: a if c else b, bool)
ARRAYS = Backend(np.sqrt, np.maximum, np.where, lambda c: bool(np.any(c)))


def symbolic() -> Backend:
    """The CasADi ``SX`` backend (casadi imported on first use)."""
    import casadi

    return Backend(casadi.sqrt, casadi.fmax, casadi.if_else, lambda _c: True)


STATE_NAMES = (
    "x", "y", "z", "vx", "vy", "vz", "q0", "q1", "q2", "q3", "p", "q", "r",
    "omega1", "omega2", "omega3", "omega4",
)
N_STATE = len(STATE_NAMES)


class QuadDynamics:
    """State derivative and RK4 step of one vehicle with a set of effects on.

    ``derivative(s, omega_cmd, wind)`` is the callable contract: ``s`` the 17-float
    state list, ``omega_cmd`` the four commanded rotor speeds [rad/s] (used only
    with ``motor_lag``), ``wind`` the air velocity (wx, wy, wz) in N [m/s].
    """

    def __init__(self, params: SimParams, effects=()):
        self.params = params
        self.effects = normalise_effect_names(effects, SIMULATOR)
        vehicle = params.vehicle
        self.mass = vehicle.mass
        self.inertia = vehicle.inertia
        self.thrust_constant = vehicle.value("rotor_thrust_constant")
        self.torque_constant = vehicle.value("rotor_torque_constant")
        self.prop_inertia = vehicle.value("prop_inertia")
        self.yaw_signs = vehicle.yaw_signs
        cg = params.imbalance.cg_offset if "motor_imbalance" in self.effects else (0.0, 0.0)
        depth = params.com_offset.depth if "com_offset" in self.effects else 0.0
        self.imu_position = np.array([0.0, 0.0, -depth])
        """r: the IMU (at the geometric centre) from the CoM in B [m]; zero unless ``com_offset``."""
        self.rotor_positions = np.column_stack(
            [vehicle.motor_positions - np.asarray(cg), np.full(4, params.geometry.rotor_plane_z - depth)]
        )
        self.feet = np.asarray(params.geometry.feet, dtype=float) - np.array([cg[0], cg[1], depth])
        self.thrust_axes = np.tile([0.0, 0.0, -1.0], (4, 1))
        """(4, 3) unit thrust directions e_i in B; rotor 1's tilted by γ with ``bent_arm``."""
        if "bent_arm" in self.effects:
            gamma = params.bent_arm.tilt
            arm = vehicle.motor_positions[0] / float(np.hypot(*vehicle.motor_positions[0]))
            self.thrust_axes[0] = (-math.sin(gamma) * arm[1], math.sin(gamma) * arm[0], -math.cos(gamma))
        motor_gains = params.imbalance.motor_gains if "motor_imbalance" in self.effects else (1.0, 1.0, 1.0, 1.0)
        self.motor_gains = tuple(float(g) for g in motor_gains)
        self.derivative = self._build_derivative(SCALAR)
        self._compiled: dict = {}
        self.batch_derivative = self._build_derivative(ARRAYS)
        """The same derivative on a batch: each state entry a (B,) array, ``omega_cmd`` a sequence of four (B,)
        arrays, ``wind`` three scalars or (B,) arrays (the truth model's rollouts,
        :mod:`quad_modelling.core.sim.truth_model`)."""

    # ------------------------------------------------------------------ command path

    @property
    def stop_input(self) -> float:
        """The command at or below which a rotor stands still [input unit]: u_0, or the input range's minimum where the
        speed map's u_0 lies below it (the Crazyflie's map, a fit over the spinning range, reaches 381 rad/s at PWM 0:
        its disarmed rotors spun at that, 6 % of the hover thrust, review of session 34)."""
        return max(self.params.esc.zero_speed_input, self.params.vehicle.input_min)

    def omega_command(self, u, voltage: float) -> list[float]:
        """Steady rotor speeds the ESCs drive to [rad/s]:
        :math:`\\Omega_{c,i} = g_i k_u (u_i - u_0) V / V_{ref}` above :attr:`stop_input`, else 0."""
        esc = self.params.esc
        scale = esc.speed_gain * voltage / self.params.battery.reference_voltage
        u0, stop = esc.zero_speed_input, self.stop_input
        return [g * scale * (ui - u0) if ui > stop else 0.0 for g, ui in zip(self.motor_gains, u)]

    def omega_commands(self, u: np.ndarray, voltage) -> np.ndarray:
        """:meth:`omega_command` of a batch: commands ``u`` (B, 4), battery voltage ``voltage`` scalar or (B,) [V]
        -> (B, 4) [rad/s], the same operations in the same order."""
        esc = self.params.esc
        scale = esc.speed_gain * np.asarray(voltage, dtype=float) / self.params.battery.reference_voltage
        u = np.asarray(u, dtype=float)
        gains = np.asarray(self.motor_gains)
        if np.ndim(scale):
            factor = gains[None, :] * scale[:, None]
        else:
            factor = gains * scale
        return np.where(u > self.stop_input, factor * (u - esc.zero_speed_input), 0.0)

    def allocation(self) -> np.ndarray:
        r"""The true allocation M (4x4): lift and torque per newton of each rotor's thrust,
        :math:`M_{:,i} = (-e_{i,z},\ r_i \times e_i - s_i (d/a)\, e_i)` with the thrust directions
        :attr:`thrust_axes` e_i; for :math:`e_i = -e_z` the columns are :math:`(1, -y_i, x_i, s_i d/a)`."""
        ratio = self.torque_constant / self.thrust_constant
        axes = self.thrust_axes
        torque = np.cross(self.rotor_positions, axes) - (np.asarray(self.yaw_signs, dtype=float) * ratio)[:, None] * axes
        return np.vstack([-axes[:, 2], torque.T])

    def hover_thrusts(self) -> np.ndarray:
        r"""Rotor thrusts [N] of a steady hover out of ground effect: no torque and a body force
        :math:`F_B = \sum_i T_i e_i` of magnitude m g, :math:`T = k M^{-1} (1, 0, 0, 0)^T` with the true
        allocation M (:meth:`allocation`) and k = m g (with ``bent_arm``, :math:`k = m g / |F_B(k=1)|`:
        the side force :math:`T_1 \sin\gamma` is held by leaning, :meth:`hover_tilt`, so the lift row
        alone falls short by a factor :math:`\cos` of the lean)."""
        thrusts = np.linalg.solve(self.allocation(), [self.mass * GRAVITY, 0.0, 0.0, 0.0])
        if "bent_arm" in self.effects:
            thrusts *= self.mass * GRAVITY / float(np.linalg.norm(thrusts @ self.thrust_axes))
        return thrusts

    def hover_commands(self, voltage: float) -> list[float]:
        r"""Engine commands that hold this vehicle (with its CG offset, motor gains and bent arm)
        in a steady hover at battery voltage ``voltage`` (attitude :meth:`hover_tilt`): the thrusts
        :meth:`hover_thrusts` through :math:`u_i = u_0 + \sqrt{T_i/a} / (g_i k_u V/V_{ref})`."""
        thrusts = self.hover_thrusts()
        esc = self.params.esc
        scale = esc.speed_gain * voltage / self.params.battery.reference_voltage
        return [float(command_for_rotor_speed(rotor_speed_for_thrust(self.thrust_constant, t), g * scale, -g * scale * esc.zero_speed_input))
                for t, g in zip(thrusts, self.motor_gains)]

    def hover_tilt(self) -> tuple[float, float]:
        r"""Roll and pitch [rad] at which the thrusts :meth:`hover_thrusts` lift straight up:
        the body force :math:`F_B = \sum_i T_i e_i` must point along :math:`R^T (0, 0, -1) =
        (\sin\theta, -\sin\phi\cos\theta, -\cos\phi\cos\theta)`, so
        :math:`\phi = \operatorname{atan2}(-F_y, -F_z),\ \theta = \operatorname{atan2}(F_x, \sqrt{F_y^2 + F_z^2})`.
        Level (0, 0) unless ``bent_arm`` is on (then :math:`\approx T_1 \sin\gamma / (m g)` away from its side force)."""
        if "bent_arm" not in self.effects:
            return 0.0, 0.0
        fx, fy, fz = self.hover_thrusts() @ self.thrust_axes
        return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))

    # ------------------------------------------------------------------ states

    @property
    def rest_height(self) -> float:
        """CG height above ground when standing level on the feet [m]."""
        return float(np.max(self.feet[:, 2]))

    def state_at_rest(self) -> list[float]:
        """Standing level on its feet, rotors stopped (feet just touching z = 0)."""
        s = [0.0] * N_STATE
        s[2] = -self.rest_height
        s[6] = 1.0
        return s

    def hover_state(self, height: float, yaw: float = 0.0) -> list[float]:
        """Level at CG height ``height`` [m] with each rotor at the speed giving T_i = m g / 4."""
        s = [0.0] * N_STATE
        s[2] = -height
        s[6], s[9] = math.cos(yaw / 2), math.sin(yaw / 2)
        hover = hover_rotor_speed(self.mass, self.thrust_constant, GRAVITY)
        s[13:17] = [hover] * 4
        return s

    # ------------------------------------------------------------------ integration

    def step(self, s: list[float], omega_cmd, wind, dt: float, derivative=None) -> tuple[list[float], list[float]]:
        """One classical RK4 step; returns (new state, derivative at the start k1).
        The quaternion is renormalised after the step. ``derivative``: another derivative with the same contract
        (default :attr:`derivative`); with :attr:`batch_derivative` every state entry is a (B,) array and ``dt``
        a scalar or (B,) array."""
        f = derivative or self.derivative
        h2 = 0.5 * dt
        k1 = f(s, omega_cmd, wind)
        k2 = f([a + h2 * b for a, b in zip(s, k1)], omega_cmd, wind)
        k3 = f([a + h2 * b for a, b in zip(s, k2)], omega_cmd, wind)
        k4 = f([a + dt * b for a, b in zip(s, k3)], omega_cmd, wind)
        h6 = dt / 6.0
        new = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)]
        norm2 = new[6] * new[6] + new[7] * new[7] + new[8] * new[8] + new[9] * new[9]
        n = 1.0 / (math.sqrt(norm2) if isinstance(norm2, float) else np.sqrt(norm2))
        new[6] *= n
        new[7] *= n
        new[8] *= n
        new[9] *= n
        return new, k1

    def compiled_steps(self, n: int) -> tuple[np.ndarray, np.ndarray, Callable]:
        """``n`` :meth:`step` calls in a row under one command and wind as a CasADi Function of the numbers in
        ``x = (s (17), omega_cmd (4), wind (3), dt)``, built from :meth:`step` and the derivative on
        :func:`symbolic` numbers (once per ``n`` and vehicle), with its call buffers: (x (25,), out (n + 1, 23),
        evaluate). ``evaluate()`` reads x and fills out: row j < n the state before step j and its k1's translational
        and angular accelerations (the simulator's record), row n the state after (its last six entries zero)."""
        compiled = self._compiled.get(n)
        if compiled is None:
            import casadi

            derivative = self._build_derivative(symbolic())
            x = casadi.SX.sym("x", N_STATE + 8)
            s = [x[i] for i in range(N_STATE)]
            commands, air, dt = [x[N_STATE + i] for i in range(4)], [x[N_STATE + 4 + i] for i in range(3)], x[N_STATE + 7]
            columns = []
            for _ in range(n):
                new, k1 = self.step(s, commands, air, dt, derivative)
                columns.append(casadi.vertcat(*s, *k1[3:6], *k1[10:13]))
                s = new
            columns.append(casadi.vertcat(*s, casadi.DM.zeros(6)))
            function = casadi.Function(f"quad_steps_{n}", [x], [casadi.densify(casadi.horzcat(*columns))])
            buffer, evaluate = function.buffer()
            inputs, out = np.zeros(N_STATE + 8), np.zeros((n + 1, N_STATE + 6))  # out: the (23, n + 1) result, column-major
            buffer.set_arg(0, memoryview(inputs))
            buffer.set_res(0, memoryview(out))
            compiled = self._compiled[n] = (inputs, out, evaluate, buffer, function)  # the buffer and function live as long as evaluate is called
        return compiled[:3]

    def advance(self, s, omega_cmd, wind, dt: float, n: int) -> np.ndarray:
        """``n`` RK4 steps of ``dt`` [s] from state ``s`` under rotor speed commands ``omega_cmd`` [rad/s] and air
        velocity ``wind`` [m/s, N] (:meth:`compiled_steps`; the same numbers as ``n`` :meth:`step` calls): a new
        (n + 1, 23) array, row j < n the state before step j and its k1 accelerations (ẍ, ÿ, z̈ in N; ṗ, q̇, ṙ in B),
        row n the state after (first 17 entries)."""
        inputs, out, evaluate = self.compiled_steps(n)
        inputs[:N_STATE] = s
        inputs[N_STATE:N_STATE + 4] = omega_cmd
        inputs[N_STATE + 4:N_STATE + 7] = wind
        inputs[N_STATE + 7] = dt
        evaluate()
        return out.copy()

    @staticmethod
    def rotation(s) -> np.ndarray:
        """R_N<-B (3x3) of a state."""
        q0, q1, q2, q3 = s[6:10]
        return np.array(
            [
                [1 - 2 * (q2 * q2 + q3 * q3), 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
                [2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 * q1 + q3 * q3), 2 * (q2 * q3 - q0 * q1)],
                [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 1 - 2 * (q1 * q1 + q2 * q2)],
            ]
        )

    def rotor_thrusts(self, s) -> np.ndarray:
        """T_i = a Ω_i² k_GE(h_i) [N] of a state (ground effect when on)."""
        omega = np.asarray(s[13:17], dtype=float)
        return self.thrust_constant * omega**2 * self.ground_effect_factors(s)

    def ground_effect_factors(self, s) -> np.ndarray:
        """k_GE(h_i) per rotor (ones when ``ground_effect`` is off)."""
        if "ground_effect" not in self.effects:
            return np.ones(4)
        radius = self.params.geometry.rotor_radius
        hub_z = s[2] + self.rotation(s)[2] @ self.rotor_positions.T
        height = np.maximum(-hub_z, self.params.ground_effect_min_height * radius)
        return 1.0 / (1.0 - (radius / (4.0 * height)) ** 2)

    # ------------------------------------------------------------------ the derivative

    def _build_derivative(self, backend: Backend):
        """The state derivative (module docstring) as a closure over the constants, on the numbers of ``backend``
        (floats, (B,) arrays or CasADi expressions); the ground contact evaluated only where a foot may touch."""
        p = self.params
        effects = set(self.effects)
        lag = "motor_lag" in effects
        drag_on = "rotor_drag" in effects
        ge_on = "ground_effect" in effects
        gyro_on = "gyroscopic" in effects
        wind_on = "wind" in effects
        bent_on = "bent_arm" in effects
        # rotor 1's e_1 - (0, 0, -1): the change of its thrust direction (zeros when not bent)
        b1x, b1y, b1z = float(self.thrust_axes[0, 0]), float(self.thrust_axes[0, 1]), 1.0 + float(self.thrust_axes[0, 2])
        g = GRAVITY
        m = self.mass
        inv_m = 1.0 / m
        ixx, iyy, izz = (float(v) for v in self.inertia)
        a_t = self.thrust_constant
        d_q = self.torque_constant
        i_p = self.prop_inertia
        s1, s2, s3, s4 = (float(v) for v in self.yaw_signs)
        (x1, y1, _), (x2, y2, _), (x3, y3, _), (x4, y4, zr) = (tuple(float(c) for c in row) for row in self.rotor_positions)
        inv_tau = 1.0 / p.motor_time_constant
        k_h, k_v = p.rotor_drag.horizontal, p.rotor_drag.vertical
        radius_quarter = p.geometry.rotor_radius / 4.0
        ge_min_h = p.ground_effect_min_height * p.geometry.rotor_radius
        half_rho_cda = 0.5 * p.wind.air_density * p.wind.body_drag_area
        feet = [tuple(float(c) for c in f) for f in self.feet]
        reach = max(math.sqrt(fx * fx + fy * fy + fz * fz) for fx, fy, fz in feet)
        contact_gate = -reach - 0.01
        k_total = m * (2.0 * math.pi * p.ground.natural_frequency) ** 2
        k_foot = k_total / len(feet)
        c_foot = 2.0 * p.ground.damping_ratio * math.sqrt(k_total * m) / len(feet)
        mu = p.ground.friction
        eps2 = p.ground.slip_speed**2
        sqrt, maximum, where, anywhere = backend.sqrt, backend.maximum, backend.where, backend.anywhere

        def ground_contact(ax, ay, az, tx, ty, tz, pz, vx, vy, vz, r00, r01, r02, r10, r11, r12, r20, r21, r22, wp, wq, wr):
            """The feet's contact forces and moments added to (ax, ay, az) [m/s², N] and (tx, ty, tz) [N m, B]: a foot
            above the ground (foot_z <= 0) or leaving it faster than its spring pushes (N <= 0) adds zero."""
            for bx, by, bz in feet:
                foot_z = pz + r20 * bx + r21 * by + r22 * bz
                # foot velocity v + R (omega x r_f)
                ox = wq * bz - wr * by
                oy = wr * bx - wp * bz
                oz = wp * by - wq * bx
                fvx = vx + r00 * ox + r01 * oy + r02 * oz
                fvy = vy + r10 * ox + r11 * oy + r12 * oz
                fvz = vz + r20 * ox + r21 * oy + r22 * oz
                normal = where(foot_z > 0.0, maximum(k_foot * foot_z + c_foot * fvz, 0.0), 0.0)
                slip = mu * normal / sqrt(fvx * fvx + fvy * fvy + eps2)
                gx = -slip * fvx
                gy = -slip * fvy
                gz = -normal
                ax += gx * inv_m
                ay += gy * inv_m
                az += gz * inv_m
                # torque r_f x (R^T F)
                bfx = r00 * gx + r10 * gy + r20 * gz
                bfy = r01 * gx + r11 * gy + r21 * gz
                bfz = r02 * gx + r12 * gy + r22 * gz
                tx += by * bfz - bz * bfy
                ty += bz * bfx - bx * bfz
                tz += bx * bfy - by * bfx
            return ax, ay, az, tx, ty, tz

        def derivative(s, wc, wind):
            px, py, pz, vx, vy, vz, q0, q1, q2, q3, wp, wq, wr, o1, o2, o3, o4 = s
            r00 = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
            r01 = 2.0 * (q1 * q2 - q0 * q3)
            r02 = 2.0 * (q1 * q3 + q0 * q2)
            r10 = 2.0 * (q1 * q2 + q0 * q3)
            r11 = 1.0 - 2.0 * (q1 * q1 + q3 * q3)
            r12 = 2.0 * (q2 * q3 - q0 * q1)
            r20 = 2.0 * (q1 * q3 - q0 * q2)
            r21 = 2.0 * (q2 * q3 + q0 * q1)
            r22 = 1.0 - 2.0 * (q1 * q1 + q2 * q2)
            if lag:
                d1 = (wc[0] - o1) * inv_tau
                d2 = (wc[1] - o2) * inv_tau
                d3 = (wc[2] - o3) * inv_tau
                d4 = (wc[3] - o4) * inv_tau
            else:
                d1 = d2 = d3 = d4 = 0.0
            t1 = a_t * o1 * o1
            t2 = a_t * o2 * o2
            t3 = a_t * o3 * o3
            t4 = a_t * o4 * o4
            if ge_on:
                hub = pz + r22 * zr
                h = -(hub + r20 * x1 + r21 * y1)
                h = maximum(h, ge_min_h)
                t1 /= 1.0 - (radius_quarter / h) ** 2
                h = -(hub + r20 * x2 + r21 * y2)
                h = maximum(h, ge_min_h)
                t2 /= 1.0 - (radius_quarter / h) ** 2
                h = -(hub + r20 * x3 + r21 * y3)
                h = maximum(h, ge_min_h)
                t3 /= 1.0 - (radius_quarter / h) ** 2
                h = -(hub + r20 * x4 + r21 * y4)
                h = maximum(h, ge_min_h)
                t4 /= 1.0 - (radius_quarter / h) ** 2
            fx = 0.0
            fy = 0.0
            fz = -(t1 + t2 + t3 + t4)
            tx = -(y1 * t1 + y2 * t2 + y3 * t3 + y4 * t4)
            ty = x1 * t1 + x2 * t2 + x3 * t3 + x4 * t4
            tz = d_q * (s1 * o1 * o1 + s2 * o2 * o2 + s3 * o3 * o3 + s4 * o4 * o4) + i_p * (s1 * d1 + s2 * d2 + s3 * d3 + s4 * d4)
            if bent_on:
                # force T_1 (e_1 - (0, 0, -1)) at r_1, and the reaction -s_1 (Q_1 + I_p dOmega_1) turned with the shaft
                dfx = t1 * b1x
                dfy = t1 * b1y
                dfz = t1 * b1z
                fx += dfx
                fy += dfy
                fz += dfz
                react = s1 * (d_q * o1 * o1 + i_p * d1)
                tx += y1 * dfz - zr * dfy - react * b1x
                ty += zr * dfx - x1 * dfz - react * b1y
                tz += x1 * dfy - y1 * dfx - react * b1z
            if wind_on:
                ax_rel = vx - wind[0]
                ay_rel = vy - wind[1]
                az_rel = vz - wind[2]
            else:
                ax_rel, ay_rel, az_rel = vx, vy, vz
            if drag_on:
                vbx = r00 * ax_rel + r10 * ay_rel + r20 * az_rel
                vby = r01 * ax_rel + r11 * ay_rel + r21 * az_rel
                vbz = r02 * ax_rel + r12 * ay_rel + r22 * az_rel
                osum = o1 + o2 + o3 + o4
                ux = -k_h * vbx
                uy = -k_h * vby
                uz = -k_v * vbz
                fx += osum * ux
                fy += osum * uy
                fz += osum * uz
                cx = o1 * x1 + o2 * x2 + o3 * x3 + o4 * x4
                cy = o1 * y1 + o2 * y2 + o3 * y3 + o4 * y4
                cz = osum * zr
                tx += cy * uz - cz * uy
                ty += cz * ux - cx * uz
                tz += cx * uy - cy * ux
            lx = ixx * wp  # the body's angular momentum I ω, plus the rotors' h_r with ``gyroscopic``
            ly = iyy * wq
            lz = izz * wr
            if gyro_on:
                lz = lz - i_p * (s1 * o1 + s2 * o2 + s3 * o3 + s4 * o4)
                if bent_on:
                    h1 = i_p * s1 * o1  # rotor 1's momentum I_p s_1 Omega_1 e_1, minus its untilted part
                    lx += h1 * b1x
                    ly += h1 * b1y
                    lz += h1 * b1z
            tx -= wq * lz - wr * ly
            ty -= wr * lx - wp * lz
            tz -= wp * ly - wq * lx
            ax = (r00 * fx + r01 * fy + r02 * fz) * inv_m
            ay = (r10 * fx + r11 * fy + r12 * fz) * inv_m
            az = (r20 * fx + r21 * fy + r22 * fz) * inv_m + g
            if wind_on:
                k = half_rho_cda * inv_m * sqrt(ax_rel * ax_rel + ay_rel * ay_rel + az_rel * az_rel)
                ax -= k * ax_rel
                ay -= k * ay_rel
                az -= k * az_rel
            if anywhere(pz > contact_gate):  # a foot may be on the ground
                ax, ay, az, tx, ty, tz = ground_contact(ax, ay, az, tx, ty, tz, pz, vx, vy, vz, r00, r01, r02, r10, r11, r12,
                                                        r20, r21, r22, wp, wq, wr)
            return [
                vx, vy, vz, ax, ay, az,
                -0.5 * (q1 * wp + q2 * wq + q3 * wr),
                0.5 * (q0 * wp + q2 * wr - q3 * wq),
                0.5 * (q0 * wq + q3 * wp - q1 * wr),
                0.5 * (q0 * wr + q1 * wq - q2 * wp),
                tx / ixx, ty / iyy, tz / izz,
                d1, d2, d3, d4,
            ]

        return derivative
