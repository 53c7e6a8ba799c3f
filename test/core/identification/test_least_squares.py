"""The one fitting engine: known linear and nonlinear answers within bounds, held parameters, at-bound flags,
HAC sigma against the textbook sigma on white residuals, degenerate columns reported rather than crashing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quad_modelling.core.identification.least_squares import (
    AT_BOUND_FRACTION,
    POOR_RANGE_FRACTION,
    POOR_RELATIVE_SIGMA,
    Parameter,
    bound_side,
    fit_least_squares,
    poorly_determined,
)
from quad_modelling.core.identification.uncertainty import bandwidth_samples, hac_covariance

PERIOD_S = 0.1
"""Sample spacing of the synthetic residuals [s]: a HAC bandwidth of 10 samples."""


def line_data(windows: int = 40, samples: int = 100, noise: float = 0.1, seed: int = 0):
    """y = 2 x + 0.5 + white noise on (windows, samples, 1)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (windows, samples, 1))
    return x, 2.0 * x + 0.5 + noise * rng.standard_normal(x.shape)


def line_residuals(x, y):
    return lambda v: y - (v[0] * x + v[1])


def test_linear_problem_equals_ordinary_least_squares():
    x, y = line_data()
    fit = fit_least_squares(line_residuals(x, y), [Parameter("slope", 0.0, -10.0, 10.0), Parameter("offset", 0.0, -10.0, 10.0)],
                            sample_period_s=PERIOD_S, max_evaluations=50)
    design = np.column_stack([x.ravel(), np.ones(x.size)])
    exact = np.linalg.lstsq(design, y.ravel(), rcond=None)[0]
    assert fit.values == pytest.approx(exact, rel=1e-7)
    assert fit.success and fit.cost == pytest.approx(0.5 * np.sum((y.ravel() - design @ exact) ** 2), rel=1e-9)
    assert fit.residuals.shape == y.shape and fit.moving.all() and not fit.held.any()
    assert fit.at_bound("slope") is None and fit.advice("slope") == "" and fit.advice("offset") == ""
    assert abs(fit.value("slope") - 2.0) < 3 * fit.sigma_of("slope")  # the truth within 3 sigma


def test_hac_sigma_equals_the_textbook_sigma_for_white_residuals():
    """For independent residuals the HAC sandwich estimates s² (JᵀJ)⁻¹: over 4000 samples with a 10-sample
    bandwidth its sampling error is ~3 % of sigma (Andrews 1991, Econometrica 59(3): the Bartlett
    estimator's variance is of order L/n); seeds 0-5 give ratios 0.96-1.04."""
    x, y = line_data(windows=40, samples=100)
    fit = fit_least_squares(line_residuals(x, y), [Parameter("slope", 0.0, -10.0, 10.0), Parameter("offset", 0.0, -10.0, 10.0)],
                            sample_period_s=PERIOD_S, max_evaluations=50)
    assert bandwidth_samples(PERIOD_S) == 10
    design = np.column_stack([x.ravel(), np.ones(x.size)])
    s2 = np.sum(fit.residuals**2) / (x.size - 2)
    textbook = np.sqrt(np.diag(s2 * np.linalg.inv(design.T @ design)))
    assert fit.sigma == pytest.approx(textbook, rel=0.1)


def test_nonlinear_problem_in_log_coordinates():
    """y = A exp(-t / tau): tau searched as ln tau; its sigma is tau sigma(ln tau) (first order)."""
    rng = np.random.default_rng(1)
    t = np.linspace(0.0, 2.0, 50)[None, :, None] * np.ones((20, 1, 1))
    y = 3.0 * np.exp(-t / 0.4) + 0.01 * rng.standard_normal(t.shape)
    fit = fit_least_squares(lambda v: y - v[0] * np.exp(-t / v[1]),
                            [Parameter("amplitude", 1.0, 0.0, 10.0), Parameter("tau", 1.0, 1e-3, 10.0, transform="log")],
                            sample_period_s=PERIOD_S, max_evaluations=200)
    assert fit.value("amplitude") == pytest.approx(3.0, rel=0.01) and fit.value("tau") == pytest.approx(0.4, rel=0.01)
    i = fit.index("tau")
    assert fit.search_values[i] == pytest.approx(math.log(fit.value("tau")), rel=1e-12)
    assert fit.sigma[i] == pytest.approx(fit.value("tau") * math.sqrt(fit.search_covariance[i, i]), rel=1e-9)
    assert 0 < fit.sigma_of("tau") < 0.01


def test_held_parameter_keeps_its_value_and_the_rest_fits_around_it():
    x, y = line_data()
    fit = fit_least_squares(line_residuals(x, y), [Parameter("slope", 0.0, -10.0, 10.0), Parameter("offset", 0.2, -10.0, 10.0)],
                            held=["offset"], sample_period_s=PERIOD_S, max_evaluations=50)
    assert fit.value("offset") == 0.2 and fit.held.tolist() == [False, True]
    assert fit.value("slope") == pytest.approx(np.sum(x * (y - 0.2)) / np.sum(x * x), rel=1e-7)  # conditional least squares
    assert math.isnan(fit.sigma_of("offset")) and np.isnan(fit.covariance[1]).all() and np.isfinite(fit.sigma_of("slope"))
    assert fit.at_bound("offset") is None and fit.advice("offset", "fixed by the caller") == "held at 0.2 (fixed by the caller)"


def test_parameter_pinned_at_a_bound_is_flagged_and_poorly_determined():
    x, y = line_data()
    fit = fit_least_squares(line_residuals(x, y), [Parameter("slope", 0.0, -1.0, 1.0), Parameter("offset", 0.0, -10.0, 10.0)],
                            sample_period_s=PERIOD_S, max_evaluations=50)
    assert fit.value("slope") == pytest.approx(1.0, abs=2 * AT_BOUND_FRACTION) and fit.at_bound("slope") == "upper"
    assert fit.advice("slope") == "ended on its search bound [-1, 1]" and fit.at_bound("offset") is None


def test_degenerate_columns_are_reported_not_fatal():
    """A parameter the residual ignores has no Jacobian column: NaN sigma, the others keep theirs. Two parameters
    the residual sees only as a sum make JᵀJ singular: their sigmas are NaN and both are poorly determined."""
    x, y = line_data()
    ignored = fit_least_squares(line_residuals(x, y), [Parameter("slope", 0.0, -10.0, 10.0), Parameter("offset", 0.0, -10.0, 10.0),
                                                       Parameter("unused", 0.3, 0.0, 1.0)],
                                sample_period_s=PERIOD_S, max_evaluations=50)
    assert ignored.moving.tolist() == [True, True, False] and ignored.value("unused") == pytest.approx(0.3)
    assert math.isnan(ignored.sigma_of("unused")) and np.isfinite(ignored.sigma[:2]).all()
    assert ignored.advice("unused") == "no uncertainty (the fit cannot separate it)"
    collinear = fit_least_squares(lambda v: y - ((v[0] + v[1]) * x + v[2]),
                                  [Parameter("a", 0.0, -10.0, 10.0), Parameter("b", 0.0, -10.0, 10.0), Parameter("offset", 0.0, -10.0, 10.0)],
                                  sample_period_s=PERIOD_S, max_evaluations=50)
    assert collinear.value("a") + collinear.value("b") == pytest.approx(2.0, abs=0.02)
    assert np.isnan(collinear.sigma).all() and all(collinear.advice(n) for n in ("a", "b"))


def test_the_lowest_cost_start_wins():
    """y = sin(w t) has a local minimum near a poor start; a second start reaches the true frequency."""
    t = np.linspace(0.0, 10.0, 400)[None, :, None]
    y = np.sin(3.0 * t)
    residuals = lambda v: y - np.sin(v[0] * t)  # noqa: E731
    parameter = [Parameter("w", 1.0, 0.1, 5.0)]
    single = fit_least_squares(residuals, parameter, sample_period_s=PERIOD_S, max_evaluations=100)
    several = fit_least_squares(residuals, parameter, starts=[{"w": 2.9}], sample_period_s=PERIOD_S, max_evaluations=100)
    assert abs(single.value("w") - 3.0) > 0.1 and several.value("w") == pytest.approx(3.0, rel=1e-6)
    assert several.cost < 1e-12 < single.cost and several.evaluations > single.evaluations
    randomised = [fit_least_squares(residuals, [Parameter("w", 2.0, 0.1, 5.0, transform="unit")], random_starts=3,
                                    sample_period_s=PERIOD_S, max_evaluations=100) for _ in range(2)]
    assert randomised[0].values == randomised[1].values and randomised[0].evaluations == randomised[1].evaluations  # seeded


def test_non_finite_residuals_count_as_a_large_cost_instead_of_crashing():
    """A window whose prediction diverges beyond slope 2.5 (NaN) is a constant 1e6 residual there: scipy alone
    refuses a non-finite start; the other windows lead the search back, and the fit ends on the exact answer."""
    x, y = line_data(windows=4)

    def residuals(v):
        r = y - (v[0] * x + 0.5)
        if v[0] > 2.5:
            r[0] = np.nan
        return r

    fit = fit_least_squares(residuals, [Parameter("slope", 4.0, -5.0, 5.0)], sample_period_s=PERIOD_S, max_evaluations=50)
    assert fit.value("slope") == pytest.approx(np.sum(x * (y - 0.5)) / np.sum(x**2), rel=1e-7)
    assert np.isfinite(fit.residuals).all()


def test_bad_requests_raise():
    x, y = line_data(windows=2)
    slope = Parameter("slope", 0.0, -1.0, 1.0)
    with pytest.raises(ValueError, match="every parameter"):
        fit_least_squares(line_residuals(x, y), [slope], held=["slope"], sample_period_s=PERIOD_S, max_evaluations=5)
    with pytest.raises(ValueError, match="'offset' is none of the parameters"):
        fit_least_squares(line_residuals(x, y), [slope], held=["offset"], sample_period_s=PERIOD_S, max_evaluations=5)
    with pytest.raises(ValueError, match="'slope', which is held"):
        fit_least_squares(line_residuals(x, y), [slope, Parameter("offset", 0.0, -1.0, 1.0)], held=["slope"], starts=[{"slope": 0.5}],
                          sample_period_s=PERIOD_S, max_evaluations=5)
    with pytest.raises(ValueError, match="repeated"):
        fit_least_squares(line_residuals(x, y), [slope, slope], sample_period_s=PERIOD_S, max_evaluations=5)
    with pytest.raises(ValueError, match="windows, samples, variables"):
        fit_least_squares(lambda v: y.ravel() - v[0], [slope], sample_period_s=PERIOD_S, max_evaluations=5)
    with pytest.raises(ValueError, match="positive lower bound"):
        Parameter("tau", 1.0, 0.0, 1.0, transform="log")
    with pytest.raises(ValueError, match="increasing"):
        Parameter("a", 0.0, 1.0, -1.0)


def test_bound_rule_is_a_fraction_of_the_searched_range():
    assert bound_side(0.3, 0.3, 3.0) == "lower" and bound_side(3.0 - 0.002, 0.3, 3.0) == "upper"
    assert bound_side(0.3 + 0.003, 0.3, 3.0) is None  # 0.11 % of the range away
    # a log parameter: the fraction of the decades searched (0.1 % of ln 1000 = 0.69 % of the value)
    assert bound_side(0.002 * 1.006, 0.002, 2.0, "log") == "lower" and bound_side(0.002 * 1.01, 0.002, 2.0, "log") is None


def test_poorly_determined_rule_and_its_constants():
    assert POOR_RELATIVE_SIGMA == 0.5 and POOR_RANGE_FRACTION == 0.5
    assert poorly_determined(-31.0, 15.0, "1/s", (-500.0, -0.5)) == ""  # 48 % of the value
    assert poorly_determined(-31.0, 25.0, "1/s", (-500.0, -0.5)) == "sigma 81 % of the value"
    assert poorly_determined(0.0, 0.01, "m", (-0.1, 0.1)) == "sigma 0.01 m about a value of 0"
    # far from zero in a narrow range: 6 % of the value, but 60 % of the range searched
    assert poorly_determined(105.0, 6.0, "V", (100.0, 110.0)) == "sigma 60 % of the search range [100, 110]"
    assert poorly_determined(105.0, 6.0, "V") == ""  # not searched directly: no range to compare with
    assert poorly_determined(1.0, math.nan) == "no uncertainty (the fit cannot separate it)"
    assert poorly_determined(math.nan, 0.1) == "not identifiable from these flights"
    assert poorly_determined(0.3, 0.01, bounds=(0.3, 3.0), at_bound=True) == "ended on its search bound [0.3, 3]"


def test_hac_sigma_grows_with_autocorrelated_residuals():
    """AR(1) noise (rho 0.9, ~1 s correlation at 10 samples/s): neighbours repeat each other. The offset's true
    sigma is sqrt((1 + rho) / (1 - rho)) = 4.4x the textbook one that counts each sample as new; the 10-sample
    Bartlett window recovers 2.8x (it truncates and down-weights the lags: for correlations longer than the
    bandwidth the HAC sigma is still optimistic). The slope's regressor is white, so its sigma stays the textbook one."""
    rng = np.random.default_rng(2)
    noise = np.zeros((40, 100, 1))
    for k in range(1, 100):
        noise[:, k] = 0.9 * noise[:, k - 1] + 0.1 * rng.standard_normal((40, 1))
    x = rng.uniform(-1.0, 1.0, noise.shape)
    y = 2.0 * x + 0.5 + noise
    fit = fit_least_squares(line_residuals(x, y), [Parameter("slope", 0.0, -10.0, 10.0), Parameter("offset", 0.0, -10.0, 10.0)],
                            sample_period_s=PERIOD_S, max_evaluations=50)
    design = np.column_stack([x.ravel(), np.ones(x.size)])
    textbook = np.sqrt(np.diag(np.sum(fit.residuals**2) / (x.size - 2) * np.linalg.inv(design.T @ design)))
    assert 2.5 < fit.sigma_of("offset") / textbook[1] < 4.4
    assert fit.sigma_of("slope") / textbook[0] == pytest.approx(1.0, abs=0.1)


def test_an_infinite_bound_is_reached_only_by_the_value():
    assert bound_side(0.0, 0.0, math.inf) == "lower" and bound_side(1e-9, 0.0, math.inf) is None
    assert bound_side(1e300, 0.0, math.inf) is None and bound_side(math.inf, 0.0, math.inf) == "upper"


def test_a_value_nine_times_its_lower_bound_in_a_four_decade_range_is_not_at_it():
    """A positive range of more than two decades is judged in log coordinates: 1.55e-11 in [1.79e-12, 1.79e-8]
    was 'AT BOUND' (0.08 % of the linear range) though 9 times the bound (a review, session 29)."""
    from quad_modelling.core.identification.least_squares import bound_side

    assert bound_side(1.55e-11, 1.79e-12, 1.79e-8) is None
    assert bound_side(1.7905e-12, 1.79e-12, 1.79e-8) == "lower" and bound_side(1.7899e-8, 1.79e-12, 1.79e-8) == "upper"
    assert bound_side(0.0005, 0.0, 1.0) == "lower" and bound_side(0.5, 0.1, 1.0) is None  # narrow or from 0: linear


def test_a_jacobian_whose_columns_differ_by_rounding_is_singular():
    """Two columns equal but for the last bits (finite differences of two parameters the residual sees only as a sum)
    are one direction: LinAlgError on every CPU, not a covariance from an inverse of rounding (finite sigmas of 5e-4
    came out where LU's pivot was not exactly 0). Independent columns keep the sandwich's covariance (lag 0)."""
    rng = np.random.default_rng(3)
    column = rng.normal(size=(4, 50, 2, 1))
    twins = np.concatenate([column, column * (1.0 + 4e-16), rng.normal(size=(4, 50, 2, 1))], axis=3)
    residuals = rng.normal(size=(4, 50, 2))
    with pytest.raises(np.linalg.LinAlgError, match="rank 2"):
        hac_covariance(twins, residuals, 0)
    independent = rng.normal(size=(4, 50, 2, 3))
    flat = independent.reshape(-1, 3)
    bread = np.linalg.inv(flat.T @ flat)
    scores = (independent * residuals[..., None]).sum(axis=2).reshape(-1, 3)  # each sample's J^T r
    assert hac_covariance(independent, residuals, 0) == pytest.approx(bread @ scores.T @ scores @ bread, rel=1e-9)
