"""run-bag over real DDS gives the same RMS/TIC as the offline evaluation of the same bag (DESIGN 2)."""

import json

import pytest

from quad_modelling.cli import main
from quad_modelling.core.evaluation.windowed import evaluate
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.io.bag_io import read_bag
from test.conftest import REPO

BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"


def test_live_results_equal_offline_evaluation(tmp_path, capsys):
    """naive, greybox and a NARX trained on the training span, live and offline; the dummy rides along."""
    assert main(["train", str(BAG), "--drop", "0:0", "--train", "0:20", "--epochs", "5", "--training", "thesis", "--quiet", "-o", str(tmp_path / "narx.npz")]) == 0
    specs = ("naive", "greybox", f"narx:{tmp_path / 'narx.npz'}")
    names = ("naive", "greybox", "narx", "dummy")
    out = tmp_path / "live"
    code = main(["run-bag", str(BAG), "--models", ",".join(specs), "--train", "0:20", "--eval", "20:40", "--no-figures", "-o", str(out)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "naive (eval)" in printed and str(out) in printed
    live = json.loads((out / "results.json").read_text())
    log = read_bag(BAG)
    vehicle = load_vehicle(log.meta.vehicle)
    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="0:20", eval="20:40", window_s=10.0, warm_s=0.2)
    offline = evaluate([log], [make_model(m, vehicle) for m in (*specs, "dummy")], vehicle, config, multistep=False).to_json()
    assert live["windows"] == offline["windows"] == {m: {"train": 2, "eval": 2} for m in names}
    for model in names:
        for span in ("train", "eval"):
            for var, entry in offline["models"][model][span].items():
                for metric in ("rms", "tic"):
                    assert live["models"][model][span][var][metric] == pytest.approx(entry[metric], rel=1e-6), (model, span, var, metric)
    assert live["live"]["marked"] == []  # windows outside both spans are not scored, not marked
    assert (out / "tables.md").is_file() and (out / "logs" / "replay.log").is_file()


def test_unknown_model_is_a_clear_error_before_any_node_starts(tmp_path, capsys):
    assert main(["run-bag", str(BAG), "--models", "naive,warp_drive", "-o", str(tmp_path / "x")]) == 2
    assert "unknown model" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def _processes_mentioning(text: str) -> list[int]:
    """Pids whose command line holds ``text`` (the nodes' --params-file lies in the run's staging path)."""
    from pathlib import Path

    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text.encode() in (entry / "cmdline").read_bytes():
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def test_sigterm_stops_every_node_and_removes_the_staging(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "live"
    proc = subprocess.Popen([sys.executable, "-m", "quad_modelling.cli", "run-bag", str(BAG), "--models", "naive", "--rate", "1",
                             "--no-figures", "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob(".live.tmp-*/live/logs/replay.log")) and time.monotonic() < deadline:
            time.sleep(0.1)
        staging = list(tmp_path.glob(".live.tmp-*"))
        assert staging and proc.poll() is None, "the nodes never started"
        time.sleep(2.0)  # the nodes are up and replaying (at real time, 40 s of flight)
        assert _processes_mentioning(str(staging[0]))  # the node processes, found by their params file
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "quad-modelling run-bag: interrupted (SIGTERM)"
    assert list(tmp_path.iterdir()) == []  # no output, no staging
    assert _processes_mentioning(str(staging[0])) == []  # no orphaned node
