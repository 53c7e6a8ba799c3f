"""Live forms under a real timer: jittered command intervals are integrated, not refused; physical bounds."""

import dataclasses

import numpy as np

from quad_modelling.core.models.bounds import MARGIN, PhysicalBounds
from quad_modelling.core.models.greybox import GreyboxModel, GreyboxPredictor, GreyboxStream
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from test.conftest import synthetic_log


def test_greybox_stream_steps_over_the_real_jittered_intervals_exactly():
    """The linear model is exact under zero-order hold: stepping a 100 Hz timer with +-2 ms jitter (stamps on a
    1 ms grid) must give the states of the same model stepped every 1 ms with each command held until the next."""
    vehicle = load_vehicle("crazyflie21")
    continuous = GreyboxModel(vehicle)
    rng = np.random.default_rng(7)
    stamps_ms = np.cumsum(10 + rng.integers(-2, 3, 60))  # 8..12 ms steps
    commands = 200.0 * rng.standard_normal((60, 4))  # trimmed inputs [PWM counts]
    x0 = np.zeros(16)
    x0[3], x0[9] = 0.3, 0.05  # moving north, rolled
    nominal = continuous.discretise(0.01)
    stream = GreyboxStream(nominal, nominal.ad @ x0 + nominal.bd @ commands[0], np.zeros(4), np.zeros(18), continuous,
                           (float(stamps_ms[0]) / 1e3, x0, commands[0]))
    pushed = np.array([stream.push_at(commands[k], stamps_ms[k] / 1e3) for k in range(1, 60)])

    fine = continuous.discretise(0.001)
    x, expected = x0.copy(), []
    for k in range(1, 60):
        for _ in range(int(stamps_ms[k] - stamps_ms[k - 1])):  # command k-1 held until stamp k
            x = fine.ad @ x + fine.bd @ commands[k - 1]
        expected.append(fine.cd @ x + fine.dd @ commands[k])
    assert np.allclose(pushed, np.array(expected), rtol=1e-9, atol=1e-9)
    assert np.abs(pushed[:, 0]).max() > 0.1  # it moved (0.3 m/s for ~0.6 s)


def test_greybox_starts_a_window_on_a_jittered_500_hz_timer_instead_of_refusing_it():
    """+-0.9 ms jitter on a 2 ms period (steps 0.2..3.8 ms, beyond the offline 25 % uniformity check)."""
    vehicle = load_vehicle("crazyflie21")
    log = synthetic_log(n=400, rate=500.0)
    rng = np.random.default_rng(1)
    jittered = dataclasses.replace(log, t=log.t + rng.uniform(-0.0009, 0.0009, len(log)))
    assert np.ptp(np.diff(jittered.t)) > 0.5 * 0.002
    predictions = predict_window_by_stream(GreyboxPredictor(vehicle), jittered, 100)
    assert np.isfinite(predictions).all()
    uniform = predict_window_by_stream(GreyboxPredictor(vehicle), log, 100)
    # 0.6 s of open loop on the same commands: the jitter moves the position by millimetres, not metres
    assert np.abs(predictions[:, 0:3] - uniform[:, 0:3]).max() < 0.02


def test_bounds_come_from_the_vehicle_and_reject_a_diverged_prediction_but_not_a_flight():
    vehicle = load_vehicle("crazyflie21")
    bounds = PhysicalBounds.from_vehicle(vehicle)
    # full thrust of four rotors (Omega_0 + B_m/|A_m| * 65535 = 1924 + 2672 = 4596 rad/s, the greybox's constants
    # derived from k_f 1.788e-8, k_u 0.0408, tau_m 0.05) on 27 g: 55.9 m/s² plus g, times the margin
    assert 50 * MARGIN < bounds.max_acceleration - MARGIN * GRAVITY < 60 * MARGIN
    log = synthetic_log(n=300)
    predicted = predict_window_by_stream(GreyboxPredictor(vehicle), log, 20)
    elapsed = log.t - log.t[19]
    assert bounds.violation(predicted, elapsed, predicted[19]) is None
    absurd = predicted.copy()
    absurd[150, 0] = 1e30  # a finite but absurd position
    message = bounds.violation(absurd, elapsed, predicted[19])
    assert message is not None and message.startswith("position change 1e+30 m beyond")
    spin = predicted.copy()
    spin[200, 15] = 1e8  # 1e8 rad/s² angular acceleration (the bound: 2.6e6)
    assert bounds.violation(spin, elapsed, predicted[19]).startswith("angular acceleration")


def test_one_row_at_a_time_the_bounds_say_what_the_batch_says():
    """The live predictor tests one row per input (the float path): the same verdict and sentence as the batch."""
    vehicle = load_vehicle("crazyflie21")
    bounds = PhysicalBounds.from_vehicle(vehicle)
    log = synthetic_log(n=300)
    predicted = predict_window_by_stream(GreyboxPredictor(vehicle), log, 20)
    elapsed = log.t - log.t[19]
    rng = np.random.default_rng(4)
    spoiled = predicted.copy()
    rows = rng.choice(np.arange(20, 300), 40, replace=False)
    columns = rng.integers(0, 18, 40)
    spoiled[rows, columns] = rng.choice([1e30, -1e9, np.nan, np.inf, 2.6e6], 40)
    verdicts = []
    for i in range(20, 300):
        row = bounds.violation(spoiled[i], elapsed[i], predicted[19])
        assert row == bounds.violation(spoiled[i:i + 1], elapsed[i:i + 1], predicted[19])
        verdicts.append(row)
    flagged = {i for i, v in zip(range(20, 300), verdicts) if v is not None}
    assert flagged <= set(rows.tolist()) and len(flagged) >= 25  # only spoiled rows; the attitude is not bounded
