"""The diagnose verb: thesis .mat inputs through load_flight, outputs written atomically, verdict first."""

from __future__ import annotations

import json

import pytest

from quad_modelling.cli import main
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG
from quad_modelling.core.sim.simulate import simulate
from quad_modelling.io.matlog import write_matlog


@pytest.fixture(scope="session")
def mat_flights(tmp_path_factory):
    """Two short simulated LinkQuad flights with motor imbalance (train seed 11, test seed 12) as thesis .mat logs.

    (Imbalance, not motor lag: the verb identifies the base model's motor pole on the training
    flights, which absorbs a lag the flights carry.)"""
    folder = tmp_path_factory.mktemp("diagnose_flights")
    paths = []
    for seed in (11, 12):
        log = simulate("linkquad", effects=("motor_imbalance",), seed=seed, duration=50.0)
        paths.append(str(write_matlog(log, folder / f"imbalance_{seed}.mat")))
    return paths


def test_diagnose_writes_json_report_and_figures(mat_flights, tmp_path, capsys):
    out = tmp_path / "diag"
    code = main(["diagnose", "--train", mat_flights[0], "--test", mat_flights[1], "--vehicle", "linkquad",
                 "--effects", "motor_imbalance,battery,motor_lag", "-o", str(out)])
    assert code == 0
    data = json.loads((out / "diagnosis.json").read_text())
    assert set(data["gap"]["acc_z"]) == {"rms", "tic"}
    names = [e["name"] for e in data["effects"]]
    assert sorted(names) == ["battery", "motor_imbalance", "motor_lag"]
    # the flights were simulated with motor imbalance, the model lacks it: the known answer leads the ranking
    assert data["effects"][0]["name"] == "motor_imbalance" and data["effects"][0]["verdict"] == "found"
    ranking = [(e["verdict"] != "found", -e["shrink"]) for e in data["effects"]]
    assert ranking == sorted(ranking)  # found first, then by held-out shrink
    for e in data["effects"]:
        assert e["verdict"] in ("found", "rejected", "insignificant")
        assert set(e["before"]) == set(e["after"]) == set(data["gap"])
    assert data["ladder"][0]["effects"] == []
    report = (out / "report.md").read_text()
    assert report.splitlines()[2] == "## Verdict" and "Where:" in report and "Which:" in report
    assert f"low-passed at {DIAGNOSIS_CONFIG.smooth_cutoff_hz:g} Hz" in report
    assert data["config"]["smooth_cutoff_hz"] == DIAGNOSIS_CONFIG.smooth_cutoff_hz
    assert (out / "gap_by_regime.png").stat().st_size > 0 and (out / "effect_shrink.png").stat().st_size > 0
    assert "->" in capsys.readouterr().out
    # never overwrite without --force
    assert main(["diagnose", "--train", mat_flights[0], "--test", mat_flights[1], "--vehicle", "linkquad",
                 "--effects", "motor_lag", "-o", str(out)]) == 2


def test_diagnose_rejects_unknown_effects_and_missing_inputs(mat_flights, tmp_path, capsys):
    assert main(["diagnose", "--train", mat_flights[0], "--test", mat_flights[1], "--effects", "warp_drive", "-o", str(tmp_path / "x")]) == 2
    assert "warp_drive" in capsys.readouterr().err
    assert main(["diagnose", "--train", mat_flights[0], "-o", str(tmp_path / "y")]) == 2
    assert main(["diagnose", "--train", mat_flights[0], "--test", mat_flights[1], "--smooth", "0", "-o", str(tmp_path / "z")]) == 2
    assert "--smooth" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
