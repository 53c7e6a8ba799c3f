"""Issue 18: a flight without accelerometer or gyro is a flight; what needs them says so; commands saturate."""

import dataclasses

import numpy as np
import pytest

from quad_modelling.core.evaluation.windowed import evaluate
from quad_modelling.core.flight_log import saturate_commands
from quad_modelling.core.identification.identify import identify
from quad_modelling.core.models.base import ConstantStatePredictor
from quad_modelling.core.models.greybox import GreyboxPredictor
from quad_modelling.core.models.narx import measured_outputs
from quad_modelling.core.preprocess import (
    attitude_rates,
    measured_variables,
    state_measurement,
    unmeasured_variables,
)
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import DataError
from test.conftest import synthetic_log
from test.core.flightgen import linear_flight


def pose_only(log):
    return dataclasses.replace(log, acc_b=None, gyro_b=None, meta=dataclasses.replace(log.meta, source="pose.mat"))


def test_a_log_without_imu_validates_and_names_what_it_lacks():
    log = pose_only(synthetic_log())
    assert log.missing_sensors() == ["acc_b", "gyro_b"] and len(log.slice(10, 20)) == 10
    with pytest.raises(DataError) as info:
        log.require(("acc_b", "gyro_b"), "identify")
    assert str(info.value) == "pose.mat: identify needs the accelerometer (acc_b) and the gyro (gyro_b), which this flight does not have"
    log.require(("vbat",), "anything")  # present: no error


def test_unmeasured_variables_are_nan_and_named_by_sensor():
    full = synthetic_log()
    no_gyro = dataclasses.replace(full, gyro_b=None)
    measured = measured_variables(no_gyro)
    assert unmeasured_variables(no_gyro) == {v: "gyro" for v in ("roll_rate", "pitch_rate", "yaw_rate", "roll_acc", "pitch_acc", "yaw_acc")}
    assert np.isnan(measured[:, 12:18]).all()
    np.testing.assert_array_equal(measured[:, :12], measured_variables(full)[:, :12])
    assert list(unmeasured_variables(pose_only(full))) == ["acc_x", "acc_y", "acc_z", "roll_rate", "pitch_rate", "yaw_rate",
                                                           "roll_acc", "pitch_acc", "yaw_acc"]


def test_attitude_rates_follow_the_euler_kinematics():
    # Constant roll 0.3 rad, level pitch, yaw turning at 0.5 rad/s: p = 0, q = 0.5 sin 0.3, r = 0.5 cos 0.3.
    log = synthetic_log(n=200)
    euler = np.column_stack([np.full(200, 0.3), np.zeros(200), (0.5 * (log.t - log.t[0]) + np.pi) % (2 * np.pi) - np.pi])
    log = dataclasses.replace(log, euler=euler, gyro_b=None)
    rates = attitude_rates(log)
    np.testing.assert_allclose(rates, np.tile([0.0, 0.5 * np.sin(0.3), 0.5 * np.cos(0.3)], (200, 1)), atol=1e-9)
    state = state_measurement(log)
    np.testing.assert_allclose(state[:, 12:15], rates)
    np.testing.assert_allclose(state[:, 15:18], 0.0, atol=1e-9)


def test_pose_only_flight_scores_velocity_like_the_full_flight_and_marks_the_rest():
    vehicle = load_vehicle("linkquad")
    full = linear_flight(vehicle, duration=42.0, seed=0)
    models = [ConstantStatePredictor(vehicle), GreyboxPredictor(vehicle)]
    config = EvaluationConfig.preset("short")
    with_imu = evaluate([full], models, vehicle, config).to_json()
    without = evaluate([pose_only(full)], models, vehicle, config).to_json()
    for model in ("naive", "greybox"):
        scores = without["models"][model]["eval"]
        for v in ("vel_x", "vel_y", "vel_z"):  # level collective flight: rates from the attitude equal the gyro's (zero)
            assert scores[v]["tic"] == pytest.approx(with_imu["models"][model]["eval"][v]["tic"], abs=1e-3)
        assert scores["vel_z"]["rms"] == pytest.approx(with_imu["models"][model]["eval"]["vel_z"]["rms"], rel=1e-9)
        assert scores["acc_z"] == {"rms": None, "tic": None, "needs": "accelerometer"}
        assert scores["yaw_acc"] == {"rms": None, "tic": None, "needs": "gyro"}
    greybox = without["horizons"]["models"]["greybox"]
    assert greybox["angular_velocity"] == {"needs": "gyro"}
    assert greybox["velocity"]["sim_err"] == pytest.approx(with_imu["horizons"]["models"]["greybox"]["velocity"]["sim_err"], rel=1e-9)
    # the greybox flew this flight: far better than holding the state (0.015 with the causal trim of the second
    # before each start)
    assert greybox["position"]["ratio_sim_err"] < 0.02


def test_what_needs_a_missing_sensor_refuses_in_one_line():
    vehicle = load_vehicle("linkquad")
    log = pose_only(linear_flight(vehicle, duration=42.0, seed=0))
    with pytest.raises(DataError, match=r"^pose.mat: identify \(it fits the measured Z and angular accelerations\) needs the "
                                         r"accelerometer \(acc_b\) and the gyro \(gyro_b\), which this flight does not have$"):
        identify([log], vehicle, EvaluationConfig.preset("short"))
    with pytest.raises(DataError, match=r"^pose.mat: NARX training \(its outputs are velocities and gyro rates\) needs the gyro"):
        measured_outputs(log)


def test_saturation_clips_both_ends_within_the_margin_and_refuses_beyond():
    t = 10.0 + np.arange(6) * 0.01
    u = np.full((6, 4), 1.5e-3)
    u[2, 0], u[3, 0], u[4, 3] = 2.13e-3, 2.11e-3, 0.85e-3  # 2.5 % above, 0.8 % above, 4.2 % below [0.9, 2.1] ms
    clipped, warnings, counts = saturate_commands(u, t, 0.0009, 0.0021, "lab.mat", "linkquad", "s")
    assert clipped[2, 0] == clipped[3, 0] == 0.0021 and clipped[4, 3] == 0.0009 and counts == {"u1": 2, "u4": 1}
    assert warnings == [
        "lab.mat: column u1: 2 values above the linkquad input range [0.0009, 0.0021] s clipped (max 0.00213 at row 3, t=0.02 s)",
        "lab.mat: column u4: 1 values below the linkquad input range [0.0009, 0.0021] s clipped (min 0.00085 at row 5, t=0.04 s)",
    ]
    u[5, 1] = 2.2e-3  # 8.3 % beyond
    with pytest.raises(DataError, match=r"^lab.mat: column u2 data row 6 \(t=0.05 s into the flight\) is 0.0022, outside the linkquad"):
        saturate_commands(u, t, 0.0009, 0.0021, "lab.mat", "linkquad", "s")
    with pytest.raises(DataError, match=r"column m1 data row 1 .* is -1, outside the cf input range \[0, 65535\] PWM"):
        saturate_commands(np.array([[-1.0, 0, 0, 0], [0, 0, 0, 0]]), t[:2], 0, 65535, "f.csv", "cf", "PWM", ("m1", "m2", "m3", "m4"))
