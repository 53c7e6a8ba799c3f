"""Known-answer validation: the effect-attributable gap and the sensor ceiling reported next to the literal shrink."""

from __future__ import annotations

from dataclasses import replace

import pytest

from quad_modelling.core.diagnosis.validation import validate
from quad_modelling.core.sim.params import sim_params_for


@pytest.fixture(scope="module")
def result():
    return validate("linkquad", effects=("motor_imbalance",), seeds=(0,), pairs=(), duration=45.0)


def test_attributable_gap_of_a_withheld_effect(result):
    run = result["runs"][0]
    assert run["effect"] == "motor_imbalance" and run["correct"]
    # the effect-on test flight has a larger base-model gap than its effect-off twin (same seed and script)
    assert run["gap_on"] > run["gap_off"] > 0.0
    assert 0.1 < run["attributable_share"] < 1.0
    assert run["attributable_share"] == pytest.approx(1.0 - run["gap_off"] / run["gap_on"])
    # the fitted effect removes most of the attributable gap
    assert run["attributable_removed"] > 0.8  # 0.99 on this seed
    # (G_on - G_after)/G_on = (1 - G_off/G_on) (G_on - G_after)/(G_on - G_off)
    assert run["shrink_all_windows"] == pytest.approx(run["attributable_share"] * run["attributable_removed"])
    summary = result["attributable_removed_by_effect"]["motor_imbalance"]
    assert summary["min"] == summary["median"] == pytest.approx(run["attributable_removed"])
    assert set(result["metrics"]) == {"shrink", "attributable_share", "attributable_removed", "sensor_ceiling"}
    assert result["null"]["found"] == []


def test_sensor_ceiling_bounds_the_literal_shrink(result):
    run = result["runs"][0]
    # the IMU noise left after the derivative and the 3 Hz low-pass is a gap no model can remove
    assert run["gap_sensor"] > 0.0
    assert 0.5 < run["sensor_ceiling"] < 1.0  # 0.89 on this seed (shrink 0.81)
    assert run["shrink"] < run["sensor_ceiling"]
    assert result["sensor_ceiling_by_effect"]["motor_imbalance"]["median"] == pytest.approx(run["sensor_ceiling"])


def test_sensor_ceiling_of_a_perfect_imu_is_one():
    """With an IMU without noise, bias or drift the measurement is the truth: nothing is out of reach."""
    params = sim_params_for("linkquad")
    perfect = replace(params.sensors, acc_noise=0.0, acc_bias=0.0, acc_drift=0.0, gyro_noise=0.0, gyro_bias=0.0, gyro_drift=0.0)
    result = validate("linkquad", effects=("motor_imbalance",), seeds=(0,), pairs=(), duration=45.0,
                      sim_params=replace(params, sensors=perfect))
    run = result["runs"][0]
    assert run["gap_sensor"] == pytest.approx(0.0, abs=1e-12)
    assert run["sensor_ceiling"] == pytest.approx(1.0)
    assert run["correct"]
