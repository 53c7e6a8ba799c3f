"""The sensor ceiling: a perfect model anchored as the diagnosis anchors carries the IMU bias (the warm start
does), so only what no model can predict -- the white noise and the bias walk after the warm start -- is left."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from quad_modelling.core.diagnosis.ceiling import perfect_model_prediction, sensor_ceiling
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG
from quad_modelling.core.diagnosis.fitting import variable_scales
from quad_modelling.core.diagnosis.statistics import window_rms
from quad_modelling.core.diagnosis.validation import noise_free_imu_log
from quad_modelling.core.identification.base_model import BaseModel, predict_batch
from quad_modelling.core.identification.window_batch import prepare_windows
from quad_modelling.core.models.greybox import GreyboxParameters
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.core.sim.simulate import run_simulation
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import DataError

SCORED = ("acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc", "yaw_acc")


@pytest.fixture(scope="module")
def linkquad():
    return load_vehicle("linkquad")


def _run(sensors_change: dict, seed: int = 7):
    params = sim_params_for("linkquad")
    return run_simulation("linkquad", effects=(), seed=seed, duration=35.0, params=replace(params, sensors=replace(params.sensors, **sensors_change)))


@pytest.fixture(scope="module")
def biased(linkquad):
    """An IMU with a large turn-on bias (0.5 m/s², 0.02 rad/s) and no white noise or walk: (measured, noise-free,
    true-signal) batches of the same windows."""
    run = _run({"acc_noise": 0.0, "acc_drift": 0.0, "acc_bias": 0.5, "gyro_noise": 0.0, "gyro_drift": 0.0, "gyro_bias": 0.02})
    truth = replace(run.log, acc_b=run.truth["specific_force_b"], gyro_b=run.truth["rates_b"])
    return tuple(prepare_windows([log], linkquad, DIAGNOSIS_CONFIG) for log in (run.log, noise_free_imu_log(run), truth))


def test_the_perfect_model_of_a_noise_free_imu_is_the_measurement(biased):
    """With no white noise the noise-free IMU is the IMU: the perfect model predicts the scored variables exactly."""
    measured, sensor, _ = biased
    np.testing.assert_allclose(sensor.measured, measured.measured, atol=1e-12)
    perfect = perfect_model_prediction(measured, sensor)
    cols = [INDEX[v] for v in SCORED]
    np.testing.assert_allclose(perfect[:, measured.warm :, cols], measured.measured[:, measured.warm :, cols], atol=1e-12)


def test_the_bias_turning_with_the_attitude_is_carried_not_charged(biased, linkquad):
    """The previous ceiling compared the measurement with the true signals and charged the model for the
    accelerometer bias turning with the attitude (0.5 m/s² here): the perfect model carries it, as the base model's
    warm-start body force does, and leaves no gap; the true signals leave one on acc_x/acc_y."""
    measured, sensor, truth = biased
    perfect = perfect_model_prediction(measured, sensor)
    cols = [INDEX[v] for v in ("acc_x", "acc_y")]
    assert window_rms(measured, perfect, cols).max() < 1e-9
    assert window_rms(measured, truth.measured, cols).mean() > 5e-3
    base = BaseModel(GreyboxParameters.from_vehicle(linkquad))
    predicted = predict_batch(base, measured)
    ceiling = sensor_ceiling(measured, sensor, predicted, variable_scales(measured, predicted), SCORED)
    assert ceiling["sensor_ceiling"] == pytest.approx(1.0, abs=1e-6)
    assert all(value == pytest.approx(1.0, abs=1e-6) for value in ceiling["by_variable"].values())


def test_white_noise_is_the_gap_no_model_removes(linkquad):
    """The simulator's IMU as designed: the perfect model keeps a gap (the noise through the derivative and the
    3 Hz low-pass), so the ceiling is below 1, above 0, and the same per variable as for the run."""
    run = _run({})
    measured, sensor = (prepare_windows([log], linkquad, DIAGNOSIS_CONFIG) for log in (run.log, noise_free_imu_log(run)))
    base = BaseModel(GreyboxParameters.from_vehicle(linkquad))
    predicted = predict_batch(base, measured)
    scales = variable_scales(measured, predicted)
    ceiling = sensor_ceiling(measured, sensor, predicted, scales, ("roll_acc",))
    assert 0.0 < ceiling["sensor_ceiling"] < 1.0
    assert ceiling["by_variable"]["roll_acc"] == pytest.approx(ceiling["sensor_ceiling"], abs=1e-9)
    assert ceiling["gap_perfect"] > 0.0
    with pytest.raises(DataError, match="other windows"):
        perfect_model_prediction(measured, measured.subset(np.arange(len(measured) - 1)))
