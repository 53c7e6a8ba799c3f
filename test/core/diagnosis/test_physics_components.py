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


class _ImbalanceFit:
    """A motor-imbalance fit's estimates: gains (mean 1) and the CG offset, each with its sigma; ``held`` the CG's
    reason when the fit held it at 0."""

    def __init__(self, gains, gain_sigma, offset, offset_sigma, held: str = ""):
        self._estimates = [ConstantEstimate(f"motor_imbalance.gain_{i}", g, "1", gain_sigma, (0.5, 2.0)) for i, g in enumerate(gains, 1)]
        self._estimates += [ConstantEstimate(f"motor_imbalance.cg_offset_{a}", c, "m", offset_sigma, (-0.05, 0.05), held=held)
                            for a, c in zip("xy", offset)]

    def estimates(self):
        return self._estimates


def test_the_imbalances_main_component_is_the_one_furthest_from_its_null_in_sigmas():
    # a 6 mm CG offset at 0.09 mm sigma (67 sigma) outranks a 1.5 % gain at 0.15 % (10 sigma), though 0.006 < 0.015
    parts = components("motor_imbalance", _ImbalanceFit((1.015, 0.99, 1.008, 0.987), 0.0015, (0.006, -0.004), 9e-5))
    assert [p["component"] for p in parts[:3]] == ["CG offset x", "CG offset y", "motor 1 gain"]
    assert all(p["resolved"] for p in parts[:3]) and parts[0]["unit"] == "m"
    gains = components("motor_imbalance", _ImbalanceFit((1.2, 0.93, 0.94, 0.93), 0.03, (0.0, 0.0), float("nan"), held="held at 0"))
    assert gains[0]["component"] == "motor 1 gain" and gains[0]["resolved"]
    assert not any(p["resolved"] for p in gains if p["component"].startswith("CG"))  # held at 0: never resolved
