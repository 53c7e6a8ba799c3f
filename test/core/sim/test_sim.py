"""Physics of the truth simulator: hover, free fall, yaw, stability, each effect's direction, determinism."""

import dataclasses
import math

import numpy as np
import pytest

from quad_modelling.core.effect_names import SIM_DEFAULT_EFFECTS as DEFAULT_EFFECTS
from quad_modelling.core.effect_names import SIM_EFFECTS, SIMULATOR, parse_effect_names
from quad_modelling.core.sim.dynamics import QuadDynamics
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.core.sim.pilot import PHASE_FLYING, TURN_RAMP, make_pilot_script
from quad_modelling.core.sim.simulate import (
    open_circuit_voltage,
    run_simulation,
    simulate,
)
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import ConfigError
from quad_modelling.io.matlog import read_matlog, write_matlog

VEHICLES = ("linkquad", "crazyflie21")
NO_WIND = tuple(e for e in SIM_EFFECTS if e != "wind")


def fly_open_loop(dynamics, state, seconds, omega_cmd=None, wind=(0.0, 0.0, 0.0), dt=1e-3):
    state = list(state)
    omega_cmd = list(state[13:17]) if omega_cmd is None else omega_cmd
    for _ in range(int(round(seconds / dt))):
        state, _ = dynamics.step(state, omega_cmd, wind, dt)
    return state


@pytest.fixture(scope="module")
def default_flight():
    """The default: a 220 s LinkQuad flight with the realistic effect mix."""
    return run_simulation("linkquad", DEFAULT_EFFECTS, seed=0, duration=220.0)


@pytest.fixture(scope="module")
def plain_flight():
    """A 40 s LinkQuad flight with no effects."""
    return run_simulation("linkquad", (), seed=5, duration=40.0)


# --------------------------------------------------------------------------- parameters


def test_linkquad_physical_constants_give_a_realistic_hover_and_keep_the_thesis_products():
    params = sim_params_for("linkquad")
    v = params.vehicle
    assert params.adjustments == {} and v.greybox == {}  # flown as the vehicle file's physical constants
    assert v.hover_rotor_speed == pytest.approx(542.5, abs=1.0)  # Table 3-1's a gives 4302 rad/s
    thesis = load_vehicle("linkquad").greybox_constants()  # Table 3-1's own identified values
    assert thesis["thrust_constant"].value == 1.59e-7 and thesis["thrust_constant"].source.startswith("thesis Table 3-1")
    # d/a and the thesis thrust gain K = 2 B_m sqrt(a m g / 4) are preserved by k_f, k_m, k_u/tau_m
    assert v.value("rotor_torque_constant") / v.value("rotor_thrust_constant") == pytest.approx(2.93e-9 / 1.59e-7, rel=1e-3)
    derived = v.greybox_constants()
    assert derived["motor_a_m"].value == -9.56 and derived["motor_b_m"].value == 1.0705e7
    gain = 2 * derived["motor_b_m"].value * math.sqrt(v.value("rotor_thrust_constant") * v.hover_thrust_per_rotor)
    gain_thesis = 2 * 8.49e7 * math.sqrt(1.59e-7 * v.hover_thrust_per_rotor)
    assert gain == pytest.approx(gain_thesis, rel=1e-3)
    # the hover command lies inside the ESC pulse range, near mid-stick
    u_hover = QuadDynamics(params).hover_commands(params.battery.reference_voltage)
    assert all(v.input_min < u < v.input_max for u in u_hover)
    assert u_hover[0] == pytest.approx(1.484e-3, abs=5e-6)


def test_crazyflie_hovers_at_42_percent_pwm_on_the_files_speed_map():
    params = sim_params_for("crazyflie21")
    u_hover = QuadDynamics(params).hover_commands(params.battery.reference_voltage)
    # Landry's k_f on Foerster's map: sqrt(m g / 4 k_f) = 1516 rad/s at (1516 - 381) / 0.0408 = 27850 PWM
    assert all(u == pytest.approx(27850, rel=2e-3) for u in u_hover)
    # the simulated world keeps Landry 2015's rotor constants, named against the vehicle file's (Foerster 2015)
    kf = params.adjustments["rotor_thrust_constant"]
    assert (kf["config"], kf["used"]) == (1.788e-8, 2.88e-8) and kf["reason"].startswith("Landry 2015")
    # and the measured speed map the file gives (identify holds it): the ESC answers it exactly
    assert set(params.adjustments) == {"rotor_thrust_constant", "rotor_torque_constant"}
    assert params.esc.speed_gain == params.vehicle.value("rotor_speed_gain") == 0.04076521
    assert params.esc.speed_offset == pytest.approx(params.vehicle.value("rotor_speed_offset"), rel=1e-12)


def test_the_crazyflies_rotors_stand_still_until_armed_though_its_speed_map_reaches_381_rad_s_at_pwm_0():
    """The vehicle file's speed map (a fit over the spinning range) gives 381 rad/s at PWM 0: the simulator's rotors stand
    still at the input range's minimum (motors off), spin at the armed idle (0.3 x hover) and hover at 1516 rad/s."""
    from quad_modelling.core.sim.simulate import run_simulation

    run = run_simulation("crazyflie21", (), seed=3, duration=14.0)
    t, omega = run.log.t, run.truth["omega"]
    assert np.all(omega[t < 0.9] == 0.0)  # off until armed at 1 s (the log held 381 rad/s here)
    idle = (t > 1.2) & (t < 1.9)
    assert np.allclose(omega[idle], 0.3 * 1516.0, rtol=0.01)
    assert QuadDynamics(sim_params_for("crazyflie21")).omega_command([0.0, 1.0, 27850.0, 65535.0], 3.8)[:2] == [0.0, pytest.approx(380.88, abs=0.1)]


def test_the_fed_forward_height_rate_and_acceleration_are_the_derivatives_of_the_smooth_references():
    """The Crazyflie's script (low passes as smooth steps): the stabiliser's fed-forward rate and acceleration equal the
    numerical derivatives of the height reference without the throttle manoeuvres (its stick steps are not fed forward)."""
    from quad_modelling.core.sim.pilot import make_pilot_script

    params = sim_params_for("crazyflie21")
    script = make_pilot_script(params, 90.0, np.random.default_rng(11))
    assert any(m.shape == "smooth_step" for m in script.manoeuvres)
    smooth = dataclasses.replace(script, manoeuvres=tuple(m for m in script.manoeuvres if m.channel != "throttle"))
    t = np.arange(0.0, 90.0, 1e-3)
    height = smooth.references(t)[:, 3]
    rate, acceleration = script.height_feedforward(t)
    inner = slice(1, -1)
    assert np.max(np.abs(np.gradient(height, t)[inner] - rate[inner])) < 2e-3  # m/s; the ramps' kinks are 1 ms wide
    # the acceleration steps where a cosine ramp starts or ends: off by up to half the step at those few samples only
    assert np.percentile(np.abs(np.gradient(rate, t)[inner] - acceleration[inner]), 99.9) < 1e-3  # m/s²
    assert np.max(rate) > 0.1 and np.min(rate) < -0.1


def test_effect_names_parse():
    assert parse_effect_names("none", SIMULATOR) == ()
    assert parse_effect_names("all", SIMULATOR) == SIM_EFFECTS
    assert parse_effect_names(None, SIMULATOR) == DEFAULT_EFFECTS and "wind" not in DEFAULT_EFFECTS
    assert parse_effect_names("wind,battery", SIMULATOR) == ("battery", "wind")
    with pytest.raises(ConfigError, match="unknown simulator effect 'drag'"):
        parse_effect_names("drag", SIMULATOR)


# --------------------------------------------------------------------------- rigid body


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_hover_needs_total_thrust_mg(vehicle):
    dynamics = QuadDynamics(sim_params_for(vehicle), ())
    state = dynamics.hover_state(5.0)
    assert dynamics.rotor_thrusts(state).sum() == pytest.approx(dynamics.mass * GRAVITY, rel=1e-12)
    derivative = dynamics.derivative(state, state[13:17], (0.0, 0.0, 0.0))
    np.testing.assert_allclose(derivative[3:6], 0.0, atol=1e-12)
    np.testing.assert_allclose(derivative[10:13], 0.0, atol=1e-9)
    later = fly_open_loop(dynamics, state, 2.0)
    np.testing.assert_allclose(later[:6], state[:6], atol=1e-9)
    # one rotor speed 1 % low: the vehicle sinks at (1 - 0.99^2)/4 g
    slow = list(state)
    slow[13:17] = [0.99 * w for w in state[13:17]]
    az = dynamics.derivative(slow, slow[13:17], (0.0, 0.0, 0.0))[5]
    assert az == pytest.approx(GRAVITY * (1 - 0.99**2), rel=1e-9)


def test_closed_loop_hover_carries_the_weight(plain_flight):
    truth = plain_flight.truth
    params = plain_flight.params
    flying = (truth["phase"] == PHASE_FLYING) & (truth["t"] > 8.0) & (truth["t"] < plain_flight.script.land_start)
    total = truth["thrust"][flying].sum(axis=1)
    mg = params.vehicle.mass * GRAVITY
    # the mean vertical acceleration over a long hover is zero, so the mean thrust is m g (tilts < 10 deg)
    assert total.mean() == pytest.approx(mg, rel=0.01)
    # and the accelerometer reads about -g on z in FRD
    specific = truth["specific_force_b"][flying]
    assert specific[:, 2].mean() == pytest.approx(-GRAVITY, rel=0.003)  # T = m g / cos(tilt)
    assert abs(specific[:, 0].mean()) < 0.02 and abs(specific[:, 1].mean()) < 0.02
    acc = plain_flight.log.acc_b[flying]  # plus the sensor's bias (sigma 0.05 m/s²) and drift
    assert acc[:, 2].mean() == pytest.approx(-GRAVITY, abs=0.25)


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_free_fall_with_motors_off_accelerates_at_g(vehicle):
    dynamics = QuadDynamics(sim_params_for(vehicle), NO_WIND)  # drag, ground effect etc. vanish with the rotors stopped
    state = dynamics.hover_state(50.0)
    state[13:17] = [0.0] * 4
    later = fly_open_loop(dynamics, state, 1.5, omega_cmd=[0.0] * 4)
    assert later[5] == pytest.approx(GRAVITY * 1.5, rel=1e-9)
    assert later[2] - state[2] == pytest.approx(0.5 * GRAVITY * 1.5**2, rel=1e-9)
    np.testing.assert_allclose(later[6:10], [1.0, 0.0, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("vehicle", VEHICLES)
def test_pure_yaw_torque_spins_without_tilting(vehicle):
    params = sim_params_for(vehicle)
    dynamics = QuadDynamics(params, ("gyroscopic",))
    state = dynamics.hover_state(20.0)
    hover = state[13]
    # counter-clockwise rotors (yaw sign +1) faster, clockwise slower, same total thrust
    fast, slow = hover * math.sqrt(1.05), hover * math.sqrt(0.95)
    state[13:17] = [fast if s > 0 else slow for s in dynamics.yaw_signs]
    torque = dynamics.torque_constant * sum(s * w * w for s, w in zip(dynamics.yaw_signs, state[13:17]))
    assert torque > 0
    later = fly_open_loop(dynamics, state, 2.0)
    yaw_rate = torque / params.vehicle.inertia[2] * 2.0
    assert later[12] == pytest.approx(yaw_rate, rel=1e-9)
    assert abs(later[10]) < 1e-9 and abs(later[11]) < 1e-9  # no roll/pitch rate
    assert abs(later[7]) < 1e-9 and abs(later[8]) < 1e-9  # quaternion: rotation about z only
    yaw = 0.5 * yaw_rate * 2.0  # psi = alpha t² / 2
    assert later[6] == pytest.approx(math.cos(yaw / 2), abs=1e-6) and later[9] == pytest.approx(math.sin(yaw / 2), abs=1e-6)
    assert later[2] == pytest.approx(state[2], abs=1e-9)


@pytest.mark.slow
def test_flight_stays_bounded_for_220_s_and_lands(default_flight):
    truth = default_flight.truth
    params = default_flight.params
    flying = truth["phase"] == PHASE_FLYING
    assert np.rad2deg(np.abs(truth["euler"][:, :2])).max() < 35.0
    assert np.abs(truth["pos_n"][:, :2]).max() < 3.0
    assert truth["height"].max() < 2.0 and truth["height"].min() > 0.0
    speed = np.linalg.norm(truth["vel_n"], axis=1)
    assert speed.max() < 3.0
    energy = 0.5 * params.vehicle.mass * speed**2 + params.vehicle.mass * GRAVITY * truth["height"]
    assert energy.max() < params.vehicle.mass * GRAVITY * 2.0
    # the thesis protocol spans: flying through 30-190 s, take-off before 30 s, on the ground after
    t = truth["t"]
    assert flying[(t >= 30) & (t <= 190)].all()
    assert truth["height"][(t > 10) & (t < 25)].mean() == pytest.approx(params.pilot.hover_height, abs=0.1)
    assert np.all(truth["height"][t > 215] < params.rest_height + 0.01)
    assert np.all(truth["omega"][t > 215] < 1e-6)  # motors off, rotors spun down
    log = default_flight.log
    assert log.u.min() >= params.vehicle.input_min and log.u.max() <= params.vehicle.input_max
    assert len(log) == 22000 and log.sample_rate == pytest.approx(100.0)


# --------------------------------------------------------------------------- effects


def test_rotor_drag_decelerates_in_proportion_to_rotor_speed():
    params = sim_params_for("linkquad")
    for effects, expect_drag in (((), False), (("rotor_drag",), True)):
        dynamics = QuadDynamics(params, effects)
        state = dynamics.hover_state(10.0)
        state[3] = 2.0  # 2 m/s north, level
        ax = dynamics.derivative(state, state[13:17], (0.0, 0.0, 0.0))[3]
        if expect_drag:
            assert ax == pytest.approx(-params.rotor_drag.horizontal * sum(state[13:17]) * 2.0 / dynamics.mass, rel=1e-9)
            later = fly_open_loop(dynamics, state, 0.5)
            assert 0.0 < later[3] < 2.0
        else:
            assert ax == 0.0
    # twice the rotor speed, twice the drag
    dynamics = QuadDynamics(params, ("rotor_drag",))
    state = dynamics.hover_state(10.0)
    state[3] = 1.0
    a1 = dynamics.derivative(state, state[13:17], (0, 0, 0))[3]
    state[13:17] = [2 * w for w in state[13:17]]
    assert dynamics.derivative(state, state[13:17], (0, 0, 0))[3] == pytest.approx(2 * a1, rel=1e-9)


def test_ground_effect_raises_thrust_near_the_ground():
    params = sim_params_for("linkquad")
    radius, hub_z = params.geometry.rotor_radius, params.geometry.rotor_plane_z
    on, off = QuadDynamics(params, ("ground_effect",)), QuadDynamics(params, ())
    for height, expect_gain in ((0.25, True), (20.0, False)):
        state = on.hover_state(height)
        hub_height = height - hub_z
        factor = 1.0 / (1.0 - (radius / (4 * hub_height)) ** 2)
        assert on.rotor_thrusts(state).sum() == pytest.approx(factor * off.rotor_thrusts(state).sum(), rel=1e-12)
        az = on.derivative(state, state[13:17], (0, 0, 0))[5]
        assert az == pytest.approx(-(factor - 1.0) * GRAVITY, rel=1e-9)
        assert (az < -0.05) if expect_gain else (abs(az) < 1e-4)
        assert off.derivative(state, state[13:17], (0, 0, 0))[5] == pytest.approx(0.0, abs=1e-12)


def test_battery_drain_raises_the_commands_needed_to_hover(default_flight):
    params = default_flight.params
    dynamics = QuadDynamics(params, ())
    assert dynamics.hover_commands(11.0)[0] > dynamics.hover_commands(12.0)[0]
    assert open_circuit_voltage(0.5, 3) < open_circuit_voltage(0.9, 3)
    log, t = default_flight.log, default_flight.log.t
    early, late = (t > 30) & (t < 50), (t > 170) & (t < 190)
    assert np.median(log.vbat[late]) < np.median(log.vbat[early]) - 0.2
    u0 = params.esc.zero_speed_input
    rise = np.median(log.u[late] - u0) / np.median(log.u[early] - u0)
    voltage_ratio = np.median(log.vbat[early]) / np.median(log.vbat[late])
    assert rise > 1.02  # the input trend of thesis Fig 2.2
    assert rise == pytest.approx(voltage_ratio, rel=0.01)  # Omega ~ (u - u0) V stays at hover


def test_no_battery_no_input_trend(plain_flight):
    log, t = plain_flight.log, plain_flight.log.t
    assert np.ptp(log.vbat) < 0.1  # ADC noise only
    early, late = (t > 8) & (t < 14), (t > 24) & (t < 30)
    assert np.median(log.u[late]) == pytest.approx(np.median(log.u[early]), rel=2e-3)


def test_motor_lag_is_first_order_with_the_thesis_pole():
    params = sim_params_for("linkquad")
    tau = params.motor_time_constant
    assert tau == pytest.approx(1 / 9.56)
    lagged = QuadDynamics(params, ("motor_lag",))
    state = lagged.hover_state(50.0)
    target = [w * 1.1 for w in state[13:17]]
    later = fly_open_loop(lagged, state, 0.105, omega_cmd=target)
    expected = state[13] + (target[0] - state[13]) * (1 - math.exp(-0.105 / tau))
    assert later[13] == pytest.approx(expected, rel=1e-6)


def test_input_delay_postpones_the_rotor_response():
    params = sim_params_for("linkquad")
    first_spin = {}
    for effects in ((), ("input_delay",)):
        result = run_simulation("linkquad", effects, seed=1, duration=6.0)
        truth = result.truth
        first_spin[effects] = truth["t"][np.argmax(truth["omega"][:, 0] > 0)]
    assert first_spin[()] == pytest.approx(1.0, abs=1e-9)  # motors armed at t_arm = 1 s
    assert first_spin[("input_delay",)] - first_spin[()] == pytest.approx(params.input_delay, abs=0.0051)


def test_gyroscopic_torques_couple_the_axes():
    params = sim_params_for("linkquad")
    on, off = QuadDynamics(params, ("gyroscopic",)), QuadDynamics(params, ())
    ixx, iyy, izz = params.vehicle.inertia
    state = on.hover_state(10.0)
    p, r = 0.5, 1.5
    state[10], state[12] = p, r
    state[13:17] = [w * (1.02 if s > 0 else 0.98) for w, s in zip(state[13:17], on.yaw_signs)]
    h_z = -params.vehicle.value("prop_inertia") * sum(s * w for s, w in zip(on.yaw_signs, state[13:17]))
    q_dot = on.derivative(state, state[13:17], (0, 0, 0))[11]
    assert q_dot == pytest.approx(((izz - ixx) * p * r + p * h_z) / iyy, rel=1e-9)
    # off: the propellers' part goes, the body's own -ω × Iω (rigid-body physics) stays
    assert off.derivative(state, state[13:17], (0, 0, 0))[11] == pytest.approx((izz - ixx) * p * r / iyy, rel=1e-9)


def test_motor_imbalance_shifts_the_cg_and_spreads_the_gains():
    params = sim_params_for("linkquad")
    on = QuadDynamics(params, ("motor_imbalance",))
    state = on.hover_state(10.0)
    cx, cy = params.imbalance.cg_offset
    mg = on.mass * GRAVITY
    deriv = on.derivative(state, state[13:17], (0, 0, 0))
    # equal thrusts about a CG at (cx, cy): tau_x = cy m g, tau_y = -cx m g
    assert deriv[10] == pytest.approx(cy * mg / params.vehicle.inertia[0], rel=1e-9)
    assert deriv[11] == pytest.approx(-cx * mg / params.vehicle.inertia[1], rel=1e-9)
    u = [1.5e-3] * 4
    speeds = on.omega_command(u, params.battery.reference_voltage)
    assert np.allclose(np.array(speeds) / speeds[0], np.array(params.imbalance.motor_gains) / params.imbalance.motor_gains[0])
    assert len(set(QuadDynamics(params, ()).omega_command(u, 12.0))) == 1


def test_wind_pushes_the_vehicle_downwind():
    params = sim_params_for("linkquad")
    for effects in (("wind",), ("wind", "rotor_drag")):
        dynamics = QuadDynamics(params, effects)
        state = dynamics.hover_state(10.0)
        ax = dynamics.derivative(state, state[13:17], (3.0, 0.0, 0.0))[3]
        assert ax > 0.0
    calm = QuadDynamics(params, ("rotor_drag",))
    assert calm.derivative(state, state[13:17], (3.0, 0.0, 0.0))[3] == 0.0  # wind off: the air does not move


def test_wind_flight_records_gusty_wind():
    result = run_simulation("linkquad", ("wind",), seed=2, duration=12.0)
    wind = result.truth["wind_n"]
    assert np.allclose(wind.mean(axis=0)[:2], result.params.wind.mean_ned[:2], atol=0.6)
    assert wind[:, 0].std() > 0.05


# --------------------------------------------------------------------------- script, sensors, determinism


def test_script_fits_the_thesis_spans_and_differs_between_seeds():
    params = sim_params_for("linkquad")
    scripts = [make_pilot_script(params, 220.0, np.random.default_rng(seed)) for seed in (1, 2)]
    for script in scripts:
        assert script.t_lift + script.climb_time < 30.0 <= script.manoeuvre_start
        assert script.land_start >= 220.0 - 22.0 and script.manoeuvre_end <= 198.0
        assert len(script.manoeuvres) > 15
        channels = {m.channel for m in script.manoeuvres}
        shapes = {m.shape for m in script.manoeuvres}
        assert {"roll", "pitch", "yaw", "throttle"} <= channels and {"step", "doublet", "sweep"} <= shapes
        # manoeuvres in both the training (30-150 s) and the evaluation (150-190 s) span
        assert any(150 < m.start < 190 for m in script.manoeuvres)
    assert scripts[0].manoeuvres != scripts[1].manoeuvres
    with pytest.raises(ConfigError, match="at least"):
        make_pilot_script(params, 2.0, np.random.default_rng(0))


def test_leading_manoeuvres_are_flown_first_and_the_rest_of_the_card_after():
    """``PilotParams.leading`` (the validation's low pass, physics_validation.LEADING): the classes flown first, in
    order; without it the script is the one the seed always drew; an unknown class is refused in one line."""
    import dataclasses

    params = sim_params_for("linkquad")
    plain = make_pilot_script(params, 60.0, np.random.default_rng(5))
    led = params.replace(pilot=dataclasses.replace(params.pilot, leading=("low_hover", "turn")))
    script = make_pilot_script(led, 60.0, np.random.default_rng(5))
    assert script.manoeuvres[0].channel == "low_hover" and script.manoeuvres[1].shape == "turn"
    low, high = params.pilot.low_hover
    first = script.manoeuvres[0]
    assert low - params.pilot.hover_height <= first.amplitude <= high - params.pilot.hover_height
    assert plain == make_pilot_script(params, 60.0, np.random.default_rng(5))  # deterministic (and as before the field)
    with pytest.raises(ConfigError, match="pilot.leading: 'loop' is not a manoeuvre class"):
        make_pilot_script(params.replace(pilot=dataclasses.replace(params.pilot, leading=("loop",))), 60.0,
                          np.random.default_rng(5))


def test_turns_hold_a_yaw_rate_while_the_pilot_flies_tilt_doublets():
    """A turn's yaw reference is the integral of a held rate (cosine entry and exit); roll/pitch doublets
    are flown inside it, so yaw and tilt rates are simultaneous (what excites gyroscopic torques). Every
    round of the test card has each manoeuvre class."""
    params = sim_params_for("linkquad")
    script = make_pilot_script(params, 220.0, np.random.default_rng(3))
    assert {"roll", "pitch", "yaw", "throttle", "low_hover"} <= {m.channel for m in script.manoeuvres}
    turns = [m for m in script.manoeuvres if m.shape == "turn"]
    assert len(turns) >= 2 and all(m.channel == "yaw" for m in turns)
    low, high = params.pilot.turn_rate
    for turn in turns:
        end = turn.start + turn.duration
        t = np.linspace(turn.start - 1.0, end + 1.0, 40001)
        yaw = turn.value(t)
        rate = np.gradient(yaw, t)
        held = (t > turn.start + TURN_RAMP) & (t < end - TURN_RAMP)
        assert low <= abs(turn.amplitude) <= high
        np.testing.assert_allclose(rate[held], turn.amplitude, rtol=1e-3)
        assert yaw[t < turn.start].max() == 0.0 and np.abs(rate[t > end]).max() < 1e-6
        assert yaw[-1] == pytest.approx(turn.amplitude * (turn.duration - TURN_RAMP), rel=1e-6)
        inside = [m for m in script.manoeuvres if m.channel in ("roll", "pitch") and turn.start < m.start < end]
        assert inside and all(m.shape == "doublet" and m.start + m.duration <= end - TURN_RAMP for m in inside)


def test_same_seed_same_log_other_seed_other_log():
    a = simulate("crazyflie21", ("battery", "wind"), seed=7, duration=14.0)
    b = simulate("crazyflie21", ("battery", "wind"), seed=7, duration=14.0)
    c = simulate("crazyflie21", ("battery", "wind"), seed=8, duration=14.0)
    assert a.allclose(b, rtol=0.0, atol=0.0) and a.meta.notes == b.meta.notes
    assert not a.allclose(c)


def test_sensors_are_noisy_in_the_documented_amounts(plain_flight):
    log, truth, sensors = plain_flight.log, plain_flight.truth, plain_flight.params.sensors
    pos_error = log.pos_n - truth["pos_n"]
    assert 0.2e-3 < pos_error.std() < 1.0e-3  # mm-level motion capture
    vel_error = log.vel_n - truth["vel_n"]
    assert vel_error.std() < 0.03
    gyro_error = log.gyro_b - truth["rates_b"]
    assert gyro_error.std() < 5 * (sensors.gyro_noise + sensors.gyro_bias)
    assert np.abs(np.diff(gyro_error, axis=0)).mean() == pytest.approx(sensors.gyro_noise * 2 / math.sqrt(math.pi), rel=0.1)
    assert np.rad2deg(np.abs(log.euler - truth["euler"])).max() < 0.5


def test_log_round_trips_through_the_thesis_mat_file_with_its_answer(tmp_path, plain_flight):
    path = write_matlog(plain_flight.log, tmp_path / "sim.mat")
    back = read_matlog(path)
    assert back.allclose(plain_flight.log)
    notes = back.meta.notes
    assert notes["seed"] == 5 and notes["effects"] == [] and back.meta.vehicle == "linkquad"
    assert notes["truth_constants"]["rotor_thrust_constant"] == pytest.approx(1.0e-5)
    assert set(notes["effects_off"]) == set(SIM_EFFECTS)
    assert notes["truth_constants"]["rotor_delay"] == notes["truth_constants"]["rotor_time_constant"] == 0.0  # all off
    flight = simulate("linkquad", ("rotor_drag", "input_delay"), seed=3, duration=6.0)
    assert flight.meta.notes["effect_parameters"]["input_delay"]["delay_s"] == pytest.approx(0.02)
    flown = flight.meta.notes["truth_constants"]  # the values flown, not the vehicle file's (lag off: 0, not 0.1046)
    assert flown["rotor_delay"] == pytest.approx(0.02) and flown["rotor_time_constant"] == 0.0
    assert flown["rotor_drag_xy"] == flight.meta.notes["effect_parameters"]["rotor_drag"]["k_h_N_s_per_m_rad"]
    assert set(flight.meta.notes["effect_parameters"]) == {"rotor_drag", "input_delay"}
