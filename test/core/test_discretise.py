import numpy as np
import pytest

from quad_modelling.core.discretise import zero_order_hold
from quad_modelling.errors import DataError


def test_zero_order_hold_of_a_double_integrator_with_damping_equals_the_analytic_solution():
    # x1' = x2, x2' = -c x2 + u: with u held, x2(dt) = e^{-c dt} x2 + (1 - e^{-c dt}) u / c,
    # x1(dt) = x1 + (1 - e^{-c dt}) x2 / c + (dt - (1 - e^{-c dt}) / c) u / c
    c, dt = 3.0, 0.05
    a_d, b_d = zero_order_hold(np.array([[0.0, 1.0], [0.0, -c]]), np.array([[0.0], [1.0]]), dt)
    e = np.exp(-c * dt)
    np.testing.assert_allclose(a_d, [[1.0, (1 - e) / c], [0.0, e]], rtol=1e-12)
    np.testing.assert_allclose(b_d, [[(dt - (1 - e) / c) / c], [(1 - e) / c]], rtol=1e-12)


def test_zero_order_hold_results_are_read_only_and_reject_a_non_positive_period():
    a_d, _ = zero_order_hold(np.array([[-1.0]]), np.array([[1.0]]), 0.1)
    assert a_d[0, 0] == pytest.approx(np.exp(-0.1), rel=1e-12)
    with pytest.raises(ValueError):
        a_d[0, 0] = 0.0
    with pytest.raises(DataError, match="sample period must be positive"):
        zero_order_hold(np.array([[-1.0]]), np.array([[1.0]]), 0.0)
