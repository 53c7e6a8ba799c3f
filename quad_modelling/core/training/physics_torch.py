"""The physics step on torch tensors, for training through it: the one physics of :mod:`quad_modelling.core.physics`.

The hybrid's residual net is trained by back-propagating a rollout loss through the physics integration, which
numpy cannot differentiate. The physics functions (:mod:`quad_modelling.core.physics`) take torch tensors as they
take numpy arrays (:mod:`quad_modelling.core.physics.arrays`), so this module only converts: a
:class:`TorchState` of tensors shaped as :class:`~quad_modelling.core.physics.rigid_body.PhysicsState`'s, and
:class:`TorchParameters`, the :class:`~quad_modelling.core.physics.parameters.PhysicsParameters` as tensors of one
dtype. In float64 the step equals the numpy step to 1e-9 (test). The disturbance accelerations are passed as
``linear_n`` (B, 3) [m/s², N] and ``angular_b`` (B, 3) [rad/s², B]. torch is imported lazily by the callers (this
module imports it at the top: only training imports it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from quad_modelling.core.physics import rigid_body
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import PhysicsState


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
    command path (delay δ, motor gains, battery scaling) is not here: the caller feeds the commands the rotors answer
    (:func:`~quad_modelling.core.physics.rotors.effective_commands`)."""

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
    ground_effect: tuple[float, float] | None = None
    gyroscopic: tuple[float, float] | None = (1.0, 0.0)
    cg_offset: tuple[float, float] | None = None
    """The motor imbalance's CG offset (c_x, c_y) [m]: a moment of the rotor forces, so the step needs it."""

    @classmethod
    def from_params(cls, p: PhysicsParameters, dtype=torch.float64) -> TorchParameters:
        def t(x):
            return torch.as_tensor(np.asarray(x, dtype=float), dtype=dtype)

        return cls(float(p.mass), t(p.inertia), float(p.prop_inertia), t(p.positions), t(p.spins), float(p.speed_gain),
                   float(p.speed_offset), float(p.time_constant), float(p.thrust_constant), float(p.torque_constant), t(p.drag),
                   float(p.drag_arm), p.ground_effect, p.gyroscopic, p.cg_offset)


def step(p: TorchParameters, state: TorchState, u: torch.Tensor, dt: torch.Tensor, linear_n: torch.Tensor,
         angular_b: torch.Tensor) -> TorchState:
    """One semi-implicit Euler step of :func:`quad_modelling.core.physics.rigid_body.step` on tensors, ``dt`` (B,) [s]."""
    return rigid_body.step(p, state, u, dt, linear_n, angular_b)
