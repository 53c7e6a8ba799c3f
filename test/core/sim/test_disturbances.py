"""The simulator's airframe disturbances (no catalogue effect): ``com_offset`` (CoM below the IMU) and
``bent_arm`` (motor 1 tilted about its arm); the noise-free IMU truth; logs without them unchanged."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quad_modelling.core.effect_names import SIM_DEFAULT_EFFECTS
from quad_modelling.core.sim import sensors as sim_sensors
from quad_modelling.core.sim.dynamics import QuadDynamics
from quad_modelling.core.sim.params import BentArmParams, ComOffsetParams, sim_params_for
from quad_modelling.core.sim.pilot import PHASE_FLYING
from quad_modelling.core.sim.simulate import run_simulation
from quad_modelling.core.physics.rigid_body import GRAVITY

VEHICLES = ("linkquad", "crazyflie21")
CALM = (0.0, 0.0, 0.0)


def wrench_change(vehicle, effects, base, state):
    """(force [N] in B, torque [N m]) that ``effects`` add to ``base`` at a level, unrotated ``state``."""
    params = sim_params_for(vehicle)
    on, off = QuadDynamics(params, effects), QuadDynamics(params, base)
    d_on, d_off = on.derivative(state, state[13:17], CALM), off.derivative(state, state[13:17], CALM)
    force = on.mass * (np.array(d_on[3:6]) - np.array(d_off[3:6]))
    torque = np.asarray(params.vehicle.inertia) * (np.array(d_on[10:13]) - np.array(d_off[10:13]))
    return force, torque


@pytest.fixture(scope="module")
def com_flight():
    """A 30 s LinkQuad flight with the CoM 4 cm under the IMU (four times the shipped guess, for a lever arm
    well above rounding; without rotor drag a vertical offset puts no moment on the vehicle)."""
    params = sim_params_for("linkquad").replace(com_offset=ComOffsetParams(depth=0.04))
    return run_simulation("linkquad", ("com_offset",), seed=1, duration=30.0, params=params)


# --------------------------------------------------------------------------- bent_arm


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_a_bent_arm_turns_rotor_1s_thrust_into_a_yaw_torque_T1_sin_gamma_l1(vehicle):
    params = sim_params_for(vehicle)
    gamma = params.bent_arm.tilt
    assert gamma == pytest.approx(math.radians(3.0))
    state = QuadDynamics(params, ()).hover_state(20.0)  # level, heading north, equal rotor speeds
    force, torque = wrench_change(vehicle, ("bent_arm",), (), state)
    x1, y1 = params.vehicle.motor_positions[0]
    arm = math.hypot(x1, y1)
    omega1 = state[13]
    t1 = params.vehicle.value("rotor_thrust_constant") * omega1**2
    q1 = params.vehicle.value("rotor_torque_constant") * omega1**2
    s1 = float(params.vehicle.yaw_signs[0])
    # the yaw torque: T_1 sin(gamma) l_1, less the (1 - cos gamma) share of rotor 1's drag torque it turns away from z
    assert torque[2] == pytest.approx(t1 * math.sin(gamma) * arm - s1 * q1 * (1.0 - math.cos(gamma)), rel=1e-9)
    assert torque[2] == pytest.approx(t1 * math.sin(gamma) * arm, rel=0.015)
    assert torque[2] > 0.0  # a positive tilt yaws the vehicle clockwise seen from above
    # the side force T_1 sin(gamma), horizontal in B and square to the arm; the lift drops by T_1 (1 - cos gamma)
    assert math.hypot(force[0], force[1]) == pytest.approx(t1 * math.sin(gamma), rel=1e-9)
    assert force[0] * x1 + force[1] * y1 == pytest.approx(0.0, abs=1e-12)
    assert force[2] == pytest.approx(t1 * (1.0 - math.cos(gamma)), rel=1e-9)
    # roll/pitch: the side force acts at the hub, z_r above the CG, plus the tilted drag torque's share
    hub = np.array([x1, y1, params.geometry.rotor_plane_z])
    expected = np.cross(hub, force) - s1 * q1 * force / t1
    np.testing.assert_allclose(torque[:2], expected[:2], rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_the_trim_holds_a_damaged_airframe_still(vehicle):
    """hover_commands cancel the bent arm's yaw torque with the rotor drag torques, and hover_tilt leans
    the body so the thrusts, side force included, lift straight up: zero acceleration, to rounding."""
    params = sim_params_for(vehicle)
    dynamics = QuadDynamics(params, ("motor_imbalance", "com_offset", "bent_arm"))
    v_ref = params.battery.reference_voltage
    roll, pitch = dynamics.hover_tilt()
    state = dynamics.hover_state(20.0)
    x, y, z, w = Rotation.from_euler("ZYX", [0.3, pitch, roll]).as_quat()
    state[6:10] = [w, x, y, z]
    state[13:17] = dynamics.omega_command(dynamics.hover_commands(v_ref), v_ref)
    derivative = dynamics.derivative(state, state[13:17], CALM)
    np.testing.assert_allclose(derivative[3:6], 0.0, atol=1e-12)
    np.testing.assert_allclose(derivative[10:13], 0.0, atol=1e-9)
    # the lean is the side force over the weight, away from it
    thrusts = dynamics.rotor_thrusts(state)
    side = thrusts[0] * math.sin(params.bent_arm.tilt)
    assert math.hypot(roll, pitch) == pytest.approx(side / (dynamics.mass * GRAVITY), rel=2e-3)
    # the rotors that yaw the other way (s_i = -1 with a positive bent-arm torque) carry more thrust
    signs = np.asarray(dynamics.yaw_signs)
    assert thrusts[signs < 0].sum() > thrusts[signs > 0].sum()
    assert QuadDynamics(params, ("motor_imbalance",)).hover_tilt() == (0.0, 0.0)


# --------------------------------------------------------------------------- com_offset


def test_com_offset_puts_the_hubs_feet_and_imu_d_z_above_the_com():
    params = sim_params_for("linkquad")
    depth = params.com_offset.depth
    assert depth == pytest.approx(0.01)
    low, nominal = QuadDynamics(params, ("com_offset", "rotor_drag")), QuadDynamics(params, ("rotor_drag",))
    np.testing.assert_array_equal(low.imu_position, [0.0, 0.0, -depth])
    np.testing.assert_array_equal(nominal.imu_position, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(low.rotor_positions[:, 2], nominal.rotor_positions[:, 2] - depth)
    assert low.rest_height == pytest.approx(nominal.rest_height - depth)
    # hovering: thrust along body z and gravity act on the CoM's vertical line, no torque whatever d_z
    state = low.hover_state(10.0)
    force, torque = wrench_change("linkquad", ("com_offset", "rotor_drag"), ("rotor_drag",), state)
    np.testing.assert_allclose(np.concatenate([force, torque]), 0.0, atol=1e-15)
    # flying north at 2 m/s: the same rotor drag F_x now acts d_z higher above the CoM, a nose-up
    # moment -d_z F_x more
    state[3] = 2.0
    force, torque = wrench_change("linkquad", ("com_offset", "rotor_drag"), ("rotor_drag",), state)
    f_x = -params.rotor_drag.horizontal * sum(state[13:17]) * 2.0
    np.testing.assert_allclose(force, 0.0, atol=1e-15)
    assert torque[1] == pytest.approx(-depth * f_x, rel=1e-9) and torque[1] > 0.0
    assert torque[0] == pytest.approx(0.0, abs=1e-15) and torque[2] == pytest.approx(0.0, abs=1e-15)


def test_lever_arm_terms_are_the_second_derivative_of_the_imu_position():
    """A body turning at omega + alpha t about its CoM carries a point at r along R(t) r; its acceleration
    (central difference of R(t) r, R = exp of the integrated rates to second order) is
    alpha x r + omega x (omega x r)."""
    omega, alpha, r = np.array([0.3, -0.2, 1.1]), np.array([2.0, -1.0, 0.5]), np.array([0.01, -0.02, -0.04])
    h = 1e-3

    def position(t):
        return Rotation.from_rotvec(omega * t + alpha * t * t / 2).apply(r)

    numeric = (position(h) - 2 * position(0.0) + position(-h)) / h**2
    np.testing.assert_allclose(sim_sensors.lever_arm_acceleration(alpha[None], omega[None], r)[0], numeric, atol=1e-6)


def test_an_imu_above_the_com_reads_the_lever_arm_terms():
    """Level, free of noise, CoM 4 cm below the IMU, rates (1, 0.5, 0) rad/s, angular acceleration
    (2, -1, 0) rad/s²: f_imu = f_cm + (-d qdot, d pdot, d (p² + q²)) = (0, 0, -g) + (0.04, 0.08, 0.05)."""
    params = sim_params_for("linkquad")
    quiet = dataclasses.replace(params.sensors, acc_noise=0.0, acc_bias=0.0, acc_drift=0.0,
                                gyro_noise=0.0, gyro_bias=0.0, gyro_drift=0.0)
    steps, n = 10, 20
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n * steps, 1))
    hovering = np.zeros((n * steps, 3))  # the CoM does not accelerate: f_cm = (0, 0, -g)
    rates, alpha = np.tile([1.0, 0.5, 0.0], (n * steps, 1)), np.tile([2.0, -1.0, 0.0], (n * steps, 1))
    imu = sim_sensors.imu(quat, hovering, rates, steps, 0.01, quiet, np.random.default_rng(0), alpha, (0.0, 0.0, -0.04))
    np.testing.assert_allclose(imu.specific_force_b, np.tile([0.0, 0.0, -GRAVITY], (n, 1)), atol=1e-15)
    np.testing.assert_allclose(imu.lever_arm_acc_b, np.tile([0.04, 0.08, 0.05], (n, 1)), atol=1e-15)
    np.testing.assert_allclose(imu.acc_b, np.tile([0.04, 0.08, 0.05 - GRAVITY], (n, 1)), atol=1e-14)
    np.testing.assert_array_equal(imu.acc_b, imu.noise_free_acc_b)
    np.testing.assert_array_equal(imu.gyro_b, rates[::steps])


def test_a_flight_with_the_com_low_logs_the_lever_arm_of_its_rates(com_flight):
    """Lever-arm truth of a flown flight against the rigid-body formula on the logged true rates
    (r = (0, 0, -d_z): x = -d_z (qdot + p r), y = d_z (pdot - q r)), and in the noise-free accelerometer."""
    truth = com_flight.truth
    depth = com_flight.params.com_offset.depth
    flying = truth["phase"] == PHASE_FLYING
    p, q, r = truth["rates_b"].T
    pdot, qdot = np.gradient(p, truth["t"]), np.gradient(q, truth["t"])
    formula = np.column_stack([-depth * (qdot + p * r), depth * (pdot - q * r)])
    lever = truth["imu_lever_arm_acc_b"][:, :2]
    for axis in range(2):
        rms = np.sqrt(np.mean(lever[flying, axis] ** 2))
        assert rms > 1.5e-3  # the 4 cm lever arm is seen: a few mm/s²
        # amplitude and shape; the rest (~15 %) is the difference between the period average of the
        # true angular acceleration and a central difference of period-averaged rates
        assert np.sqrt(np.mean(formula[flying, axis] ** 2)) == pytest.approx(rms, rel=0.1)
        assert np.corrcoef(lever[flying, axis], formula[flying, axis])[0, 1] > 0.98
    # the noise-free accelerometer minus the CoM's specific force and the lever arm is bias + random walk:
    # steps of sigma_d sqrt(dt), nothing faster
    sensors, dt = com_flight.params.sensors, 1.0 / com_flight.params.log_rate
    drift = truth["imu_noise_free_acc_b"] - truth["specific_force_b"] - truth["imu_lever_arm_acc_b"]
    assert np.diff(drift, axis=0).std() == pytest.approx(sensors.acc_drift * math.sqrt(dt), rel=0.1)
    drift = truth["imu_noise_free_gyro_b"] - truth["rates_b"]
    assert np.diff(drift, axis=0).std() == pytest.approx(sensors.gyro_drift * math.sqrt(dt), rel=0.1)


def test_the_logged_imu_is_the_noise_free_imu_plus_white_noise_of_the_configured_sigma(com_flight):
    log, truth, sensors = com_flight.log, com_flight.truth, com_flight.params.sensors
    for logged, clean, sigma in ((log.acc_b, "imu_noise_free_acc_b", sensors.acc_noise),
                                 (log.gyro_b, "imu_noise_free_gyro_b", sensors.gyro_noise)):
        white = logged - truth[clean]
        np.testing.assert_allclose(white.std(axis=0), sigma, rtol=0.1)
        np.testing.assert_allclose(white.mean(axis=0), 0.0, atol=4 * sigma / math.sqrt(len(white)))
        lag1 = np.mean(white[1:] * white[:-1], axis=0) / white.var(axis=0)
        assert np.all(np.abs(lag1) < 0.06)  # white: no sample-to-sample correlation


# --------------------------------------------------------------------------- flights


@pytest.fixture(scope="module")
def flights():
    """Flights by (vehicle, effects, seed, duration), each flown once."""
    cache = {}

    def fly(vehicle, effects, seed, duration):
        key = (vehicle, effects, seed, duration)
        if key not in cache:
            cache[key] = run_simulation(vehicle, effects, seed=seed, duration=duration)
        return cache[key]

    return fly


def script_errors(result):
    """(height error RMS [m], yaw error RMS [rad]) against the pilot's references while holding, largest
    horizontal distance from the origin [m], largest tilt [rad]."""
    truth, script = result.truth, result.script
    t = truth["t"]
    refs = script.references(t)
    held = (truth["phase"] == PHASE_FLYING) & (t > script.t_lift + script.climb_time + 1.0) & (t < script.land_start)
    height = truth["height"][held] - refs[held, 3]
    yaw = (truth["euler"][held, 2] - refs[held, 2] + np.pi) % (2 * np.pi) - np.pi
    return (np.sqrt(np.mean(height**2)), np.sqrt(np.mean(yaw**2)), np.abs(truth["pos_n"][:, :2]).max(),
            np.abs(truth["euler"][:, :2]).max())


@pytest.mark.parametrize(("vehicle", "base", "disturbances", "seed", "duration"), [
    # seed 3 turns with doublets at speed: with the CoM 4 cm low the hub moment of rotor drag rocks it to 30°
    ("linkquad", SIM_DEFAULT_EFFECTS, ("com_offset",), 3, 60.0),
    ("linkquad", (), ("bent_arm",), 1, 30.0),
    ("crazyflie21", SIM_DEFAULT_EFFECTS, ("com_offset", "bent_arm"), 1, 30.0),
])
def test_each_disturbance_flies_the_script_as_well_as_the_sound_airframe(vehicle, base, disturbances, seed, duration, flights):
    """The stabiliser's integrators (trimmed for the airframe) hold the bent arm's yaw torque, the pilot's
    trim its side force, and the shipped CoM depth leaves the rotor-drag hub moment flyable: the script is
    flown as closely as without the disturbance, and the flight lands."""
    result, sound = flights(vehicle, base + disturbances, seed, duration), flights(vehicle, base, seed, duration)
    truth, params = result.truth, result.params
    assert all(np.all(np.isfinite(v)) for v in truth.values())
    assert np.all(np.isfinite(result.log.acc_b)) and np.all(np.isfinite(result.log.u))
    height, yaw, distance, tilt = script_errors(result)
    height_0, yaw_0, distance_0, tilt_0 = script_errors(sound)
    assert height == pytest.approx(height_0, abs=0.005)
    assert yaw == pytest.approx(yaw_0, abs=np.deg2rad(1.0))
    assert distance < distance_0 + 0.1
    assert tilt < tilt_0 + np.deg2rad(3.0)
    # back on its feet, the pilot has cut the throttle on touchdown
    assert truth["height"][-1] < QuadDynamics(params, base + disturbances).rest_height + 0.01
    assert truth["phase"][-1] != PHASE_FLYING


def test_disturbances_of_zero_size_leave_the_log_bit_identical():
    """The disturbance code paths add exact zeros and draw no random numbers: switched on at zero size they
    fly the flight of the switch off, bit for bit (every seeded log without them is what it was)."""
    params = sim_params_for("linkquad")
    zero = params.replace(com_offset=ComOffsetParams(depth=0.0), bent_arm=BentArmParams(tilt=0.0))
    plain = run_simulation("linkquad", SIM_DEFAULT_EFFECTS, seed=4, duration=8.0, params=params)
    switched = run_simulation("linkquad", SIM_DEFAULT_EFFECTS + ("com_offset", "bent_arm"), seed=4, duration=8.0, params=zero)
    assert switched.log.allclose(plain.log, rtol=0.0, atol=0.0)
    for key, value in plain.truth.items():
        np.testing.assert_array_equal(switched.truth[key], value, err_msg=key)
