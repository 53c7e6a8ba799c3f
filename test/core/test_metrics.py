import numpy as np

from quad_modelling.core.evaluation.metrics import rms, sim_err, tic, vector_error_norm


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
