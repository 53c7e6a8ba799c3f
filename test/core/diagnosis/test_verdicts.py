"""Verdicts with reasons: found only when the held-out shrink passes, the total error falls and the parameters are
inside their bounds, plausible and stable across folds of the training flights; otherwise weak or not supported,
with the first rule that failed named."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from quad_modelling.core.diagnosis.attribution import verdict_with_reason
from quad_modelling.core.diagnosis.catalogue import CATALOGUE
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG
from quad_modelling.core.diagnosis.verdicts import (
    DETERMINED_SIGMAS,
    FOLD_MIN_WINDOWS,
    ParameterCheck,
    fold_stability,
    material_parameters,
    parameter_checks,
    parameter_failure,
    training_folds,
)
from quad_modelling.core.identification.base_model import BaseModel, predict_batch
from quad_modelling.core.identification.window_batch import prepare_windows
from quad_modelling.core.models.greybox import GreyboxParameters
from quad_modelling.core.sim.simulate import simulate
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle

GROUND = CATALOGUE["ground_effect"]


@pytest.fixture(scope="module")
def linkquad():
    return load_vehicle("linkquad")


@pytest.fixture(scope="module")
def base(linkquad):
    return BaseModel(GreyboxParameters.from_vehicle(linkquad), reference_voltage=12.0)


@pytest.fixture(scope="module")
def batch(linkquad):
    """Two 35 s effects-off flights (seeds 5 and 6): 8 windows, 4 per flight."""
    flights = [simulate("linkquad", effects=("gyroscopic",), seed=s, duration=35.0) for s in (5, 6)]
    return prepare_windows(flights, linkquad, DIAGNOSIS_CONFIG)


def _check(name="c_ge", value=0.002, sigma=1e-4, lower=0.0, upper=0.5, plausible=(1e-5, 0.02), material=True, null=0.0):
    return ParameterCheck(name, value, sigma, "m2", lower, upper, plausible, material, False, null)


def test_a_material_parameter_on_its_bound_makes_the_effect_weak():
    """Ground effect with its height offset on the 2 m upper bound (the issue's NanoBench and wind cases): weak."""
    checks = [_check(), _check("h_off", 2.0, float("nan"), 0.005, 2.0, (0.01, 0.4), null=None)]
    assert checks[1].at_bound == "upper" and checks[0].at_bound is None
    assert parameter_failure(GROUND, checks) == "h_off = 2 m2 is at its upper search bound 2"
    # the same value, not material (its term is under a tenth of the correction): no failure
    checks[1] = replace(checks[1], material=False)
    assert parameter_failure(GROUND, checks) is None


def test_an_implausible_material_parameter_makes_the_effect_weak_and_names_the_source():
    checks = [_check(value=0.04), _check("h_off", 0.2, 0.01, 0.005, 2.0, (0.01, 0.4), null=None)]
    text = parameter_failure(GROUND, checks)
    assert text.startswith("c_ge = 0.04 m2 is outside the plausible 1e-05..0.02") and "Cheeseman" in text


def test_determined_means_three_sigma_from_the_null():
    assert _check(value=3.1e-3, sigma=1e-3).determined
    assert not _check(value=2.9e-3, sigma=1e-3).determined
    assert not _check(sigma=float("nan")).determined  # a singular fit determines nothing
    assert _check(null=None, sigma=float("nan")).determined  # a shape parameter matters whenever the effect does
    assert DETERMINED_SIGMAS == 3.0


def test_training_folds_deal_flights_alternately_or_split_one_flight_in_time(batch):
    folds = training_folds(batch)
    assert len(folds) == 2 and sorted(np.concatenate(folds).tolist()) == list(range(len(batch)))
    sources = [sorted({batch.sources[i] for i in fold}) for fold in folds]
    if len(set(batch.sources)) > 1:
        assert sources[0] != sources[1]
    one = batch.subset(np.arange(len(batch)))
    one = replace(one, sources=["only"] * len(one))
    halves = training_folds(one)
    assert halves[0].tolist() == list(range(len(one) // 2)) and halves[1][0] == len(one) // 2
    assert training_folds(one.subset(np.arange(2 * FOLD_MIN_WINDOWS - 1))) == []


def test_fold_stability_same_sign_within_half_of_the_full_fit(batch):
    theta = np.array([0.002, 0.2])
    checks = [_check(), _check("h_off", 0.2, 0.01, 0.005, 2.0, (0.01, 0.4), null=None)]
    stable = fold_stability(GROUND, theta, checks, batch, lambda fold: np.array([0.0025, 0.15]))
    assert stable["stable"] is True and stable["folds"] == 2 and stable["values"]["c_ge"] == [0.0025, 0.0025]
    far = fold_stability(GROUND, theta, checks, batch, lambda fold: np.array([0.0031, 0.2]))  # +55 %
    assert far["stable"] is False and "c_ge 0.002 m2 on all, 0.0031, 0.0031 on the folds" in far["reason"]
    flipped = fold_stability(GROUND, theta, checks, batch, lambda fold: np.array([-0.001, 0.2]))
    assert flipped["stable"] is False
    # an undetermined parameter (within 3 sigma of its null) does not decide: the finding does not rest on it
    loose = [replace(checks[0], sigma=1e-3), checks[1]]
    assert fold_stability(GROUND, theta, loose, batch, lambda fold: np.array([-0.001, 0.2]))["stable"] is True
    # ... but a finding none of whose material parameters is determined rests on nothing
    nothing = [replace(checks[0], sigma=1e-3), replace(checks[1], sigma=0.1, null=0.0)]
    none_determined = fold_stability(GROUND, theta, nothing, batch, lambda fold: theta)
    assert none_determined["stable"] is False and none_determined["reason"].startswith("no material parameter is determined")
    too_few = fold_stability(GROUND, theta, checks, batch.subset(np.arange(3)), lambda fold: theta)
    assert too_few["stable"] is None and "too few training windows (3)" in too_few["reason"]


def test_the_verdict_names_the_first_rule_that_fails(batch):
    theta = np.array([0.002, 0.2])
    good = [_check(), _check("h_off", 0.2, 0.01, 0.005, 2.0, (0.01, 0.4), null=None)]
    falls, rises = {"before": 1.0, "after": 0.98}, {"before": 1.0, "after": 1.034}
    same = lambda fold: theta  # noqa: E731 - a refit that reproduces the full fit

    verdict, reason, _ = verdict_with_reason(GROUND, theta, good, 0.3, 0.2, 0.1, 9, 10, falls, same, batch)
    assert verdict == "found" and "total held-out error 1.000 -> 0.980" in reason and "stable across 2 training folds" in reason
    verdict, reason, _ = verdict_with_reason(GROUND, theta, good, 0.02, 0.2, 0.01, 9, 10, falls, same, batch)
    assert (verdict, reason) == ("not supported", "it fits the training flights (20% shrink) but not the held-out ones (2.0% < 5%)")
    verdict, reason, _ = verdict_with_reason(GROUND, theta, good, 0.3, 0.2, 0.1, 9, 10, rises, same, batch)
    assert verdict == "not supported" and "does not fall (1.000 -> 1.034)" in reason  # battery on the NanoBench flights
    at_bound = [good[0], replace(good[1], value=2.0)]
    verdict, reason, _ = verdict_with_reason(GROUND, theta, at_bound, 0.3, 0.2, 0.1, 9, 10, falls, same, batch)
    assert verdict == "weak" and "upper search bound" in reason
    verdict, reason, stability = verdict_with_reason(GROUND, theta, good, 0.3, 0.2, 0.1, 9, 10, falls,
                                                     lambda fold: -theta, batch)
    assert verdict == "weak" and reason.startswith("unstable across 2 training folds") and stability["stable"] is False


def test_material_parameters_are_those_whose_term_moves_the_correction(batch, base):
    """Gyroscopic torques with k_prop = 0: its term vanishes, so it is not material; k_body's term is the whole
    correction. A held parameter is never material."""
    effect = CATALOGUE["gyroscopic"]
    cols = np.array([INDEX[v] for v in ("roll_acc", "pitch_acc")])
    reference = predict_batch(base, batch)
    material = material_parameters(effect, np.array([1.0, 0.0]), base, batch, cols, reference)
    assert material.tolist() == [True, False]
    assert material_parameters(effect, np.array([1.0, 0.0]), base, batch, cols, reference, held=("k_body",)).tolist() == [False, False]
    checks = parameter_checks(effect, np.array([1.0, 0.0]), np.array([0.05, np.nan]), base, material)
    assert [c.plausible for c in checks] == [(0.5, 1.5), (0.0, 3.0)]
    assert checks[0].to_json(effect.plausible_source)["plausible_ok"] and checks[0].determined


def test_a_shrink_that_rounds_to_zero_reads_plus_zero():
    from quad_modelling.core.diagnosis.verdicts import signed_percent

    assert [signed_percent(x) for x in (-0.0004, 0.0004, 0.065, -0.0251, -0.0006)] == ["+0.0%", "+0.0%", "+6.5%", "-2.5%", "-0.1%"]
