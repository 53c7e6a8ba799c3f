from types import SimpleNamespace

import numpy as np
import pytest

from quad_modelling.core.diagnosis.statistics import window_rms, window_tic
from quad_modelling.core.evaluation.metrics import (
    SIM_ERR_HORIZON,
    mae_by_horizon,
    rms,
    root_mean_square,
    sim_err,
    tic,
    vector_error_norm,
)
from quad_modelling.core.evaluation.windowed import SpanScores
from quad_modelling.core.variables import INDEX, VARIABLES
from quad_modelling.errors import DataError


def test_rms_of_known_error():
    measured = np.array([1.0, 2.0, 3.0, 4.0])
    predicted = np.array([1.0, 0.0, 3.0, 2.0])  # errors 0, 2, 0, 2 -> mean square 2
    assert np.isclose(rms(measured, predicted), np.sqrt(2.0))


def test_tic_is_one_for_zero_prediction_and_zero_measurement():
    y = np.sin(np.linspace(0, 6, 200))
    assert np.isclose(tic(y, np.zeros_like(y)), 1.0)
    assert np.isclose(tic(np.zeros_like(y), y), 1.0)


def test_tic_is_zero_when_perfect_and_for_two_zero_signals():
    y = np.cos(np.linspace(0, 6, 200))
    assert tic(y, y) == 0.0
    assert tic(np.zeros(5), np.zeros(5)) == 0.0


def test_tic_hand_computed_and_columnwise():
    measured = np.array([[1.0, 2.0], [1.0, 2.0]])
    predicted = np.array([[3.0, 2.0], [3.0, 2.0]])
    # column 0: rms err 2, rms(m) 1, rms(p) 3 -> 0.5; column 1: perfect
    np.testing.assert_allclose(tic(measured, predicted), [0.5, 0.0])
    np.testing.assert_allclose(rms(measured, predicted), [2.0, 0.0])


def test_tic_favours_bold_predictions_as_the_thesis_says():
    y = np.ones(10)
    assert tic(y, 2 * y) < tic(y, 0 * y + 0.0)
    assert np.isclose(tic(y, 2 * y), 1 / 3)  # |1-2| / (1 + 2)
    assert np.isclose(tic(y, 0.5 * y), 1 / 3)  # 0.5 / 1.5


def test_vector_norm_and_simerr():
    assert np.allclose(vector_error_norm(np.array([[3.0, 4.0, 0.0]]), np.zeros((1, 3))), [5.0])
    assert sim_err(np.arange(1, 51, dtype=float)) == 1275.0


# --- the one scorer: batched forms, zero signals, MAE_h, SimErr -------------------------------------------


def test_rms_and_tic_of_a_sine_against_a_scaled_sine():
    """y_m = A sin, y_p = k A sin: RMS = |1 - k| A / sqrt(2), TIC = |1 - k| / (1 + |k|), whatever A."""
    t = np.arange(1000) / 1000.0
    y = 3.0 * np.sin(2 * np.pi * 5.0 * t)  # whole periods: RMS(y) = 3 / sqrt(2)
    assert np.isclose(root_mean_square(y), 3.0 / np.sqrt(2.0))
    assert np.isclose(rms(y, 0.6 * y), 0.4 * 3.0 / np.sqrt(2.0))
    assert np.isclose(tic(y, 0.6 * y), 0.4 / 1.6)
    assert np.isclose(tic(y, -y), 1.0)  # opposite sign: the other end of [0, 1]


def test_zero_signals_give_the_documented_scores():
    zero, y = np.zeros(50), np.linspace(-1.0, 1.0, 50)
    assert rms(zero, zero) == 0.0 and tic(zero, zero) == 0.0  # 0/0: both zero is a perfect prediction
    assert rms(y, y) == 0.0 and tic(y, y) == 0.0
    assert np.isclose(tic(y, zero), 1.0) and np.isclose(tic(zero, y), 1.0)  # the dummy's TIC
    assert np.isclose(rms(y, zero), root_mean_square(y))


def test_batched_scores_over_windows_equal_the_scores_of_each_window():
    """(W, N, k) with axis=1 -> (W, k): the same numbers as scoring every window on its own (axis 0)."""
    rng = np.random.default_rng(3)
    measured = rng.normal(size=(4, 30, 3))
    predicted = measured + rng.normal(scale=0.5, size=(4, 30, 3))
    predicted[2, :, 1] = 0.0  # one dummy-like column
    measured[3, :, 2] = predicted[3, :, 2] = 0.0  # one window with both signals zero
    per_window_rms = np.array([rms(measured[w], predicted[w]) for w in range(4)])
    per_window_tic = np.array([tic(measured[w], predicted[w]) for w in range(4)])
    np.testing.assert_allclose(rms(measured, predicted, axis=1), per_window_rms)
    np.testing.assert_allclose(tic(measured, predicted, axis=1), per_window_tic)
    assert tic(measured, predicted, axis=1)[2, 1] == 1.0 and tic(measured, predicted, axis=1)[3, 2] == 0.0


def test_diagnosis_window_scores_are_the_scorer_over_the_rows_after_the_warm_start():
    """A batch whose error is 9 on the warm rows and 2 after: the warm rows are not scored."""
    warm, n = 5, 25
    measured = np.ones((2, n, len(VARIABLES)))
    predicted = measured.copy()
    predicted[:, :warm] += 9.0
    predicted[:, warm:] -= 2.0  # y_p = -1 after the warm start: RMS 2, TIC 2 / (1 + 1)
    batch = SimpleNamespace(measured=measured, warm=warm)
    cols = [INDEX["vel_x"], INDEX["yaw_acc"]]
    np.testing.assert_allclose(window_rms(batch, predicted, cols), np.full((2, 2), 2.0))
    np.testing.assert_allclose(window_tic(batch, predicted, cols), np.full((2, 2), 1.0))
    assert window_rms(batch, predicted).shape == (2, len(VARIABLES))


def test_mae_by_horizon_and_simerr_of_known_errors():
    """e_{s,h} = s + h (3 starts): MAE_h = 1 + h; SimErr = sum_{h=1..50} (1 + h) = 50 + 1275."""
    starts, horizons = np.arange(3)[:, None], np.arange(1, 51)[None, :]
    mae = mae_by_horizon((starts + horizons).astype(float))
    np.testing.assert_allclose(mae, 1.0 + np.arange(1, 51))
    assert sim_err(mae) == 1325.0
    assert sim_err(np.ones(80)) == SIM_ERR_HORIZON == 50  # only h = 1..50 count
    # Norms of error 3-vectors: (3, 4, 0) and (0, 0, 1) at one horizon -> MAE 3
    norms = vector_error_norm(np.array([[[3.0, 4.0, 0.0]], [[0.0, 0.0, 1.0]]]), np.zeros((2, 1, 3)))
    np.testing.assert_allclose(mae_by_horizon(norms), [3.0])


def test_mae_without_starts_and_simerr_of_too_few_horizons_are_data_errors():
    with pytest.raises(DataError, match="at least one start"):
        mae_by_horizon(np.zeros((0, 50)))
    with pytest.raises(DataError, match="h = 1..50, got only 10"):
        sim_err(np.ones(10))


def test_span_scores_are_the_mean_of_the_window_scores():
    scores = SpanScores.over_windows([np.array([1.0, 2.0]), np.array([3.0, 6.0])], [np.array([0.2, 0.0]), np.array([0.4, 1.0])])
    np.testing.assert_allclose(scores.rms, [2.0, 4.0])
    np.testing.assert_allclose(scores.tic, [0.3, 0.5])
    assert scores.windows == 2
