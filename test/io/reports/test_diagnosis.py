"""Diagnosis report text: the verdict and the exact tables of report.md from a known diagnosis document."""

import math

from quad_modelling.core.variables import EVAL_VARIABLES
from quad_modelling.io.reports.diagnosis import markdown_report, verdict_text


def test_verdict_text_names_the_effect_and_the_shrink():
    gap = {v: {"rms": 1.0, "tic": 0.5} for v in ("vel_x", "vel_y", "vel_z", "acc_x", "acc_y", "acc_z", "roll_rate", "pitch_rate",
                                                  "yaw_rate", "roll_acc", "pitch_acc", "yaw_acc")}
    effect = {"name": "rotor_drag", "summary": "drag", "variables": ["acc_x"], "shrink": 0.4, "train_shrink": 0.45,
              "after": {**{v: 1.0 for v in gap}, "acc_x": 0.6}, "verdict": "found", "confounded_with": ["battery"],
              "evidence": {"shrink_ci90": [0.3, 0.5], "windows_improved": 9, "windows": 10}}
    text = verdict_text({"gap": gap, "regimes": {"regimes": {}}, "effects": [effect], "ladder": [{}], "learnable": {}})
    assert "rotor_drag" in text and "40%" in text and "9/10" in text and "battery" in text
    none = verdict_text({"gap": gap, "regimes": {"regimes": {}}, "effects": [{**effect, "verdict": "insignificant"}], "ladder": [{}]})
    assert "none found" in none


def _document(effects, learnable=None):
    """A diagnosis document: every variable's base RMS 0.1 (SI), TIC 0.5; the effects as given."""
    gap = {v: {"rms": 0.1, "tic": 0.5} for v in EVAL_VARIABLES}
    return {
        "config": {"train_flights": ["/data/a.mat"], "test_flights": ["/data/b.mat"], "drop_start": 6.0, "drop_end": 4.5, "warm_s": 0.2,
                   "smooth_cutoff_hz": 3.0},
        "windows": {"train_count": 7, "test_count": 7, "window_s": 5.0, "ground_contact_dropped": {"train": 0, "test": 1}},
        "base": {"note": "vehicle constants", "values": {"motor_a_m": -500.0}},
        "effects": effects, "rule": {"found": "shrink >= 0.05"}, "gap": gap, "learnable": learnable,
        "ladder": [{"effects": [], "normalised_gap": 1.0}, {"effects": ["rotor_drag"], "normalised_gap": 0.8}],
        "regimes": {"regimes": {"speed": {"edges": [0.0, 0.5, 1.0, 1.5, 2.0], "unit": "m/s", "normalised_rms": [1.0, 1.1, 1.2, 1.5],
                                          "ratio_top_to_bottom": 1.5},
                                "height": {"note": "too little spread"}},
                    "frequency": {"acc_z": {"0-1 Hz": 0.25, ">1 Hz": 0.75}},
                    "worst_windows": [{"flight": "/data/b.mat", "t_start_s": 10.0, "t_end_s": 15.0, "normalised_gap": 2.345}]},
    }


def _section(report: str, title: str) -> list[str]:
    """The table under the heading ``title``."""
    lines = report.splitlines()
    start = next(k for k in range(lines.index(title), len(lines)) if lines[k].startswith("|"))
    end = next((k for k in range(start, len(lines)) if not lines[k].startswith("|")), len(lines))
    return lines[start:end]


DRAG = {"name": "rotor_drag", "summary": "drag", "variables": ["acc_x"], "verdict": "found", "shrink": 0.4, "train_shrink": 0.45,
        "confounded_with": [], "params": {"k_d": 0.01234}, "after": {**{v: 0.1 for v in EVAL_VARIABLES}, "roll_acc": 0.05},
        "evidence": {"shrink_ci90": [0.3, math.nan], "windows_improved": 9, "windows": 10, "signature_correlation": 0.876}}
LAG = {"name": "motor_lag", "verdict": "insignificant", "shrink": 0.0, "train_shrink": 0.0, "evidence": {}, "note": "no window | excited",
       "after": {v: 0.1 for v in EVAL_VARIABLES}}


def test_report_tables_in_display_units():
    report = markdown_report(_document([DRAG, LAG], learnable={"gap": {v: {"rms": 0.02} for v in EVAL_VARIABLES}}), "linkquad", ["f.png"])
    assert _section(report, "## Effects (ranked by conditional contribution)") == [
        "| effect | verdict | held-out shrink | 90% interval | training shrink | windows better | signature corr. | confounded with "
        "| on top of | alone | parameters |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        "| rotor_drag | **found** | 40.0% | 30.0%..nan% | 45.0% | 9/10 | 0.88 | - | - | - | k_d=0.0123 |",
        "| motor_lag | insignificant | - | - | - | - | - | - | - | - | no window \\| excited |",
    ]
    gap = _section(report, "## Held-out gap per variable (display units)")
    assert gap[:3] == ["| variable | base RMS | base TIC | +rotor_drag | +motor_lag | NARX |", "|---|---|---|---|---|---|",
                       "| vel_x [m/s] | 0.1 | 0.50 | 0.1 | 0.1 | 0.02 |"]
    # 0.1 rad/s2 = 5.73 deg/s2; the effect brings roll_acc to 0.05 rad/s2 = 2.86 deg/s2
    assert gap[-3] == "| roll_acc [deg/s2] | 5.73 | 0.50 | 2.86 | 5.73 | 1.15 |"
    assert _section(report, "## Ladder") == ["| rung | mean RMS / base RMS (12 variables) |", "|---|---|", "| base | 1.000 |",
                                             "| base + rotor_drag | 0.800 |"]
    assert _section(report, "## Where: residual by regime") == [
        "| regime | quartile edges | RMS per quartile (low -> high) | top/bottom |", "|---|---|---|---|",
        "| speed [m/s] | 0, 0.5, 1, 1.5, 2 | 1.00, 1.10, 1.20, 1.50 | 1.50 |", "| height | - | too little spread | - |"]
    assert _section(report, "## Where: residual power by frequency band") == [
        "| variable | 0-1 Hz | >1 Hz |", "|---|---|---|", "| acc_z | 25% | 75% |"]
    assert _section(report, "## Worst held-out windows") == [
        "| flight | start [s] | end [s] | normalised gap |", "|---|---|---|---|", "| b.mat | 10.0 | 15.0 | 2.35 |"]
    assert report.endswith("## Figures\n\n![f.png](f.png)\n")


def test_gap_table_without_effects_or_floor_has_three_columns():
    gap = _section(markdown_report(_document([]), "linkquad", []), "## Held-out gap per variable (display units)")
    assert gap[:3] == ["| variable | base RMS | base TIC |", "|---|---|---|", "| vel_x [m/s] | 0.1 | 0.50 |"]
