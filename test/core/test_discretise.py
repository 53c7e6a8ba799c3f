import numpy as np
import pytest

from quad_modelling.core.discretise import discrete_motor, motor_thrusts, zero_order_hold
from quad_modelling.core.models.greybox import GreyboxModel
from quad_modelling.core.vehicle import load_vehicle
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



def test_motor_step_reaches_one_minus_one_over_e_of_its_steady_thrust_at_tau():
    tau, k, dt = 0.05, 2.0, 0.001  # A_m = -20 1/s, K = 2 N/s per unit
    pole, gain = discrete_motor(-1.0 / tau, k, dt)
    u = np.zeros(200)
    u[1:] = 1.0  # a unit step at t = dt; the thrust answers one sample later
    thrust = motor_thrusts(u, pole, gain)
    steady = k * tau  # -K / A_m = 0.1 N
    assert thrust[0] == 0.0 and thrust[1] == 0.0
    assert thrust[1 + 50] == pytest.approx(steady * (1 - np.exp(-1.0)), rel=1e-12)  # t - t_step = tau
    assert thrust[-1] == pytest.approx(steady * (1 - np.exp(-198 * dt / tau)), rel=1e-12)


def test_motor_filter_starts_in_steady_state_and_runs_along_any_axis():
    pole, gain = discrete_motor(-10.0, 3.0, 0.01)
    u = np.full((5, 30, 4), 2.0)
    thrust = motor_thrusts(u, pole, gain, axis=1)
    np.testing.assert_allclose(thrust, 2.0 * 3.0 / 10.0, rtol=1e-12)  # steady state K u / -A_m = 0.6 N
    one = np.random.default_rng(0).standard_normal((40, 4))
    np.testing.assert_allclose(motor_thrusts(one[None], pole, gain, axis=1)[0], motor_thrusts(one, pole, gain), rtol=1e-12)


def test_the_motor_filter_is_the_zero_order_hold_of_the_greybox_thrust_states():
    vehicle = load_vehicle("crazyflie21")
    model = GreyboxModel(vehicle)
    discrete = model.discretise(0.01)
    a_d, b_d = zero_order_hold(model.a, model.b, 0.01)
    np.testing.assert_array_equal(discrete.ad, a_d)
    pole, gain = discrete_motor(model.parameters.motor_a_m, model.parameters.input_gain, 0.01)
    assert pole == pytest.approx(discrete.ad[12, 12], rel=1e-12) and gain == pytest.approx(discrete.bd[12, 0], rel=1e-12)
