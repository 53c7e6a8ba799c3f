"""Diagnosis report text: the verdict and the exact tables of report.md from known diagnosis documents,
every line at most 100 characters, the residual spectrum of a known residual."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from quad_modelling.core.diagnosis.localisation import rank_unexplained
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import EVAL_VARIABLES, INDEX
from quad_modelling.io.reports.diagnosis import markdown_report, residual_spectra, verdict_text, write_figures
from quad_modelling.io.reports.formatting import REPORT_WIDTH

LONG_RULE = ("held-out shrink >= 0.05 on the effect's variables, bootstrap 5% bound > 0 (1000 resamples of held-out windows), "
             ">= 60% of held-out windows improved; scored on the windows the effect excites (its correction >= 5% of the "
             "window's gap, at least 3 windows); " * 3)


def _where(best_first: str = "acc_z") -> dict:
    """rank_unexplained's document: ``best_first`` holds 60 % of the error, the 1-3 Hz band 70 %, speed 1.8x."""
    rest = [v for v in ("acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc", "yaw_acc") if v != best_first]
    variables = [{"variable": best_first, "rms": 0.1, "unit": "m/s2", "normalised": 1.2, "share": 0.6}]
    variables += [{"variable": v, "rms": 0.01, "unit": "rad/s2" if "_acc" in v else "m/s2", "normalised": 0.16, "share": 0.08}
                  for v in rest]
    return {
        "scored_variables": ["acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc", "yaw_acc"],
        "variables": variables,
        "regimes": [{"regime": "speed", "unit": "m/s", "quartile_edges": [0.0, 0.5, 1.0, 1.5, 2.0], "normalised_rms": [1.0, 1.2, 1.5, 1.8],
                     "ratio_top_to_bottom": 1.8, "ratio": 1.8, "side": "high", "concentrated": True},
                    {"regime": "height", "unit": "m", "quartile_edges": [0.1, 0.4, 0.5, 0.6, 1.0], "normalised_rms": [1.25, 1.1, 1.0, 1.0],
                     "ratio_top_to_bottom": 0.8, "ratio": 1.25, "side": "low", "concentrated": False},
                    {"regime": "tilt", "unit": "deg", "ratio_top_to_bottom": None, "ratio": None, "side": None, "concentrated": False,
                     "note": "constant over the held-out windows"}],
        "bands": [{"band": "1-3 Hz", "share": 0.7, "variables": [{"variable": best_first, "share": 0.9}, {"variable": "acc_x", "share": 0.05}]},
                  {"band": "0.2-1 Hz", "share": 0.2, "variables": [{"variable": "acc_x", "share": 0.5}]},
                  {"band": "0-0.2 Hz", "share": 0.08, "variables": [{"variable": "acc_y", "share": 0.5}]},
                  {"band": ">3 Hz", "share": 0.02, "variables": [{"variable": "yaw_acc", "share": 0.4}]}],
        "concentration_min_ratio": 1.5,
    }


def _document(effects, learnable=None, where=None, best=None):
    """A diagnosis document: every variable's base RMS 0.1 (SI), TIC 0.5, roll_acc TIC 0.7; the effects as given."""
    gap = {v: {"rms": 0.1, "tic": 0.5} for v in EVAL_VARIABLES}
    gap["roll_acc"]["tic"] = 0.7
    data = {
        "config": {"train_flights": [f"/data/flights/B{k}_circle_medium_rep{k}.csv.gz" for k in range(12)],
                   "test_flights": ["/data/b.mat"], "drop_start": 6.0, "drop_end": 4.5, "warm_s": 0.2, "smooth_cutoff_hz": 3.0},
        "windows": {"train_count": 7, "test_count": 7, "window_s": 5.0, "ground_contact_dropped": {"train": 0, "test": 1}},
        "base": {"note": "identified on the training windows (acc_z, roll/pitch/yaw acceleration): tau_m, steady gain, d/a, arm "
                         "scale, rotor-reaction scale", "values": {f"constant_{k}": 0.001 * k for k in range(1, 15)}},
        "effects": effects, "rule": {"found": LONG_RULE, "weak": "found, but a parameter at a bound", "rejected": "old rule"},
        "gap": gap, "learnable": learnable,
        "ladder": [{"effects": [], "normalised_gap": 1.0}, {"effects": ["rotor_drag"], "normalised_gap": 0.8}],
        "regimes": {"regimes": {"speed": {"edges": [0.0, 0.5, 1.0, 1.5, 2.0], "unit": "m/s", "normalised_rms": [1.0, 1.1, 1.2, 1.5],
                                          "ratio_top_to_bottom": 1.5},
                                "throttle": {"edges": [0.774, 0.858, 0.875, 0.902, 0.971], "unit": "fraction",
                                             "normalised_rms": [1.4, 1.45, 1.56, 1.72], "ratio_top_to_bottom": 1.23},
                                "height": {"note": "too little spread"}},
                    "frequency": {"acc_z": {"0-1 Hz": 0.25, ">1 Hz": 0.75}},
                    "worst_windows": [{"flight": "/data/b.mat", "t_start_s": 10.0, "t_end_s": 15.0, "normalised_gap": 2.345}]},
        "skipped": ["../shared/data/nanobench/B9_trefoil_fast_rep2.csv.gz: column motor_motor_m2 data row 1255 (t=12.54 s into the "
                    "flight) is 66254, outside the crazyflie's PWM range"],
    }
    if where is not None:
        data["where"] = where
    if best is not None:
        data["best_effects"] = best
    return data


def _section(report: str, title: str, nth: int = 0) -> list[str]:
    """The ``nth`` table under the heading ``title``."""
    lines = report.splitlines()
    k = lines.index(title)
    for _ in range(nth + 1):
        start = next(j for j in range(k, len(lines)) if lines[j].startswith("|"))
        k = next((j for j in range(start, len(lines)) if not lines[j].startswith("|")), len(lines))
    return lines[start:k]


def _block(report: str, heading: str) -> list[str]:
    """The lines of an effect block, from its heading to the next heading."""
    lines = report.splitlines()
    start = lines.index(heading)
    end = next(j for j in range(start + 1, len(lines)) if lines[j].startswith("#"))
    return lines[start:end]


DRAG = {"name": "rotor_drag", "summary": "rotor/body drag: force against the velocity, and its moment about the CG",
        "variables": ["acc_x", "acc_y"], "candidate_variables": ["acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc"],
        "verdict": "found", "reason": "shrinks the held-out gap by 40% on 9 of 10 windows, as on the training flights.",
        "shrink": 0.4, "train_shrink": 0.45, "confounded_with": [], "given": [], "alone": {},
        "params": {"c_h": 0.386, "c_m": -0.868}, "param_units": {"c_h": "1/s", "c_m": "1/m"},
        "parameters": [{"name": "c_h", "value": 0.386, "sigma": 0.0123, "unit": "1/s", "lower": 0.0, "upper": 5.0, "at_bound": False,
                        "plausible": [0.1, 1.0], "plausible_source": "Foerster 2015", "plausible_ok": True},
                       {"name": "c_m", "value": -0.868, "sigma": None, "unit": "1/m", "lower": -5.0, "upper": 5.0, "at_bound": False}],
        "before": {v: 0.1 for v in EVAL_VARIABLES}, "after": {**{v: 0.1 for v in EVAL_VARIABLES}, "acc_x": 0.06, "acc_y": 0.065},
        "shrink_by_variable": {"train": {"acc_x": 0.42, "acc_y": 0.47}, "held_out": {"acc_x": 0.4, "acc_y": 0.35}},
        "total_error": {"before": 1.0, "after": 0.8, "change": -0.2},
        "fold_stability": {"folds": 3, "stable": True, "values": {"c_h": [0.38, 0.39, 0.4]}, "reason": "every fold within 10% of the fit"},
        "evidence": {"shrink_ci90": [0.3, math.nan], "windows_improved": 9, "windows": 10, "signature_correlation": 0.876}}
BATTERY = {"name": "battery", "summary": "battery sag", "variables": ["acc_z"], "candidate_variables": ["acc_z"], "verdict": "weak",
           "reason": "passes the held-out test, but kappa sits at its upper bound, so the form stands in for something else.",
           "shrink": 0.1, "train_shrink": 0.017, "confounded_with": [], "given": ["rotor_drag"],
           "alone": {"shrink": 0.115, "train_shrink": 0.02, "verdict": "weak"},
           "parameters": [{"name": "kappa", "value": 2.0, "sigma": 0.4, "unit": "1", "lower": 0.0, "upper": 2.0, "at_bound": True,
                           "plausible": [0.5, 1.5], "plausible_source": "guess", "plausible_ok": False}],
           "before": {v: 0.1 for v in EVAL_VARIABLES}, "after": {**{v: 0.1 for v in EVAL_VARIABLES}, "acc_z": 0.09},
           "shrink_by_variable": {"train": {"acc_z": 0.017}, "held_out": {"acc_z": 0.1}},
           "total_error": {"before": 0.8, "after": 0.79, "change": -0.01},
           "fold_stability": {"folds": 3, "stable": None, "values": {}, "reason": "fewer than 2 windows in a fold"},
           "evidence": {"shrink_ci90": [0.05, 0.14], "windows_improved": 24, "windows": 27, "signature_correlation": 0.72}}
LAG = {"name": "motor_lag", "summary": "first-order motor lag", "verdict": "not supported", "shrink": 0.0, "train_shrink": 0.0,
       "evidence": {}, "reason": "no held-out window excites it | the correction is below 5% of every window's gap.",
       "note": "no window | excited", "after": {v: 0.1 for v in EVAL_VARIABLES}}


def test_every_line_of_the_report_and_the_verdict_fits_in_100_characters():
    """Long flight lists, base notes, rule texts, skipped-flight messages and units are wrapped; a table
    with a row too wide (a long flight name) becomes a list."""
    wide = _document([DRAG], learnable={"gap": {v: {"rms": 0.02} for v in EVAL_VARIABLES}})
    long_name = "/data/" + "very_long_flight_name_" * 4 + ".csv.gz"
    wide["regimes"]["worst_windows"][0]["flight"] = long_name
    for data in (_document([DRAG, BATTERY, LAG], where=_where(), best=["rotor_drag"]),
                 _document([{**LAG, "verdict": "insignificant", "reason": ""}], where=_where(), best=[]), wide):
        report = markdown_report(data, "crazyflie21", ["residual_spectrum.png"])
        too_long = [line for line in report.splitlines() if len(line) > REPORT_WIDTH]
        assert too_long == []
        assert max(len(line) for line in verdict_text(data).splitlines()) <= REPORT_WIDTH
        assert "rejected" not in report and "insignificant" not in report
    assert REPORT_WIDTH == 100
    lines = report.splitlines()
    worst = lines.index("## Worst held-out windows")
    assert lines[worst + 2:worst + 4] == ["- " + long_name[6:] + ":", "  start [s] 10.0; end [s] 15.0; normalised gap 2.35"]


def test_verdict_names_the_effect_the_shrink_the_reason_and_where_the_rest_lies():
    text = verdict_text(_document([DRAG, BATTERY, LAG], where=_where(), best=["rotor_drag"]))
    flat = " ".join(text.split())
    assert "Where: the base model's largest held-out gap (TIC) is in roll_acc (0.70), acc_x (0.50), acc_y (0.50)." in flat
    # the base regimes: speed 1.5x is a concentration (>= 1.5), throttle 1.23x would not be
    assert "It concentrates at high speed: 1.5x the opposite quartile's normalised RMS." in flat
    assert ("Which: rotor_drag (rotor/body drag: force against the velocity, and its moment about the CG) shrinks the held-out "
            "gap on acc_x, acc_y by 40% (90% interval 30%..nan%, 9/10 windows better); acc_x RMS 0.1 m/s2 -> 0.06 m/s2. "
            "Why: Shrinks the held-out gap by 40% on 9 of 10 windows, as on the training flights.") in flat
    assert ("After the best model (base + rotor_drag) the unexplained held-out error lies in acc_z (60%), at 1-3 Hz (70% of its "
            "power), at high speed (1.8x).") in flat
    assert "Weak (hints, not findings):\n- battery: Passes the held-out test, but kappa sits at its upper bound" in text
    assert "Not supported: motor_lag (reasons under Effects in report.md)." in flat


def test_nothing_found_says_where_the_gap_lies_instead():
    """The answer for a disturbance outside the catalogue: the variables holding half the error, the band, the regime."""
    where = _where("roll_acc")
    where["variables"][0]["share"] = 0.4  # roll_acc 40 % + acc_x 8 % + acc_y 8 %: three variables, still below half
    text = " ".join(verdict_text(_document([LAG], where=where, best=[])).split())
    assert ("Which: nothing in the catalogue explains the gap; it lies in roll_acc (40%), acc_x (8%), acc_y (8%), at 1-3 Hz (70% of "
            "its power), at high speed (1.8x).") in text
    assert "After the best model" not in text
    where["regimes"][0]["concentrated"] = False
    text = " ".join(verdict_text(_document([LAG], where=where, best=[])).split())
    assert "in no particular regime (no quartile ratio >= 1.5x)" in text
    # an older document without the ranking after the best model
    assert "none found" in verdict_text(_document([{**LAG, "verdict": "insignificant"}]))


def test_summary_table_and_effect_blocks_with_units_sigma_and_bounds():
    report = markdown_report(_document([DRAG, BATTERY, LAG], where=_where(), best=["rotor_drag"]), "linkquad", ["f.png"])
    assert _section(report, "## Effects") == [
        "| # | effect | verdict | held-out | training | windows | total error |",
        "|---|---|---|---|---|---|---|",
        "| 1 | rotor_drag | found | 40.0% | 45.0% | 9/10 | -0.200 |",
        "| 2 | battery | weak | 10.0% | 1.7% | 24/27 | -0.010 |",
        "| 3 | motor_lag | not supported | - | - | - | - |",
    ]
    drag = _block(report, "### 1. rotor_drag: found")
    assert drag[2:4] == ["Rotor/body drag: force against the velocity, and its moment about the CG.",
                         "Reason: Shrinks the held-out gap by 40% on 9 of 10 windows, as on the training flights."]
    assert "- scored on acc_x, acc_y (candidates acc_x, acc_y, acc_z, roll_acc, pitch_acc)" in drag
    assert "- total error (mean held-out RMS over the scored variables / base): 1.000 -> 0.800 (-0.200)" in drag
    assert ("- fold stability (3 folds): stable -- every fold within 10% of the fit; per fold: c_h 0.38, 0.39, 0.4"
            in " ".join(" ".join(drag).split()))
    assert _section(report, "### 1. rotor_drag: found") == [
        "| variable | RMS before | RMS after | held-out shrink | training shrink |", "|---|---|---|---|---|",
        "| acc_x [m/s2] | 0.1 | 0.06 | 40.0% | 42.0% |", "| acc_y [m/s2] | 0.1 | 0.065 | 35.0% | 47.0% |"]
    assert _section(report, "### 1. rotor_drag: found", 1) == [
        "| parameter | value | unit | bounds | at bound |", "|---|---|---|---|---|",
        "| c_h | 0.386 ± 0.0123 | 1/s | [0, 5] | no |", "| c_m | -0.868 | 1/m | [-5, 5] | no |"]
    assert "- c_h: plausible 0.1..1 1/s (Foerster 2015): inside" in drag
    battery = _block(report, "### 2. battery: weak")
    assert "| kappa | 2 ± 0.4 | 1 | [0, 2] | yes |" in battery
    assert "- kappa: plausible 0.5..1.5 1 (guess): OUTSIDE" in battery
    assert "alone: weak 11.5%" in " ".join(battery) and "on top of: rotor_drag" in " ".join(battery)
    assert "- fold stability (3 folds): not assessed -- fewer than 2 windows in a fold" in battery
    lag = _block(report, "### 3. motor_lag: not supported")
    assert "Reason: No held-out window excites it | the correction is below 5% of every window's gap." in lag
    assert "- note: no window | excited" in lag


def test_where_after_the_best_model_and_the_base_tables_in_display_units():
    report = markdown_report(_document([DRAG, LAG], learnable={"gap": {v: {"rms": 0.02} for v in EVAL_VARIABLES}}, where=_where("roll_acc"),
                                       best=["rotor_drag"]), "linkquad", ["f.png"])
    gap = _section(report, "## Held-out gap per variable (display units)")
    assert gap[:3] == ["| variable | base RMS | base TIC | best RMS | NARX RMS |", "|---|---|---|---|---|",
                       "| vel_x [m/s] | 0.1 | 0.50 | - | 0.02 |"]
    # 0.1 rad/s2 = 5.73 deg/s2 (base), 0.1 -> 5.73 (best), NARX 0.02 -> 1.15
    assert gap[-3] == "| roll_acc [deg/s2] | 5.73 | 0.70 | 5.73 | 1.15 |"
    assert gap[-2] == "| pitch_acc [deg/s2] | 5.73 | 0.50 | 0.573 | 1.15 |"
    where = "## Where: unexplained error after the best model"
    assert report.splitlines()[report.splitlines().index(where) + 2].startswith("Best model: base + rotor_drag. Ranked on the scored")
    assert _section(report, where)[:4] == ["| # | variable | RMS | normalised | share |", "|---|---|---|---|---|",
                                           "| 1 | roll_acc [deg/s2] | 5.73 | 1.20 | 60% |", "| 2 | acc_x [m/s2] | 0.01 | 0.16 | 8% |"]
    assert _section(report, where, 1)[:3] == ["| band | share of power | largest contributors |", "|---|---|---|",
                                              "| 1-3 Hz | 70% | roll_acc 90%, acc_x 5% |"]
    assert _section(report, where, 2) == [
        "| regime | ratio | larger at | concentrated | quartile edges |", "|---|---|---|---|---|",
        "| speed [m/s] | 1.80 | high | yes | 0, 0.5, 1, 1.5, 2 |", "| height [m] | 1.25 | low | no | 0.1, 0.4, 0.5, 0.6, 1 |",
        "| tilt | - | - | no | constant over the held-out windows |"]
    assert _section(report, "## Ladder") == ["| rung | mean RMS / base RMS (scored variables) | (12 variables) |", "|---|---|---|",
                                             "| base | 1.000 | - |", "| base + rotor_drag | 0.800 | - |"]
    assert _section(report, "## Where: base model residual by regime") == [
        "| regime | quartile edges | RMS per quartile | top/bottom |", "|---|---|---|---|",
        "| speed [m/s] | 0, 0.5, 1, 1.5, 2 | 1.00, 1.10, 1.20, 1.50 | 1.50 |",
        "| throttle [fraction] | 0.774, 0.858, 0.875, 0.902, 0.971 | 1.40, 1.45, 1.56, 1.72 | 1.23 |",
        "| height | - | too little spread | - |"]
    assert _section(report, "## Where: base model residual power by frequency band") == [
        "| variable | 0-1 Hz | >1 Hz |", "|---|---|---|", "| acc_z | 25% | 75% |"]
    assert _section(report, "## Worst held-out windows") == [
        "| flight | start [s] | end [s] | normalised gap |", "|---|---|---|---|", "| b.mat | 10.0 | 15.0 | 2.35 |"]
    assert report.endswith("## Figures\n\n![f.png](f.png)\n")


def test_an_older_document_is_shown_in_the_new_vocabulary():
    """rejected/insignificant become 'not supported', the reason falls back to the shrinks, params keep their units."""
    old = {**DRAG, "verdict": "rejected", "reason": None, "parameters": None, "shrink_by_variable": None, "total_error": None,
           "fold_stability": None, "given": ["battery"], "alone": {"shrink": 0.02, "train_shrink": 0.3, "verdict": "rejected"}}
    report = markdown_report(_document([old], best=[]), "linkquad", [])
    block = _block(report, "### 1. rotor_drag: not supported")
    assert "Reason: Held-out shrink 40.0%, training shrink 45.0%." in block
    assert "alone: not supported 2.0%" in " ".join(block)
    assert _section(report, "### 1. rotor_drag: not supported", 1) == [
        "| parameter | value | unit | bounds | at bound |", "|---|---|---|---|---|",
        "| c_h | 0.386 | 1/s | - | - |", "| c_m | -0.868 | 1/m | - | - |"]
    # the variables table falls back to the effect's scored variables and its before/after RMS
    assert _section(report, "### 1. rotor_drag: not supported")[2] == "| acc_x [m/s2] | 0.1 | 0.06 | - | - |"
    assert "rejected" not in report and "## Where: unexplained error after the best model" not in report


def test_gap_table_without_effects_or_floor_has_three_columns():
    gap = _section(markdown_report(_document([]), "linkquad", []), "## Held-out gap per variable (display units)")
    assert gap[:3] == ["| variable | base RMS | base TIC |", "|---|---|---|", "| vel_x [m/s] | 0.1 | 0.50 |"]


# ----------------------------------------------------------------------------- figures on a known residual


def _known_result():
    """Held-out windows whose base residual is 0.2 sin(2 pi 2 t) rad/s2 on pitch_acc, and a best model that
    explains it but for 0.02 sin(2 pi 0.5 t) m/s2 on acc_z; scales 0.1."""
    windows, warm, samples, dt = 6, 20, 520, 0.01
    t = (np.arange(samples) - warm) * dt
    measured = np.zeros((windows, samples, 18))
    measured[:, :, INDEX["pitch_acc"]] = 0.2 * np.sin(2 * np.pi * 2.0 * t)
    best = measured.copy()
    best[:, :, INDEX["acc_z"]] = -0.02 * np.sin(2 * np.pi * 0.5 * t)
    zeros3 = np.zeros((windows, samples, 3))
    velocity = zeros3.copy()
    velocity[:, :, 0] = np.linspace(0.0, 2.0, windows)[:, None]
    batch = WindowBatch(sources=["sim"] * windows, t0=np.arange(windows) * 5.0, dt=dt, warm=warm, u=np.zeros((windows, samples, 4)),
                        u_history=np.zeros((windows, 50, 4)), u_trim=np.full((windows, 4), 0.5), u_span=1.0, measured=measured,
                        anchor_states=np.zeros((windows, 12)), velocity=velocity, velocity_abs=velocity, velocity_smooth=velocity,
                        euler=zeros3, rates=zeros3, height=np.ones((windows, samples)), vbat=None, input_min=0.0)
    scales = np.full(18, 0.1)
    result = SimpleNamespace(test_batch=batch, base_test=np.zeros_like(measured), best_test=best, scales=scales, outcomes=[])
    return result, rank_unexplained(batch, best, scales)


def test_residual_spectrum_before_and_after_the_best_model(tmp_path):
    result, where = _known_result()
    f, before, after = residual_spectra(result)
    pitch, acc_z = 4, 2  # columns of SCORED_VARIABLES
    assert f[np.argmax(before[:, pitch])] == pytest.approx(2.0, abs=0.2)  # the 2 Hz residual, normalised by s_v = 0.1
    assert np.sum(before[:, pitch]) * (f[1] - f[0]) == pytest.approx((0.2 / 0.1) ** 2 / 2, rel=0.02)
    assert np.max(after[:, pitch]) == 0.0 and np.max(before[:, acc_z]) == 0.0
    assert f[np.argmax(after[:, acc_z])] == pytest.approx(0.5, abs=0.2)
    assert np.sum(after[:, acc_z]) * (f[1] - f[0]) == pytest.approx((0.02 / 0.1) ** 2 / 2, rel=0.02)
    assert where["variables"][0]["variable"] == "acc_z" and where["bands"][0]["band"] == "0.2-1 Hz"
    regimes = {"speed": {"edges": [0.0, 0.5, 1.0, 1.5, 2.0], "unit": "m/s", "normalised_rms": [1.0, 1.0, 1.0, 1.0], "ratio_top_to_bottom": 1.0}}
    data = {"regimes": {"regimes": regimes, "window_gap": [1.0] * 6}, "best_effects": ["rotor_drag"],
            "effects": [{**DRAG, "verdict": "found"}, {**LAG, "verdict": "rejected"}]}
    written = write_figures(result, data, tmp_path)
    assert written == ["gap_by_regime.png", "effect_shrink.png", "residual_spectrum.png"]
    assert (tmp_path / "residual_spectrum.png").stat().st_size > 10_000
    # without the scales (an older Diagnosis) there is no spectrum
    result.scales = None
    (tmp_path / "again").mkdir()
    assert write_figures(result, data, tmp_path / "again") == ["gap_by_regime.png", "effect_shrink.png"]


# ----------------------------------------------------------------------------- a real small diagnosis


@pytest.fixture(scope="module")
def real_diagnosis():
    """Simulated LinkQuad flights with motor imbalance (train seed 11, test seed 12, 50 s), base identified
    on the training flight, two effects assessed."""
    from quad_modelling.core.diagnosis.catalogue import CATALOGUE
    from quad_modelling.core.diagnosis.diagnose import diagnose
    from test.conftest import simulated
    from quad_modelling.core.vehicle import load_vehicle

    train, test = (simulated("linkquad", ("motor_imbalance",), s, 50.0) for s in (11, 12))  # test_diagnosis.py's flights
    return diagnose([train], [test], load_vehicle("linkquad"), [CATALOGUE["motor_imbalance"], CATALOGUE["battery"]])


def test_write_diagnosis_on_a_real_diagnosis(real_diagnosis, tmp_path):
    """The whole path: diagnosis.json, a report of lines <= 100 characters in the new vocabulary, the figures,
    and the ranking after the best model on the scored variables only, with the test flight's RMS."""
    import json

    from quad_modelling.core.diagnosis.localisation import SCORED_VARIABLES
    from quad_modelling.io.reports.diagnosis import write_diagnosis

    result = real_diagnosis
    data = result.to_json()
    best = getattr(result, "best_test", None)
    best = result.base_test if best is None else best
    data.setdefault("where", rank_unexplained(result.test_batch, best, result.scales))  # until diagnose() stores it
    files = write_diagnosis(result, data, tmp_path / "diag", "linkquad")
    assert files[:2] == ["diagnosis.json", "report.md"] and "residual_spectrum.png" in files
    for name in files:
        assert (tmp_path / "diag" / name).stat().st_size > 0
    report = (tmp_path / "diag" / "report.md").read_text()
    assert max(len(line) for line in report.splitlines()) <= REPORT_WIDTH
    assert "rejected" not in report and "insignificant" not in report
    assert report.splitlines()[2] == "## Verdict" and "Where:" in report and "Which:" in report
    for effect in data["effects"]:
        assert f"### {data['effects'].index(effect) + 1}. {effect['name']}: " in report
    where = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())["where"]
    ranked = [v["variable"] for v in where["variables"]]
    assert sorted(ranked) == sorted(SCORED_VARIABLES)
    # the ranked RMS is the held-out RMS of the best model: the base model's gap when it is the base
    if not data.get("best_effects"):
        assert {v["variable"]: v["rms"] for v in where["variables"]} == pytest.approx({v: data["gap"][v]["rms"] for v in ranked})
    assert sum(b["share"] for b in where["bands"]) == pytest.approx(1.0)
