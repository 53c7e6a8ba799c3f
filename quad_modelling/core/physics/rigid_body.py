r"""The rigid body: rotor wrench, gyroscopic torque, Newton-Euler derivative and the integration step.

Frames and units: N = NED, B = FRD (:mod:`quad_modelling.core.frames`), SI. Per batch member the state is

.. math:: x = (p_N, v_N, R, \omega_B, \Omega)

position [m] and velocity [m/s] in N, attitude :math:`R = R_{N \leftarrow B}`, body rates
:math:`\omega = (p, q, r)` [rad/s], rotor speeds :math:`\Omega_i` [rad/s] (command order)
(:class:`PhysicsState`). Constants: :class:`~quad_modelling.core.physics.parameters.PhysicsParameters`.

Wrench in B (:func:`rotor_wrench`), rotor i at :math:`(x_i, y_i)` with spin :math:`s_i` (+1 = counter-clockwise
seen from above), thrust and yaw torque :math:`T_i = k_f \Omega_i^2`, :math:`Q_i = k_m \Omega_i^2`
(:mod:`~quad_modelling.core.physics.rotors`), rotor drag :math:`F_d, \tau_d` (:mod:`~quad_modelling.core.physics.aero`):

.. math::

    F_B = (0, 0, -\textstyle\sum_i T_i) + F_d, \qquad
    \tau_B = \big(-\textstyle\sum_i y_i T_i,\ \sum_i x_i T_i,\ \sum_i s_i Q_i + I_p \sum_i s_i \dot\Omega_i\big) + \tau_d
        \;[- c \times F_B]

the bracket with the ``motor_imbalance`` term's CG offset c (:func:`cg_offset_moment`).

Motion (:func:`accelerations`), with the gyroscopic torque :math:`-\omega \times I\omega`
(:func:`gyroscopic_torque`; the optional ``gyroscopic`` term scales it and adds the rotors' part
:math:`-\omega \times h_r`, :func:`rotor_momentum`; without an entry the body's term alone acts):

.. math::

    \dot v_N = R F_B / m + g e_z, \qquad
    \dot\omega = I^{-1}(\tau_B - \omega \times I \omega), \qquad
    \dot R = R [\omega]_\times

Integration (:func:`step`): semi-implicit (symplectic) Euler over the real sample interval :math:`\Delta t`,

.. math::

    \omega_{k+1} = \omega_k + \Delta t \dot\omega_k,\quad R_{k+1} = R_k \mathrm{Exp}(\omega_{k+1} \Delta t),\quad
    v_{k+1} = v_k + \Delta t \dot v_k,\quad p_{k+1} = p_k + \Delta t\, v_{k+1}

where the rotor terms of the accelerations are the step's exact means under the held command: thrust and yaw
torque with :math:`\bar\Omega` (:func:`~quad_modelling.core.physics.rotors.interval_rotor_speed`,
:math:`\bar\Omega^2` the mean of :math:`\Omega^2`), the rotor reaction with :math:`(\Omega_{k+1} - \Omega_k)/\Delta t`;
the rotor speeds stepped exactly (:func:`~quad_modelling.core.physics.rotors.rotor_step`), |ω| limited to the
gyro full scale and |v| to :data:`MAX_SPEED_MPS`. Why: the rotor lag, the only fast mode, is integrated exactly,
leaving the rigid body, whose open-loop modes are integrators (no stiffness); semi-implicit Euler keeps the
attitude on SO(3) (the exponential map, :func:`rotation_increment`) and costs one wrench evaluation per sample, a
quarter of RK4's. Its local error is :math:`O(\Delta t^2)` per step.

The mixer's allocation (:func:`allocation_matrix`) is the same wrench written per newton of thrust.

Every function takes numpy arrays or torch tensors (:mod:`quad_modelling.core.physics.arrays`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quad_modelling.core.flight_log import GYRO_FULL_SCALE
from quad_modelling.core.frames import FLOAT_ROWS
from quad_modelling.core.physics import arrays
from quad_modelling.core.physics.aero import ground_effect_factor, rotor_drag
from quad_modelling.core.physics.rotors import (
    interval_rotor_speed, rotor_acceleration, rotor_step, rotor_thrusts, rotor_yaw_torques, steady_rotor_speed,
)

GRAVITY = 9.81
"""Local gravity used by the models [m/s²] (thesis value, Eq 3-10)."""

MAX_SPEED_MPS = 50.0
"""Largest speed the open-loop state may reach [m/s] (racing multirotors reach ~40 m/s): with the rates limited to
the gyro full scale (:data:`~quad_modelling.core.flight_log.GYRO_FULL_SCALE`), it keeps a long open-loop window
(the thesis's 10 s) finite, where an uncontrolled rigid body tumbles and ω × Iω grows without bound."""


@dataclass
class PhysicsState:
    """A batch of B model states (module docstring), SI, N = NED, B = FRD.

    pos_n, vel_n (B, 3); rot (B, 3, 3) R_N<-B; rates (B, 3) body rates; rotor (B, 4) rotor speeds [rad/s];
    yaw (B,) continuous (unwrapped) yaw [rad] that the Euler output follows.
    """

    pos_n: np.ndarray
    vel_n: np.ndarray
    rot: np.ndarray
    rates: np.ndarray
    rotor: np.ndarray
    yaw: np.ndarray

    def take(self, index) -> PhysicsState:
        """The members ``index`` of the batch."""
        return PhysicsState(self.pos_n[index], self.vel_n[index], self.rot[index], self.rates[index], self.rotor[index], self.yaw[index])


def _inertia(p, like):
    """(I_xx, I_yy, I_zz) of ``p`` on ``like``'s backend."""
    return p.inertia if arrays.is_tensor(like) else np.asarray(p.inertia, dtype=float)


def allocation_matrix(positions: np.ndarray, spins: np.ndarray, torque_ratio: float) -> np.ndarray:
    """M (4, 4): lift and torque (F, τ_x, τ_y, τ_z) per newton of each rotor's thrust (columns), of the wrench
    (module docstring) without drag: :math:`M_{:,i} = (1, -y_i, x_i, s_i k_m/k_f)`; ``torque_ratio`` = k_m/k_f [m]."""
    positions = np.asarray(positions, dtype=float)
    return np.vstack([np.ones(len(positions)), -positions[:, 1], positions[:, 0], np.asarray(spins, dtype=float) * torque_ratio])


def rotor_wrench(p, rotor, rotor_dot, vel_b, height=None):
    """(F_B (B, 3) [N], τ_B (B, 3) [N m]) in B of rotor speeds ``rotor`` (B, 4), their rates ``rotor_dot`` (B, 4)
    [rad/s²] and the body airspeed ``vel_b`` (B, 3) [m/s] (module docstring); with the ground-effect term on, the
    thrusts grow by :func:`~quad_modelling.core.physics.aero.ground_effect_factor` at ``height`` (B,) [m]."""
    thrust = rotor_thrusts(p.thrust_constant, rotor)
    if p.ground_effect is not None and height is not None:
        thrust = thrust * ground_effect_factor(arrays.clamp_min(height, 0.0), *p.ground_effect)[..., None]
    drag_force, drag_moment = rotor_drag(p, rotor, vel_b)
    force = drag_force - arrays.unit_z_like(drag_force, 1.0) * thrust.sum(axis=-1)[..., None]
    torque = arrays.columns([
        -thrust @ p.positions[:, 1],
        thrust @ p.positions[:, 0],
        rotor_yaw_torques(p.torque_constant, rotor) @ p.spins + p.prop_inertia * (rotor_dot @ p.spins),
    ]) + drag_moment
    if p.cg_offset is not None:
        torque = torque + cg_offset_moment(p.cg_offset, force)
    return force, torque


def cg_offset_moment(offset, force):
    r"""The moment change [N m] (B, 3) in B of rotor forces ``force`` (B, 3) [N] (thrust and rotor drag, in B) when
    the CG sits at :math:`c = (c_x, c_y, 0)` = ``offset`` [m] (FRD) from the geometric centre the rotor positions
    :math:`r_i` are measured from (the ``motor_imbalance`` term's CG offset). About the CG rotor i's force acts at
    :math:`r_i - c`, so :math:`\sum_i (r_i - c) \times F_i = \sum_i r_i \times F_i - c \times F`, F the sum:

    .. math:: -c \times F = (-c_y F_z,\ c_x F_z,\ c_y F_x - c_x F_y)

    For the thrust alone, :math:`F = (0, 0, -T)`, :math:`T = \sum_i T_i`: :math:`(c_y T, -c_x T, 0)` -- a CG to the
    right (c_y > 0) leaves more thrust on the left of it, rolling right (+p); a CG forward (c_x > 0) pitches the
    nose down (-q). The truth simulator's rotor arms :math:`r_i - c` (``docs/simulator.md``) give the same. Not
    the rotor drag's vertical arm ``drag_arm`` (:mod:`~quad_modelling.core.physics.aero`), a separate constant."""
    c_x, c_y = offset
    return arrays.columns([-c_y * force[..., 2], c_x * force[..., 2], c_y * force[..., 0] - c_x * force[..., 1]])


def rotor_momentum(prop_inertia: float, spins, rotor):
    """h_r = (0, 0, -I_p Σ_i s_i Ω_i) [N m s] in B: the rotors' angular momentum (a counter-clockwise rotor's points
    up, -z in FRD), of rotor speeds ``rotor`` (B, 4) [rad/s]."""
    return arrays.unit_z_like(rotor[..., :3], -1.0) * (prop_inertia * (rotor @ spins))[..., None]


def gyroscopic_torque(rates, inertia, momentum=None, body_scale: float = 1.0):
    """-ω × (k_b I ω + h_r) [N m] in B of body rates ``rates`` (B, 3) [rad/s], principal inertias ``inertia`` (3,)
    [kg m²], the rotors' momentum ``momentum`` (B, 3) (:func:`rotor_momentum`; None: the body's term alone) and the
    body term's scale ``body_scale`` k_b (1: rigid-body physics; the ``gyroscopic`` term's parameter)."""
    angular_momentum = body_scale * (rates * inertia)
    if momentum is not None:
        angular_momentum = angular_momentum + momentum
    return -arrays.cross(rates, angular_momentum)


def accelerations(p, vel_n, rot, rates, rotor, rotor_dot, pos_n=None):
    """(dv_N/dt (B, 3) [m/s², N], dω/dt (B, 3) [rad/s², B]) of a state (module docstring), ``rotor_dot`` dΩ/dt (B, 4);
    ``pos_n`` (B, 3) gives the height above the ground plane z_N = 0 the ground-effect term needs."""
    height = None if pos_n is None else -pos_n[..., 2]
    force_b, torque_b = rotor_wrench(p, rotor, rotor_dot, arrays.rotate_back(rot, vel_n), height)
    acc_n = arrays.rotate(rot, force_b) / p.mass + arrays.unit_z_like(force_b, GRAVITY)
    inertia = _inertia(p, rates)
    if p.gyroscopic is None:
        return acc_n, torque_b / inertia
    body_scale, rotor_scale = p.gyroscopic
    momentum = rotor_scale * rotor_momentum(p.prop_inertia, p.spins, rotor) if rotor_scale else None
    return acc_n, (torque_b + gyroscopic_torque(rates, inertia, momentum, body_scale)) / inertia


def derivative(p, state, u, linear_n, angular_b):
    """dx/dt of every batch member under the commands the rotors answer ``u`` (B, 4), with constant extra
    accelerations ``linear_n`` (B, 3) [m/s², N] and ``angular_b`` (B, 3) [rad/s², B] (module docstring's motion):
    (dp_N/dt = v_N, dv_N/dt, dR/dt = R [ω]×, dω/dt, dΩ/dt), shaped as the state's fields. The continuous
    dynamics that :func:`step` discretises (without its limits on |ω| and |v|). Without motor lag (τ_m = 0) the rotor
    speeds are no state: the forces act at the steady speeds Ω_ss(u) of the commands (as :func:`step`'s rotors jump
    to them) and dΩ/dt is 0 (the state's rotor entries are not read)."""
    rotor_dot = rotor_acceleration(p, state.rotor, u)
    rotor = state.rotor if p.time_constant > 0.0 else steady_rotor_speed(p, u)
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, rotor, rotor_dot, state.pos_n)
    return state.vel_n, acc_n + linear_n, times_skew(state.rot, state.rates), ang_acc + angular_b, rotor_dot


def limit_norm(vectors, limit: float):
    """Rows of ``vectors`` scaled down to norm ``limit`` where longer."""
    norm = arrays.vector_norm(vectors, keepdims=True)
    return arrays.where(arrays.greater(norm, limit), vectors * (limit / arrays.clamp_min(norm, 1e-12)), vectors)


def continue_yaw(previous, rot):
    """The yaw of ``rot`` [rad] unwrapped next to ``previous`` (the continuous yaw the Euler output follows)."""
    psi = arrays.atan2(rot[..., 1, 0], rot[..., 0, 0])
    return previous + arrays.remainder(psi - previous + np.pi, 2.0 * np.pi) - np.pi


def continued_yaw(yaw0: float, rot: np.ndarray) -> np.ndarray:
    r"""(K,) continuous yaw of attitudes ``rot`` (K, 3, 3) from ``yaw0`` at row 0, each row unwrapped next to the one
    before: :func:`continue_yaw` applied row by row, summed as its steps (ψ_k the yaw of rot_k, ψ̂_0 = ``yaw0``):

    .. math:: ψ̂_k = ψ̂_0 + \sum_{j=1}^{k} \mathrm{wrap}(ψ_j - ψ_{j-1}),\quad ψ_0 := ψ̂_0,\quad \mathrm{wrap}(a) = ((a + π) \bmod 2π) - π

    (each ψ̂_j differs from ψ_j by whole turns: the same numbers to rounding, ~1e-15 a row); up to
    :data:`~quad_modelling.core.frames.FLOAT_ROWS` attitudes (the live window's step: 2) row by row on floats."""
    psi = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
    if len(psi) <= FLOAT_ROWS:
        out = [yaw0]
        for value in psi[1:].tolist():
            out.append(out[-1] + (value - out[-1] + np.pi) % (2.0 * np.pi) - np.pi)
        return np.array(out)
    out = np.empty(len(psi))
    out[0] = yaw0
    out[1:] = yaw0 + np.cumsum((psi[1:] - np.concatenate([[yaw0], psi[1:-1]]) + np.pi) % (2.0 * np.pi) - np.pi)
    return out


def times_skew(rot, phi):
    """R [φ]× (B, 3, 3) of matrices R (B, 3, 3) and vectors φ (B, 3): row i is r_iᵀ[φ]× = (r_i × φ)ᵀ, one cross
    product of R's rows with φ: no [φ]× built and no 3x3 product. On torch that is 187 tensor operations per step of
    the hybrid's training rollout instead of 194, but cheaper ones (a 3x3 product as a (B, 3, 3, 3) broadcast sum cost
    128 us, B = 256): the training 0.84x (bench/results/training_time.md)."""
    return arrays.cross(rot, phi[..., None, :])


def rotation_increment(rot, rates_b, dt):
    """R_{k+1} = R_k Exp([ω Δt]×): (B, 3, 3) attitudes R_NED←FRD turned by body rates ``rates_b`` (B, 3)
    [rad/s, FRD] held for ``dt`` (B,) [s] (Rodrigues' formula, exact for a constant ω; stays orthonormal).

    .. math:: \\mathrm{Exp}(\\phi) = I + a\\,[\\phi]_\\times + b\\,[\\phi]_\\times^2, \\qquad
              a = \\frac{\\sin\\|\\phi\\|}{\\|\\phi\\|}, \\quad b = \\frac{1 - \\cos\\|\\phi\\|}{\\|\\phi\\|^2}, \\qquad
              \\phi = \\omega \\Delta t

    computed as R + a (R[φ]×) + b (R[φ]×)[φ]× (:func:`times_skew`).
    """
    phi = rates_b * dt[..., None]
    angle = arrays.vector_norm(phi)
    small = arrays.less(angle, 1e-8)
    safe = arrays.where(small, angle * 0.0 + 1.0, angle)
    a = arrays.where(small, 1.0 - angle**2 / 6.0, arrays.sin(safe) / safe)
    b = arrays.where(small, 0.5 - angle**2 / 24.0, (1.0 - arrays.cos(safe)) / safe**2)
    turned = times_skew(rot, phi)
    return rot + a[..., None, None] * turned + b[..., None, None] * times_skew(turned, phi)


def step(p, state, u, dt, linear_n, angular_b, rates_next=None, down_velocity_next=None):
    """One semi-implicit Euler step (module docstring) of every batch member under commands ``u`` (B, 4) held for
    ``dt`` (B,) [s], with constant extra accelerations ``linear_n`` (B, 3) [m/s², N] and ``angular_b`` (B, 3)
    [rad/s², B] (the model's disturbance estimate). ``rates_next`` (B, 3) [rad/s, B]: body rates given for the end
    of the step (a rate predictor's, :mod:`quad_modelling.core.models.direct`) in place of the integrated ones; the
    attitude then turns with them. ``down_velocity_next`` (B,) [m/s, N down]: the velocity's down component given
    for the end of the step (the direct model's vertical map) in place of the integrated (and limited) one; the
    position integrates it. Returns a state of ``state``'s type."""
    rotor = rotor_step(p, state.rotor, u, dt)
    nonzero = arrays.where(arrays.greater(dt, 0.0), dt, dt * 0.0 + 1.0)  # dt = 0: the state unchanged, dΩ/dt 0 (not 0/0)
    rotor_dot = (rotor - state.rotor) / nonzero[..., None]  # the step's mean dΩ/dt, exact
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, interval_rotor_speed(p, state.rotor, u, dt), rotor_dot,
                                   state.pos_n)
    rates = limit_norm(state.rates + dt[..., None] * (ang_acc + angular_b) if rates_next is None else rates_next, GYRO_FULL_SCALE)
    rot = rotation_increment(state.rot, rates, dt)
    vel = limit_norm(state.vel_n + dt[..., None] * (acc_n + linear_n), MAX_SPEED_MPS)
    if down_velocity_next is not None:
        vel = arrays.columns([vel[..., 0], vel[..., 1], down_velocity_next])
    pos = state.pos_n + dt[..., None] * vel
    return type(state)(pos, vel, rot, rates, rotor, continue_yaw(state.yaw, rot))
