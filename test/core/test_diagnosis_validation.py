"""Known-answer validation: the effect-attributable gap reported next to the literal shrink."""

from __future__ import annotations

import pytest

from quad_modelling.core.diagnosis_validation import validate


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
    assert set(result["metrics"]) == {"shrink", "attributable_share", "attributable_removed"}
    assert result["null"]["found"] == []
