"""NARX blackbox model: learns a known linear system, files, streaming, reproducibility."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.models.model_files import FORMAT_VERSION
from quad_modelling.core.models.narx import (
    ARRAY_NAMES,
    DIFFERENTIATED,
    INTEGRATED,
    OUTPUTS,
    NarxConfig,
    NarxModel,
    NarxPredictor,
    lagged_inputs,
    load_narx,
)
from quad_modelling.core.models.streaming import prime
from quad_modelling.core.training.narx import (
    Segment,
    _noisy_outputs,
    flight_segments,
    train_narx,
)
from quad_modelling.core.preprocess import (
    MeasurementGap,
    mark_measurement_gaps,
    measured_variables,
    trimmed_variables,
)
from quad_modelling.core.variables import columns
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import DataError, ModelError, OutputExistsError

DT = 0.01
POLES = np.array([0.95, 0.9, 0.97, 0.85, 0.92, 0.8])
"""y_k(t) = a_k y_k(t−1) + b_k·(u(t−1) − u_trim): six stable first-order systems."""
GAINS = 1e-3 * np.array(
    [[1, 0, -1, 0], [0, 1, 0, -1], [1, 1, 1, 1], [0, -1, 0, 1], [1, 0, -1, 0], [1, -1, 1, -1]], dtype=float
)
U_TRIM = 1500.0
SMALL = NarxConfig(hidden=4, output_delays=2, input_delays=(0, 1, 2), epochs=20, iterations_per_epoch=25,
                   noise_snr_db=(None,) * 6)


def linear_system(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Low-pass random commands around U_TRIM and the six linear systems' exact responses."""
    rng = np.random.default_rng(seed)
    u = U_TRIM + 300.0 * lfilter([0.1], [1.0, -0.9], rng.standard_normal((n, 4)), axis=0)
    y = np.zeros((n, 6))
    for t in range(1, n):
        y[t] = POLES * y[t - 1] + GAINS @ (u[t - 1] - U_TRIM)
    return u, y


def flight_from(u: np.ndarray, y: np.ndarray, vehicle: str = "linkquad") -> FlightLog:
    """A FlightLog whose velocities are y[:, :3] and gyro rates y[:, 3:] (positions/angles integrated)."""
    n = len(u)
    t = np.arange(n) * DT
    return FlightLog(
        t=t, u=u, acc_b=np.zeros((n, 3)), gyro_b=y[:, 3:], pos_n=np.cumsum(y[:, :3], axis=0) * DT,
        vel_n=y[:, :3], euler=np.cumsum(y[:, 3:], axis=0) * DT, meta=FlightMeta(vehicle, "synthetic"),
    )


@pytest.fixture(scope="module")
def trained() -> NarxModel:
    u, y = linear_system(3000, seed=0)
    return train_narx([Segment(u, y, "synthetic", (0.0, 30.0))], DT, "linkquad", SMALL, seed=1)


def relative_rms(prediction: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.sqrt(((prediction - truth) ** 2).mean(axis=0)) / truth.std(axis=0)


def test_reproduces_linear_system_closed_loop_on_new_inputs(trained):
    u, y = linear_system(1000, seed=5)
    predicted = trained.simulate(u, y[:2])
    error = relative_rms(predicted, y)
    # A zero prediction scores 1.0 (or more); the NARX tracks every system within 10 % of its spread.
    assert np.all(error < 0.10), error
    one_step = relative_rms(trained.one_step(u, y), y)
    assert np.all(one_step < 0.03), one_step
    assert np.array_equal(predicted[:2], y[:2])


def test_normalisation_round_trip_and_statistics(trained):
    u, y = linear_system(3000, seed=0)
    assert np.allclose(trained.normalise_outputs(y).mean(axis=0), 0.0, atol=1e-9)
    assert np.allclose(trained.normalise_outputs(y).std(axis=0), 1.0, atol=1e-9)
    assert np.allclose(trained.normalise_inputs(u).std(axis=0), 1.0, atol=1e-9)
    assert np.allclose(trained.denormalise_outputs(trained.normalise_outputs(y)), y, rtol=0, atol=1e-12)


def test_save_load_gives_identical_predictions(trained, tmp_path):
    path = trained.save(tmp_path / "model.npz")
    loaded = load_narx(path, vehicle="linkquad")
    u, y = linear_system(500, seed=7)
    assert np.array_equal(loaded.simulate(u, y[:2]), trained.simulate(u, y[:2]))
    assert loaded.config == trained.config and loaded.dt == trained.dt
    assert loaded.training["segments"] == [{"source": "synthetic", "span": [0.0, 30.0]}]
    with pytest.raises(OutputExistsError):
        trained.save(path)
    trained.save(path, force=True)


def test_model_file_holds_no_pickle(trained, tmp_path):
    path = trained.save(tmp_path / "model.npz")
    with np.load(path, allow_pickle=False) as archive:
        assert all(archive[name].dtype != object for name in archive.files)
        header = json.loads(str(archive["header"]))
    assert header["format_version"] == FORMAT_VERSION and header["vehicle"] == "linkquad"


def _rewrite_header(path: Path, out: Path, **changes) -> Path:
    with np.load(path, allow_pickle=False) as archive:
        contents = {name: archive[name] for name in archive.files}
    header = json.loads(str(contents.pop("header")))
    header.update(changes)
    np.savez(out, header=np.array(json.dumps(header)), **contents)
    return out


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"vehicle": "crazyflie21"}, "trained for vehicle 'crazyflie21', not 'linkquad'"),
        ({"format_version": 99}, "format version 99"),
        ({"format_version": 1}, "model format version 1, this program reads version 2; retrain the model with quad-modelling train"),
        ({"variables": ["vel_x"]}, "variable set"),
        ({"kind": "hybrid"}, "is a 'hybrid' model, expected 'narx'"),
        ({"format": "something.else"}, "not a quad_modelling.narx model file"),
    ],
)
def test_mismatched_model_file_refused(trained, tmp_path, changes, message):
    good = trained.save(tmp_path / "model.npz")
    bad = _rewrite_header(good, tmp_path / "bad.npz", **changes)
    with pytest.raises(ModelError, match=message) as info:
        load_narx(bad, vehicle="linkquad")
    assert "bad.npz" in str(info.value)


def test_corrupt_or_missing_model_file_refused(trained, tmp_path):
    good = trained.save(tmp_path / "model.npz")
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(good.read_bytes()[: len(good.read_bytes()) // 2])
    with pytest.raises(ModelError, match="corrupt.npz: not a readable model file"):
        load_narx(corrupt)
    with pytest.raises(ModelError, match="no such model file"):
        load_narx(tmp_path / "absent.npz")
    with np.load(good, allow_pickle=False) as archive:
        contents = {name: archive[name] for name in archive.files}
    contents["w_y"] = contents["w_y"][:, :, :1]
    np.savez(tmp_path / "shape.npz", **contents)
    with pytest.raises(ModelError, match="array w_y has shape"):
        load_narx(tmp_path / "shape.npz")


def test_a_file_with_an_array_this_program_does_not_read_is_refused(trained, tmp_path):
    good = trained.save(tmp_path / "model.npz")
    with np.load(good, allow_pickle=False) as archive:
        contents = {name: archive[name] for name in archive.files}
    np.savez(tmp_path / "newer.npz", **contents, w_skip=np.zeros(3))
    with pytest.raises(ModelError, match="newer.npz: holds array 'w_skip', which this program's narx model does not read"):
        load_narx(tmp_path / "newer.npz", vehicle="linkquad")


def test_a_model_file_with_a_zero_scale_or_delays_beyond_the_limit_is_refused(trained, tmp_path):
    """An edited scale of 0 divided the inputs into NaN forecasts (exit 0, scores changed); an input delay of 10^9
    asked for 30 GiB: both one ModelError naming the file."""
    good = trained.save(tmp_path / "model.npz")
    with np.load(good, allow_pickle=False) as archive:
        contents = {name: archive[name] for name in archive.files}
    for name in ("u_std", "y_std", "y_step"):
        edited = {**contents, name: np.where(np.arange(len(contents[name])) == 1, 0.0, contents[name])}
        np.savez(tmp_path / f"{name}.npz", **edited)
        with pytest.raises(ModelError, match=f"{name}.npz: array {name} holds a scale <= 0 \\(index 1\\)"):
            load_narx(tmp_path / f"{name}.npz")
    header = json.loads(str(contents["header"]))
    header["config"]["input_delays"] = [*header["config"]["input_delays"][:-1], 10**9]
    np.savez(tmp_path / "delays.npz", **{**contents, "header": np.array(json.dumps(header))})
    with pytest.raises(ModelError, match="delays.npz: .*at most 1000 hidden units and delays of at most 1000 samples"):
        load_narx(tmp_path / "delays.npz")


def test_same_seed_same_weights_other_seed_differs():
    u, y = linear_system(600, seed=3)
    config = NarxConfig(hidden=3, output_delays=2, input_delays=(0, 1), epochs=2, iterations_per_epoch=5)
    first = train_narx([Segment(u, y)], DT, "linkquad", config, seed=4)
    again = train_narx([Segment(u, y)], DT, "linkquad", config, seed=4)
    other = train_narx([Segment(u, y)], DT, "linkquad", config, seed=5)
    for name in ARRAY_NAMES:
        assert np.array_equal(getattr(first, name), getattr(again, name)), name
    assert not np.allclose(first.w_u, other.w_u)


def test_stream_matches_closed_loop_sample_for_sample(trained):
    u, y = linear_system(300, seed=9)
    batch = trained.simulate(u, y[:2])
    stream = trained.stream(u[:2], y[:2])
    streamed = np.array([stream.push(row) for row in u[2:]])
    assert np.allclose(streamed, batch[2:], rtol=0, atol=1e-12)


def test_noise_injection_has_the_requested_snr():
    rng = np.random.default_rng(0)
    y = rng.standard_normal((20000, 6)) * np.array([1, 2, 3, 4, 5, 6])
    noisy = _noisy_outputs([Segment(np.zeros((20000, 4)), y)], (None, None, None, 10.0, 10.0, 20.0), rng)[0]
    noise_power = (noisy - y).var(axis=0)
    assert np.all(noise_power[:3] == 0.0)
    # 10 dB: noise power = signal power / 10; 20 dB: / 100
    assert np.allclose(noise_power[3:] / y[:, 3:].var(axis=0), [0.1, 0.1, 0.01], rtol=0.05)


def test_predict_window_gives_consistent_18_variables(trained):
    u, y = linear_system(1000, seed=11)
    window = flight_from(u, y)
    prediction = trained.predict_window(window, warm_samples=20)
    assert prediction.shape == (1000, 18)
    assert np.array_equal(prediction[:20], measured_variables(window.slice(0, 20)))  # the warm-up is measured
    velocity = prediction[:, columns(OUTPUTS)]
    position = prediction[:, columns(INTEGRATED)]
    # causal trapezoid integration and backward differences from the last warm row
    assert np.allclose(np.diff(position[19:], axis=0), 0.5 * (velocity[20:] + velocity[19:-1]) * DT)
    acceleration = prediction[:, columns(DIFFERENTIATED)]
    assert np.allclose(acceleration[20:], (velocity[20:] - velocity[19:-1]) / DT)
    # closed loop over 10 s: a small learnt bias integrates on the slow poles (a = 0.97), hence 15 %
    assert np.all(relative_rms(velocity, y) < 0.15)


def test_streaming_predictor_equals_offline_window_prediction(trained):
    from quad_modelling.core.models.streaming import predict_window_by_stream

    u, y = linear_system(600, seed=14)
    window = flight_from(u, y)
    predictor = NarxPredictor(trained)
    streamed = predict_window_by_stream(predictor, window, 20)
    assert np.allclose(streamed, trained.predict_window(window, 20), rtol=0, atol=1e-10)
    longer_memory = dataclasses.replace(trained, config=dataclasses.replace(trained.config, output_delays=3))
    with pytest.raises(DataError, match="needs 3 warm-start samples, got 2"):
        NarxPredictor(longer_memory).start_window(window.slice(0, 2))


def test_predictor_returns_trimmed_prediction(trained):
    u, y = linear_system(1000, seed=12)
    window = flight_from(u, y)
    trimmed = NarxPredictor(trained).predict_window(window, warm_samples=20)
    absolute = trained.predict_window(window, warm_samples=20)
    measured = trimmed_variables(window)
    # same offset as the measurement's trim (mean over the first 1 s = 100 samples): errors are unchanged
    assert np.allclose(absolute - trimmed, measured_variables(window)[:100].mean(axis=0))
    assert np.array_equal(trimmed[:20, columns(OUTPUTS)], measured[:20, columns(OUTPUTS)])


def test_other_sample_rate_and_short_windows_refused(trained):
    u, y = linear_system(200, seed=13)
    fast = flight_from(u, y)
    fast.t = fast.t / 2.5  # 250 Hz
    with pytest.raises(DataError, match="trained at 10.000 ms"):
        trained.predict_window(fast, warm_samples=20)
    jittered = flight_from(u[:30], y[:30])  # stamps +-1 ms about 100 Hz, as a stack's clock gives them: accepted
    jittered.t = jittered.t + np.random.default_rng(10).uniform(-0.001, 0.001, 30)  # median step 10.15 ms: refused at 1 %
    assert np.isfinite(trained.predict_window(jittered, warm_samples=20)).any()
    with pytest.raises(DataError, match="shorter than the 20 warm-up samples"):
        trained.predict_window(flight_from(u[:15], y[:15]), warm_samples=20)
    with pytest.raises(ModelError, match="at least 2 measured samples"):
        trained.simulate(u, y[:1])


def test_training_refuses_bad_data():
    with pytest.raises(DataError, match="no training data"):
        train_narx([], DT, "linkquad", SMALL)
    u, y = linear_system(50, seed=1)
    with pytest.raises(DataError, match="shapes"):
        train_narx([Segment(u, y[:, :5], "flight.mat")], DT, "linkquad", SMALL)
    with pytest.raises(ModelError, match="input_delays"):
        NarxConfig(input_delays=(1, 1))


def test_training_segments_split_at_a_marked_measurement_gap():
    from test.conftest import synthetic_log

    log = synthetic_log(n=3000)  # 30 s at 100 Hz from t = 5 s
    whole = flight_segments([log], [None])
    assert len(whole) == 1 and len(whole[0].u) == 3000
    mark_measurement_gaps(log, [MeasurementGap("/quad/mocap/odom", float(log.t[400]), float(log.t[1068]), ("pos_n", "vel_n", "euler"))])
    parts = flight_segments([log], [None])
    assert [len(p.u) for p in parts] == [401, 1932]  # rows 0..400 and 1068..2999: no row inside the gap, no lag across it
    assert [p.span for p in parts] == [(0.0, pytest.approx(4.0)), (pytest.approx(10.68), pytest.approx(29.99))]
    np.testing.assert_array_equal(parts[1].u, log.u[1068:])
    spanned = flight_segments([log], [(2.0, 20.0)])  # a span: split the same way
    assert [len(p.u) for p in spanned] == [201, 932]


def test_a_live_node_primes_the_model_at_its_own_sample_period(trained):
    """The node primes with the period it was told (0.01 s when it is not yet known); a NARX model accepts
    only the period it was trained at, so it is primed at that one -- left unprimed, a 400 Hz NARX node's first
    window paid its one-time costs live (37 ms, bench_nodes)."""
    predictor = NarxPredictor(trained)
    started = []
    start_window = predictor.start_window
    predictor.start_window = lambda warm: started.append(warm.sample_rate) or start_window(warm)
    prime(predictor, load_vehicle("linkquad"), 0.01 if trained.dt != 0.01 else 0.02, 20)
    assert predictor.sample_period_s == trained.dt and started == [pytest.approx(1.0 / trained.dt)]


def test_lagged_inputs_are_each_delay_s_block_side_by_side():
    """[ũ(t − d)]_{d ∈ D_u}: block j of row t is u[max(t − D_u[j], 0)], in D_u's order, rows before a delay's reach
    repeating u(0)."""
    u = np.arange(24, dtype=float).reshape(6, 4)
    delays = (2, 0, 5)
    lagged = lagged_inputs(u, delays)
    assert lagged.shape == (6, 12)
    for t in range(6):
        for j, d in enumerate(delays):
            np.testing.assert_array_equal(lagged[t, 4 * j:4 * j + 4], u[max(t - d, 0)])
