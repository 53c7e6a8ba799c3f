"""Known-answer validation run as a user runs it: the base identified on the effect-on flights, single effects
scored against their sensor ceiling, an out-of-catalogue disturbance left unexplained, pairs only of searched
effects."""

from __future__ import annotations

from dataclasses import replace

import pytest

from quad_modelling.core.diagnosis.validation import check_pairs, validate, validation_cases
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.errors import ConfigError
from quad_modelling.io.reports.validation import validation_markdown, validation_summary

pytestmark = pytest.mark.slow  # the greybox --validate: simulated flights on a local Dask cluster (about 1 min): `make test-slow`

DURATION = 45.0


@pytest.fixture(scope="module")
def result():
    """Seed 0: motor imbalance alone, the null case and the CoM-offset disturbance, base fitted the user's way."""
    return validate("linkquad", effects=("motor_imbalance",), seeds=(0,), pairs=[], disturbances=("com_offset",), duration=DURATION,
                    jobs=2)  # three cases on two local workers: the fan-out as --validate runs it


def test_a_withheld_effect_is_found_with_the_base_fitted_on_the_same_effect_on_flights(result):
    run = result["runs"][0]
    assert result["base_from"] == "effects-on" and "effect-on training flights" in result["flights"]["base"]
    assert run["effect"] == "motor_imbalance" and run["top"] == "motor_imbalance" and run["verdict"] == "found"
    assert run["right"] and result["accuracy"] == 1.0
    assert run["params"]["cg_x"] > 0 and run["params"]["cg_y"] < 0  # the simulator's CG offset: +6 mm, -4 mm


def test_the_shrink_stays_below_its_sensor_ceiling(result):
    """The perfect model's ceiling bounds the literal shrink (target: never more than 2 points above it)."""
    run = result["runs"][0]
    assert 0.2 < run["sensor_ceiling"] < 1.0
    assert run["shrink"] <= run["sensor_ceiling"] + 0.02
    assert set(run["ceiling_by_variable"]) == set(run["variables"])
    assert run["ceiling_fraction"] == pytest.approx(run["shrink"] / run["sensor_ceiling"])
    assert result["targets"]["shrink_not_above_ceiling"]["above"] == 0


def test_null_and_out_of_catalogue_cases_find_nothing_and_say_where_the_gap_lies(result):
    assert [n["right"] for n in result["null"]["runs"]] == [True]
    com = result["disturbances"][0]
    assert com["effects"] == ["com_offset"] and com["found"] == [] and com["right"]
    assert com["where"]["variables"] and com["where"]["bands"]
    assert abs(sum(share for _, share in com["where"]["variables"])) <= 1.0
    assert result["targets"]["disturbances_unexplained"] == {"target": "nothing found", "runs": 1, "right": 1}


def test_the_report_states_the_targets_in_lines_of_at_most_100_characters(result):
    text = validation_markdown(result)
    assert "## Targets" in text and "disturbances: nothing found" in text
    assert max(len(line) for line in text.splitlines()) <= 100
    assert validation_summary(result).startswith("single 100% of 1; null 1/1 clean")


def test_pairs_are_scored_only_over_searched_effects():
    assert check_pairs([("rotor_drag", "battery")], ("rotor_drag", "battery", "motor_lag")) == [("rotor_drag", "battery")]
    with pytest.raises(ConfigError, match="'battery' is not among the searched --effects"):
        check_pairs([("rotor_drag", "battery")], ("rotor_drag", "motor_lag"))
    with pytest.raises(ConfigError, match="no effect the simulator switches"):
        check_pairs([("rotor_drag", "wind")], ("rotor_drag",))
    with pytest.raises(ConfigError, match="two different effects"):
        check_pairs([("rotor_drag", "rotor_drag")], ("rotor_drag",))
    # the default pairs are cut to the searched effects instead of failing
    cases = validation_cases(("rotor_drag", "battery"), (0, 1), [("rotor_drag", "battery")], True, ("wind",))
    assert [(c.kind, c.label) for c in cases if c.seed == 0] == [
        ("single", "rotor_drag"), ("single", "battery"), ("null", "none"), ("pair", "rotor_drag + battery"),
        ("all", "rotor_drag + battery"), ("disturbance", "wind")]
    with pytest.raises(ConfigError, match="--base-from"):
        validate("linkquad", effects=("battery",), seeds=(0,), base_from="yesterday")


def test_effects_off_base_mode_and_a_perfect_imu_reach_a_ceiling_of_one():
    """The comparison mode identifies the base on the seeds flown with every effect off; with an IMU without noise,
    bias or drift the noise-free IMU is the IMU and nothing is out of a perfect model's reach."""
    params = sim_params_for("linkquad")
    perfect = replace(params.sensors, acc_noise=0.0, acc_bias=0.0, acc_drift=0.0, gyro_noise=0.0, gyro_bias=0.0, gyro_drift=0.0)
    result = validate("linkquad", effects=("motor_imbalance",), seeds=(0,), pairs=[], disturbances=(), null=False,
                      duration=DURATION, sim_params=replace(params, sensors=perfect), base_from="effects-off",
                      catalogue=("motor_imbalance", "battery", "rotor_drag"))
    run = result["runs"][0]
    assert "every effect off" in result["flights"]["base"]
    assert run["sensor_ceiling"] == pytest.approx(1.0)
    assert run["right"]
