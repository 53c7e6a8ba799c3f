"""The rotors of the one physics: command map and its inverse, thrust and its inverse, hover, lag, battery."""

from __future__ import annotations

import numpy as np

from quad_modelling.core.models.greybox import GreyboxParameters
from quad_modelling.core.physics import rotors
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle

CF = load_vehicle("crazyflie21")
P = PhysicsParameters.from_vehicle(CF)


def test_command_map_and_its_inverse_round_trip_and_clip_at_zero_speed():
    u = np.array([0.0, 1000.0, 30000.0, 65535.0])
    speed = rotors.steady_rotor_speed(P, u)
    assert np.allclose(speed, P.speed_gain * u + P.speed_offset)
    assert np.allclose(rotors.command_for_rotor_speed(speed, P.speed_gain, P.speed_offset), u)
    below = -2.0 * P.speed_offset / P.speed_gain  # a command whose map is negative
    assert rotors.steady_rotor_speed(P.with_values(speed_offset=-P.speed_offset), np.array([below / 4]))[0] == 0.0


def test_four_hover_thrusts_carry_the_weight_and_the_thrust_inverse_returns_the_speed():
    hover = rotors.hover_rotor_speed(P.mass, P.thrust_constant, GRAVITY)
    thrust = rotors.rotor_thrusts(P.thrust_constant, np.full(4, hover))
    assert np.isclose(thrust.sum(), P.mass * GRAVITY, rtol=1e-12)
    assert np.isclose(rotors.rotor_speed_for_thrust(P.thrust_constant, thrust[0]), hover, rtol=1e-12)
    assert np.isclose(P.hover_rotor_speed(GRAVITY), hover)
    assert np.isclose(rotors.steady_rotor_speed(P, P.hover_command(GRAVITY)), hover)
    assert np.allclose(rotors.rotor_yaw_torques(P.torque_constant, np.full(4, hover)), P.torque_constant * hover**2)


def test_the_greybox_constants_are_derived_from_the_physical_ones_without_a_greybox_section():
    """A_m = -1/tau_m, B_m = k_u/tau_m (the rotor lag linearised), a = k_f, d = k_m; a greybox section wins."""
    assert CF.greybox == {}
    g = GreyboxParameters.from_vehicle(CF)
    tau, k_u = CF.value("rotor_time_constant"), CF.value("rotor_speed_gain")
    assert (g.motor_a_m, g.motor_b_m) == (-1.0 / tau, k_u / tau) == rotors.linear_motor(tau, k_u)
    assert (g.thrust_constant, g.torque_constant) == (CF.value("rotor_thrust_constant"), CF.value("rotor_torque_constant"))
    assert (g.ixx, g.iyy, g.izz) == tuple(CF.inertia)  # the airframe's inertias
    assert CF.greybox_constants()["motor_b_m"].source == "derived: rotor_speed_gain/rotor_time_constant"
    linkquad = load_vehicle("linkquad")  # the thesis reproduction: Table 3-1's own identified values
    t = GreyboxParameters.from_vehicle(linkquad)
    assert (t.motor_a_m, t.motor_b_m, t.thrust_constant, t.torque_constant) == (-9.56, 8.49e7, 1.59e-7, 2.93e-9)
    assert {c.status for c in linkquad.greybox.values()} == {"effective"}
    assert linkquad.value("rotor_thrust_constant") == 1.0e-5  # the physical one, a different value named for what it is


def test_the_greybox_derives_its_thesis_constants_from_the_same_rotor_formulas():
    """Eq 3-7: K = 2 B_m sqrt(a m g / 4) = B_m ∂T/∂Ω at Ω0 = sqrt(m g / (4 a))."""
    g = GreyboxParameters.from_vehicle(CF)
    a, m = g.thrust_constant, g.mass
    assert np.isclose(g.hover_rotor_speed, np.sqrt(m * GRAVITY / (4 * a)), rtol=1e-14)
    assert np.isclose(g.input_gain, 2 * g.motor_b_m * np.sqrt(a * m * GRAVITY / 4), rtol=1e-14)
    assert np.isclose(CF.hover_rotor_speed, g.hover_rotor_speed, rtol=1e-14)
    pos = np.asarray(g.motor_positions)
    assert np.allclose(g.torque_matrix(), np.vstack([-pos[:, 1], pos[:, 0], g.torque_constant / a * np.asarray(g.yaw_signs)]))


def test_rotor_lag_step_is_the_exact_first_order_response_and_the_series_form_agrees():
    tau = P.time_constant
    u_step = np.full((1, 4), 40000.0)
    start = rotors.steady_rotor_speed(P, np.full((1, 4), 20000.0))
    target = rotors.steady_rotor_speed(P, u_step)
    after = rotors.rotor_step(P, start, u_step, 0.03)
    assert np.allclose(after, target + (start - target) * np.exp(-0.03 / tau), rtol=1e-14)
    assert np.allclose(rotors.rotor_acceleration(P, start, u_step), (target - start) / tau)
    t = np.array([0.0, 0.01, 0.025, 0.04])
    u = np.vstack([np.full(4, 20000.0), u_step[0], u_step[0], u_step[0]])
    series = rotors.rotor_speeds(P, u, t)
    step_by_step = [start[0]]
    for k in range(3):
        step_by_step.append(rotors.rotor_step(P, step_by_step[-1], u[k], t[k + 1] - t[k]))
    assert np.allclose(series, np.array(step_by_step), rtol=1e-12)


def test_delayed_commands_table_and_live_lookup_agree():
    p = P.with_values(delay=0.02)
    t = np.arange(10) * 0.01
    u = np.arange(40.0).reshape(10, 4)
    table = rotors.delayed_commands(p, u, t)
    live = [rotors.delayed_command_at(p, list(t[: k + 1]), list(u[: k + 1]), t[k]) for k in range(10)]
    assert np.array_equal(table, np.array(live))
    assert np.array_equal(table[5], u[3])


def test_delayed_commands_on_irregular_stamps_equal_the_live_lookup_row_by_row():
    """Jittered stamps (some within STAMP_TOLERANCE_S of t - δ), repeated stamps and delays between, on and off the
    samples: the table's rows are the live lookup's, bit for bit."""
    rng = np.random.default_rng(40)
    for trial in range(300):
        n = int(rng.integers(2, 40))
        t = np.sort(np.arange(n) * 0.01 + rng.choice([0.0, 3e-8, 2e-7], n) * rng.choice([-1.0, 1.0], n))
        if trial % 3 == 0:
            t[1:] = np.where(rng.random(n - 1) < 0.2, t[:-1], t[1:])  # repeated stamps
        p = P.with_values(delay=float(rng.choice([0.01, 0.02, 0.015, 0.0123, 0.5])))
        u = rng.normal(size=(n, 4))
        table = rotors.delayed_commands(p, u, t)
        live = [rotors.delayed_command_at(p, t[: k + 1].tolist(), list(u[: k + 1]), float(t[k])) for k in range(n)]
        np.testing.assert_array_equal(table, np.array(live), err_msg=f"trial {trial}")


def test_battery_factor_is_one_at_the_reference_voltage_and_linear_in_the_voltage():
    assert rotors.battery_speed_factor(3.9, 3.9, 0.2) == 1.0
    assert np.isclose(rotors.battery_speed_factor(3.7, 3.9, 0.2), 0.96)


def test_a_delay_between_samples_interpolates_the_commands_and_live_equals_offline():
    """δ = 1.5 sample periods: the rotors answer the mean of the commands 1 and 2 rows back (a zero-order-held command
    averaged over the step); the live lookup gives the same rows; δ a whole number of periods picks one row."""
    from quad_modelling.core.physics.rotors import delayed_command_at, delayed_commands

    class P:
        delay = 0.015

    t = np.arange(20) * 0.01
    u = np.column_stack([np.arange(20.0) ** 2 + i for i in range(4)])
    offline = delayed_commands(P, u, t)
    np.testing.assert_allclose(offline[5], 0.5 * (u[3] + u[4]))
    for k in range(len(t)):
        np.testing.assert_allclose(delayed_command_at(P, list(t[: k + 1]), list(u[: k + 1]), t[k]), offline[k])
    P.delay = 0.02
    np.testing.assert_allclose(delayed_commands(P, u, t)[5], u[3])
