"""Hybrid physics + residual net: torch twin = numpy step, observer, training, stability, causality, live, files."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core import frames
from quad_modelling.core.evaluation.multistep import GROUPS, multistep_mae
from quad_modelling.core.models import physics
from quad_modelling.core.models.hybrid import (
    COMMAND_FILTERS_S,
    CORRECTIONS,
    FEATURES,
    HybridModel,
    HybridPredictor,
    features,
    filter_inputs,
    filter_step,
    filtered_commands,
    load_hybrid,
    observer_rows,
)
from quad_modelling.core.physics.symmetry import model_symmetries
from quad_modelling.core.training.hybrid import HybridTrainingConfig, flight_segments, segment_arrays, train_hybrid_on_flights
from quad_modelling.core.models.physics import PhysicsPredictor
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import PhysicsState
from quad_modelling.core.physics.rotors import steady_rotor_speed
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.models.residual_net import ResidualNet, zero_net
from quad_modelling.core.training.rollout import RolloutConfig
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import SpanSpec
from quad_modelling.errors import ModelError
from quad_modelling.io.loader import load_flight

BAG = Path(__file__).resolve().parents[3] / "bags" / "nanobench_B7_oval_medium_rep2"
HORIZON = 50
SMALL = HybridTrainingConfig(hidden=(16,), rollout=RolloutConfig(horizon=10, batch_size=128, max_epochs=4, patience=2,
                                                                 learning_rate=3e-3, windows_per_epoch=768))


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("crazyflie21")


@pytest.fixture(scope="module")
def params(vehicle):
    return PhysicsParameters.from_vehicle(vehicle)


@pytest.fixture(scope="module")
def flight():
    return load_flight(BAG)


@pytest.fixture(scope="module")
def span(flight):
    return SpanSpec.parse("train", "0%:60%").interval(flight, 5.0, 5.0)


@pytest.fixture(scope="module")
def trained(flight, vehicle, span):
    return train_hybrid_on_flights([flight], [span], vehicle, SMALL, seed=0)


@pytest.fixture(scope="module")
def sim_flight():
    from quad_modelling.core.sim.simulate import simulate

    return simulate("crazyflie21", ("motor_lag", "rotor_drag"), seed=3, duration=12.0)


def random_states(params, batch, rng):
    """Flying states near hover: speeds ~1 m/s, attitudes within 0.5 rad, rates ~2 rad/s, rotors near hover speed."""
    hover = params.hover_rotor_speed(GRAVITY)
    return PhysicsState(rng.normal(size=(batch, 3)), rng.normal(size=(batch, 3)),
                                frames.euler_ned_to_matrix(rng.uniform(-0.5, 0.5, (batch, 3))), 2 * rng.normal(size=(batch, 3)),
                                hover * rng.uniform(0.8, 1.2, (batch, 4)), rng.uniform(-3, 3, batch))


def constant_net(angular: np.ndarray) -> ResidualNet:
    """A net whose correction is the constant angular acceleration ``angular`` (3,) [rad/s²] and no linear one."""
    net = zero_net(np.zeros(len(FEATURES)), np.ones(len(FEATURES)), np.ones(len(CORRECTIONS)), (4,), np.random.default_rng(0))
    net.biases[-1][3:] = angular
    return net


# ---- the command filters -------------------------------------------------------------------------------
def test_the_command_filters_are_first_order_lags_of_the_commands_before_each_row():
    # irregular stamps, two blocks of the closed form: z_{k+1} = u_k + (z_k - u_k) exp(-dt_k / tau), row by row
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.004, 0.016, 150))
    u = rng.uniform(20000.0, 60000.0, (150, 4))
    start = rng.uniform(20000.0, 60000.0, (3, 4))
    z = filtered_commands(u, t, COMMAND_FILTERS_S, start)
    expected = [start]
    for k in range(149):
        expected.append(u[k] + (expected[-1] - u[k]) * np.exp(-(t[k + 1] - t[k]) / np.array(COMMAND_FILTERS_S))[:, None])
    assert z.shape == (150, 3, 4) and np.allclose(z, expected, rtol=1e-13, atol=0)
    assert np.allclose(filter_step(start, u[0], t[1] - t[0], COMMAND_FILTERS_S), expected[1], rtol=1e-14, atol=0)
    assert np.array_equal(filtered_commands(u, t, COMMAND_FILTERS_S)[0], np.repeat(u[:1], 3, axis=0))  # settled on u_0
    # row k reads the commands before it only; a constant command is a fixed point
    changed = u.copy()
    changed[70:] += 1000.0
    assert np.array_equal(filtered_commands(changed, t, COMMAND_FILTERS_S, start)[:71], z[:71])
    assert np.allclose(filtered_commands(np.full((150, 4), 3e4), t, COMMAND_FILTERS_S), 3e4, rtol=1e-14, atol=0)
    held = np.repeat(u[:1], 60, axis=0)  # one command held (a receding horizon's held inputs), the filters elsewhere
    held[-1] += 500.0  # the last row's command is read by no row
    expected = [start]
    for k in range(59):
        expected.append(filter_step(expected[-1], held[k], t[k + 1] - t[k], COMMAND_FILTERS_S))
    assert np.allclose(filtered_commands(held, t[:60], COMMAND_FILTERS_S, start), expected, rtol=1e-13, atol=0)
    # a step: after one time constant the fast filter holds 1/e of the old command's difference, the slow one more
    steps = np.where(np.arange(150)[:, None] < 10, 0.0, 1.0) * np.ones(4)
    uniform = np.arange(150) * 0.01
    after = filtered_commands(steps, uniform, COMMAND_FILTERS_S)[10 + 3]  # 30 ms after the step (commands 10..12 held)
    assert after[0, 0] == pytest.approx(1 - np.exp(-1.0), rel=1e-12) and after[1, 0] < after[0, 0]
    inputs = filter_inputs(z, u)
    assert inputs.shape == (150, 12) and np.array_equal(inputs[:, 4:8], z[:, 1] - u)
    assert features(COMMAND_FILTERS_S)[21:25] == ("u_filtered_30ms_1", "u_filtered_30ms_2", "u_filtered_30ms_3", "u_filtered_30ms_4")


def test_a_trained_hybrid_has_the_command_filters_and_a_file_saved_without_them_predicts_as_before(trained, flight, params,
                                                                                                      vehicle, tmp_path):
    assert trained.filters == COMMAND_FILTERS_S and trained.net.n_inputs == len(FEATURES) + 12
    assert trained.training["config"]["command_filters_s"] == list(COMMAND_FILTERS_S)
    # a hybrid without filters (every file saved before them), its header without the key: the 21 inputs of before
    plain = HybridModel(params, zero_net(np.zeros(len(FEATURES)), np.ones(len(FEATURES)), np.ones(len(CORRECTIONS)), (4,),
                                         np.random.default_rng(1)), vehicle.name)
    plain.net.weights[-1][:] = np.random.default_rng(2).normal(0.0, 0.5, plain.net.weights[-1].shape)
    path = plain.save(tmp_path / "plain.npz")
    with np.load(path) as stored:
        arrays = {k: stored[k] for k in stored.files}
    header = json.loads(str(arrays.pop("header")))
    del header["config"]["command_filters_s"]
    with open(tmp_path / "before.npz", "wb") as stream:
        np.savez(stream, header=np.array(json.dumps(header)), **arrays)
    loaded = load_hybrid(tmp_path / "before.npz", vehicle)
    segment, starts = flight.slice(1000, 1300), np.arange(0, 200, 13)
    assert loaded.filters == () and np.array_equal(loaded.predict_horizons(segment, starts, HORIZON),
                                                   plain.predict_horizons(segment, starts, HORIZON))
    with pytest.raises(ModelError, match="hybrid residual net takes 21 inputs .* expected 33 and 6 \\(3 command filters\\)"):
        HybridModel(params, plain.net, vehicle.name, filters=COMMAND_FILTERS_S)


# ---- the torch twin ------------------------------------------------------------------------------------
def test_torch_twin_equals_the_numpy_physics_step_in_float64(params):
    import torch

    from quad_modelling.core.training import physics_torch as pt

    rng = np.random.default_rng(1)
    state = random_states(params, 64, rng)
    twin = pt.TorchState.from_numpy(state)
    tp = pt.TorchParameters.from_params(params, torch.float64)
    hover_u = params.hover_command(GRAVITY)
    for _ in range(30):  # jittered intervals 5..30 ms, per-member commands and disturbances
        u = hover_u * rng.uniform(0.9, 1.1, (64, 4))
        dt = rng.uniform(0.005, 0.03, 64)
        d = physics.Disturbance(rng.normal(size=(64, 3)), rng.normal(size=(64, 3)))
        state = physics.step(params, state, u, dt, d)
        twin = pt.step(tp, twin, *(torch.as_tensor(a) for a in (u, dt, d.linear_n, d.angular_b)))
    back = twin.to_numpy()
    for name in ("pos_n", "vel_n", "rot", "rates", "rotor", "yaw"):
        assert np.max(np.abs(getattr(back, name) - getattr(state, name))) < 1e-9, name
    assert np.max(np.abs(state.rates)) > 1.0  # the states moved: not a trivial comparison


def test_the_traced_rollout_step_gives_the_python_steps_losses_and_gradients_bit_for_bit(flight, params, span, monkeypatch):
    """The training runs each rollout step as a TorchScript trace (rollout.traced_step): on real windows of the flight,
    at batch sizes other than the one traced, with and without gradients, the losses and every gradient equal those of
    the same step run by Python."""
    import torch

    from quad_modelling.core.training import hybrid, rollout
    from quad_modelling.core.training import physics_torch as pt

    segments = hybrid.flight_segments(params, [flight], [span], physics.Observer())
    history = max(int(s["obs_n_lin"].max()) for s in segments)
    windows = rollout.RolloutWindows(segments, history, 11, stride=7)
    net = hybrid._make_module(*hybrid.feature_statistics(segments), np.full(6, 0.5), (16,))
    torch.manual_seed(0)
    torch.nn.init.normal_(net.last.weight, std=0.5)  # a net that corrects: the gradients flow through every step
    tp = pt.TorchParameters.from_params(params, torch.float32)
    scales = hybrid.naive_scales(segments, 10)
    traced_loss = hybrid.rollout_loss(tp, history, 10, scales)
    monkeypatch.setattr(rollout, "traced_step", lambda module, example: module)
    python_loss = hybrid.rollout_loss(tp, history, 10, scales)

    def loss_and_gradients(loss_fn, batch):
        net.zero_grad()
        loss = loss_fn(net, batch)
        loss.backward()
        return loss.item(), [p.grad.clone() for p in net.parameters()]

    for size in (64, 23, 64, 101):
        batch = windows[list(range(size))]
        (traced, traced_grads), (python, python_grads) = loss_and_gradients(traced_loss, batch), loss_and_gradients(python_loss, batch)
        assert traced == python and all(torch.equal(a, b) for a, b in zip(traced_grads, python_grads)), size
        with torch.no_grad():
            assert traced_loss(net, batch).item() == python_loss(net, batch).item()
    assert max(float(g.abs().max()) for g in traced_grads) > 0.0


# ---- observer and the zero net -------------------------------------------------------------------------
def test_observer_rows_are_the_last_history_seconds_before_the_anchor():
    t = np.cumsum(np.random.default_rng(2).choice([0.01, 0.02, 0.03], size=300))
    anchors = np.arange(300)
    first, span = observer_rows(t, anchors, 0.5)
    for a in anchors:
        expected = min(j for j in range(a + 1) if t[a] - t[j] <= 0.5 + 1e-9)
        assert first[a] == expected and span[a] == t[a] - t[expected]


def test_a_zero_net_is_the_physics_model_exactly(flight, params, vehicle):
    model = HybridModel(params, constant_net(np.zeros(3)), vehicle.name)
    segment = flight.slice(1000, 1400)
    starts = np.arange(0, 300, 7)
    hybrid = model.predict_horizons(segment, starts, HORIZON)
    assert np.array_equal(hybrid, PhysicsPredictor(vehicle).predict_horizons(segment, starts, HORIZON))


def test_the_observer_does_not_count_the_nets_correction_twice(flight, params, vehicle):
    # a net adding a constant angular acceleration c: the hybrid observer removes its mean c over the history,
    # so every anchor with history predicts exactly what the physics model predicts
    c = np.array([3.0, -2.0, 0.5])
    model = HybridModel(params, constant_net(c), vehicle.name)
    segment = flight.slice(1000, 1400)
    starts = np.arange(1, 300, 7)
    state, disturbance = model.anchor(segment, starts)
    _, base, _ = physics.anchor_state(params, segment, starts, model.observer)
    assert np.allclose(disturbance.angular_b, base.angular_b - c, rtol=0, atol=1e-9)
    assert np.allclose(disturbance.linear_n, base.linear_n, rtol=0, atol=1e-12)
    hybrid = model.predict_horizons(segment, starts, HORIZON)
    assert np.allclose(hybrid, PhysicsPredictor(vehicle).predict_horizons(segment, starts, HORIZON), rtol=0, atol=1e-9)


# ---- training ------------------------------------------------------------------------------------------
def held_out_sim_err(predictor, segment, vehicle):
    mae, _ = multistep_mae(predictor, segment, HORIZON, vehicle)
    return mae.sum(axis=1)


def test_rollout_training_beats_the_physics_base_on_held_out_rows(trained, flight, vehicle, span):
    record = trained.training["rollout"]
    assert record["best_epoch"] >= 1 and min(record["val_loss"][1:]) < record["val_loss"][0]
    # the rows after the training span (never trained on): SimErr of velocity and angular velocity
    start = int(np.searchsorted(flight.t - flight.t[0], span[1])) + 1
    segment = flight.slice(start, len(flight) - 500)
    hybrid = held_out_sim_err(HybridPredictor(trained), segment, vehicle)
    base = held_out_sim_err(PhysicsPredictor(vehicle), segment, vehicle)
    groups = list(GROUPS)
    for group in ("velocity", "angular_velocity"):
        g = groups.index(group)
        assert hybrid[g] < 0.8 * base[g], (group, hybrid[g], base[g])


@pytest.mark.slow
def test_the_physics_model_answers_a_flights_mirror_image_with_the_mirrored_motion(flight, params):
    """What the hybrid's training reads of a flight's image under each symmetry of the physics model is the image of
    what it reads of the flight: rotor speeds and commands permuted, velocity and the observer's linear disturbance
    M v, rates and its angular disturbance det(M) M ω, attitude M R M^T."""
    segment = flight.slice(500, 1500)
    original = segment_arrays(params, segment, physics.Observer())
    symmetries = model_symmetries(params)
    assert len(symmetries) == 4
    for s in symmetries:
        image = segment_arrays(params, s.image(segment), physics.Observer())
        m, axial = s.matrix, s.axial
        assert np.allclose(image["rotor"], original["rotor"][:, s.source], rtol=1e-12)
        assert np.array_equal(image["u"], original["u"][:, np.concatenate([s.source, 4 + s.source])])
        assert np.allclose(image["vel"], original["vel"] @ m.T, atol=1e-12)
        assert np.allclose(image["rates"], original["rates"] @ axial.T, atol=1e-12)
        rot = original["rot"].reshape(-1, 3, 3)
        assert np.allclose(image["rot"].reshape(-1, 3, 3), m @ rot @ m.T, atol=1e-12)
        assert np.allclose(image["d"][:, :3], original["d"][:, :3] @ m.T, rtol=1e-9, atol=1e-9)
        assert np.allclose(image["d"][:, 3:], original["d"][:, 3:] @ axial.T, rtol=1e-9, atol=1e-9)


def test_the_training_flights_images_join_them_and_the_validation_stays_as_flown(trained, flight, params, span):
    names = ["turn 180°", "mirror x -> -x", "mirror y -> -y"]
    assert trained.training["mirror_images"] == names
    from quad_modelling.core.training.rollout import RolloutWindows

    history, horizon = trained.training["history_rows"], SMALL.rollout.horizon + 1
    alone = len(RolloutWindows(flight_segments(params, [flight], [span], physics.Observer()), history, horizon))
    assert trained.training["windows"] == 4 * alone
    assert trained.training["flights"] == [flight.meta.source]


@pytest.mark.slow
def test_training_is_deterministic(trained, flight, vehicle, span):
    again = train_hybrid_on_flights([flight], [span], vehicle, SMALL, seed=0)
    for a, b in zip(trained.net.arrays().values(), again.net.arrays().values()):
        assert np.array_equal(a, b)
    other = train_hybrid_on_flights([flight], [span], vehicle, SMALL, seed=1)
    assert not np.array_equal(trained.net.weights[0], other.net.weights[0])


def test_the_training_loss_is_the_mean_simerr_ratio_of_the_numpy_prediction(flight, params, vehicle):
    # the rollout loss (torch twin, all horizons' error norms at once) of a non-zero net on every 7th window equals the
    # module docstring's L computed from the numpy hybrid's own multi-step prediction from the same anchors
    import torch

    from quad_modelling.core.preprocess import state_measurement
    from quad_modelling.core.training import hybrid as training
    from quad_modelling.core.training import physics_torch as pt
    from quad_modelling.core.training.rollout import RolloutWindows

    segment, observer, horizon, scales = flight.slice(1000, 1300), physics.Observer(), 10, (0.05, 0.2)
    arrays = training.segment_arrays(params, segment, observer, COMMAND_FILTERS_S)  # the net reads the filters too
    history = int(max(arrays["obs_n_lin"].max(), arrays["obs_n_ang"].max()))
    windows = RolloutWindows([arrays], history, horizon + 1, stride=7)
    mean, std = training.feature_statistics([arrays])
    torch.manual_seed(0)
    net = training._make_module(mean, np.maximum(std, 1e-6), np.ones(len(CORRECTIONS)), (8,))
    torch.nn.init.normal_(net.last.weight, std=0.3)
    loss_fn = training.rollout_loss(pt.TorchParameters.from_params(params, torch.float32), history, horizon, scales)
    with torch.no_grad():
        loss = float(loss_fn(net, windows[list(range(len(windows)))]))
    anchors = windows.starts(torch.arange(len(windows))).numpy() + history
    predicted = HybridModel(params, net.to_numpy(), vehicle.name, observer, filters=COMMAND_FILTERS_S).predict_horizons(segment, anchors, horizon)
    measured = state_measurement(segment)[anchors[:, None] + np.arange(1, horizon + 1)]

    def ratio(cols, scale):
        error = np.linalg.norm(predicted[:, 1:, cols] - measured[..., cols], axis=-1)
        eps = 1e-3 * scale
        return (np.sqrt(error**2 + eps**2) - eps).mean() / scale

    expected = 0.5 * (ratio(slice(3, 6), scales[0]) + ratio(slice(12, 15), scales[1]))
    assert len(anchors) > 20 and loss == pytest.approx(expected, rel=1e-4)
    zero = HybridModel(params, net.to_numpy(), vehicle.name, observer, filters=COMMAND_FILTERS_S)
    zero.net.weights[-1][:] = 0.0
    zero.net.biases[-1][:] = 0.0
    assert not np.allclose(zero.predict_horizons(segment, anchors, horizon), predicted, rtol=0, atol=1e-3)  # the net acts


# ---- stability, causality, live ------------------------------------------------------------------------
def rollout_bounds(log, params, horizon_s):
    """Largest speed [m/s] and rate [rad/s] a 50-step rollout may reach from the flight's states: the measured
    maximum plus what the vehicle's largest force / torque could add over the horizon (all rotors at the speed of
    the largest command, plus gravity; the roll/pitch torque of two rotors at that speed on their arm)."""
    rotor_max = float(steady_rotor_speed(params, np.array(params.input_max)))
    thrust_max = params.thrust_constant * rotor_max**2
    acc_max = 4 * thrust_max / params.mass + GRAVITY
    arm = float(np.max(np.abs(params.positions)))
    ang_acc_max = 2 * thrust_max * 2 * arm / min(params.inertia[:2])
    speed = np.linalg.norm(log.vel_n, axis=1).max() + acc_max * horizon_s
    rate = np.linalg.norm(log.gyro_b, axis=1).max() + ang_acc_max * horizon_s
    return speed, rate


@pytest.mark.parametrize("which", ["bag", "simulator"])
def test_stable_over_50_steps_from_every_start(which, trained, flight, sim_flight, params):
    log = flight if which == "bag" else sim_flight
    starts = np.arange(0, len(log) - HORIZON)
    predicted = trained.predict_horizons(log, starts, HORIZON)
    assert np.all(np.isfinite(predicted))
    speed, rate = rollout_bounds(log, params, HORIZON * float(np.max(np.diff(log.t))))
    assert np.linalg.norm(predicted[..., 3:6], axis=-1).max() < speed
    assert np.linalg.norm(predicted[..., 12:15], axis=-1).max() < rate


def test_predictions_use_no_measurement_after_the_anchor(trained, flight):
    segment = flight.slice(800, 1400)
    anchor = 300
    starts = np.arange(0, anchor + 1, 10)
    before = trained.predict_horizons(segment, starts, HORIZON)
    rng = np.random.default_rng(5)
    changes = {}
    for name in ("pos_n", "vel_n", "euler", "gyro_b", "acc_b"):
        values = getattr(segment, name).copy()
        values[anchor + 1:] += 0.3 * rng.normal(size=values[anchor + 1:].shape)
        changes[name] = values
    changes["u"] = segment.u.copy()
    changes["u"][anchor + HORIZON + 1:] *= 0.5  # commands after the last predicted row
    altered = dataclasses.replace(segment, **changes)
    assert np.array_equal(trained.predict_horizons(altered, starts, HORIZON), before)
    later = trained.predict_horizons(altered, np.array([anchor + 1]), HORIZON)
    assert not np.allclose(later, trained.predict_horizons(segment, np.array([anchor + 1]), HORIZON))


def test_live_stream_equals_the_offline_prediction(trained, flight):
    window = flight.slice(1200, 1500)
    warm = 20
    live = predict_window_by_stream(HybridPredictor(trained), window, warm)
    offline = trained.predict_horizons(window, np.array([warm - 1]), len(window) - warm)[0]
    assert np.allclose(live[warm:], offline[1:], rtol=0, atol=1e-9)
    assert np.max(np.abs(live[warm:, 12:15] - offline[1:, 12:15])) < 1e-9


# ---- files ---------------------------------------------------------------------------------------------
def test_save_load_registry_round_trip(trained, flight, vehicle, tmp_path):
    path = trained.save(tmp_path / "hybrid.npz")
    segment = flight.slice(1000, 1300)
    starts = np.arange(0, 200, 13)
    expected = trained.predict_horizons(segment, starts, HORIZON)
    assert np.array_equal(load_hybrid(path, vehicle).predict_horizons(segment, starts, HORIZON), expected)
    predictor = make_model(f"hybrid:{path}", vehicle)
    assert predictor.name == "hybrid"
    assert np.array_equal(predictor.predict_horizons(segment, starts, HORIZON), expected)


def test_loading_refuses_changed_physics_constants_and_other_vehicles(trained, vehicle, tmp_path):
    path = trained.save(tmp_path / "hybrid.npz")
    key = "rotor_thrust_constant"
    changed = dataclasses.replace(vehicle, constants={**vehicle.constants, key: dataclasses.replace(vehicle.constants[key], value=vehicle.constants[key].value * 1.1)})
    with pytest.raises(ModelError, match=f"hybrid model was trained with other physics constants of vehicle 'crazyflie21' than .* \\({key}\\); pass the vehicle it was trained with: --vehicle {re.escape(str(vehicle.path))} ") as err:
        load_hybrid(path, changed)
    assert "\n" not in str(err.value)
    with pytest.raises(ModelError, match="trained for vehicle 'crazyflie21', not 'linkquad'"):
        load_hybrid(path, load_vehicle("linkquad"))
    from quad_modelling.core.models.narx import load_narx

    with pytest.raises(ModelError, match="is a 'hybrid' model, expected 'narx'"):
        load_narx(path)


def test_a_hybrid_file_saved_with_the_old_inertia_keys_still_loads(trained, flight, vehicle, tmp_path):
    """A file saved before effective_ixx/iyy records the physics fit's inertias as physics_ixx/iyy: read as the new keys."""
    path = trained.save(tmp_path / "hybrid.npz")
    with np.load(path) as stored:
        arrays = {k: stored[k] for k in stored.files}
    header = json.loads(str(arrays.pop("header")))
    physics = header["training"]["physics"]
    physics["physics_ixx"], physics["physics_iyy"] = physics.pop("effective_ixx"), physics.pop("effective_iyy")
    old = tmp_path / "old_hybrid.npz"
    with open(old, "wb") as stream:
        np.savez(stream, header=np.array(json.dumps(header)), **arrays)
    segment, starts = flight.slice(1000, 1300), np.arange(0, 200, 13)
    assert np.array_equal(load_hybrid(old, vehicle).predict_horizons(segment, starts, HORIZON),
                          trained.predict_horizons(segment, starts, HORIZON))


def test_predicting_needs_no_torch(trained, tmp_path):
    path = trained.save(tmp_path / "hybrid.npz")
    code = (
        "import sys, importlib.abc\n"
        "class NoTorch(importlib.abc.MetaPathFinder):\n"  # any torch import now fails
        "    def find_spec(self, name, path, target=None):\n"
        "        if name.split('.')[0] == 'torch': raise ImportError('torch is blocked')\n"
        "sys.meta_path.insert(0, NoTorch())\n"
        "import numpy as np\n"
        "from quad_modelling.core.models.hybrid import load_hybrid\n"
        "from quad_modelling.core.vehicle import load_vehicle\n"
        "from quad_modelling.io.loader import load_flight\n"
        f"m = load_hybrid({str(path)!r}, load_vehicle('crazyflie21'))\n"
        f"p = m.predict_horizons(load_flight({str(BAG)!r}).slice(0, 200), np.arange(0, 100), 50)\n"
        "print(p.shape, bool(np.isfinite(p).all()), 'torch' in sys.modules)\n"
    )
    root = Path(__file__).resolve().parents[3]
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root,
                          env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "(100, 51, 18) True False"


def test_a_file_with_an_array_this_program_does_not_read_is_refused(trained, vehicle, tmp_path):
    path = trained.save(tmp_path / "hybrid.npz")
    with np.load(path) as contents:
        arrays = {k: contents[k] for k in contents.files}
    assert all(ResidualNet.stores(name) for name in arrays if name != "header")
    np.savez(tmp_path / "newer.npz", **arrays, net_gate=np.ones(3))
    with pytest.raises(ModelError, match="newer.npz: holds array 'net_gate', which this program's hybrid model does not read"):
        load_hybrid(tmp_path / "newer.npz", vehicle)


def test_a_file_whose_input_std_holds_a_zero_is_refused(trained, vehicle, tmp_path):
    """The nets divide their inputs by it: an edited 0 gave NaN forecasts with exit 0 and a CasADi export of NaN."""
    path = trained.save(tmp_path / "hybrid.npz")
    with np.load(path) as contents:
        arrays = {k: contents[k] for k in contents.files}
    arrays["net_in_std"] = np.where(np.arange(len(arrays["net_in_std"])) == 0, 0.0, arrays["net_in_std"])
    np.savez(tmp_path / "zero_std.npz", **arrays)
    with pytest.raises(ModelError, match=r"zero_std.npz: .*input std holds a value <= 0 \(feature 0\)"):
        load_hybrid(tmp_path / "zero_std.npz", vehicle)
