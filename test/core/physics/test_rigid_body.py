"""The rigid body of the one physics: allocation = wrench per newton, rotor drag and its moment, the ground-effect
factor, numpy = torch, and the truth simulator's rigid body equal to it where their forms coincide."""

from __future__ import annotations

import numpy as np
import pytest

from quad_modelling.core import frames
from quad_modelling.core.physics import aero, rigid_body, rotors
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.sim.dynamics import QuadDynamics
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle

CF = load_vehicle("crazyflie21")
P = PhysicsParameters.from_vehicle(CF)


def test_allocation_matrix_is_the_wrench_per_newton_of_thrust():
    rng = np.random.default_rng(0)
    rotor = rng.uniform(1000.0, 2500.0, (5, 4))
    bare = P.with_values(drag=(0.0, 0.0, 0.0), prop_inertia=0.0)
    force, torque = rigid_body.rotor_wrench(bare, rotor, np.zeros_like(rotor), np.zeros((5, 3)))
    thrust = rotors.rotor_thrusts(P.thrust_constant, rotor)
    wrench = thrust @ rigid_body.allocation_matrix(P.positions, P.spins, P.torque_constant / P.thrust_constant).T
    assert np.allclose(wrench[:, 0], -force[:, 2], rtol=1e-12)
    assert np.allclose(wrench[:, 1:], torque, rtol=1e-12, atol=1e-18)


def test_rotor_drag_opposes_the_airspeed_and_acts_at_the_rotor_plane():
    rotor = np.full((1, 4), 2000.0)
    vel_b = np.array([[1.0, -0.5, 0.2]])
    force, moment = aero.rotor_drag(P, rotor, vel_b)
    assert np.allclose(force, -8000.0 * np.asarray(P.drag) * vel_b)
    assert np.allclose(moment, np.cross([0.0, 0.0, P.drag_arm], force))


def test_ground_effect_factor_grows_near_the_ground_and_vanishes_far_from_it():
    h = np.array([0.05, 0.3, 100.0])
    k = aero.ground_effect_factor(h, 0.002, 0.01)
    assert np.allclose(k, 1.0 + 0.002 / (h + 0.01) ** 2)
    assert k[0] > k[1] > k[2] > 1.0 and k[2] < 1.0 + 1e-6


def test_level_hover_is_an_equilibrium_and_rotor_momentum_adds_the_propeller_gyroscopic_torque():
    hover = P.hover_rotor_speed(GRAVITY)
    rot = np.eye(3)[None]
    acc, ang = rigid_body.accelerations(P, np.zeros((1, 3)), rot, np.zeros((1, 3)), np.full((1, 4), hover), np.zeros((1, 4)))
    assert np.allclose(acc, 0.0, atol=1e-12) and np.allclose(ang, 0.0, atol=1e-9)
    rates = np.array([[0.3, -0.2, 0.1]])
    rotor = np.array([[1500.0, 1600.0, 1700.0, 1800.0]])
    h = rigid_body.rotor_momentum(P.prop_inertia, P.spins, rotor)
    assert np.allclose(h, [[0.0, 0.0, -P.prop_inertia * (rotor @ P.spins)[0]]])
    inertia = np.asarray(P.inertia)
    with_rotors = rigid_body.gyroscopic_torque(rates, inertia, h)
    assert np.allclose(with_rotors - rigid_body.gyroscopic_torque(rates, inertia), -np.cross(rates, h))


@pytest.mark.parametrize("cg_offset", [None, (0.004, -0.003)])
def test_numpy_and_torch_give_the_same_wrench_and_accelerations_in_float64(cg_offset):
    import torch

    from quad_modelling.core.training.physics_torch import TorchParameters

    rng = np.random.default_rng(2)
    rot = rigid_body.rotation_increment(np.tile(np.eye(3), (8, 1, 1)), rng.normal(size=(8, 3)), np.full(8, 0.5))
    args = (rng.normal(size=(8, 3)), rot, rng.normal(size=(8, 3)), rng.uniform(1000, 2500, (8, 4)), rng.normal(size=(8, 4)))
    p = P.with_values(cg_offset=cg_offset)
    acc, ang = rigid_body.accelerations(p, *args)
    acc_t, ang_t = rigid_body.accelerations(TorchParameters.from_params(p), *(torch.as_tensor(a) for a in args))
    if cg_offset is not None:
        assert not np.allclose(ang, rigid_body.accelerations(P, *args)[1], rtol=1e-3)  # the offset acts
    assert np.allclose(acc_t.numpy(), acc, rtol=1e-12, atol=1e-12) and np.allclose(ang_t.numpy(), ang, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("vehicle", ["crazyflie21", "linkquad"])
def test_the_simulators_rigid_body_equals_the_one_physics_where_their_forms_coincide(vehicle):
    """With motor lag and gyroscopic torques on and nothing else (no drag, ground effect, wind, imbalance), in the
    air, the simulator's derivative is the one physics' rigid body with the rotors' momentum: the same wrench,
    Newton-Euler and quaternion kinematics (its RK4 is its own, for speed)."""
    params = sim_params_for(vehicle)
    dyn = QuadDynamics(params, ("motor_lag", "gyroscopic"))
    v = params.vehicle
    esc = params.esc
    p = PhysicsParameters(mass=v.mass, inertia=tuple(float(x) for x in v.inertia), prop_inertia=v.value("prop_inertia"),
                          positions=v.motor_positions, spins=v.yaw_signs, speed_gain=esc.speed_gain, speed_offset=esc.speed_offset,
                          time_constant=params.motor_time_constant, delay=0.0, thrust_constant=v.value("rotor_thrust_constant"),
                          torque_constant=v.value("rotor_torque_constant"), drag=(0.0, 0.0, 0.0), drag_arm=0.0,
                          input_min=v.input_min, input_max=v.input_max)
    rng = np.random.default_rng(3)
    hover = v.hover_rotor_speed
    for _ in range(5):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        state = [0.0, 0.0, -20.0, *rng.normal(size=3), *q, *rng.normal(scale=0.5, size=3), *(hover * rng.uniform(0.8, 1.2, 4))]
        u = v.input_min + rng.uniform(0.4, 0.7, 4) * (v.input_max - v.input_min)
        omega_cmd = rotors.steady_rotor_speed(p, u)
        ds = dyn.derivative(state, list(omega_cmd), (0.0, 0.0, 0.0))
        rot = QuadDynamics.rotation(state)[None]
        rates = np.array([state[10:13]])
        rotor = np.array([state[13:17]])
        rotor_dot = rotors.rotor_acceleration(p, rotor, u[None])
        force_b, torque_b = rigid_body.rotor_wrench(p, rotor, rotor_dot, np.zeros((1, 3)))
        inertia = np.asarray(p.inertia)
        ang = (torque_b + rigid_body.gyroscopic_torque(rates, inertia, rigid_body.rotor_momentum(p.prop_inertia, p.spins, rotor))) / inertia
        acc, _ = rigid_body.accelerations(p, np.array([state[3:6]]), rot, rates, rotor, rotor_dot)
        assert np.allclose(ds[3:6], acc[0], rtol=1e-10, atol=1e-10)
        assert np.allclose(ds[10:13], ang[0], rtol=1e-10, atol=1e-8)
        assert np.allclose(ds[13:17], rotor_dot[0], rtol=1e-12)


@pytest.mark.parametrize("vehicle", ["crazyflie21", "linkquad"])
def test_the_simulators_true_allocation_and_idle_command_use_the_one_physics_where_no_rotor_is_bent(vehicle):
    """The simulator's own allocation (tilted thrust axes, for ``bent_arm``) is the one physics' allocation of its rotor
    positions when every axis points along -z, with the CG offset of ``motor_imbalance`` as well; the stabiliser's idle
    command is the one command map's inverse of the idle rotor speed."""
    from quad_modelling.core.sim.control import Stabiliser

    params = sim_params_for(vehicle)
    v = params.vehicle
    ratio = v.value("rotor_torque_constant") / v.value("rotor_thrust_constant")
    for effects in ((), ("motor_imbalance",)):
        dyn = QuadDynamics(params, effects)
        expected = rigid_body.allocation_matrix(dyn.rotor_positions[:, :2], v.yaw_signs, ratio)
        assert np.allclose(dyn.allocation(), expected, rtol=1e-12, atol=1e-15)
    bent = QuadDynamics(params, ("bent_arm",)).allocation()
    assert not np.allclose(bent, rigid_body.allocation_matrix(v.motor_positions, v.yaw_signs, ratio), rtol=1e-6)
    idle = Stabiliser(params).u_idle
    assert np.isclose(rotors.steady_rotor_speed(params.esc, idle), params.esc.idle_speed_fraction * v.hover_rotor_speed, rtol=1e-12)


def test_the_interval_rotor_speed_squared_is_the_mean_of_the_squared_speed_over_the_step():
    """Ω̄² = (1/Δt) ∫ Ω(t)² dt under the exact lag (trapezoid on 20 001 points), spinning up, spinning down, and
    τ_m = 0 (the command acts from the step's start); a series takes each row's step to the next."""
    p = P.with_values(time_constant=0.03)
    u = np.array([[0.2, 0.5, 0.8, 0.35]])
    rotor = np.array([[1500.0, 2600.0, 900.0, 2000.0]])
    dt = np.array([0.01])
    target = rotors.steady_rotor_speed(p, u)
    t = np.linspace(0.0, 0.01, 20001)
    omega = target + (rotor - target) * np.exp(-t[:, None] / 0.03)
    mean_square = np.trapezoid(omega**2, t, axis=0) / 0.01
    assert np.allclose(rotors.interval_rotor_speed(p, rotor, u, dt)[0] ** 2, mean_square, rtol=1e-8)
    assert np.array_equal(rotors.interval_rotor_speed(p.with_values(time_constant=0.0), rotor, u, dt), target)
    times = np.array([0.0, 0.01, 0.03])
    commands = np.vstack([u, u[:, ::-1], u])
    speeds = rotors.rotor_speeds(p, commands, times)
    series = rotors.interval_rotor_speeds(p, speeds, commands, times)
    assert np.allclose(series[1], rotors.interval_rotor_speed(p, speeds[1:2], commands[1:2], np.array([0.02]))[0], rtol=1e-12)
    assert np.array_equal(series[2], speeds[2])


@pytest.mark.parametrize("lag", [True, False])
def test_the_model_step_follows_the_simulator_over_50_samples_where_their_forms_coincide(lag):
    """The LinkQuad in the air under random commands held for 10 ms, 50 samples: the simulator (RK4 at 1 kHz, body
    gyroscopic torque, motor lag or rotors that jump with their reaction impulse) and the model's step with the true
    constants end within 1e-3 rad/s and 1e-2 m/s of each other (measured 7e-4 / 6e-3 with lag, 3e-4 / 7e-3 without:
    the model's own O(Δt²) step; the rates move 0.7-2.9 rad/s). The step integrating the start-of-step rotor speed
    instead ended 0.11 / 0.07 and 0.29 / 0.25 off (a command acting a sample late)."""
    params = sim_params_for("linkquad")
    dyn = QuadDynamics(params, ("motor_lag",) if lag else ())
    v, esc = params.vehicle, params.esc
    p = PhysicsParameters(mass=v.mass, inertia=tuple(float(x) for x in v.inertia), prop_inertia=v.value("prop_inertia"),
                          positions=v.motor_positions, spins=v.yaw_signs, speed_gain=esc.speed_gain, speed_offset=esc.speed_offset,
                          time_constant=params.motor_time_constant if lag else 0.0, delay=0.0,
                          thrust_constant=v.value("rotor_thrust_constant"), torque_constant=v.value("rotor_torque_constant"),
                          drag=(0.0, 0.0, 0.0), drag_arm=0.0, input_min=v.input_min, input_max=v.input_max)
    rng = np.random.default_rng(7)
    hover_u = dyn.hover_commands(params.battery.reference_voltage)
    commands = np.array(hover_u) * (1.0 + rng.uniform(-0.04, 0.04, (50, 4)))
    sim = dyn.hover_state(20.0)
    sim[10:13] = [0.3, -0.2, 0.1]
    sim[13:17] = list(rotors.steady_rotor_speed(p, commands[0]))
    state = rigid_body.PhysicsState(np.array([sim[0:3]]), np.array([sim[3:6]]), QuadDynamics.rotation(sim)[None], np.array([sim[10:13]]),
                                    np.array([sim[13:17]]), np.zeros(1))
    zero = np.zeros((1, 3))
    for u in commands:
        target = list(rotors.steady_rotor_speed(p, u))
        if not lag:  # the simulator's apply_commands: rotors jump, the body takes the reaction impulse
            sim[12] += dyn.prop_inertia / float(dyn.inertia[2]) * sum(s * (n - o) for s, n, o in zip(dyn.yaw_signs, target, sim[13:17]))
            sim[13:17] = target
        for _ in range(10):
            sim, _ = dyn.step(sim, target, (0.0, 0.0, 0.0), 0.001)
        state = rigid_body.step(p, state, u[None], np.array([0.01]), zero, zero)
    assert np.max(np.abs(state.rates[0] - sim[10:13])) < 1e-3
    assert np.max(np.abs(state.vel_n[0] - sim[3:6])) < 1e-2
    assert np.allclose(state.rotor[0], sim[13:17], rtol=1e-9)


def test_a_cg_offset_in_a_level_hover_rolls_and_pitches_by_the_weight_times_the_offset():
    """Four equal thrusts carrying the weight m g, the CG at c = (4, -3) mm: about the CG the thrust acts at the
    geometric centre, -c from it, so the moment is (-c) x (0, 0, -m g) = (c_y m g, -c_x m g, 0): the CG 3 mm left
    (c_y < 0) rolls left (p' < 0), 4 mm forward (c_x > 0) pitches the nose down (q' < 0). No force changes."""
    hover = P.hover_rotor_speed(GRAVITY)
    args = (np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), np.full((1, 4), hover), np.zeros((1, 4)))
    offset = P.with_values(cg_offset=(0.004, -0.003))
    acc, ang = rigid_body.accelerations(offset, *args)
    weight = P.mass * GRAVITY
    assert np.allclose(ang[0], [-0.003 * weight / P.inertia[0], -0.004 * weight / P.inertia[1], 0.0], rtol=1e-9, atol=1e-12)
    assert np.allclose(acc, rigid_body.accelerations(P, *args)[0], atol=1e-12)
    assert np.allclose(rigid_body.cg_offset_moment((0.01, 0.02), np.array([[1.0, 2.0, -3.0]])),
                       -np.cross([0.01, 0.02, 0.0], [1.0, 2.0, -3.0]), rtol=1e-12)


@pytest.mark.parametrize("vehicle", ["crazyflie21", "linkquad"])
def test_the_simulators_cg_offset_gives_the_one_physics_cg_offset_moment(vehicle):
    """With ``motor_imbalance`` on, the simulator's rotors sit at r_i - c about its CG (its gains act on the command
    path, not in the derivative): its angular acceleration equals the one physics' with the same CG offset, and not
    without one (the sign and size of cg_offset_moment checked against the truth's own form)."""
    params = sim_params_for(vehicle)
    dyn = QuadDynamics(params, ("motor_lag", "motor_imbalance"))
    v = params.vehicle
    p = PhysicsParameters(mass=v.mass, inertia=tuple(float(x) for x in v.inertia), prop_inertia=v.value("prop_inertia"),
                          positions=v.motor_positions, spins=v.yaw_signs, speed_gain=params.esc.speed_gain,
                          speed_offset=params.esc.speed_offset, time_constant=params.motor_time_constant, delay=0.0,
                          thrust_constant=v.value("rotor_thrust_constant"), torque_constant=v.value("rotor_torque_constant"),
                          drag=(0.0, 0.0, 0.0), drag_arm=0.0, input_min=v.input_min, input_max=v.input_max,
                          cg_offset=params.imbalance.cg_offset)
    rng = np.random.default_rng(4)
    hover = v.hover_rotor_speed
    state = [0.0, 0.0, -20.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, *(hover * rng.uniform(0.9, 1.1, 4))]
    rotor = np.array([state[13:17]])
    ds = dyn.derivative(state, list(rotor[0]), (0.0, 0.0, 0.0))
    _, ang = rigid_body.accelerations(p, np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), rotor, np.zeros((1, 4)))
    _, without = rigid_body.accelerations(p.with_values(cg_offset=None), np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), rotor,
                                          np.zeros((1, 4)))
    assert np.allclose(ds[10:13], ang[0], rtol=1e-10, atol=1e-9)
    assert np.abs(ds[10:12] - without[0, :2]).min() > 0.1  # the offset's moment is what matched [rad/s²]


def test_a_step_of_zero_seconds_returns_the_state_unchanged():
    """rigid_body.step with dt = 0 gives back the state, finite (not 0/0 in the rotor terms), in the numpy form."""
    v = load_vehicle("crazyflie21")
    p = PhysicsParameters.from_vehicle(v)
    rot = np.eye(3)[None]
    state = rigid_body.PhysicsState(np.array([[0.1, 0.2, -1.0]]), np.array([[0.5, -0.2, 0.1]]), rot, np.array([[0.7, -0.4, 0.2]]),
                                    np.full((1, 4), 1500.0), np.zeros(1))
    after = rigid_body.step(p, state, np.full((1, 4), 40000.0), np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))
    for name in ("pos_n", "vel_n", "rot", "rates", "rotor"):
        assert np.array_equal(getattr(after, name), getattr(state, name)), name


def test_without_motor_lag_the_derivative_answers_the_commands_as_the_step_does():
    """τ_m = 0: the rotor speeds are no state, the forces act at the commands' steady speeds. The derivative read the
    rotor-speed state (whose dΩ/dt is 0 without lag), so an MPC on the exported f(x, u) had no control authority;
    now f's acceleration is the step's over a short step, from any rotor entries, and differs between commands."""
    p = P.with_values(time_constant=0.0)
    state = rigid_body.PhysicsState(np.zeros((2, 3)), np.zeros((2, 3)), np.repeat(np.eye(3)[None], 2, axis=0),
                                    np.zeros((2, 3)), np.zeros((2, 4)), np.zeros(2))  # stale rotor entries: 0 rad/s
    u = np.array([[40000.0] * 4, [50000.0, 50000.0, 40000.0, 40000.0]])
    _, acc, _, ang, rotor_dot = rigid_body.derivative(p, state, u, np.zeros((2, 3)), np.zeros((2, 3)))
    dt = 1e-6
    after = rigid_body.step(p, state, u, np.full(2, dt), np.zeros((2, 3)), np.zeros((2, 3)))
    assert np.allclose(acc, (after.vel_n - state.vel_n) / dt, rtol=1e-6, atol=1e-6)
    assert np.allclose(ang, (after.rates - state.rates) / dt, rtol=1e-6, atol=1e-6)
    assert acc[0, 2] < 0.0 and acc[1, 2] < acc[0, 2] - 1.0 and abs(ang[1]).max() > 1.0  # net thrust up; more of it; a torque
    assert np.array_equal(rotor_dot, np.zeros((2, 4)))


def test_continued_yaw_is_continue_yaw_row_by_row():
    """continued_yaw (the carried forecast's yaw over its rollout, summed as wrapped steps) equals continue_yaw applied
    row by row to rounding, across ±π, several whole turns from yaw0 and fast yaw steps (up to 2.5 rad a row)."""
    rng = np.random.default_rng(21)
    for _ in range(200):
        rows = int(rng.integers(1, 60))
        euler = np.column_stack([rng.normal(0.0, 0.3, rows), rng.normal(0.0, 0.3, rows), np.cumsum(rng.uniform(-2.5, 2.5, rows))])
        rot = frames.euler_ned_to_matrix(euler)
        yaw0 = euler[0, 2] + 2.0 * np.pi * int(rng.integers(-5, 6))
        expected = [yaw0]
        for k in range(1, rows):
            expected.append(float(rigid_body.continue_yaw(expected[-1], rot[k])))
        got = rigid_body.continued_yaw(yaw0, rot)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got, euler[:, 2] - euler[0, 2] + yaw0, rtol=0, atol=1e-9)
