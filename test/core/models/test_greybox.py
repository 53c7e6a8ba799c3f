import numpy as np
import pytest

from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.models.greybox import (
    GreyboxModel,
    GreyboxParameters,
    GreyboxPredictor,
    continuous_matrices,
    lifted_horizons,
    linear_horizons,
)
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.variables import INDEX
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import ConfigError


@pytest.fixture(params=["linkquad", "crazyflie21"])
def vehicle(request):
    return load_vehicle(request.param)


def test_trimmed_model_at_rest_stays_at_rest(vehicle):
    model = GreyboxModel(vehicle).discretise(0.01)
    states, outputs = model.simulate(np.zeros(16), np.zeros((1000, 4)))
    assert np.all(states == 0.0) and np.all(outputs == 0.0)


def test_motor_steady_state_is_k_over_minus_a_m(vehicle):
    p = GreyboxParameters.from_vehicle(vehicle)
    assert np.isclose(p.input_gain, 2 * p.motor_b_m * np.sqrt(p.thrust_constant * p.mass * GRAVITY / 4))
    u = np.full((2000, 4), 1.0)
    thrusts = GreyboxModel(vehicle).discretise(0.01).motor_thrusts(u)
    np.testing.assert_allclose(thrusts[-1], -p.input_gain / p.motor_a_m, rtol=1e-9)


def step_response(vehicle, motor):
    u = np.zeros((50, 4))
    u[:, motor] = 1.0 if vehicle.name == "linkquad" else 1.0
    _, y = GreyboxModel(vehicle).discretise(0.01).simulate(np.zeros(16), u)
    return y[-1]


def test_linkquad_plus_step_signs():
    v = load_vehicle("linkquad")
    front, right, back, left = (step_response(v, i) for i in range(4))
    # more thrust: upwards (negative NED z acceleration) for every rotor
    for y in (front, right, back, left):
        assert y[INDEX["acc_z"]] < 0
    # front rotor pitches the nose up (theta > 0), which accelerates backwards (X'' = -g theta)
    assert front[INDEX["pitch_acc"]] > 0 and front[INDEX["pitch_rate"]] > 0 and front[INDEX["acc_x"]] < 0
    assert back[INDEX["pitch_acc"]] < 0 and back[INDEX["acc_x"]] > 0
    # right rotor rolls left wing down (phi < 0): Y'' = g phi < 0
    assert right[INDEX["roll_acc"]] < 0 and right[INDEX["acc_y"]] < 0
    assert left[INDEX["roll_acc"]] > 0 and left[INDEX["acc_y"]] > 0
    # yaw: rotors 1, 3 spin cw (yaw sign -1, thesis (-1)^i), rotors 2, 4 ccw
    assert front[INDEX["yaw_acc"]] < 0 and right[INDEX["yaw_acc"]] > 0
    assert back[INDEX["yaw_acc"]] < 0 and left[INDEX["yaw_acc"]] > 0
    # pure axes: the front rotor gives no roll, the right rotor no pitch
    assert abs(front[INDEX["roll_acc"]]) < 1e-9 * abs(front[INDEX["pitch_acc"]])
    assert abs(right[INDEX["pitch_acc"]]) < 1e-9 * abs(right[INDEX["roll_acc"]])


def test_thesis_yaw_form_matches_linkquad_config():
    v = load_vehicle("linkquad")
    np.testing.assert_array_equal(v.yaw_signs, [(-1) ** i for i in range(1, 5)])


def test_plus_torque_rows_are_thesis_equations():
    p = GreyboxParameters.from_vehicle(load_vehicle("linkquad"))
    t = p.torque_matrix()
    l = 0.215
    np.testing.assert_allclose(t[0], [0, -l, 0, l], atol=1e-15)  # tau_phi = l (T4 - T2)
    np.testing.assert_allclose(t[1], [l, 0, -l, 0], atol=1e-15)  # tau_theta = l (T1 - T3)


def test_x_geometry_step_signs():
    v = load_vehicle("crazyflie21")
    front_right = step_response(v, 0)
    back_left = step_response(v, 2)
    # front-right motor: nose up (pitch > 0) and right side up (roll < 0)
    assert front_right[INDEX["pitch_acc"]] > 0 and front_right[INDEX["roll_acc"]] < 0
    assert back_left[INDEX["pitch_acc"]] < 0 and back_left[INDEX["roll_acc"]] > 0
    a, *_ = continuous_matrices(GreyboxParameters.from_vehicle(v))
    d = 0.032527
    np.testing.assert_allclose(a[9, 12:16] * v.value("ixx"), -d * np.array([1, 1, -1, -1]))
    np.testing.assert_allclose(a[10, 12:16] * v.value("iyy"), d * np.array([1, -1, -1, 1]))


def test_collective_step_gives_free_vertical_acceleration(vehicle):
    p = GreyboxParameters.from_vehicle(vehicle)
    u = np.ones((3000, 4))
    _, y = GreyboxModel(vehicle).discretise(0.01).simulate(np.zeros(16), u)
    steady_thrust = -p.input_gain / p.motor_a_m
    assert np.isclose(y[-1, INDEX["acc_z"]], -4 * steady_thrust / p.mass, rtol=1e-6)
    assert abs(y[-1, INDEX["roll_acc"]]) < 1e-9 * abs(y[-1, INDEX["acc_z"]]) + 1e-12


def test_streaming_step_equals_simulate_and_euler_close_to_zoh():
    v = load_vehicle("linkquad")
    model = GreyboxModel(v)
    zoh = model.discretise(0.01, "zoh")
    rng = np.random.default_rng(1)
    u = rng.normal(0, 1e-6, (300, 4))
    x0 = np.zeros(16)
    states, outputs = zoh.simulate(x0, u)
    x = x0
    for k in range(300):
        x_next, y = zoh.step(x, u[k])
        np.testing.assert_allclose(y, outputs[k], rtol=1e-10, atol=1e-12)
        x = x_next
    _, euler_out = model.discretise(0.001, "euler").simulate(x0, np.repeat(u, 10, axis=0))
    np.testing.assert_allclose(euler_out[::10][:, INDEX["vel_z"]], outputs[:, INDEX["vel_z"]], rtol=0.05, atol=1e-4)


def test_lifted_horizons_give_the_recursion_s_outputs(vehicle):
    """y_h = G_x[h] x_0 + G_u[h] vec(u) is linear_horizons' recursion unrolled: the same outputs for random anchors
    and inputs (attitude trim zero), and the blocks of inputs after h do not enter y_h."""
    model = GreyboxModel(vehicle).discretise(0.01, "zoh")
    rng = np.random.default_rng(3)
    horizon = 50
    x0, u = rng.normal(0, 0.5, (4, 16)), rng.normal(0, 500.0, (4, horizon + 1, 4))
    expected = linear_horizons(model, x0, u, np.zeros((4, 2)))
    g_x, g_u = lifted_horizons(model, horizon)
    assert g_x.shape == (horizon + 1, 18, 16) and g_u.shape == (horizon + 1, 18, 4 * (horizon + 1))
    got = np.einsum("hvs,as->ahv", g_x, x0) + np.einsum("hvk,ak->ahv", g_u, u.reshape(4, -1))
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-9 * np.abs(expected).max())
    later_h, later_j = np.triu_indices(horizon + 1, 1)  # input rows j > h
    assert not g_u.reshape(horizon + 1, 18, horizon + 1, 4)[later_h, :, later_j].any()  # causal


def test_predictor_anchors_on_measurement_and_registry():
    v = load_vehicle("linkquad")
    n = 300
    t = np.arange(n) / 100.0
    z = np.zeros((n, 3))
    vel = np.zeros((n, 3))
    vel[:, 2] = 0.5  # steady descent at 0.5 m/s, hover thrust
    log = FlightLog(t=t, u=np.full((n, 4), 1.5e-3), acc_b=np.tile([0, 0, -GRAVITY], (n, 1)), gyro_b=z,
                    pos_n=np.column_stack([z[:, :2], 0.5 * t]), vel_n=vel, euler=z, meta=FlightMeta("linkquad", "t"))
    pred = GreyboxPredictor(v).predict_window(log, 20)
    # trimmed: descent velocity is the trim value, so the prediction stays at zero velocity deviation
    np.testing.assert_allclose(pred[:, INDEX["vel_z"]], 0.0, atol=1e-9)
    assert make_model("greybox:euler", v).name == "greybox:euler"
    with pytest.raises(ConfigError, match="unknown model"):
        make_model("nonsense", v)


def test_streaming_form_gives_the_offline_numbers():
    """The live node's start_window/push and the vectorised offline prediction agree."""
    from quad_modelling.core.models.streaming import predict_window_by_stream
    from quad_modelling.core.vehicle import load_vehicle
    from test.core.flightgen import linear_flight

    vehicle = load_vehicle("linkquad")
    window = linear_flight(vehicle, duration=10.0, seed=3)
    predictor = GreyboxPredictor(vehicle)
    streamed = predict_window_by_stream(predictor, window, 20)
    np.testing.assert_allclose(streamed, predictor.predict_absolute(window, 20), rtol=1e-9, atol=1e-9)
    assert np.isfinite(streamed).all() and not np.allclose(streamed[20:], streamed[19])


def _fly_open_loop(dynamics, params, du: np.ndarray, lag: bool) -> np.ndarray:
    """Truth simulator from hover, open loop, commands hover + du (N, 4) held for 10 ms each; (N, 3) [vel_z, roll_rate, roll]."""
    voltage = params.battery.reference_voltage
    u_hover = np.array(dynamics.hover_commands(voltage))
    s = dynamics.hover_state(3.0)
    out = []
    for row in du:
        command = dynamics.omega_command(u_hover + row, voltage)
        if not lag:
            s[13:17] = command  # without motor_lag the rotors jump to the ESC target (sim.apply_commands)
        out.append((s[5], s[10], 0.0))
        for _ in range(10):
            s, _ = dynamics.step(s, command, (0.0, 0.0, 0.0), 0.001)
    return np.array(out)


@pytest.mark.parametrize("motor_lag", [False, True])
def test_linear_model_matches_the_nonlinear_simulator_on_a_small_manoeuvre(motor_lag):
    """Effects off (and motor_lag on, the thesis's own motor model): a 10 us collective doublet
    and a 2 us roll doublet from hover; the linear model's Z velocity and roll rate follow the
    6-DoF simulator (TIC < 0.1)."""
    from quad_modelling.core.evaluation.metrics import tic
    from quad_modelling.core.sim.dynamics import QuadDynamics
    from quad_modelling.core.sim.params import sim_params_for

    params = sim_params_for("linkquad")
    dynamics = QuadDynamics(params, effects=("motor_lag",) if motor_lag else ())
    truth = params.vehicle
    if not motor_lag:  # rotors follow the ESC at once: a fast motor pole with the same steady gain -B_m/A_m
        a_m, b_m = truth.greybox_value("motor_a_m"), truth.greybox_value("motor_b_m")
        truth = truth.with_greybox({"motor_a_m": -1000.0, "motor_b_m": b_m * 1000.0 / -a_m}, "test")
    t = np.arange(300) * 0.01
    doublet = np.where(t < 0.5, 0.0, np.where(t < 1.0, 1.0, np.where(t < 1.5, -1.0, 0.0)))
    collective = np.repeat(10e-6 * doublet[:, None], 4, axis=1)
    measured = _fly_open_loop(dynamics, params, collective, motor_lag)
    _, y = GreyboxModel(truth).discretise(0.01).simulate(np.zeros(16), collective)
    assert tic(measured[:, 0], y[:, INDEX["vel_z"]]) < 0.1
    assert np.max(np.abs(measured[:, 0])) > 0.05  # the manoeuvre really moves the vehicle

    roll = np.zeros((150, 4))
    roll[:, 3], roll[:, 1] = 2e-6 * doublet[:150], -2e-6 * doublet[:150]  # left rotor up, right down: roll right
    measured = _fly_open_loop(dynamics, params, roll, motor_lag)
    _, y = GreyboxModel(truth).discretise(0.01).simulate(np.zeros(16), roll)
    assert tic(measured[:, 1], y[:, INDEX["roll_rate"]]) < 0.1
    assert measured[60, 1] > 0  # positive roll rate during the first half of the doublet
