"""The physics-base diagnosis reads each component against the base's own value (its null)."""

from __future__ import annotations

from quad_modelling.core.diagnosis.physics_base import components
from quad_modelling.core.identification.constants_report import ConstantEstimate


class _Fit:
    """The part of a PhysicsFit that :func:`components` reads: its estimates."""

    def __init__(self, body: float, rotor: float, sigma: float = 0.01):
        self._estimates = [ConstantEstimate("gyroscopic.body_scale", body, "1", sigma, (0.0, 10.0)),
                           ConstantEstimate("gyroscopic.rotor_scale", rotor, "1", sigma, (0.0, 10.0))]

    def estimates(self):
        return self._estimates


def test_a_body_gyroscopic_scale_equal_to_the_bases_is_not_resolved():
    # the base already has the rigid body's -omega x I omega (scale 1): a fitted 0.98 +- 0.027 (simulated LinkQuad,
    # gyroscopic on) says nothing new, where against a null of 0 it read as resolved
    body, rotor = components("gyroscopic", _Fit(0.98, 0.5, 0.027))
    assert body["component"] == "body scale" and not body["resolved"]
    assert rotor["resolved"]  # 0.5 +- 0.027 is far from the base's 0 rotors' part


def test_a_body_scale_away_from_one_is_resolved():
    body, _ = components("gyroscopic", _Fit(0.5, 0.0))
    assert body["resolved"]
