r"""Aerodynamic terms of the physics model: rotor drag, ground effect (the model's forms, one definition each).

Symbols as :mod:`~quad_modelling.core.physics.rotors`; body frame B = FRD, SI units.

* rotor drag (:func:`rotor_drag`): each rotor's blade drag and flapping give a force against the airspeed,
  proportional to its speed; summed over the rotors, with :math:`D = \mathrm{diag}(d_{xy}, d_{xy}, d_z)`
  [N s/(m rad)] and the body airspeed :math:`v_B = R^T v_N`,

  .. math:: F_d = -\Big(\sum_i \Omega_i\Big) D\, v_B, \qquad \tau_d = (0, 0, h_d) \times F_d = (-h_d F_{d,y},\ h_d F_{d,x},\ 0)

  acting at the rotor plane, :math:`h_d` [m] from the CG along FRD z (negative: above it);
* ground effect (:func:`ground_effect_factor`, the model's identifiable form): near the ground a rotor gives
  more thrust, :math:`T_i \to k_{GE}(h) T_i` with :math:`k_{GE}(h) = 1 + c_{ge} / (h + h_{off})^2`, h the height
  above the ground [m], :math:`c_{ge}` [m²] and :math:`h_{off}` [m] identified (the truth simulator's
  Cheeseman-Bennett form :math:`1/(1 - (R_p/4h)^2)` is its own: ``docs/simulator.md``).
"""

from __future__ import annotations

from quad_modelling.core.physics import arrays


def rotor_drag(p, rotor, vel_b):
    """(F_d (B, 3) [N], τ_d (B, 3) [N m]) in B of rotor speeds ``rotor`` (B, 4) [rad/s] and body airspeed ``vel_b``
    (B, 3) [m/s] (module docstring; ``p.drag`` = (d_xy, d_xy, d_z), ``p.drag_arm`` = h_d)."""
    force = -(rotor.sum(axis=-1)[..., None] * p.drag) * vel_b
    moment = arrays.columns([-p.drag_arm * force[..., 1], p.drag_arm * force[..., 0], arrays.zeros_like(force[..., 2])])
    return force, moment


def ground_effect_factor(height, coefficient: float, offset: float):
    """k_GE(h) = 1 + c_ge / (h + h_off)² [1] at heights ``height`` [m] above the ground (module docstring)."""
    return 1.0 + coefficient / ((height + offset) * (height + offset))
