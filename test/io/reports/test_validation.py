"""Validation report text: the targets table, the shrink against the ceiling, the cases, from known case results."""

from quad_modelling.core.diagnosis.validation import summarise
from quad_modelling.io.reports.validation import validation_markdown, validation_summary


def _single(effect, seed, top, right, shrink, ceiling, verdict, reason="", ranking=None):
    return {"kind": "single", "effects": [effect], "seed": seed, "effect": effect, "top": top, "right": right,
            "right_by_signature": right or (effect == "battery" and top == "trim_drift"), "inseparable_twin_first": False,
            "shrink": shrink, "sensor_ceiling": ceiling, "ceiling_fraction": shrink / ceiling, "shrink_above_ceiling": shrink - ceiling,
            "verdict": verdict, "reason": reason, "ranking": ranking or [top], "found": [top] if verdict == "found" or not right else [effect],
            "variables": ["acc_z"], "ceiling_by_variable": {"acc_z": ceiling}}


def _validation():
    results = [
        _single("motor_lag", 0, "motor_lag", True, 0.62, 0.75, "found"),
        _single("battery", 0, "trim_drift", False, 0.04, 0.3, "not supported", "held-out shrink 3.8% < 5%", ["trim_drift", "battery"]),
        {"kind": "null", "effects": [], "seed": 0, "found": [], "right": True,
         "where": {"variables": [("acc_x", 0.22), ("pitch_acc", 0.21)], "bands": [("0-0.2 Hz", 0.35)]}},
        {"kind": "disturbance", "effects": ["bent_arm"], "seed": 0, "found": ["motor_imbalance"], "right": False,
         "where": {"variables": [("pitch_acc", 0.23)], "bands": [("0-0.2 Hz", 0.59)]}},
        {"kind": "pair", "effects": ["motor_lag", "rotor_drag"], "seed": 0, "top3": ["motor_lag", "rotor_drag", "battery"],
         "found": ["motor_lag", "rotor_drag"], "right": True},
        {"kind": "all", "effects": ["motor_lag", "battery", "rotor_drag"], "seed": 0, "found_of_on": ["motor_lag", "rotor_drag"],
         "right": False, "false": ["trim_drift"]},
    ]
    return summarise(results, "linkquad", (0,), 90.0, "effects-on", ("motor_lag", "battery"), 123.4, 2)


def test_targets_come_first_with_the_measured_values():
    lines = validation_markdown(_validation()).splitlines()
    assert lines[0] == "# Diagnosis validation on simulated linkquad flights"
    start = lines.index("## Targets")
    assert lines[start + 2:start + 6] == [
        "| target | wanted | measured |",
        "|---|---|---|",
        "| single effects right (first and found) | >= 90 % | 50% of 2 |",
        "| ... or a signature first (battery: trim drift) |  | 100% |",
    ]
    assert "| shrink >= 80 % of a ceiling >= 20 % | all runs | 1 of 2 (min 13%) |" in lines
    assert "| pairs: both found in the top 3 | >= 90 % | 100% of 1 |" in lines
    assert "| disturbances: nothing found | all | 0 of 1 |" in lines
    # three effects on: the target that applies to three, not issue #17's ">= 5 of 7" (it read so beside "2 of 3")
    assert "| all effects on: found | all 3 found (3 effects run; the target >= 5 of 7 is for all 7) | 2 of 3 |" in lines
    assert "| time | < 600 s on 2 cores | 123 s (jobs 2) |" in lines
    assert max(len(line) for line in lines) <= 100


def test_cases_wrong_runs_and_where_the_gap_lies():
    text = validation_markdown(_validation())
    assert "| battery | 0 | trim_drift | no | 4.0% | 30.0% | not supported |" in text
    assert "- battery seed 0: ranked trim_drift, battery; battery not supported: held-out shrink 3.8% < 5%" in text
    assert "| bent_arm | 0 | motor_imbalance | no | pitch_acc 23%, 0-0.2 Hz 59% |" in text
    assert "All effects on, seed 0: 2 of 3 found (motor_lag, rotor_drag); missed: battery; found but not on: trim_drift." in \
        " ".join(text.split())


def test_validation_summary_line():
    assert validation_summary(_validation()) == (
        "single 50% of 2; null 1/1 clean; pairs 100%; all on: 2/3 found; disturbances 0/1 unexplained")
