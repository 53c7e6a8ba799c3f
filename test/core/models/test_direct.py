"""The direct model: body rates from a ridge regression per horizon, the rest of the state from the physics model."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.models.direct import COMMAND_LEAD, DirectModel, DirectPredictor, RateRegression, feature_count, load_direct
from quad_modelling.core.models.physics import PhysicsPredictor
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.physics.rigid_body import rotation_increment
from quad_modelling.core.preprocess import nav_acceleration
from quad_modelling.core.training.direct import fit_rate_regression, train_direct
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import ConfigError, DataError, ModelError
from quad_modelling.io.loader import load_flight

BAG = Path(__file__).resolve().parents[3] / "bags" / "nanobench_B7_oval_medium_rep2"
POLE = 0.9
"""ω_{k+1} = POLE ω_k + G ũ_{k-DELAY} + e_k: the known system of the synthetic flights."""
DELAY = 3
GAIN = np.array([[1.0, -1.0, -1.0, 1.0], [1.0, 1.0, -1.0, -1.0], [0.5, -0.5, 0.5, -0.5]]) * 2e-5
"""G [rad/s per command unit]: roll, pitch and yaw patterns of the four commands."""
NOISE = 0.002
"""e_k's standard deviation [rad/s]: the part of each row no model can predict."""
DRAG = np.array([[0.0, -0.005, 0.0], [0.005, 0.0, 0.0], [0.0, 0.0, 0.0]])
"""M [rad/s per m/s]: the rate a row gains from the body velocity v^B (a rotor-drag-like moment), where it is on."""
LEG = 1000
"""Rows of each constant ground velocity of the synthetic flights."""
YAW = 0.7
"""The synthetic flights' constant heading [rad]: v^B is v^N turned by it."""


def arx_flight(seed: int, rows: int = 6000, yaw: float = YAW, drag: np.ndarray | None = None) -> tuple[FlightLog, np.ndarray]:
    """(a level 100 Hz flight at heading ``yaw`` whose gyro rates follow the known system
    ω_{k+1} = POLE ω_k + G ũ_{k-DELAY} + M v^B_k + e_k (M = ``drag``, none by default), flown in legs of :data:`LEG`
    rows at a constant random velocity; the centred commands ũ)."""
    drag = np.zeros((3, 3)) if drag is None else drag
    rng = np.random.default_rng(seed)
    u = 40000.0 + np.cumsum(rng.standard_normal((rows, 4)) * 300.0, axis=0) * 0.05 + rng.standard_normal((rows, 4)) * 800.0
    centred = u - 40000.0
    vel_n = np.repeat(rng.uniform(-2.0, 2.0, (rows // LEG + 1, 3)) * [1.0, 1.0, 0.2], LEG, axis=0)[:rows]
    euler = np.zeros((rows, 3)) + [0.0, 0.0, yaw]
    vel_b = frames.nav_to_body(vel_n, euler)
    rates = np.zeros((rows, 3))
    for k in range(rows - 1):
        rates[k + 1] = POLE * rates[k] + GAIN @ centred[max(k - DELAY, 0)] + drag @ vel_b[k] + NOISE * rng.standard_normal(3)
    zeros = np.zeros((rows, 3))
    log = FlightLog(t=np.arange(rows) * 0.01, u=u, acc_b=zeros + [0.0, 0.0, -9.81], gyro_b=rates, pos_n=zeros + [0.0, 0.0, -1.0],
                    vel_n=vel_n, euler=euler, meta=FlightMeta("crazyflie21", f"arx seed {seed}"))
    return log, centred


def expected_rates(log: FlightLog, centred: np.ndarray, anchor: int, horizon: int, drag: np.ndarray | None = None) -> np.ndarray:
    """E[ω_{s+h} | rows <= s, commands] inside one leg: the known system (M = ``drag``) run from the measured ω_s
    without its noise."""
    drag = np.zeros((3, 3)) if drag is None else drag
    out = [log.gyro_b[anchor]]
    vel_b = frames.nav_to_body(log.vel_n[anchor], log.euler[anchor])
    for h in range(horizon):
        out.append(POLE * out[-1] + GAIN @ centred[anchor + h - DELAY] + drag @ vel_b)
    return np.array(out)


def inside_legs(starts: np.ndarray, horizon: int) -> np.ndarray:
    """The starts whose horizon stays in one leg of constant velocity."""
    return starts[starts % LEG + horizon < LEG]


def test_the_regression_recovers_a_known_linear_system_on_a_flight_it_never_saw():
    regression, anchors = fit_rate_regression([arx_flight(0)[0]], [None], horizon=20)
    assert anchors == 6000 - COMMAND_LEAD - 20
    held_out, centred = arx_flight(1)
    starts = np.arange(100, 5900, 7)
    predicted = regression.rates(held_out, starts, 20)
    truth = np.array([expected_rates(held_out, centred, s, 20) for s in starts])
    assert np.array_equal(predicted[:, 0], held_out.gyro_b[starts])
    # the map is the system's conditional mean up to the ridge's small bias, and it predicts the measured rates
    # nearly as well as the known system itself (whose error is the noise e no model can predict)
    measured = held_out.gyro_b[starts[:, None] + np.arange(21)[None, :]]
    for h in (1, 5, 10, 20):
        floor = NOISE * np.sqrt(np.sum(POLE ** (2 * np.arange(h))))  # std of sum_i POLE^i e
        assert np.sqrt(np.mean((predicted[:, h] - truth[:, h]) ** 2)) < 0.6 * floor
        rms_model = np.sqrt(np.mean((measured[:, h] - predicted[:, h]) ** 2))
        rms_known = np.sqrt(np.mean((measured[:, h] - truth[:, h]) ** 2))
        assert rms_model < 1.2 * rms_known, (h, rms_model, rms_known)


def test_the_map_reads_the_velocity_in_the_body_frame_at_any_heading():
    """Rates that gain M v^B each row, trained at one heading and scored at another: the map predicts them within the
    noise floor as on the level flight, and without the velocity it cannot."""
    regression = fit_rate_regression([arx_flight(0, drag=DRAG)[0]], [None], horizon=20)[0]
    held_out, centred = arx_flight(1, yaw=YAW - 2.0, drag=DRAG)
    starts = inside_legs(np.arange(100, 5900, 7), 20)
    truth = np.array([expected_rates(held_out, centred, s, 20, DRAG) for s in starts])
    blind = dataclasses.replace(held_out, vel_n=np.zeros_like(held_out.vel_n))
    floor = NOISE * np.sqrt(np.sum(POLE ** (2 * np.arange(20))))
    error = np.sqrt(np.mean((regression.rates(held_out, starts, 20)[:, 20] - truth[:, 20]) ** 2))
    error_blind = np.sqrt(np.mean((regression.rates(blind, starts, 20)[:, 20] - truth[:, 20]) ** 2))
    assert error < floor, (error, floor)
    assert error_blind > 3 * error, (error_blind, error)


def test_the_map_reads_the_observers_angular_disturbance_when_given():
    """The same rates, with the velocity hidden from the log but the per-row rate gain M v^B given as the observer's
    angular disturbance (a perfect observer): the map predicts within the noise floor from it alone."""
    def hidden(seed: int, yaw: float) -> tuple[FlightLog, np.ndarray, np.ndarray]:
        log, centred = arx_flight(seed, yaw=yaw, drag=DRAG)
        gain = frames.nav_to_body(log.vel_n, log.euler) @ DRAG.T  # M v^B per row [rad/s per row]
        return dataclasses.replace(log, vel_n=np.zeros_like(log.vel_n)), centred, gain

    training, _, gain = hidden(0, YAW)
    regression = fit_rate_regression([training], [None], horizon=20, angular_disturbance=lambda log, anchors: gain[anchors])[0]
    assert regression.anchor_inputs == ("body_velocity", "angular_disturbance")
    held_out, centred, gain = hidden(1, YAW - 2.0)
    starts = inside_legs(np.arange(100, 5900, 7), 20)
    seen = arx_flight(1, yaw=YAW - 2.0, drag=DRAG)[0]
    truth = np.array([expected_rates(seen, centred, s, 20, DRAG) for s in starts])
    floor = NOISE * np.sqrt(np.sum(POLE ** (2 * np.arange(20))))
    error = np.sqrt(np.mean((regression.rates(held_out, starts, 20, gain[starts])[:, 20] - truth[:, 20]) ** 2))
    error_blind = np.sqrt(np.mean((regression.rates(held_out, starts, 20, np.zeros((len(starts), 3)))[:, 20] - truth[:, 20]) ** 2))
    assert error < floor, (error, floor)
    assert error_blind > 3 * error, (error_blind, error)
    with pytest.raises(ValueError, match="needs the observer's disturbance"):
        regression.rates(held_out, starts, 20)


def test_the_robust_refit_is_not_pulled_by_a_few_violent_rows():
    """2 % of the training rows' rates struck by 3 rad/s spikes (a propeller strike, a bad gyro sample): the
    least-squares maps follow them, the reweighted ones stay near the known system."""
    flight, _ = arx_flight(0)
    rng = np.random.default_rng(7)
    struck = rng.choice(len(flight), len(flight) // 50, replace=False)
    spiked = flight.gyro_b.copy()
    spiked[struck] += rng.choice([-3.0, 3.0], (len(struck), 3))
    training = dataclasses.replace(flight, gyro_b=spiked)
    held_out, centred = arx_flight(1)
    starts = inside_legs(np.arange(100, 5900, 7), 20)
    truth = np.array([expected_rates(held_out, centred, s, 20) for s in starts])
    errors = {}
    for steps in (0, 1, 3):
        predicted = fit_rate_regression([training], [None], horizon=20, robust_steps=steps)[0].rates(held_out, starts, 20)
        errors[steps] = np.sqrt(np.mean((predicted - truth) ** 2))
    assert errors[1] < 0.7 * errors[0], errors
    assert errors[3] < errors[1], errors


def test_a_horizons_map_reads_no_command_after_its_row():
    regression = fit_rate_regression([arx_flight(0)[0]], [None], horizon=10)[0]
    for h in range(1, 11):
        assert not regression.weights[h - 1, feature_count(h):].any()
        assert regression.weights[h - 1, feature_count(h) - 4:feature_count(h)].any()  # its own row's command


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("crazyflie21")


@pytest.fixture(scope="module")
def flight():
    return load_flight(BAG)


@pytest.fixture(scope="module")
def model(flight, vehicle):
    return train_direct([flight], [(5.0, 25.0)], vehicle)


def test_the_first_rows_rates_are_the_regressions_then_the_physics_integrates_them(model, flight):
    segment = flight.slice(1000, 1300)
    starts = np.array([30, 90, 140])
    horizon = model.regression.horizon + 20
    predicted = model.predict_horizons(segment, starts, horizon)
    disturbance = PhysicsPredictor(model.physics.vehicle).horizon_inputs(segment, starts, horizon)[1]
    given = model.regression.rates(segment, starts, horizon, disturbance.angular_b)
    assert given.shape == (3, model.regression.horizon + 1, 3)
    assert np.array_equal(predicted[:, 1:model.regression.horizon + 1, 12:15], given[:, 1:])
    # the attitude turns with the given rates: R_1 = R_0 Exp([ω̂_1 Δt]×)
    state, _, _, dt = PhysicsPredictor(model.physics.vehicle).horizon_inputs(segment, starts, 1)
    euler = frames.matrix_to_euler_ned(rotation_increment(state.rot, given[:, 1], dt[:, 0]))
    assert np.allclose(predicted[:, 1, 9:11], euler[:, :2], rtol=0, atol=1e-12)
    assert np.allclose(np.angle(np.exp(1j * (predicted[:, 1, 11] - euler[:, 2]))), 0.0, atol=1e-12)
    # after H rows the physics integrates the rates on from the last given ones: a prediction to H is a prefix
    shorter = model.predict_horizons(segment, starts, model.regression.horizon)
    assert np.array_equal(predicted[:, :model.regression.horizon + 1], shorter)
    assert not np.allclose(predicted[:, -1, 12:15], given[:, -1], rtol=0, atol=1e-6)


def test_the_first_rows_down_velocity_is_the_vertical_maps_and_the_position_moves_with_it(model, flight):
    segment = flight.slice(1000, 1300)
    starts = np.array([30, 90, 140])
    h_max = model.vertical.horizon
    predicted = model.predict_horizons(segment, starts, h_max + 20)
    given = model.vertical.velocities(segment, starts, h_max + 20)
    assert given.shape == (3, h_max + 1)
    assert np.array_equal(predicted[:, 1:h_max + 1, 5], given[:, 1:])
    # semi-implicit Euler: p_{k+1} = p_k + Δt v_{k+1}, with the given v_D
    dt = np.diff(segment.t)[starts[:, None] + np.arange(h_max)[None, :]]
    assert np.allclose(np.diff(predicted[:, :h_max + 1, 2], axis=1), dt * given[:, 1:], rtol=0, atol=1e-12)
    # the horizontal velocity stays the physics model's: as without the map but for the rotor drag's (and ground
    # effect's) coupling to v_D and the altitude, from the second step on
    without = DirectModel(model.physics.vehicle, model.regression, model.dt, model.training)
    plain = without.predict_horizons(segment, starts, h_max + 20)
    assert np.array_equal(predicted[:, :2, 3:5], plain[:, :2, 3:5])
    assert np.allclose(predicted[:, :, 3:5], plain[:, :, 3:5], rtol=0, atol=1e-3)
    assert not np.allclose(predicted[:, 1:h_max + 1, 5], plain[:, 1:h_max + 1, 5], rtol=0, atol=1e-4)
    # after H rows the physics integrates v_D on from the last given one
    assert np.array_equal(predicted[:, :h_max + 1], model.predict_horizons(segment, starts, h_max))


def test_without_an_accelerometer_the_physics_integrates_the_down_velocity_in_every_form(model, flight):
    """The vertical map reads the anchor's accelerometer: on a flight without one (a topic map without the IMU's
    acceleration) every form predicts as the model without the map, and a batch mixing such a flight with one that has
    it predicts each as alone."""
    no_imu = dataclasses.replace(flight, acc_b=None)
    without = DirectModel(model.physics.vehicle, model.regression, model.dt, model.training)
    starts = np.array([1100, 1300])
    expected = without.predict_horizons(no_imu, starts, 60)
    assert np.array_equal(model.predict_horizons(no_imu, starts, 60), expected)
    mixed = model.predict_horizons_of([(no_imu, starts), (flight, starts)], 60)
    alone = [model.predict_horizons_of([part], 60)[0] for part in ((no_imu, starts), (flight, starts))]
    assert all(np.array_equal(m, a, equal_nan=True) for m, a in zip(mixed, alone))
    assert np.array_equal(alone[0][..., :6], expected[..., :6]) and not np.allclose(alone[1][..., 5], alone[0][..., 5])
    window = no_imu.slice(1200, 1300)
    live = predict_window_by_stream(DirectPredictor(model), window, 20)
    offline = without.predict_horizons(window, np.array([19]), 80)[0]
    assert np.allclose(live[20:], offline[1:], rtol=0, atol=1e-9)


def test_the_live_stream_equals_the_multi_step_form(model, flight):
    window = flight.slice(1200, 1400)
    warm = 20
    live = predict_window_by_stream(DirectPredictor(model), window, warm)
    offline = model.predict_horizons(window, np.array([warm - 1]), len(window) - warm)[0]
    assert np.allclose(live[warm:], offline[1:], rtol=0, atol=1e-9)


def test_the_direct_rates_beat_the_physics_model_on_the_bundled_flights_held_out_part(model, flight, vehicle):
    """Trained on 5-25 s of the bundled oval, scored on 25-35 s (every start, 0.5 s horizons): the angular-velocity
    SimErr falls below the physics model's, and the velocity's is no worse."""
    from quad_modelling.core.evaluation.multistep import multistep_evaluation
    from quad_modelling.core.windows import EvaluationConfig

    config = EvaluationConfig.preset("short", train="0%:60%", eval="65%:100%", horizons=(1, 10, 50))
    table = multistep_evaluation([flight], [PhysicsPredictor(vehicle), DirectPredictor(model)], vehicle, config)
    physics, direct = table["models"]["physics"], table["models"]["direct"]
    assert direct["angular_velocity"]["sim_err"] < 0.9 * physics["angular_velocity"]["sim_err"]
    assert direct["velocity"]["sim_err"] < 1.05 * physics["velocity"]["sim_err"]


def test_save_load_registry_round_trip_and_refusals(model, flight, vehicle, tmp_path):
    path = model.save(tmp_path / "direct.npz")
    segment = flight.slice(1000, 1300)
    starts = np.arange(20, 200, 13)
    expected = model.predict_horizons(segment, starts, 60)
    assert np.array_equal(load_direct(path, vehicle).predict_horizons(segment, starts, 60), expected)
    predictor = make_model(f"direct:{path}", vehicle)
    assert predictor.name == "direct" and np.array_equal(predictor.predict_horizons(segment, starts, 60), expected)
    with pytest.raises(ModelError, match="trained for vehicle 'crazyflie21', not 'linkquad'"):
        load_direct(path, load_vehicle("linkquad"))
    key = "rotor_thrust_constant"
    changed = dataclasses.replace(vehicle, constants={**vehicle.constants, key: dataclasses.replace(vehicle.constants[key], value=vehicle.constants[key].value * 1.1)})
    with pytest.raises(ModelError, match=f"direct model was trained with other physics constants .* \\({key}\\); pass the vehicle it was "
                                         f"trained with: --vehicle {re.escape(str(vehicle.path))} "):
        load_direct(path, changed)
    with pytest.raises(ConfigError, match="model spec direct needs a model file: direct:PATH"):
        make_model("direct", vehicle)


def test_a_flight_at_another_rate_is_refused_in_one_line(model, flight):
    fast = dataclasses.replace(flight, t=flight.t * 0.5)
    with pytest.raises(DataError, match=r"sample period 5\.0 ms, the direct model counts rows of 10\.0 ms") as err:
        model.predict_horizons(fast, np.array([100]), 10)
    assert "\n" not in str(err.value)
    with pytest.raises(DataError, match="sample period 5.0 ms"):
        train_direct([flight, fast], [None, None], model.physics.vehicle)


def test_too_short_training_spans_a_flight_without_gyro_and_malformed_weights_are_refused(vehicle, flight):
    with pytest.raises(DataError, match="the direct model's training .* needs the gyro \\(gyro_b\\), which this flight does not have"):
        train_direct([dataclasses.replace(flight, gyro_b=None)], [None], vehicle)
    with pytest.raises(DataError, match="training anchors for 277 inputs"):
        fit_rate_regression([flight], [(5.0, 5.3)])
    with pytest.raises(ConfigError, match="the angular_disturbance input needs the observer's disturbance"):
        fit_rate_regression([flight], [None], anchor_inputs=("angular_disturbance",))
    assert fit_rate_regression([flight], [None], horizon=5, anchor_inputs=())[0].weights.shape == (5, feature_count(5, anchor_inputs=()), 3)
    with pytest.raises(ModelError, match="do not fit 2 horizons"):
        RateRegression(np.zeros((2, 5, 3)), np.zeros((2, 3)))
    with pytest.raises(ModelError, match="NaN or infinity"):
        RateRegression(np.full((1, feature_count(1), 3), np.nan), np.zeros((1, 3)))


def test_a_file_from_before_the_body_velocity_loads_with_its_own_layout(model, flight, vehicle, tmp_path):
    """Session 19's files have no ``config.anchor_inputs`` and 6 inputs fewer (no v^B, no observer disturbance): they
    load and predict with the rates and commands alone."""
    import json

    from quad_modelling.core.models.direct import RATE_HISTORY

    h = model.regression.horizon
    assert model.regression.anchor_inputs == ("body_velocity", "angular_disturbance")
    old = RateRegression(np.delete(model.regression.weights, np.s_[3 * RATE_HISTORY:3 * RATE_HISTORY + 6], axis=1),
                         model.regression.bias, anchor_inputs=())
    path = DirectModel(vehicle, old, model.dt, model.training).save(tmp_path / "old.npz")
    with np.load(path) as contents:
        header, weights, bias = json.loads(str(contents["header"])), contents["weights"], contents["bias"]
    del header["config"]["anchor_inputs"]
    with open(path, "wb") as stream:
        np.savez(stream, header=np.array(json.dumps(header)), weights=weights, bias=bias)
    loaded = load_direct(path, vehicle)
    assert loaded.regression.anchor_inputs == () and loaded.regression.weights.shape == (h, feature_count(h, anchor_inputs=()), 3)
    segment = flight.slice(1000, 1300)
    starts = np.arange(20, 200, 13)
    moved = dataclasses.replace(segment, vel_n=segment.vel_n + 1.0)  # the old layout reads no velocity
    assert np.array_equal(loaded.regression.rates(segment, starts, h), loaded.regression.rates(moved, starts, h))
    disturbance = np.zeros((len(starts), 3))
    assert not np.array_equal(model.regression.rates(segment, starts, h, disturbance), model.regression.rates(moved, starts, h, disturbance))
    assert np.array_equal(loaded.predict_horizons(segment, starts, 60)[:, :, 12:15],
                          DirectModel(vehicle, old, model.dt).predict_horizons(segment, starts, 60)[:, :, 12:15])


def test_a_file_from_before_the_vertical_map_loads_and_integrates_the_down_velocity(model, flight, vehicle, tmp_path):
    """Files before session 22 have no ``config.vertical`` and no vertical arrays: they load without the map and
    predict as the model without it (the physics integrates v_D)."""
    import json

    path = model.save(tmp_path / "new.npz")
    with np.load(path) as contents:
        header, arrays = json.loads(str(contents["header"])), {k: contents[k] for k in ("weights", "bias")}
        assert contents["vertical_weights"].shape == model.vertical.weights.shape
    del header["config"]["vertical"]
    with open(path, "wb") as stream:
        np.savez(stream, header=np.array(json.dumps(header)), **arrays)
    loaded = load_direct(path, vehicle)
    assert loaded.vertical is None
    segment = flight.slice(1000, 1300)
    starts = np.arange(20, 200, 13)
    without = DirectModel(vehicle, model.regression, model.dt, model.training)
    assert np.array_equal(loaded.predict_horizons(segment, starts, 60), without.predict_horizons(segment, starts, 60))


def test_a_file_with_an_array_this_program_does_not_read_is_refused(model, vehicle, tmp_path):
    """A newer program's file with a part this one does not know (as the vertical map was for session 21's reader)
    is refused in one line, not loaded and predicted without it."""
    path = model.save(tmp_path / "direct.npz")
    with np.load(path) as contents:
        arrays = {k: contents[k] for k in contents.files}
    np.savez(tmp_path / "newer.npz", **arrays, lateral_weights=np.zeros((2, 3)))
    with pytest.raises(ModelError, match="newer.npz: holds array 'lateral_weights', which this program's direct model does not read") as err:
        load_direct(tmp_path / "newer.npz", vehicle)
    assert "\n" not in str(err.value)


def test_a_file_from_before_the_averaged_acceleration_reads_the_anchors_row_alone(model, flight, vehicle, tmp_path):
    """Files before session 24 have no ``config.vertical.acceleration_rows``: their vertical map read the anchor's
    down acceleration alone (n_a = 1), and loads so; a file that names a vertical setting this program does not
    read is refused in one line."""
    import json

    path = model.save(tmp_path / "new.npz")
    with np.load(path) as contents:
        header, arrays = json.loads(str(contents["header"])), {k: contents[k] for k in contents.files if k != "header"}
    assert header["config"]["vertical"]["acceleration_rows"] == model.vertical.acceleration_rows > 1
    del header["config"]["vertical"]["acceleration_rows"]
    with open(tmp_path / "old.npz", "wb") as stream:
        np.savez(stream, header=np.array(json.dumps(header)), **arrays)
    old = load_direct(tmp_path / "old.npz", vehicle)
    assert old.vertical.acceleration_rows == 1
    segment = flight.slice(1000, 1300)
    starts = np.arange(20, 200, 13)
    one_row = old.vertical.features(segment, starts, 5)[:, old.vertical.velocity_history]
    assert np.allclose(one_row, nav_acceleration(segment, rows=starts)[:, 2], rtol=0, atol=1e-12)
    assert not np.allclose(one_row, model.vertical.features(segment, starts, 5)[:, model.vertical.velocity_history])
    for bad in (0, 2.5, "5", 10**9):  # 10^9 asked numpy for 8.9 TiB
        header["config"]["vertical"]["acceleration_rows"] = bad
        with open(tmp_path / "bad.npz", "wb") as stream:
            np.savez(stream, header=np.array(json.dumps(header)), **arrays)
        with pytest.raises(ModelError, match=f"bad.npz: direct model: the vertical map's acceleration_rows {bad!r} must be a "
                                             "whole number in 1..1000") as err:
            load_direct(tmp_path / "bad.npz", vehicle)
        assert "\n" not in str(err.value)
    header["config"]["vertical"]["acceleration_rows"] = 5
    header["config"]["vertical"]["jerk_rows"] = 2
    with open(tmp_path / "newer.npz", "wb") as stream:
        np.savez(stream, header=np.array(json.dumps(header)), **arrays)
    with pytest.raises(ModelError, match="newer.npz: direct model file holds vertical-map setting 'jerk_rows', which this "
                                         "program's direct model does not read") as err:
        load_direct(tmp_path / "newer.npz", vehicle)
    assert "\n" not in str(err.value)


def test_a_file_whose_settings_contradict_its_arrays_is_refused(model, vehicle, tmp_path):
    """``config.vertical: null`` next to the vertical map's arrays predicted without the map (velocity SimErr 2.28
    against 2.46, exit 0); a ``config.horizon`` other than the weights' was not read at all."""
    import json

    path = model.save(tmp_path / "direct.npz")
    with np.load(path) as contents:
        header, arrays = json.loads(str(contents["header"])), {k: contents[k] for k in contents.files if k != "header"}
    for edit, message in ((lambda c: c.update(vertical=None), "config.vertical is null but the file holds the vertical map's arrays"),
                          (lambda c: c.update(horizon=c["horizon"] + 1), f"config.horizon {header['config']['horizon'] + 1} but "
                                                                         f"weights for {header['config']['horizon']} horizons")):
        changed = json.loads(json.dumps(header))
        edit(changed["config"])
        with open(tmp_path / "edited.npz", "wb") as stream:
            np.savez(stream, header=np.array(json.dumps(changed)), **arrays)
        with pytest.raises(ModelError) as err:
            load_direct(tmp_path / "edited.npz", vehicle)
        assert str(err.value).startswith(f"{tmp_path / 'edited.npz'}: {message}")
