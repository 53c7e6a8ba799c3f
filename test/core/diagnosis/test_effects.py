"""Effect catalogue: the batched model equals the greybox predictor; neutral parameters change nothing;
parameters of a known effect are recovered from data made with it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from quad_modelling.core.diagnosis.catalogue import CATALOGUE, parse_effect_list
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG
from quad_modelling.core.diagnosis.fitting import fit_effects, variable_scales
from quad_modelling.core.diagnosis.statistics import window_rms
from quad_modelling.core.identification.base_model import (
    ANGULAR_ACCELERATION_COLUMNS,
    RATE_COLUMNS,
    BaseModel,
    angular_acceleration_offsets,
    apply_effects,
    measurement_filter,
    predict_batch,
)
from quad_modelling.core.identification.window_batch import (
    COMMAND_HISTORY_S,
    CONTACT_GUARD_S,
    flying_span,
    prepare_windows,
)
from quad_modelling.core.models.greybox import GreyboxParameters, GreyboxPredictor
from quad_modelling.core.preprocess import GROUND_CONTACT_M
from quad_modelling.core.sim.simulate import simulate
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import span_windows
from quad_modelling.errors import ConfigError
from test.conftest import simulated, simulated_run

NEUTRAL = {
    "rotor_drag": [0.0, 0.0, 0.0, 0.0, 0.0], "battery": [0.0, 0.0], "motor_lag": [1e-4, 1.0], "input_delay": [0.0, 1.0],
    "ground_effect": [0.0, 0.2], "gyroscopic": [0.0, 0.0], "thrust_nonlinearity": [0.0],
    "motor_imbalance": [0.0] * 5, "trim_drift": [0.0] * 4,
}


@pytest.fixture(scope="session")
def linkquad():
    return load_vehicle("linkquad")


@pytest.fixture(scope="session")
def flight():
    return simulated("linkquad", (), 5, 35.0)  # the log of truth_run


@pytest.fixture(scope="session")
def batch(flight, linkquad):
    return prepare_windows([flight], linkquad, DIAGNOSIS_CONFIG)


@pytest.fixture(scope="session")
def base(linkquad):
    return BaseModel(GreyboxParameters.from_vehicle(linkquad), reference_voltage=12.0)


def test_batched_base_equals_greybox_predictor(flight, linkquad, batch, base):
    predicted = predict_batch(base, batch, smoothed=False, greybox_outputs=True)
    windows = span_windows(flight, flying_span(), DIAGNOSIS_CONFIG)
    assert len(windows) == len(batch) >= 4
    for k in (0, len(windows) - 1):
        window = flight.slice(windows[k].start, windows[k].stop)
        expected = GreyboxPredictor(linkquad).predict_window(window, batch.warm)
        np.testing.assert_allclose(predicted[k], expected, rtol=1e-9, atol=1e-9)


def test_every_catalogue_effect_is_neutral_at_its_null_parameters(batch, base):
    reference = predict_batch(base, batch)
    assert set(NEUTRAL) == set(CATALOGUE)
    for name, theta in NEUTRAL.items():
        predicted = predict_batch(base, batch, [CATALOGUE[name]], [np.array(theta)])
        np.testing.assert_allclose(predicted, reference, atol=1e-9, err_msg=name)


def test_input_delay_shifts_commands_by_whole_and_fractional_samples(batch, base):
    u = batch.u
    shifted = CATALOGUE["input_delay"].input_map(np.array([3 * batch.dt, 1.0]), batch, base, u)
    np.testing.assert_allclose(shifted[:, 3:], u[:, :-3])
    half = CATALOGUE["input_delay"].input_map(np.array([0.5 * batch.dt, 1.0]), batch, base, u)
    np.testing.assert_allclose(half[:, 1:], 0.5 * (u[:, 1:] + u[:, :-1]))


def test_motor_lag_is_a_unit_gain_first_order_lag(batch, base):
    step = np.zeros_like(batch.u[:1])
    step[:, 10:] = 1.0
    tau = 0.1
    one = replace(batch.subset([0]), u=step, u_history=np.zeros_like(batch.u_history[:1]))
    lagged = CATALOGUE["motor_lag"].input_map(np.array([tau, 1.0]), one, base, step)
    n = int(round(tau / batch.dt))  # one time constant after the step
    pole = np.exp(-batch.dt / tau)
    assert lagged[0, 10 + n, 0] == pytest.approx(1.0 - pole ** (n + 1), abs=1e-9)  # y_k = p y_(k-1) + (1-p) u_k
    assert lagged[0, 10 + n, 0] == pytest.approx(1.0 - np.exp(-1.0), abs=0.04)
    assert lagged[0, -1, 0] == pytest.approx(1.0, abs=1e-6)
    # the gain re-fits the base's command gain: it scales the lagged command, steady state included
    scaled = CATALOGUE["motor_lag"].input_map(np.array([tau, 1.5]), one, base, step)
    np.testing.assert_allclose(scaled, 1.5 * lagged, rtol=1e-12)


def test_lag_and_delay_start_from_the_commands_before_the_window(batch, base):
    """A command step 0.1 s before the window: the lag starts the window mid-transient (not in steady state
    at the window's first command), the delay shows the pre-step commands in its first samples."""
    one = batch.subset([0])
    h = one.u_history.shape[1]
    assert h == int(round(COMMAND_HISTORY_S / batch.dt))
    history = np.zeros_like(one.u_history)
    history[:, h - 10 :] = 1.0  # the step, 10 samples before the window
    step = replace(one, u=np.ones_like(one.u), u_history=history)
    tau = 0.1
    lagged = CATALOGUE["motor_lag"].input_map(np.array([tau, 1.0]), step, base, step.u)
    pole = np.exp(-batch.dt / tau)
    assert lagged[0, 0, 0] == pytest.approx(1.0 - pole**11, abs=1e-9)  # 11 samples after the step
    delayed = CATALOGUE["input_delay"].input_map(np.array([15 * batch.dt, 1.0]), step, base, step.u)
    np.testing.assert_allclose(delayed[0, :5, 0], 0.0)  # u(t - 0.15 s): before the step
    np.testing.assert_allclose(delayed[0, 5:, 0], 1.0)


def test_mapped_commands_are_trimmed_at_the_warm_start(batch, base):
    """The linearisation point is the warm start: the mapped commands have zero warm-start mean, as the
    raw trimmed ones do."""
    for name, theta in (("motor_lag", [0.1, 1.2]), ("input_delay", [0.05, 0.9]), ("thrust_nonlinearity", [2.0])):
        aug = apply_effects([CATALOGUE[name]], [np.array(theta)], batch, base)
        np.testing.assert_allclose(aug.u[:, : batch.warm].mean(axis=1), 0.0, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(batch.u[:, : batch.warm].mean(axis=1), 0.0, atol=1e-12)


def test_drag_force_opposes_the_measured_velocity(batch, base):
    e = CATALOGUE["rotor_drag"].forcing(np.array([0.5, 0.0, 0.0, 0.0, 0.0]), batch, base, batch.u)
    v = batch.velocity_smooth - batch.velocity_smooth[:, : batch.warm].mean(axis=1, keepdims=True)
    np.testing.assert_allclose(e[:, :, 0], -0.5 * v[:, :, 0], atol=1e-12)


def test_drag_moment_follows_the_body_axes_velocity_in_a_turn(batch, base):
    """Flying north at a steady 2 m/s while the heading turns by 90 degrees: the velocity in N does not change,
    the body-axes velocity turns from (2, 0) to (0, -2), so the drag moment changes (c_m v_By, -c_m v_Bx).
    Rotating the trimmed velocity v - v_0 = 0 (the form before) gave no moment at all."""
    one = batch.subset(np.array([0]))
    n = one.samples
    yaw = np.clip((np.arange(n) - one.warm) / (n - 1 - one.warm), 0.0, 1.0) * np.pi / 2
    v = np.zeros((1, n, 3))
    v[0, :, 0] = 2.0
    euler = np.zeros((1, n, 3))
    euler[0, :, 2] = yaw
    turn = replace(one, velocity_smooth=v, euler=euler)
    e = CATALOGUE["rotor_drag"].forcing(np.array([0.3, 0.3, -1.5, 0.0, 0.0]), turn, base, turn.u)
    np.testing.assert_allclose(e[0, :, 0:3], 0.0, atol=1e-12)  # no change of the velocity in N: no change of the force
    # end of the turn: v_B = (0, -2); warm start: v_B = (2, 0)
    assert e[0, -1, 3] == pytest.approx(-1.5 * (-2.0 - 0.0))
    assert e[0, -1, 4] == pytest.approx(1.5 * (0.0 - 2.0))
    # hovering (ground speed 0) in a 2 m/s south wind through the same turn: the same airspeed, the same moment
    # (wind moment m = c_m w = -1.5 * (-2, 0)); the steady wind leaves the trimmed force unchanged
    still = replace(turn, velocity_smooth=np.zeros_like(v))
    windy = CATALOGUE["rotor_drag"].forcing(np.array([0.3, 0.3, -1.5, 3.0, 0.0]), still, base, still.u)
    np.testing.assert_allclose(windy, e, atol=1e-12)


@pytest.mark.parametrize("name, truth", [("motor_lag", [0.08, 1.0]), ("input_delay", [0.035, 1.0]), ("rotor_drag", [0.4, 0.3, -1.5, 0.0, 0.0])])
def test_fit_recovers_the_parameters_of_a_known_effect(batch, base, name, truth):
    effect = CATALOGUE[name]
    made = predict_batch(base, batch, [effect], [np.array(truth)])
    synthetic = replace(batch, measured=made)
    scales = variable_scales(synthetic, predict_batch(base, synthetic))
    fit = fit_effects(base, synthetic, [effect], scales, held=effect.nuisance)
    np.testing.assert_allclose(fit.thetas[0], truth, rtol=0.05, atol=2e-3)
    assert fit.held == effect.nuisance and np.isnan(fit.sigmas[0][[effect.parameters.index(n) for n in effect.nuisance]]).all()
    free = [i for i, n in enumerate(effect.parameters) if n not in effect.nuisance]
    assert np.isfinite(fit.sigmas[0][free]).all()


def _turning_batch(batch):
    """``batch`` with every window turning its heading by 180 degrees while it flies back and forth along x at up
    to 1 m/s (0.3 Hz): the drag moment then sees the ground speed and the wind apart."""
    n = batch.samples
    turn = np.clip((np.arange(n) - batch.warm) / (n - 1 - batch.warm), 0.0, 1.0) * np.pi
    euler = batch.euler.copy()
    euler[:, :, 2] = batch.euler[:, :1, 2] + turn
    velocity = batch.velocity_smooth.copy()
    velocity[:, :, 0] += np.sin(2 * np.pi * 0.3 * np.arange(n) * batch.dt)
    return replace(batch, euler=euler, velocity_smooth=velocity)


def test_drag_wind_is_fitted_as_a_nuisance_only_where_the_data_shows_it(batch, base):
    """Rotor drag on airspeed: data made with a (1.5, -1.0) m/s wind through turns gives the wind back (freed: it
    lowers the cost by far more than 1 % and lies many sigma from zero); data made without wind keeps it held at 0."""
    from quad_modelling.core.diagnosis.attribution import _fit_with_nuisance
    from quad_modelling.core.diagnosis.catalogue import drag_wind_estimate

    effect = CATALOGUE["rotor_drag"]
    turning = _turning_batch(batch)
    scales = variable_scales(turning, predict_batch(base, turning))
    for wind, freed in (((1.5, -1.0), True), ((0.0, 0.0), False)):
        truth = [0.4, 0.3, -1.5, -1.5 * wind[0], -1.5 * wind[1]]  # the wind moment m = c_m w
        synthetic = replace(turning, measured=predict_batch(base, turning, [effect], [np.array(truth)]))
        fit = _fit_with_nuisance(effect, base, synthetic, scales, ())
        assert (fit.held == ()) is freed
        np.testing.assert_allclose(fit.thetas[0], truth, rtol=0.05, atol=0.02)
        estimate = drag_wind_estimate(fit.thetas[0], fit.sigmas[0])
        assert (estimate["w_x"], estimate["w_y"]) == pytest.approx(wind, abs=0.05)


def test_lag_and_delay_are_told_apart_on_data_that_separates_them(batch, base):
    """Data made with a 80 ms motor lag: fitted jointly with an input delay, the lag comes back and the delay
    stays near zero, and the diagnosis says the flights separate them."""
    from quad_modelling.core.diagnosis.diagnose import motor_dynamics_separability

    made = predict_batch(base, batch, [CATALOGUE["motor_lag"]], [np.array([0.08, 1.0])])
    synthetic = replace(batch, measured=made)
    scales = variable_scales(synthetic, predict_batch(base, synthetic))
    result = motor_dynamics_separability(base, synthetic, scales)
    assert result["motor_lag_s"] == pytest.approx(0.08, rel=0.05)
    assert result["input_delay_s"] < 0.005
    assert result["separable"] and "show motor lag and none of the other" in result["text"]


def test_unknown_effect_names_are_a_config_error():
    assert [e.name for e in parse_effect_list("battery, motor_lag")] == ["battery", "motor_lag"]
    assert len(parse_effect_list("all")) == len(CATALOGUE)
    with pytest.raises(ConfigError, match="wind"):
        parse_effect_list("wind")


def test_battery_effect_needs_a_voltage(batch):
    assert CATALOGUE["battery"].applicable(batch) is None
    assert "voltage" in CATALOGUE["battery"].applicable(replace(batch, vbat=None))
    assert INDEX["acc_z"] in [INDEX[v] for v in CATALOGUE["battery"].variables]


def test_measurement_filter_gives_the_model_the_gyro_derivative_filter(batch):
    """Predicted angular accelerations pass the Savitzky-Golay derivative the measured ones went through:
    a 1 Hz tone is kept, a 12 Hz tone is attenuated as the measurement attenuates it."""
    from quad_modelling.core.preprocess import differentiate

    t = np.arange(batch.samples) * batch.dt
    out = np.zeros((2, batch.samples, 18))
    for w, f in enumerate((1.0, 12.0)):
        out[w, :, INDEX["roll_acc"]] = np.sin(2 * np.pi * f * t)
    measurement_filter(out, batch.dt, np.arange(18))
    inner = slice(20, -20)
    low, high = out[0, inner, INDEX["roll_acc"]], out[1, inner, INDEX["roll_acc"]]
    assert np.sqrt(np.mean(low**2)) == pytest.approx(np.sqrt(0.5), rel=0.03)
    rate = -np.cos(2 * np.pi * 12.0 * t) / (2 * np.pi * 12.0)
    expected = differentiate(rate[:, None], batch.dt)[inner, 0]
    np.testing.assert_allclose(high, expected, atol=0.03)
    assert np.sqrt(np.mean(high**2)) < 0.5 * np.sqrt(0.5)


def test_windows_that_touch_the_ground_are_left_out(linkquad):
    """Simulated seed 2001 (effects off) touches down during its low pass at 41-51 s: those two windows are
    dropped and counted, the rest stay (every kept window is at least 1 cm above where the vehicle stood)."""
    log = simulate("linkquad", effects=(), seed=2001, duration=90.0)
    kept = prepare_windows([log], linkquad, DIAGNOSIS_CONFIG)
    assert kept.ground_contact_dropped == 2
    assert not {41.0, 46.0} & {round(float(t), 1) for t in kept.t0}
    assert kept.height.min() >= GROUND_CONTACT_M
    assert len(kept) == len(span_windows(log, flying_span(), DIAGNOSIS_CONFIG)) - 2


@pytest.fixture(scope="session")
def truth_run():
    """Effects-off flight (seed 5, 35 s) with the simulator's truth next to its log."""
    return simulated_run("linkquad", (), 5, 35.0)


@pytest.fixture(scope="session")
def identified(truth_run, linkquad):
    from quad_modelling.core.identification.greybox_fit import identify_base

    return identify_base(prepare_windows([truth_run.log], linkquad, DIAGNOSIS_CONFIG), linkquad).model


def test_accelerations_follow_the_measured_attitude_on_an_effects_off_flight(truth_run, linkquad, identified):
    """With the simulator's true IMU signals (no sensor noise), the modelled force rotated by the measured
    attitude reproduces acc_x/acc_y to 1 mm/s² RMS, where the greybox's -g theta (open-loop attitude drift
    over 5 s) is metres per second squared off; acc_z (no small-angle drop of the tilt) halves its gap."""
    truth = replace(truth_run.log, acc_b=truth_run.truth["specific_force_b"], gyro_b=truth_run.truth["rates_b"])
    batch = prepare_windows([truth], linkquad, DIAGNOSIS_CONFIG)
    new = window_rms(batch, predict_batch(identified, batch)).mean(axis=0)
    old = window_rms(batch, predict_batch(identified, batch, greybox_outputs=True)).mean(axis=0)
    assert new[INDEX["acc_x"]] < 1e-3 and new[INDEX["acc_y"]] < 1e-3
    assert old[INDEX["acc_x"]] > 1.0 and old[INDEX["acc_y"]] > 1.0
    assert new[INDEX["acc_z"]] < 0.5 * old[INDEX["acc_z"]]
    assert new[INDEX["acc_z"]] < 0.01


def test_angular_acceleration_offsets_halve_the_noise_of_the_warm_start_mean(batch, base):
    """Gyro rates ramping at 0.3 rad/s² plus white noise of 0.003 rad/s (the simulator's gyro) over the 20 warm
    samples, 400 windows: the slope offset is unbiased with the spread 0.003 / sqrt(sum (t - t_mean)^2) =
    0.0116 rad/s²; the greybox's mean of the differentiated gyro has about twice that (0.022 rad/s²)."""
    from quad_modelling.core.preprocess import differentiate

    many = batch.subset(np.zeros(400, dtype=int))
    t = np.arange(many.warm) * many.dt
    rng = np.random.default_rng(3)
    rates = 0.3 * t[None, :] + rng.normal(0.0, 0.003, size=(400, many.warm))
    warm_rows = many.warm_rows.copy()
    warm_rows[:, :, RATE_COLUMNS[0]] = rates
    offsets = angular_acceleration_offsets(replace(many, warm_rows=warm_rows, angacc_trim=np.zeros((400, 3))))[:, 0]
    greybox = np.array([differentiate(r[:, None], many.dt).mean() for r in rates])
    assert offsets.mean() == pytest.approx(0.3, abs=0.002)
    assert offsets.std() == pytest.approx(0.003 / np.sqrt(np.sum((t - t.mean()) ** 2)), rel=0.1)
    assert greybox.std() > 1.8 * offsets.std()


def test_angular_acceleration_offset_recovers_a_constant_acceleration(batch, base):
    """Gyro rates over the warm start that ramp at a constant 0.3 rad/s² on top of the model's own response
    give an offset of exactly 0.3 rad/s² (window-trimmed)."""
    one = batch.subset(np.array([0]))
    still = replace(one, u=np.zeros_like(one.u), u_history=np.zeros_like(one.u_history))
    warm_rows = still.warm_rows.copy()
    t = np.arange(still.samples) * still.dt
    warm_rows[0][:, RATE_COLUMNS] = (0.1 + 0.3 * t[: still.warm])[:, None]
    ramp = replace(still, warm_rows=warm_rows, angacc_trim=np.array([[0.05, 0.0, -0.05]]))
    predicted = predict_batch(base, ramp, smoothed=False)
    np.testing.assert_allclose(predicted[0][ramp.warm :, ANGULAR_ACCELERATION_COLUMNS], [[0.25, 0.3, 0.35]] * (ramp.samples - ramp.warm), atol=1e-9)


def test_the_touchdown_window_is_left_out(flight, linkquad):
    """Seed 5 (35 s) touches down at 32.89 s and its throttle is cut to idle at 32.84 s. With windows at 7.5 + 5k s
    and 0.5 s dropped at the end, the window 27.5-32.5 s ends 0.3 s before the cut, >= 0.1 m above the ground: it is left
    out because the contact test also looks CONTACT_GUARD_S beyond each window, on the unsmoothed height."""
    from dataclasses import replace

    config = replace(DIAGNOSIS_CONFIG, drop_start=7.5, drop_end=0.5)
    all_windows = span_windows(flight, flying_span(), config)
    starts = [round(float(flight.t[w.start]), 2) for w in all_windows]
    assert starts[-1] == 27.5
    kept = prepare_windows([flight], linkquad, config)
    assert kept.ground_contact_dropped == 1
    assert [round(float(t), 2) for t in kept.t0] == starts[:-1]
    ground = flight.pos_n[:, 2].max()
    last = (flight.t >= 27.5) & (flight.t < 32.5)
    assert np.min(ground - flight.pos_n[last, 2]) > 0.1  # the dropped window itself was airborne throughout
    for t0 in kept.t0:
        around = (flight.t >= t0 - CONTACT_GUARD_S) & (flight.t < t0 + config.window_s + CONTACT_GUARD_S)
        assert np.min(ground - flight.pos_n[around, 2]) >= GROUND_CONTACT_M


def test_sigmas_of_parameters_that_do_nothing_are_nan_not_an_error(batch, base):
    """Gyroscopic torques on windows without rotation: no parameter moves the prediction, the fit keeps its start
    and every 1-sigma is NaN (before, an empty Jacobian ended the validation in a ValueError). With rotation the
    body term is determined and only the propeller term, ~100x smaller on the LinkQuad, is not."""
    effect = CATALOGUE["gyroscopic"]
    still = replace(batch, rates=np.zeros_like(batch.rates))
    scales = variable_scales(still, predict_batch(base, still))
    fit = fit_effects(base, still, [effect], scales)
    assert np.isnan(fit.sigmas[0]).all() and fit.thetas[0].tolist() == [0.0, 0.0]
    made = predict_batch(base, batch, [effect], [np.array([1.0, 0.0])])
    turning = replace(batch, measured=made)
    fit = fit_effects(base, turning, [effect], variable_scales(turning, predict_batch(base, turning)))
    assert fit.thetas[0][0] == pytest.approx(1.0, rel=0.05) and 0.0 < fit.sigmas[0][0] < 0.1
