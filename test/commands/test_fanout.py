"""--jobs / --scheduler of evaluate, identify, diagnose and train: the numbers of the serial run, exactly (#19)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from quad_modelling.cli import main
from quad_modelling.core.evaluation.statistics import ExactSum
from quad_modelling.core.variables import INDEX

SPANS = ["--vehicle", "linkquad", "--preset", "short", "--window", "6"]
"""Spans of the two 42 s test flights (conftest ``flights``): 6 s windows, so each flight has several windows per span
(train 3, eval 2)."""


def exact(stored: dict, index: int) -> float:
    """The exact sum ``index`` of a results.json sum as float (what the mean over one window would be)."""
    return float(ExactSum.from_json(stored, "sum").mean(1)[index])


def evaluation(directory, inputs, *extra, code: int = 0):
    """results.json of ``evaluate INPUTS`` (greybox, naive, dummy) into ``directory``: (document, bytes); ``code`` the
    exit code expected (1: --skip-bad left a flight out)."""
    assert main(["evaluate", *inputs, *SPANS, "--model", "greybox", "--model", "naive", "-o", str(directory), *extra]) == code
    return json.loads((directory / "results.json").read_text()), (directory / "results.json").read_bytes()


@pytest.fixture(scope="module")
def serial(flights, tmp_path_factory):
    """The serial evaluation of the two test flights (document, bytes)."""
    return evaluation(tmp_path_factory.mktemp("serial") / "out", flights)


@pytest.mark.slow
def test_evaluate_serial_jobs_scheduler_and_merge_give_identical_numbers(flights, serial, dask_scheduler, tmp_path):
    serial, serial_bytes = serial
    _, jobs_bytes = evaluation(tmp_path / "jobs", flights, "--jobs", "2")
    _, running_bytes = evaluation(tmp_path / "running", flights, "--scheduler", dask_scheduler)
    for k, flight in enumerate(flights):  # one evaluation per flight, then merged in flight order
        evaluation(tmp_path / f"one{k}", [flight])
    assert main(["merge", *(str(tmp_path / f"one{k}") for k in range(len(flights))), "-o", str(tmp_path / "merged")]) == 0
    merged = json.loads((tmp_path / "merged" / "results.json").read_text())
    assert jobs_bytes == serial_bytes and running_bytes == serial_bytes  # every number, every key, bit for bit
    assert merged == serial
    # several windows per flight and span (so the per-flight grouping of the sums is exercised)
    assert serial["windows"]["greybox"] == {"train": 6, "eval": 4} and serial["horizons"]["starts"] > 0
    # the averages are the sums over windows / the window count; the dummy's TIC is exactly 1
    sums = serial["statistics"]["windowed"]["greybox"]["eval"]
    assert sums["windows"] == 4
    assert serial["models"]["greybox"]["eval"]["acc_z"]["rms"] == exact(sums["rms_sum"], INDEX["acc_z"]) / 4
    assert serial["models"]["dummy"]["eval"]["acc_z"]["tic"] == 1.0
    steps = serial["statistics"]["multistep"]
    mae = ExactSum.from_json(steps["error_sums"]["naive"], "naive").mean(steps["starts"])
    assert serial["horizons"]["models"]["naive"]["velocity"]["mae"]["10"] == mae[1, 9]
    assert (tmp_path / "merged" / "tables.md").read_text().count("| Z acceleration |") == 2


def test_evaluate_bad_file_among_many_on_workers(flights, serial, dask_scheduler, tmp_path, capsys):
    bad = tmp_path / "broken.mat"
    bad.write_bytes(b"not a MATLAB file")
    inputs = [flights[0], str(bad), flights[1]]
    assert main(["evaluate", *inputs, *SPANS, "-o", str(tmp_path / "x"), "--scheduler", dask_scheduler]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("quad-modelling evaluate: error: ") and "broken.mat" in err[0], err
    assert not (tmp_path / "x").exists()
    skipping, _ = evaluation(tmp_path / "skip", inputs, "--skip-bad", "--scheduler", dask_scheduler, code=1)
    assert "skipped: " in capsys.readouterr().err
    assert skipping["models"] == serial[0]["models"]  # the bad file left out: the numbers of the two good flights
    assert [f.get("skipped", False) for f in skipping["config"]["flights"]] == [False, False, True]


@pytest.mark.parametrize(("flags", "message"), [
    (["--jobs", "0"], "--jobs 0: the number of worker processes must be at least 1"),
    (["--jobs", "-2"], "--jobs -2: the number of worker processes must be at least 1"),
    (["--scheduler", "tcp://127.0.0.1:9"], "--scheduler tcp://127.0.0.1:9: cannot connect to a Dask scheduler there"),
])
def test_bad_jobs_or_unreachable_scheduler_is_one_line_exit_2(flights, tmp_path, capsys, flags, message, monkeypatch):
    from quad_modelling import fanout

    monkeypatch.setattr(fanout, "CONNECT_TIMEOUT_S", 1.0)
    verbs = (["evaluate", *flights, *SPANS], ["identify", *flights, *SPANS], ["train", flights[0], "--vehicle", "linkquad"])
    for verb in verbs if flags[0] == "--jobs" else verbs[:1]:  # the same fanout code: one verb waits for the timeout
        name = {"train": "out.npz", "identify": "out.yaml"}.get(verb[0], "out")
        assert main([*verb, "-o", str(tmp_path / name), *flags]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
        assert list(tmp_path.iterdir()) == []


def test_diagnose_validate_runs_its_cases_locally_and_refuses_a_scheduler(tmp_path, capsys):
    """--validate fans its cases out over --jobs local workers (test/core/diagnosis/test_diagnosis_validation.py runs
    them); a running scheduler is refused in one line, and a bad --jobs as for every verb."""
    assert main(["diagnose", "--validate", "-o", str(tmp_path / "out"), "--scheduler", "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--scheduler: --validate runs its cases on a local cluster (--jobs N) or here" in err[0]
    assert main(["diagnose", "--validate", "-o", str(tmp_path / "out"), "--jobs", "0"]) == 2
    assert "--jobs" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_identify_on_workers_identifies_the_serial_constants(flights, dask_scheduler, tmp_path):
    """On the running cluster: ``--jobs N`` differs only in starting a local one first (quad_modelling.fanout.dask_client),
    which the evaluate test above runs."""
    documents = []
    for name, extra in (("serial", []), ("running", ["--scheduler", dask_scheduler])):
        out = tmp_path / f"{name}.yaml"
        assert main(["identify", *flights, *SPANS, "-o", str(out), *extra]) == 0
        documents.append(yaml.safe_load(out.read_text()))
    serial = documents[0]
    assert serial["greybox"]["motor_a_m"]["value"] < 0  # a motor pole [1/s] was identified
    assert documents[1]["constants"] == serial["constants"] and documents[1]["greybox"] == serial["greybox"]
    assert documents[1]["identification"]["spans"] == serial["identification"]["spans"]


@pytest.mark.slow
def test_diagnose_and_train_on_workers_equal_serial(flights, dask_scheduler, tmp_path):
    reports = []
    for name, extra in (("serial", []), ("running", ["--scheduler", dask_scheduler])):
        out = tmp_path / f"diag_{name}"
        assert main(["diagnose", "--base", "greybox", "--train", flights[0], "--test", flights[1], "--vehicle", "linkquad", "--effects", "battery",
                     "-o", str(out), *extra]) == 0
        reports.append(json.loads((out / "diagnosis.json").read_text()))
    assert reports[1]["gap"] == reports[0]["gap"] and reports[1]["effects"] == reports[0]["effects"]
    assert set(reports[0]["gap"]["acc_z"]) == {"rms", "tic"}
    models = []
    for name, extra in (("serial", []), ("running", ["--scheduler", dask_scheduler])):
        out = tmp_path / f"narx_{name}.npz"
        assert main(["train", *flights, "--vehicle", "linkquad", "-o", str(out), "--preset", "short", "--training", "thesis",
                     "--epochs", "1", "--hidden", "2", "--delays", "2", "--input-delays", "2", "--quiet", *extra]) == 0
        with np.load(out, allow_pickle=False) as contents:
            models.append({key: contents[key] for key in contents.files})
    serial, other = models
    headers = [json.loads(str(m.pop("header"))) for m in models]
    assert headers[0]["training"]["samples"] == headers[1]["training"]["samples"] > 0
    assert serial.keys() == other.keys() and len(serial) > 2
    for key in serial:  # the same data in the same order: the same weights and normalisation
        np.testing.assert_array_equal(other[key], serial[key])


def test_only_the_first_flight_sends_its_figure_windows_and_a_span_it_lacks_comes_from_the_next(flights, tmp_path):
    """A fleet's task results stay small: the example windows (0.6 MB a span) come from one flight, not every flight;
    the figures still show the first window of each span in flight order."""
    from quad_modelling.commands.evaluate import evaluate_flight_file, example_windows
    from quad_modelling.core.evaluation.windowed import merge_flights
    from quad_modelling.core.vehicle import load_vehicle
    from quad_modelling.core.windows import EvaluationConfig
    from quad_modelling.io.matlog import write_matlog
    from test.core.flightgen import linear_flight

    vehicle = load_vehicle("linkquad")
    short = tmp_path / "short.mat"  # 20 s: windows in train 5:15 only, none in eval 25:35
    write_matlog(linear_flight(vehicle, duration=20.0, seed=5), short)
    config = EvaluationConfig.from_options("short", "0:0", train="5:15", eval="25:35", window_s=5.0, warm_s=0.2)
    task = (vehicle, ["naive", "dummy"], config, False, False)
    paths = [str(short), flights[0]]
    outcomes = [evaluate_flight_file(p, *task, paths[0]) for p in paths]
    assert [e.span for e in outcomes[0].evaluation.examples] == ["train"] and outcomes[1].evaluation.examples == []
    result = merge_flights([o.evaluation for o in outcomes], config)
    first_in_span = {"train": paths[0], "eval": paths[1]}
    examples = example_windows(result, first_in_span, task)
    assert [(e.span, e.source) for e in examples] == [("train", str(short)), ("eval", flights[0])]
    assert examples[1].measured.shape == (500, 18)  # the whole 5 s window at 100 Hz
