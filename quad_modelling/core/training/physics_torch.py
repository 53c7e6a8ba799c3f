"""A torch twin of the physics model's step (:mod:`quad_modelling.core.models.physics`), for training through it.

The hybrid's residual net is trained by back-propagating a rollout loss through the physics
integration, which numpy cannot differentiate. These functions are the numpy ones of
:mod:`~quad_modelling.core.models.physics` (same equations, same order of operations, same symbols),
written on torch tensors of any float dtype: :func:`steady_rotor_speed`, :func:`rotor_step`,
:func:`rotor_acceleration`, :func:`accelerations`, :func:`rotation_increment`
(:func:`quad_modelling.core.frames.rotation_increment`), :func:`limit_norm` (the rate and speed limits) and
:func:`step`. In float64 they give the
numpy step to 1e-9 (test); the model's equations are documented once, in the physics module.

A state is a :class:`TorchState` of tensors shaped as :class:`~quad_modelling.core.models.physics.PhysicsState`'s;
the disturbance accelerations are passed as ``linear_n`` (B, 3) [m/s², N] and ``angular_b`` (B, 3) [rad/s², B].
torch is imported lazily by the callers (this module imports it at the top: only training imports it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from quad_modelling.core.flight_log import GYRO_FULL_SCALE
from quad_modelling.core.models.physics import MAX_SPEED_MPS, PhysicsParameters, PhysicsState
from quad_modelling.core.vehicle import GRAVITY


class TorchState(NamedTuple):
    """pos_n, vel_n (B, 3); rot (B, 3, 3) R_N<-B; rates (B, 3); rotor (B, 4) [rad/s]; yaw (B,) unwrapped [rad]."""

    pos_n: torch.Tensor
    vel_n: torch.Tensor
    rot: torch.Tensor
    rates: torch.Tensor
    rotor: torch.Tensor
    yaw: torch.Tensor

    @classmethod
    def from_numpy(cls, state: PhysicsState, dtype=torch.float64) -> TorchState:
        return cls(*(torch.as_tensor(np.asarray(a), dtype=dtype) for a in
                     (state.pos_n, state.vel_n, state.rot, state.rates, state.rotor, state.yaw)))

    def to_numpy(self) -> PhysicsState:
        return PhysicsState(*(a.detach().cpu().numpy().astype(float) for a in self))


class TorchParameters(NamedTuple):
    """The :class:`PhysicsParameters` the step uses, as tensors of one dtype (positions (4, 2), spins (4,)). The
    command delay δ is not here: the caller feeds the delayed commands (:func:`physics.delayed_commands`)."""

    mass: float
    inertia: torch.Tensor
    prop_inertia: float
    positions: torch.Tensor
    spins: torch.Tensor
    speed_gain: float
    speed_offset: float
    time_constant: float
    thrust_constant: float
    torque_constant: float
    drag: torch.Tensor
    drag_arm: float

    @classmethod
    def from_params(cls, p: PhysicsParameters, dtype=torch.float64) -> TorchParameters:
        def t(x):
            return torch.as_tensor(np.asarray(x, dtype=float), dtype=dtype)

        return cls(float(p.mass), t(p.inertia), float(p.prop_inertia), t(p.positions), t(p.spins), float(p.speed_gain),
                   float(p.speed_offset), float(p.time_constant), float(p.thrust_constant), float(p.torque_constant), t(p.drag),
                   float(p.drag_arm))


def rotate(rot: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """R v (B, 3) of matrices (B, 3, 3) and vectors (B, 3), as a broadcast sum (torch's batched 3x3 matmul is slow)."""
    return (rot * v[:, None, :]).sum(dim=2)


def rotate_back(rot: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """R^T v (B, 3)."""
    return (rot * v[:, :, None]).sum(dim=1)


def matmul3(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a b of (B, 3, 3) matrices, as a broadcast sum."""
    return (a[:, :, :, None] * b[:, None, :, :]).sum(dim=2)


def steady_rotor_speed(p: TorchParameters, u: torch.Tensor) -> torch.Tensor:
    """Ω_ss = max(k_u u + Ω_off, 0) [rad/s]."""
    return torch.clamp_min(p.speed_gain * u + p.speed_offset, 0.0)


def rotor_step(p: TorchParameters, rotor: torch.Tensor, u: torch.Tensor, dt: torch.Tensor) -> torch.Tensor:
    """Ω_{k+1} = Ω_ss + (Ω_k − Ω_ss) e^{−Δt/τ_m} (``dt`` (B,) [s]; τ_m = 0: Ω_ss at once)."""
    target = steady_rotor_speed(p, u)
    if p.time_constant <= 0.0:
        return target
    return target + (rotor - target) * torch.exp(-dt / p.time_constant)[:, None]


def rotor_acceleration(p: TorchParameters, rotor: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """dΩ/dt = (Ω_ss(u) − Ω)/τ_m [rad/s²] (0 without lag)."""
    if p.time_constant <= 0.0:
        return torch.zeros_like(rotor)
    return (steady_rotor_speed(p, u) - rotor) / p.time_constant


def accelerations(p: TorchParameters, vel_n, rot, rates, rotor, rotor_dot) -> tuple[torch.Tensor, torch.Tensor]:
    """(dv_N/dt (B, 3) [m/s², N], dω/dt (B, 3) [rad/s², B]) without disturbance, as physics.accelerations."""
    w2 = rotor * rotor
    thrust = p.thrust_constant * w2
    vel_b = rotate_back(rot, vel_n)
    drag_b = -(rotor.sum(dim=1)[:, None] * p.drag) * vel_b
    force_b = drag_b - torch.nn.functional.pad(thrust.sum(dim=1)[:, None], (2, 0))
    acc_n = rotate(rot, force_b) / p.mass
    acc_n = acc_n + torch.tensor([0.0, 0.0, GRAVITY], dtype=acc_n.dtype)
    torque = torch.stack([
        -thrust @ p.positions[:, 1] - p.drag_arm * drag_b[:, 1],
        thrust @ p.positions[:, 0] + p.drag_arm * drag_b[:, 0],
        p.torque_constant * (w2 @ p.spins) + p.prop_inertia * (rotor_dot @ p.spins),
    ], dim=1)
    torque = torque - torch.linalg.cross(rates, rates * p.inertia, dim=1)
    return acc_n, torque / p.inertia


def skew(phi: torch.Tensor) -> torch.Tensor:
    """[φ]× (B, 3, 3) of vectors φ (B, 3)."""
    zero = torch.zeros_like(phi[:, 0])
    x, y, z = phi[:, 0], phi[:, 1], phi[:, 2]
    return torch.stack([torch.stack([zero, -z, y], 1), torch.stack([z, zero, -x], 1), torch.stack([-y, x, zero], 1)], 1)


def rotation_increment(rot: torch.Tensor, rates_b: torch.Tensor, dt: torch.Tensor) -> torch.Tensor:
    """R_{k+1} = R_k Exp([ω Δt]×) by Rodrigues' formula, as :func:`quad_modelling.core.frames.rotation_increment`."""
    phi = rates_b * dt[:, None]
    angle = torch.linalg.vector_norm(phi, dim=1)
    small = angle < 1e-8
    safe = torch.where(small, torch.ones_like(angle), angle)
    a = torch.where(small, 1.0 - angle**2 / 6.0, torch.sin(safe) / safe)
    b = torch.where(small, 0.5 - angle**2 / 24.0, (1.0 - torch.cos(safe)) / safe**2)
    k = skew(phi)
    eye = torch.eye(3, dtype=rot.dtype).expand_as(k)
    return matmul3(rot, eye + a[:, None, None] * k + b[:, None, None] * matmul3(k, k))


def limit_norm(vectors: torch.Tensor, limit: float) -> torch.Tensor:
    """Rows of ``vectors`` scaled down to norm ``limit`` where longer (physics._limit_norm)."""
    norm = torch.linalg.vector_norm(vectors, dim=1, keepdim=True)
    return torch.where(norm > limit, vectors * (limit / torch.clamp_min(norm, 1e-12)), vectors)


def continue_yaw(previous: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """The yaw of ``rot`` unwrapped next to ``previous`` [rad]."""
    psi = torch.atan2(rot[:, 1, 0], rot[:, 0, 0])
    return previous + torch.remainder(psi - previous + np.pi, 2.0 * np.pi) - np.pi


def step(p: TorchParameters, state: TorchState, u: torch.Tensor, dt: torch.Tensor, linear_n: torch.Tensor,
         angular_b: torch.Tensor) -> TorchState:
    """One semi-implicit Euler step of :func:`quad_modelling.core.models.physics.step`, ``dt`` (B,) [s]."""
    acc_n, ang_acc = accelerations(p, state.vel_n, state.rot, state.rates, state.rotor, rotor_acceleration(p, state.rotor, u))
    rates = limit_norm(state.rates + dt[:, None] * (ang_acc + angular_b), GYRO_FULL_SCALE)
    rot = rotation_increment(state.rot, rates, dt)
    vel = limit_norm(state.vel_n + dt[:, None] * (acc_n + linear_n), MAX_SPEED_MPS)
    pos = state.pos_n + dt[:, None] * vel
    return TorchState(pos, vel, rot, rates, rotor_step(p, state.rotor, u, dt), continue_yaw(state.yaw, rot))
