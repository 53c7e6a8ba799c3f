"""The batch predictor of the linear greybox on the linear model's own flights: the true constants predict
the measurement, and the one fit recovers them."""

import numpy as np
import pytest

from quad_modelling.core.identification.base_model import (
    base_from_vehicle,
    predict_batch,
)
from quad_modelling.core.identification.greybox_fit import identify_base
from quad_modelling.core.identification.window_batch import prepare_windows
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig, SpanSpec
from test.core.flightgen import linear_flight


@pytest.fixture(scope="module")
def truth_and_batch():
    truth = load_vehicle("crazyflie21").with_greybox({"motor_a_m": -25.0, "motor_b_m": 0.5}, "test truth")
    flights = [linear_flight(truth, duration=60.0, seed=s, source=f"f{s}.csv") for s in range(2)]
    config = EvaluationConfig(drop_start=5, drop_end=5, train="5:45", eval="45:55")
    return truth, prepare_windows(flights, load_vehicle("crazyflie21"), config, SpanSpec.parse("train", config.train))


def test_true_constants_predict_the_acceleration_of_their_own_flight(truth_and_batch):
    """The motor is anchored on the warm-start mean thrust (the point the measured offsets belong to): the
    open-loop acc_z of the true model equals the measurement (was 0.023 m/s² RMS off, signal 0.070 m/s²)."""
    truth, batch = truth_and_batch
    column = INDEX["acc_z"]
    predicted = predict_batch(base_from_vehicle(truth), batch, columns=[column])
    error = batch.measured[:, batch.warm :, column] - predicted[:, batch.warm :, column]
    # 0.0550 m/s²: K = 2 B_m sqrt(a m g / 4) with a = k_f 1.788e-8 (0.0698 with the old greybox a = 2.88e-8)
    assert np.sqrt(np.mean(batch.measured[:, batch.warm :, column] ** 2)) == pytest.approx(0.0550, abs=5e-4)
    assert np.sqrt(np.mean(error**2)) < 1e-6


def test_the_fit_recovers_the_motor_and_leaves_out_what_the_windows_do_not_excite(truth_and_batch):
    """Collective-only flights: roll/pitch/yaw acceleration are ~1e-16, left out with the constants only they show."""
    _, batch = truth_and_batch
    fit = identify_base(batch, load_vehicle("crazyflie21"))  # starts from A_m -20, B_m 0.815 (derived)
    assert fit.values["motor_a_m"] == pytest.approx(-25.0, rel=1e-4)
    assert fit.values["motor_b_m"] == pytest.approx(0.5, rel=1e-4)
    assert set(fit.fit["not_excited"]) == {"roll_acc", "pitch_acc", "yaw_acc"}
    assert fit.fit["held"] == ["yaw_drag_ratio", "arm_scale", "rotor_reaction_scale"]
    assert fit.values["arm_scale"] == 1.0 and fit.values["rotor_reaction_scale"] == pytest.approx(1.0)
    assert np.isnan(fit.sigma["torque_constant"]) and fit.sigma["motor_a_m"] > 0
