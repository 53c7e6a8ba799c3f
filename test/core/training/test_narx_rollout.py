"""NARX multi-step (rollout) training and prediction on the bundled NanoBench bag: the rollout loss beats
series-parallel training at 50 steps, early stopping keeps the best validation epoch, predict_horizons is
the stream form and causal, training is deterministic."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core.evaluation.multistep import multistep_evaluation
from quad_modelling.core.models.narx import OUTPUTS, NarxConfig, NarxPredictor
from quad_modelling.core.training.narx import (
    flight_segments,
    train_narx_on_flights,
    validation_split,
)
from quad_modelling.core.training.rollout import RolloutConfig
from quad_modelling.core.preprocess import measured_variables
from quad_modelling.core.variables import columns
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.io.loader import load_flight

BAG = Path(__file__).resolve().parents[3] / "bags" / "nanobench_B7_oval_medium_rep2"
CONFIG = NarxConfig(hidden=6, output_delays=10, input_delays=tuple(range(10)), epochs=3, noise_snr_db=(None,) * 6,
                    incremental=True)
ROLLOUT = RolloutConfig(horizon=50, batch_size=128, max_epochs=12, patience=2, learning_rate=1e-2, windows_per_epoch=512)
EVAL = EvaluationConfig.preset("short")


@pytest.fixture(scope="module")
def flight():
    return load_flight(BAG)


@pytest.fixture(scope="module")
def span(flight):
    return EVAL.spans()[0].interval(flight, EVAL.drop_start, EVAL.drop_end)


@pytest.fixture(scope="module")
def rollout_model(flight, span):
    return train_narx_on_flights([flight], [span], CONFIG, seed=0, rollout=ROLLOUT)


def _multistep(flight, model) -> dict:
    result = multistep_evaluation([flight], [NarxPredictor(model)], load_vehicle("crazyflie21"), EVAL)
    return result["models"]["narx"]


def _rollout_error(model, segment, horizon: int, stride: int) -> float:
    """The rollout loss in numpy: mean squared normalised error of the six outputs over ``horizon`` closed-loop
    steps from every ``stride``-th start of a :class:`~quad_modelling.core.training.narx.Segment`."""
    warm = model.config.warm_samples
    starts = np.arange(0, len(segment.u) - warm - horizon + 1, stride) + warm - 1
    predicted = model.simulate_from_starts(segment.u, segment.y, starts, horizon)[:, 1:]
    truth = segment.y[starts[:, None] + np.arange(1, horizon + 1)]
    return float(np.mean((model.normalise_outputs(predicted) - model.normalise_outputs(truth)) ** 2))


def test_rollout_loss_beats_series_parallel_training_on_the_evaluation_span(flight, span, rollout_model):
    # the same nets trained series-parallel only, with more L-BFGS epochs than the rollout model's pre-training
    series_parallel = train_narx_on_flights([flight], [span], dataclasses.replace(CONFIG, epochs=10), seed=0)
    (evaluation,) = flight_segments([flight], [EVAL.spans()[1].interval(flight, EVAL.drop_start, EVAL.drop_end)])
    assert _rollout_error(rollout_model, evaluation, 50, 1) < 0.5 * _rollout_error(series_parallel, evaluation, 50, 1)
    before, after = _multistep(flight, series_parallel), _multistep(flight, rollout_model)
    # series-parallel nets drift off in closed loop on the rates; the rollout-trained ones stay near the flight.
    # The ratios are 0.52 (SimErr) and 0.49 (MAE@50) on this project's current machines, below 0.5 on the earlier
    # ones: the float path of the L-BFGS and Adam training differs between CPUs, so the bound leaves room for it.
    assert after["angular_velocity"]["sim_err"] < 0.6 * before["angular_velocity"]["sim_err"]
    assert after["angular_velocity"]["mae"]["50"] < 0.6 * before["angular_velocity"]["mae"]["50"]
    assert after["angular_velocity"]["ratio_mae"]["1"] < 1.0  # and beat holding the state at one step


def test_early_stopping_keeps_the_best_validation_epoch(flight, span, rollout_model):
    info = rollout_model.training["rollout"]
    losses = info["val_loss"]
    assert info["stopped_early"] and info["epochs_run"] == info["best_epoch"] + ROLLOUT.patience
    assert losses[info["best_epoch"]] == min(losses) and losses[-1] > min(losses)
    # one flight: the validation data is the last 20 % of its span, never trained on
    _, (validation,) = validation_split([flight], [span])
    assert info["validation"] == [{"source": validation.source, "span": list(validation.span)}]
    assert all(s["span"][1] <= validation.span[0] + 0.011 for s in rollout_model.training["segments"])
    # the kept weights give the best epoch's validation loss: every 5th window, K steps from each start
    loss = _rollout_error(rollout_model, validation, ROLLOUT.horizon, ROLLOUT.val_stride)
    assert loss == pytest.approx(losses[info["best_epoch"]], rel=1e-4)


def test_predict_horizons_equals_the_stream_form(flight, rollout_model):
    segment = flight.slice(1000, 1400)
    predictor = NarxPredictor(rollout_model)
    horizon = 30
    starts = np.array([0, 4, 9, 10, 57, 300])
    batch = predictor.predict_horizons(segment, starts, horizon)
    measured = measured_variables(segment)
    for i, s in enumerate(starts):
        np.testing.assert_array_equal(batch[i][0, columns(OUTPUTS)], measured[s, columns(OUTPUTS)])
        if s + 1 >= CONFIG.output_delays:  # the live form needs n_y warm rows: all 18 variables agree
            _, stream = predictor.start_window(segment.slice(0, s + 1))
            streamed = np.array([stream.push(segment.u[s + h]) for h in range(1, horizon + 1)])
            np.testing.assert_allclose(batch[i, 1:], streamed, rtol=0, atol=1e-9)
        else:  # before n_y rows the history repeats the first measured row, as predict_horizons documents
            pad = CONFIG.output_delays - (s + 1)
            y_hist = np.concatenate([np.repeat(measured[:1, columns(OUTPUTS)], pad, axis=0), measured[: s + 1, columns(OUTPUTS)]])
            nets = rollout_model.stream(segment.u[: s + 1], y_hist)
            streamed = np.array([nets.push(segment.u[s + h]) for h in range(1, horizon + 1)])
            np.testing.assert_allclose(batch[i][1:, columns(OUTPUTS)], streamed, rtol=0, atol=1e-10)


def _altered_after(log, row):
    """The flight with every measurement after ``row`` changed (commands kept)."""
    changed = {name: getattr(log, name).copy() for name in ("pos_n", "vel_n", "euler", "gyro_b", "acc_b")}
    for value in changed.values():
        value[row + 1:] += 0.5
    return dataclasses.replace(log, **changed)


def test_predict_horizons_is_causal(flight, rollout_model):
    segment = flight.slice(1000, 1400)
    predictor = NarxPredictor(rollout_model)
    starts = np.arange(0, 121)
    reference = predictor.predict_horizons(segment, starts, 50)
    altered = predictor.predict_horizons(_altered_after(segment, 120), starts, 50)
    np.testing.assert_array_equal(altered, reference)  # nothing measured after a start (row <= 120) is read
    later = predictor.predict_horizons(_altered_after(segment, 119), np.array([120]), 50)
    assert not np.allclose(later, reference[120:121])  # ...while the measurement at the start is


def test_rollout_training_is_deterministic(flight, span):
    quick = dataclasses.replace(ROLLOUT, max_epochs=2, windows_per_epoch=256)
    config = dataclasses.replace(CONFIG, epochs=1)
    first, again, other = (train_narx_on_flights([flight], [span], config, seed=seed, rollout=quick) for seed in (3, 3, 4))
    for name, value in first.arrays().items():
        np.testing.assert_array_equal(value, again.arrays()[name])
    assert not np.array_equal(first.w_y, other.w_y)
    assert first.training["rollout"]["val_loss"] == again.training["rollout"]["val_loss"]
