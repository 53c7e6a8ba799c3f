"""The diagnose verb: thesis .mat inputs through load_flight, outputs written atomically, verdict first."""

from __future__ import annotations

import json

import pytest

from quad_modelling.cli import main
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG
from quad_modelling.core.diagnosis.verdicts import VERDICTS
from quad_modelling.io.matlog import write_matlog
from test.conftest import REPO, simulated


@pytest.fixture(scope="session")
def mat_flights(tmp_path_factory):
    """Simulated 90 s LinkQuad flights with motor imbalance as thesis .mat logs: training seeds 11 and 13, test seed
    12 (two training flights: the verdict's fold-stability rule refits on each; on the two halves of one 50 s
    flight the CG offset came out +0.9 / -1.7 mm in y, and the effect weak)."""
    folder = tmp_path_factory.mktemp("diagnose_flights")
    paths = []
    for seed in (11, 12, 13):
        log = simulated("linkquad", ("motor_imbalance",), seed, 90.0)  # the flights of test/core/diagnosis/test_diagnosis.py
        paths.append(str(write_matlog(log, folder / f"imbalance_{seed}.mat")))
    return paths


@pytest.mark.slow
def test_diagnose_writes_json_report_and_figures(mat_flights, tmp_path, capsys):
    out = tmp_path / "diag"
    code = main(["diagnose", "--base", "greybox", "--train", mat_flights[0], mat_flights[2], "--test", mat_flights[1], "--vehicle", "linkquad",
                 "--effects", "motor_imbalance,battery,motor_lag", "-o", str(out)])
    assert code == 0
    data = json.loads((out / "diagnosis.json").read_text())
    assert set(data["gap"]["acc_z"]) == {"rms", "tic"}
    names = [e["name"] for e in data["effects"]]
    assert sorted(names) == ["battery", "motor_imbalance", "motor_lag"]
    # the flights were simulated with motor imbalance, the model lacks it: the known answer leads the ranking
    assert data["effects"][0]["name"] == "motor_imbalance" and data["effects"][0]["verdict"] == "found"
    ranking = [(VERDICTS.index(e["verdict"]), -e["shrink"]) for e in data["effects"]]
    assert ranking == sorted(ranking)  # found, weak, not supported; each by held-out shrink
    for e in data["effects"]:
        assert e["verdict"] in VERDICTS and e["reason"]
        assert set(e["before"]) == set(e["after"]) == set(data["gap"])
        # every parameter with its uncertainty, unit, bounds and at-bound flag; shrink per variable; total error
        for p in e["parameters"]:
            assert {"value", "sigma", "unit", "lower", "upper", "at_bound", "plausible", "plausible_ok"} <= set(p)
            assert p["lower"] <= p["value"] <= p["upper"]
    top = data["effects"][0]
    assert top["total_error"]["after"] < top["total_error"]["before"] and top["fold_stability"]["stable"] is True
    assert set(top["shrink_by_variable"]["held_out"]) == {"roll_acc", "pitch_acc", "yaw_acc"}
    assert data["where"]["variables"] and data["best_effects"] == ["motor_imbalance"]
    assert data["ladder"][0]["effects"] == []
    report = (out / "report.md").read_text()
    assert report.splitlines()[2] == "## Verdict" and "Where:" in report and "Which:" in report
    assert max(len(line) for line in report.splitlines()) <= 100 and "rejected" not in report
    assert f"low-passed at {DIAGNOSIS_CONFIG.smooth_cutoff_hz:g} Hz" in report
    assert data["config"]["smooth_cutoff_hz"] == DIAGNOSIS_CONFIG.smooth_cutoff_hz
    for figure in ("gap_by_regime.png", "effect_shrink.png", "residual_spectrum.png"):
        assert (out / figure).stat().st_size > 0
    assert "->" in capsys.readouterr().out
    # never overwrite without --force
    assert main(["diagnose", "--base", "greybox", "--train", mat_flights[0], "--test", mat_flights[1], "--vehicle", "linkquad",
                 "--effects", "motor_lag", "-o", str(out)]) == 2


def test_diagnose_rejects_unknown_effects_and_missing_inputs(mat_flights, tmp_path, capsys):
    assert main(["diagnose", "--train", mat_flights[0], "--test", mat_flights[1], "--effects", "warp_drive", "-o", str(tmp_path / "x")]) == 2
    assert "warp_drive" in capsys.readouterr().err
    assert main(["diagnose", "--train", mat_flights[0], "-o", str(tmp_path / "y")]) == 2
    assert main(["diagnose", "--train", mat_flights[0], "--test", mat_flights[1], "--smooth", "0", "-o", str(tmp_path / "z")]) == 2
    assert "--smooth" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


@pytest.mark.parametrize("flags, message", [
    (["--pairs", "rotor_drag+warp_drive"], "'warp_drive' is no effect the simulator switches"),
    (["--pairs", "rotor_drag+battery,battery+rotor_drag"], "battery+rotor_drag is rotor_drag+battery in another order; name each pair once"),
    (["--effects", "rotor_drag,motor_lag", "--pairs", "rotor_drag+battery"], "'battery' is not among the searched --effects"),
    (["--disturbance", "gust"], "--disturbance gust: known disturbances are wind, com_offset, bent_arm"),
    (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler: --validate runs its cases on a local cluster"),
    # the options of a diagnosis of given flights, which --validate does not read
    (["--train", str(REPO / "bags" / "nanobench_B7_oval_medium_rep2")], "--train: option(s) of a diagnosis of --train/--test flights; --validate flies"),
    (["--skip-bad", "--base", "greybox", "--narx"], "--skip-bad, --narx: option(s) of a diagnosis of --train/--test flights"),
    (["--topic-map", "px4"], "--topic-map: option(s) of a diagnosis of --train/--test flights"),
    (["--base", "greybox", "--duration", "2"], "simulation duration must be at least"),  # before its cluster starts
    (["--window", "3"], "--window: option(s) of the greybox base"),  # --validate of the physics base scores as it does
])
def test_validate_refuses_bad_cases_in_one_line(tmp_path, capsys, flags, message):
    """Bad validation cases end in one line naming the flag, exit 2, before any flight is flown; nothing is written."""
    out = tmp_path / "v"
    assert main(["diagnose", "--validate", "--seeds", "0", *flags, "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()
