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


class _Gains:
    def __init__(self, gains, at_bound=()):
        self._estimates = [ConstantEstimate(f"motor_imbalance.gain_{i}", g, "1", 0.02, (0.5, 2.0), at_bound=i in at_bound)
                           for i, g in enumerate(gains, 1)]

    def estimates(self):
        return self._estimates


def test_a_half_that_ran_a_gain_to_its_search_bound_does_not_void_it():
    """Trained on B7 + B3 / B6 (a linear ramp alone): the B6 half ran motor 2's gain to 0.5 and motor 4's to 2, and
    the found imbalance read 'not resolved' on every gain; a bound is the optimiser's value, not a measurement."""
    from quad_modelling.core.diagnosis.verdicts import component_text

    final = _Gains((1.26, 0.82, 1.05, 0.87))
    folds = [_Gains((1.27, 0.80, 1.05, 0.88)), _Gains((1.3, 0.5, 1.0, 2.0), at_bound=(2, 4))]
    parts = {p["name"]: p for p in components("motor_imbalance", final, folds)}
    assert parts["motor_imbalance.gain_2"]["resolved"] and parts["motor_imbalance.gain_2"]["folds_at_bound"] == [False, True]
    assert parts["motor_imbalance.gain_1"]["resolved"]  # both halves above 1
    flipped = [_Gains((1.27, 0.80, 1.05, 0.88)), _Gains((0.9, 0.85, 1.0, 0.9))]  # a half that measured the other sign
    parts = {p["name"]: p for p in components("motor_imbalance", final, flipped)}
    assert not parts["motor_imbalance.gain_1"]["resolved"]
    text = component_text("motor_imbalance", components("motor_imbalance", _Gains((1.26, 1.0, 1.0, 1.0)), folds), True)
    assert "motor 2 gain 1 (0.8 / 0.5 at its bound on the folds)" in text


def test_a_delay_on_its_lower_bound_is_at_bound_but_does_not_refit_the_rung_with_every_observer():
    """A delay of 0 is on its search bound [0, 0.15] and flagged AT BOUND where listed (a review found it unflagged),
    but it is what flights whose commands act at their stamps give: unlike a lag on either bound or a delay on 150 ms
    it is no trade with the observer's trim, and the rung is not refitted with every observer for it."""
    from quad_modelling.core.diagnosis.physics_base import dynamics_at_bound

    def fit(delay: float, tau: float = 0.03) -> _Fit:
        estimates = _Fit(1.0, 0.0)
        estimates._estimates = [ConstantEstimate("rotor_time_constant", tau, "s", 1e-3, (0.002, 0.3), at_bound=tau in (0.002, 0.3)),
                                ConstantEstimate("rotor_delay", delay, "s", 1e-4, (0.0, 0.15), at_bound=delay in (0.0, 0.15))]
        return estimates

    assert components("input_delay", fit(0.0))[0]["at_bound"] and not components("input_delay", fit(0.0))[0]["resolved"]
    assert not dynamics_at_bound(fit(0.0)) and not dynamics_at_bound(fit(0.04))
    assert dynamics_at_bound(fit(0.15)) and dynamics_at_bound(fit(0.0, tau=0.3))
    # a training half that fits 0 measured a delay of 0: it still makes a 20 ms delay unstable over the folds, as
    # before the flag (dropped as a bound value, it turned the component resolved)
    final = fit(0.020)
    final._estimates[1] = ConstantEstimate("rotor_delay", 0.020, "s", 1e-3, (0.0, 0.15))
    assert not components("input_delay", final, [fit(0.0), fit(0.035)])[0]["resolved"]
    assert components("input_delay", final, [fit(0.018), fit(0.035)])[0]["resolved"]
