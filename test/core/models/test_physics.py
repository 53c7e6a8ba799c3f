"""The nonlinear physics model: hover, free fall, single-motor torques (FRD/NED), real sample intervals,
live = offline, multi-step = stream form, causality, the registry spec and the vehicle constants."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.physics import Disturbance, Observer, PhysicsPredictor, rollout, step
from quad_modelling.core.physics.rigid_body import PhysicsState, accelerations
from quad_modelling.core.physics.rotors import delayed_commands, first_order_scan, rotor_speeds, steady_rotor_speed
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.models.registry import make_model, streaming_predictor
from quad_modelling.core.models.streaming import predict_window_by_stream, push_sample
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle
from quad_modelling.errors import ConfigError
from quad_modelling.io.loader import load_flight
from test.conftest import FIXTURES

CF = load_vehicle("crazyflie21")
FIXTURE = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"


@pytest.fixture(scope="module")
def real() -> FlightLog:
    """1000 rows (10 s) of a real NanoBench flight, its real (jittered) stamps."""
    return load_flight(FIXTURE, CF)


def _level_state(p: PhysicsParameters, rotor: float, batch: int = 1) -> PhysicsState:
    return PhysicsState(np.tile([0.0, 0.0, -1.0], (batch, 1)), np.zeros((batch, 3)), np.tile(np.eye(3), (batch, 1, 1)),
                        np.zeros((batch, 3)), np.full((batch, 4), rotor), np.zeros(batch))


def test_hover_command_keeps_the_model_at_rest_thrust_equals_weight():
    p = PhysicsParameters.from_vehicle(CF)
    u_hover = p.hover_command(GRAVITY)
    omega_hover = steady_rotor_speed(p, np.full(4, u_hover))
    assert np.allclose(4 * p.thrust_constant * omega_hover**2, p.mass * GRAVITY, rtol=1e-12)  # T = m g
    state = _level_state(p, omega_hover[0])
    horizon = 200
    out = rollout(p, state, Disturbance.zero(1), np.full((1, horizon + 1, 4), u_hover), np.full((1, horizon), 0.01))
    assert np.abs(out[0, :, 0:3] - [0.0, 0.0, -1.0]).max() < 1e-12  # position held for 2 s
    assert np.abs(out[0, :, 3:9]).max() < 1e-12  # no velocity, no acceleration
    assert np.abs(out[0, :, 9:18]).max() < 1e-12  # level, no rates (equal rotors: the spins cancel the yaw torques)


def test_zero_commands_are_free_fall_whatever_the_attitude():
    """Rotors stopped (zero speed offset, zero command): acc = g down in N; semi-implicit Euler makes v exact
    (constant acceleration) and the position g dt t / 2 lower than g t² / 2."""
    p = PhysicsParameters.from_vehicle(CF).with_values(speed_offset=0.0, time_constant=0.0)
    state = _level_state(p, 0.0)
    state.rot = frames.euler_ned_to_matrix(np.array([[0.4, -0.3, 1.0]]))  # tilted: no thrust, so no effect
    dt, n = 0.01, 100
    out = rollout(p, state, Disturbance.zero(1), np.zeros((1, n + 1, 4)), np.full((1, n), dt))
    t = dt * np.arange(n + 1)
    assert np.allclose(out[0, :, 6:9], [0.0, 0.0, GRAVITY], atol=1e-12)
    assert np.allclose(out[0, :, 5], GRAVITY * t, atol=1e-9)
    assert np.allclose(out[0, :, 2], -1.0 + GRAVITY * t**2 / 2 + GRAVITY * dt * t / 2, atol=1e-9)
    assert np.abs(out[0, :, 3:5]).max() < 1e-12


def test_one_motor_above_hover_rolls_pitches_and_yaws_by_its_position_and_spin():
    """Crazyflie M1 front-right (x > 0, y > 0 in FRD), counter-clockwise seen from above: more thrust on it
    rolls left (roll acc < 0: the right side lifts), pitches nose up (> 0) and yaws clockwise seen from above,
    i.e. positive about FRD z down (the reaction to a ccw rotor's drag torque)."""
    p = PhysicsParameters.from_vehicle(CF)
    hover = p.hover_rotor_speed(GRAVITY)
    rotor = np.full((1, 4), hover)
    rotor[0, 0] *= 1.1
    acc_n, ang = accelerations(p, np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), rotor, np.zeros((1, 4)))
    extra = p.thrust_constant * (rotor[0, 0] ** 2 - hover**2)
    x1, y1 = CF.motor_positions[0]
    assert x1 > 0 and y1 > 0 and CF.yaw_signs[0] == 1
    assert ang[0, 0] < 0 and ang[0, 1] > 0 and ang[0, 2] > 0
    assert np.isclose(ang[0, 0], -y1 * extra / p.inertia[0], rtol=1e-12)
    assert np.isclose(ang[0, 1], x1 * extra / p.inertia[1], rtol=1e-12)
    assert np.isclose(ang[0, 2], p.torque_constant * (rotor[0, 0] ** 2 - hover**2) / p.inertia[2], rtol=1e-12)
    assert np.isclose(acc_n[0, 2], -extra / p.mass, rtol=1e-12)  # more thrust: up (NED z is down)


def test_rotor_drag_opposes_body_velocity_and_its_arm_gives_the_moment():
    p = PhysicsParameters.from_vehicle(CF).with_values(drag_arm=-0.03)
    hover = p.hover_rotor_speed(GRAVITY)
    vel = np.array([[1.0, 0.5, 0.0]])  # level: body = N
    acc_n, ang = accelerations(p, vel, np.eye(3)[None], np.zeros((1, 3)), np.full((1, 4), hover), np.zeros((1, 4)))
    drag = -4 * hover * p.drag[0] * vel[0, :2]
    assert np.allclose(acc_n[0, :2], drag / p.mass, rtol=1e-12)
    # (0, 0, h) x F: tau_x = -h F_y, tau_y = h F_x
    assert np.isclose(ang[0, 0], 0.03 * drag[1] / p.inertia[0], rtol=1e-9)
    assert np.isclose(ang[0, 1], -0.03 * drag[0] / p.inertia[1], rtol=1e-9)


def test_rotor_lag_and_delay_follow_the_commands_causally():
    p = PhysicsParameters.from_vehicle(CF).with_values(time_constant=0.05, delay=0.02)
    t = np.arange(60) * 0.01
    u = np.full((60, 4), 30000.0)
    u[10:] = 40000.0  # step at row 10
    commands = delayed_commands(p, u, t)
    assert np.all(commands[:12] == 30000.0) and np.all(commands[12:] == 40000.0)  # 20 ms later
    rotor = rotor_speeds(p, commands, t)
    low, high = steady_rotor_speed(p, np.array([30000.0, 40000.0]))
    assert np.allclose(rotor[:13], low)  # the rotor answers one sample after the delayed step
    expected = high + (low - high) * np.exp(-(t[13:] - t[12]) / 0.05)
    assert np.allclose(rotor[13:, 0], expected, rtol=1e-12)


def test_prefix_scan_equals_the_sequential_recurrence():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0.0, 1.0, (777, 2)), rng.normal(size=(777, 2))
    gain, offset = first_order_scan(a, b)
    x = np.array([0.3, -2.0])
    for k in range(777):
        x = a[k] * x + b[k]
        assert np.allclose(gain[k] * np.array([0.3, -2.0]) + offset[k], x, rtol=1e-12, atol=1e-12)


def test_a_dropped_sample_integrates_the_same_trajectory_within_the_euler_error():
    """Stamps with every 7th sample dropped (20 ms steps) against the uniform 10 ms grid, commands changing
    only at the kept rows: the rotor speeds are exact in both, so the difference is the rigid body's
    semi-implicit Euler step alone: merging two steps of h changes v by h (a_{k+1} - a_k) ~ h² |da/dt|, so
    over M merged steps |Δv| <= M h² max|da/dt| (and likewise for the rates); checked with a factor 2."""
    p = PhysicsParameters.from_vehicle(CF).with_values(delay=0.0)
    n, h = 141, 0.01
    t = np.arange(n) * h
    rng = np.random.default_rng(4)
    u_hover = p.hover_command(GRAVITY)
    u = u_hover + 800.0 * np.cumsum(rng.normal(size=(n, 4)), axis=0) / 10.0
    kept = np.array([k for k in range(n) if k % 7 != 6])
    u_kept_only = u.copy()
    for k in range(n):  # a dropped row repeats the previous command: both integrations see the same input
        if k % 7 == 6:
            u_kept_only[k] = u_kept_only[k - 1]
    state = _level_state(p, steady_rotor_speed(p, u_kept_only[0])[0])
    state.rotor = steady_rotor_speed(p, u_kept_only[:1])
    uniform = rollout(p, state, Disturbance.zero(1), u_kept_only[None], np.diff(t)[None])[0]
    jitter = rollout(p, state, Disturbance.zero(1), u_kept_only[kept][None], np.diff(t[kept])[None])[0]
    diff = np.abs(uniform[kept] - jitter)
    merged = n - len(kept)
    for cols, acc_cols in ((slice(3, 6), slice(6, 9)), (slice(12, 15), slice(15, 18))):
        jerk = np.abs(np.diff(uniform[:, acc_cols], axis=0)).max() / h
        tolerance = 2.0 * merged * h**2 * jerk
        assert 0.0 < diff[:, cols].max() < tolerance


def test_live_stream_with_stamps_equals_offline_window_and_multistep(real):
    """predict_window (the offline form, run by the stream with real stamps), a hand-driven live loop and the
    multi-step form from the last warm row give the same numbers to 1e-9."""
    model = PhysicsPredictor(CF)
    window = real.slice(100, 400)
    warm = 20
    offline = predict_window_by_stream(model, window, warm)
    predictions, stream = model.start_window(window.slice(0, warm))
    live = [push_sample(stream, window.u[k], float(window.t[k])) for k in range(warm, len(window))]
    assert np.allclose(np.vstack([predictions, live]), offline, rtol=0, atol=1e-9)
    multistep = model.predict_horizons(window, np.array([warm - 1]), len(window) - warm)[0]
    assert np.allclose(multistep[1:], offline[warm:], rtol=0, atol=1e-9)
    assert np.isfinite(offline).all() and np.abs(offline[warm:, 3:6] - window.vel_n[warm:]).max() > 0


def test_push_without_stamps_steps_by_the_warm_period(real):
    """On a uniform time base push(command) (the median warm period) equals push_at with the stamps."""
    model = PhysicsPredictor(CF)
    window = real.slice(0, 120)
    uniform = replace(window, t=window.t[0] + 0.01 * np.arange(len(window)))
    _, by_stamp = model.start_window(uniform.slice(0, 20))
    _, by_period = model.start_window(uniform.slice(0, 20))
    for k in range(20, len(uniform)):
        assert np.allclose(by_stamp.push_at(uniform.u[k], float(uniform.t[k])), by_period.push(uniform.u[k]), atol=1e-9)


def test_predictions_do_not_use_anything_after_the_anchor(real):
    """Multi-step from anchors <= 500 with horizon 50: measurements after row 500 and commands after row 550
    changed -> identical predictions; the window form: everything after the warm rows but the commands."""
    model = PhysicsPredictor(CF)
    starts = np.arange(300, 501, 20)
    before = model.predict_horizons(real, starts, 50)
    altered = replace(real, pos_n=real.pos_n.copy(), vel_n=real.vel_n.copy(), euler=real.euler.copy(),
                      gyro_b=real.gyro_b.copy(), acc_b=real.acc_b.copy(), u=real.u.copy())
    altered.pos_n[501:] += 3.0
    altered.vel_n[501:] *= -2.0
    altered.euler[501:, :2] += 0.3
    altered.gyro_b[501:] += 1.0
    altered.acc_b[501:] -= 5.0
    altered.u[551:] = 0.0
    assert np.array_equal(model.predict_horizons(altered, starts, 50), before)
    # ... while a change at the anchor itself does change them (the test can see a leak)
    altered.vel_n[500] += 0.1
    assert not np.array_equal(model.predict_horizons(altered, starts, 50)[-1], before[-1])

    window = real.slice(200, 500)
    offline = model.predict_window(window, 20)
    changed = replace(window, vel_n=window.vel_n.copy(), gyro_b=window.gyro_b.copy())
    changed.vel_n[20:] += 1.0
    changed.gyro_b[20:] -= 0.5
    # the evaluation's trim uses the window's measured first second: compare absolute predictions
    assert np.array_equal(predict_window_by_stream(model, changed, 20), predict_window_by_stream(model, window, 20))
    assert offline.shape == (300, 18)


def test_observer_holds_a_constant_disturbance_and_beats_no_observer_on_a_thrust_error(real):
    """A vehicle whose thrust constant is 20 % high predicts a climb; the linear observer measures the missing
    acceleration over its history and holds it: the 0.5 s velocity error shrinks."""
    wrong = CF.with_values({"rotor_thrust_constant": CF.value("rotor_thrust_constant") * 0.6}, "test: thrust error")
    starts = np.arange(100, 900, 50)
    truth = real.vel_n[starts + 50]
    errors = {}
    for name, observer in (("on", Observer(0.5, 0.5)), ("off", Observer(0.0, 0.0))):
        predicted = PhysicsPredictor(wrong, observer).predict_horizons(real, starts, 50)[:, -1, 3:6]
        errors[name] = np.linalg.norm(predicted - truth, axis=1).mean()
    assert errors["on"] < 0.5 * errors["off"]


def test_open_loop_state_stays_within_the_gyro_full_scale_and_the_speed_limit():
    p = PhysicsParameters.from_vehicle(CF)
    state = _level_state(p, 0.0)
    u = np.zeros((1, 1001, 4))
    u[0, :, 0] = 65535.0  # one motor at full power for 10 s: the body tumbles
    out = rollout(p, state, Disturbance.zero(1), u, np.full((1, 1000), 0.01))
    assert np.isfinite(out).all()
    assert np.linalg.norm(out[0, :, 12:15], axis=1).max() <= np.deg2rad(2000.0) + 1e-9
    assert np.linalg.norm(out[0, :, 3:6], axis=1).max() <= 50.0 + 1e-9


def test_step_is_vectorised_over_a_batch_with_its_own_intervals():
    p = PhysicsParameters.from_vehicle(CF)
    hover = p.hover_rotor_speed(GRAVITY)
    state = _level_state(p, hover, batch=3)
    state.rates = np.array([[0.1, 0.0, 0.0], [0.0, -0.2, 0.0], [0.0, 0.0, 0.3]])
    u = np.full((3, 4), p.hover_command(GRAVITY))
    dt = np.array([0.005, 0.01, 0.02])
    batch = step(p, state, u, dt, Disturbance.zero(3))
    for i in range(3):
        one = step(p, state.take([i]), u[i:i + 1], dt[i], Disturbance.zero(1))
        assert np.allclose(one.rot, batch.rot[i:i + 1], atol=1e-15) and np.allclose(one.rates, batch.rates[i:i + 1])
    assert np.allclose(np.einsum("bij,bkj->bik", batch.rot, batch.rot), np.eye(3), atol=1e-12)  # stays a rotation


def test_registry_builds_physics_and_names_what_is_missing():
    model = make_model("physics", CF)
    assert model.name == "physics" and model.observer == Observer()
    assert make_model("physics:1,0", CF).observer == Observer(1.0, 0.0)
    assert streaming_predictor("physics", CF).name == "physics"
    with pytest.raises(ConfigError, match="physics:abc"):
        make_model("physics:abc", CF)
    with pytest.raises(ConfigError, match="physics:-1"):
        make_model("physics:-1", CF)
    with pytest.raises(ConfigError, match="needs the vehicle constants rotor_delay, rotor_drag_xy, rotor_drag_z, rotor_drag_arm"):
        make_model("physics", load_vehicle("px4_iris"))


def test_vehicle_physics_constants_are_validated(tmp_path):
    text = (FIXTURES.parent.parent / "config" / "vehicles" / "crazyflie21.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("rotor_time_constant:   {value: 0.05,", "rotor_time_constant:   {value: -0.05,"))
    with pytest.raises(ConfigError, match=r"bad.yaml: constants.rotor_time_constant.value must lie in \[0, 10\) s"):
        VehicleConfig.from_yaml(bad)
    assert CF.value("rotor_speed_gain") == pytest.approx(0.04076521)


def test_starts_of_many_segments_in_one_batch_predict_as_each_segment_alone(real):
    """predict_horizons_of (one rollout for the starts of every segment, what the multi-step scores use) gives each
    segment's predict_horizons (the default observer on: each segment anchors on its own rows), without the
    accelerations no multi-step group scores."""
    model = PhysicsPredictor(CF)
    parts = [(real.slice(0, 400), np.arange(20, 340, 7)), (real.slice(300, 1000), np.arange(60, 640, 3)),
             (real.slice(500, 700), np.array([10]))]
    batched = model.predict_horizons_of(parts, 50)
    for (segment, starts), together in zip(parts, batched):
        alone = model.predict_horizons(segment, starts, 50)
        assert together.shape == alone.shape == (len(starts), 51, 18)
        states = np.r_[0:6, 9:15]
        np.testing.assert_allclose(together[..., states], alone[..., states], rtol=1e-12, atol=1e-12)
        assert np.isnan(together[..., 6:9]).all() and np.isnan(together[..., 15:18]).all()
        assert np.isfinite(alone).all()
    assert model.predict_horizons_of([], 50) == []


def test_one_anchors_disturbance_on_floats_is_the_batch_means():
    """disturbance_means at a single anchor (the carried forecast's case, floats) gives the batch form's numbers bit for
    bit: every anchor of a jittered time base, histories of 0, shorter and longer than the rows, the angular trim."""
    from quad_modelling.core.models.physics import disturbance_means, modelled_integral

    rng = np.random.default_rng(31)
    t = np.cumsum(rng.uniform(0.002, 0.003, 300))
    vel, rates, modelled = rng.normal(0, 1, (300, 3)), rng.normal(0, 1, (300, 3)), rng.normal(0, 5, (300, 6))
    integral = modelled_integral(t, modelled)
    for observer in (Observer(), Observer(linear_s=0.0, angular_s=0.05, angular_trim=False), Observer(linear_s=2.0, angular_s=0.2)):
        for anchor in (0, 1, 17, 150, 299):
            one = disturbance_means(t, vel, rates, integral, np.array([anchor]), observer)
            batch = disturbance_means(t, vel, rates, integral, np.array([anchor, anchor]), observer)
            np.testing.assert_array_equal(one.linear_n, batch.linear_n[:1])
            np.testing.assert_array_equal(one.angular_b, batch.angular_b[:1])
            assert one.linear_n.shape == one.angular_b.shape == (1, 3)
