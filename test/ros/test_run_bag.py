"""run-bag over real DDS gives the same RMS/TIC as the offline evaluation of the same bag (DESIGN 2), and the
multi-step table of every model it ran."""

import json

import pytest

from quad_modelling.cli import main
from quad_modelling.core.evaluation.multistep import multistep_evaluation
from quad_modelling.core.evaluation.windowed import evaluate
from quad_modelling.core.preprocess import resample_uniform
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.io.bag_io import read_bag
from quad_modelling.io.loader import load_flight
from test.conftest import REPO

BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"


@pytest.mark.slow
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
    # rate 0 (the default) is lossless: every node received every sample the replay played and each predictor published
    samples = live["live"]["samples"]
    assert samples["loss"] == [] and samples["sent"]["imu"] == {"count": 4227, "by": "replay"}
    assert set(samples["received"]) == {"evaluator", "naive_predictor", "greybox_predictor", "narx_predictor"}
    assert all(counts[s] == samples["sent"][s]["count"] for counts in samples["received"].values() for s in counts)
    assert (out / "tables.md").is_file() and (out / "logs" / "replay.log").is_file()
    # the params file and the logs name the output the user gets, not the staging directory that is gone
    for written in [out / "params.yaml", *(out / "logs").glob("*.log")]:
        assert ".tmp-" not in written.read_text(), written
    assert f"output_dir: {out}\n" in (out / "params.yaml").read_text()
    # The multi-step table lists every model run live (NARX by its live form), with the offline numbers.
    horizons = live["horizons"]
    assert list(horizons["models"]) == ["naive", "greybox", "narx"] and list(horizons["not_multistep"]) == ["dummy"]
    assert horizons["forms"]["narx"] == "predict_horizons" and horizons["span"] == "eval"
    multistep = multistep_evaluation([resample_uniform(log)], [make_model(m, vehicle) for m in (*specs, "dummy")], vehicle, config)
    assert horizons["starts"] == multistep["starts"] == 2000 - 50 - 19  # eval 20:40 s at 100 Hz, 20 warm rows
    for model in ("naive", "greybox", "narx"):
        for group, entry in multistep["models"][model].items():
            assert horizons["models"][model][group]["sim_err"] == pytest.approx(entry["sim_err"], rel=1e-9), (model, group)
    tables = (out / "tables.md").read_text()
    assert "## Multi-step prediction" in tables and "| narx | angular_velocity |" in tables
    assert "greybox = linear greybox, the thesis reproduction" in tables
    assert "| narx    | angular_velocity |" in printed  # the aligned console table


@pytest.mark.slow
def test_live_equals_offline_on_a_flight_with_an_irregular_step(tmp_path, capsys):
    """A second, differently cut flight (the first 10 s of the NanoBench fixture, 4 s windows) with one sample
    missing (a 20 ms step at 7.19 s, as real NanoBench logs have): the window holding it is scored by both paths on
    the same 399 recorded rows (the coverage rule; offline no longer resamples the whole flight, which moved every
    row by the stamps' jitter: before, live and offline differed by up to 1.5e-2 relative on that window and 6e-5
    on the other)."""
    import gzip

    import numpy as np

    lines = gzip.open(REPO / "test" / "fixtures" / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", "rt").read().splitlines(True)
    del lines[1 + 720]
    (tmp_path / "step.csv").write_text("".join(lines))
    assert main(["convert", str(tmp_path / "step.csv"), "-o", str(tmp_path / "bag")]) == 0
    log = read_bag(tmp_path / "bag")
    steps = np.diff(log.t)
    assert len(log) == 999 and int(np.argmax(steps)) == 719 and abs(steps.max() - 0.020) < 1e-5
    out = tmp_path / "live"
    code = main(["run-bag", str(tmp_path / "bag"), "--models", "greybox", "--window", "4", "--train", "0:4", "--eval", "4:8",
                 "--no-figures", "-o", str(out)])
    assert code == 0, capsys.readouterr().out
    live = json.loads((out / "results.json").read_text())
    vehicle = load_vehicle(log.meta.vehicle)
    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="0:4", eval="4:8", window_s=4.0, warm_s=0.2)
    offline = evaluate([log], [make_model(m, vehicle) for m in ("greybox", "dummy")], vehicle, config, multistep=False).to_json()
    assert live["windows"] == offline["windows"] == {m: {"train": 1, "eval": 1} for m in ("greybox", "dummy")}
    for model in ("greybox", "dummy"):
        for span in ("train", "eval"):
            for var, entry in offline["models"][model][span].items():
                for metric in ("rms", "tic"):
                    assert live["models"][model][span][var][metric] == pytest.approx(entry[metric], rel=1e-9), (model, span, var)
    assert live["live"]["marked"] == []
    # The live result carries the exact statistics, as evaluate writes them: merge takes it, and its numbers are the
    # merge of the offline evaluation of the same windows (same configuration, multi-step table included).
    assert live["statistics"]["windowed"]["greybox"]["eval"]["windows"] == 1 and live["statistics"]["multistep"]["starts"] > 0
    assert main(["evaluate", str(tmp_path / "bag"), "--model", "greybox", "--drop", "0:0", "--window", "4", "--train", "0:4",
                 "--eval", "4:8", "-o", str(tmp_path / "offline")]) == 0
    merged = {}
    for name, inputs in (("live", [out]), ("offline", [tmp_path / "offline"])):
        assert main(["merge", *map(str, inputs), "-o", str(tmp_path / f"merged_{name}")]) == 0, capsys.readouterr().err
        merged[name] = json.loads((tmp_path / f"merged_{name}" / "results.json").read_text())
    # the live result names its flight by its numbers: beside the offline result of the same flight it is refused (it
    # merged, every window counted twice)
    assert main(["merge", str(out), str(tmp_path / "offline"), "-o", str(tmp_path / "merged_both")]) == 2
    assert "is also in" in capsys.readouterr().err and not (tmp_path / "merged_both").exists()
    assert merged["live"]["config"]["horizons"] == merged["offline"]["config"]["horizons"] == [1, 10, 50]
    for model in ("greybox", "dummy"):
        for span in ("train", "eval"):
            for var, entry in merged["offline"]["models"][model][span].items():
                for metric in ("rms", "tic"):
                    assert merged["live"]["models"][model][span][var][metric] == pytest.approx(entry[metric], rel=1e-9), (model, var)
    assert merged["live"]["horizons"]["starts"] == merged["offline"]["horizons"]["starts"]
    for model, groups in merged["offline"]["horizons"]["models"].items():
        for group, entry in groups.items():
            assert merged["live"]["horizons"]["models"][model][group]["sim_err"] == pytest.approx(entry["sim_err"], rel=1e-9)


@pytest.mark.slow
def test_samples_the_nodes_did_not_receive_are_a_line_per_stream_in_the_summary_and_results_and_exit_1(tmp_path, capsys,
                                                                                                       monkeypatch):
    """A replay faster than real time (--rate > 0) on a busy machine loses samples on the nodes' keep-last queues (a
    queue overrun itself: test_live_graph_setup.py); when it does is the machine's doing, so here the replay is said to
    have played 3 IMU samples more than the 4227 its nodes received (a fake of the count run-bag compares with). The
    run is complete and scored, flagged: one warning line, results.json live.samples, tables.md, exit code 1."""
    from quad_modelling.nodes import replay_node

    played = replay_node.played_counts(BAG)
    assert played == {"motor_input": 4227, "mocap_odom": 4227, "imu": 4227, "battery": 4227}
    monkeypatch.setattr(replay_node, "played_counts", lambda bag, namespace="/quad": {**played, "imu": 4230})
    out = tmp_path / "live"
    code = main(["run-bag", str(BAG), "--models", "naive", "--window", "5", "--train", "10:25", "--eval", "25:35",
                 "--no-figures", "--no-multistep", "-o", str(out)])
    captured = capsys.readouterr()
    line = "imu: 4230 replayed, received 4227 by evaluator (3 lost), 4227 by naive_predictor (3 lost)"
    assert code == 1, captured.err
    assert [text for text in captured.err.splitlines() if "sample loss" in text] == [f"warning: sample loss: {line}"]
    assert captured.out.rstrip().endswith("results in {}/ (results.json, tables.md, logs/); samples lost on 1 stream(s): "
                                          "the live scores rest on incomplete input".format(out))
    live = json.loads((out / "results.json").read_text())
    assert live["live"]["samples"]["loss"] == [line] and live["windows"]["naive"] == {"train": 3, "eval": 2}
    assert live["live"]["received"] == live["live"]["samples"]["received"]["evaluator"]
    assert f"- {line}" in (out / "tables.md").read_text()


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


@pytest.mark.slow
@pytest.mark.parametrize("signum", ["SIGTERM", "SIGINT"])
def test_sigterm_stops_every_node_and_removes_the_staging(tmp_path, signum):
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "live"
    # this worker may ignore SIGINT by now (an earlier test's library did: SigIgn had SIGHUP, SIGINT, SIGQUIT), which a
    # child inherits: run-bag must interrupt anyway (cli.main installs its own SIGINT handler)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "quad_modelling.cli", "run-bag", str(BAG), "--models", "naive", "--rate", "1",
                                 "--no-figures", "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONPATH": str(REPO)})
    finally:
        signal.signal(signal.SIGINT, previous)  # the child has inherited the ignored SIGINT
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob(".live.tmp-*/live/logs/replay.log")) and time.monotonic() < deadline:
            time.sleep(0.1)
        staging = list(tmp_path.glob(".live.tmp-*"))
        assert staging and proc.poll() is None, "the nodes never started"
        time.sleep(2.0)  # the nodes are up and replaying (at real time, 40 s of flight)
        assert _processes_mentioning(str(staging[0]))  # the node processes, found by their params file
        proc.send_signal(getattr(signal, signum))
        signalled = time.monotonic()
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == {"SIGTERM": 143, "SIGINT": 130}[signum], \
        f"exit {proc.returncode} {time.monotonic() - signalled:.1f} s after the signal; stderr: {err!r}; stdout: {out[-1500:]!r}"
    assert err.strip().splitlines()[-1] == f"quad-modelling run-bag: interrupted ({signum})"
    assert list(tmp_path.iterdir()) == []  # no output, no staging
    assert _processes_mentioning(str(staging[0])) == []  # no orphaned node


def test_nodes_expected_elsewhere_that_never_appear_are_named_in_one_line(tmp_path, capsys):
    """--nodes evaluator: the evaluator starts here, the replay and the predictor are expected on another host; none
    comes within --remote-timeout, so run-bag stops its evaluator and names both, leaving nothing behind."""
    out = tmp_path / "ground"
    code = main(["run-bag", str(BAG), "--nodes", "evaluator", "--remote-timeout", "3", "--no-figures", "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 2
    assert "starting evaluator here; expecting /quad/naive_predictor, /quad/replay on another host" in captured.out
    assert captured.err.strip().splitlines()[-1].startswith(
        "quad-modelling run-bag: error: /quad/naive_predictor, /quad/replay never appeared within --remote-timeout 3 s "
        "(ROS_DOMAIN_ID ")
    assert list(tmp_path.iterdir()) == []


def test_bad_nodes_and_discovery_flags_are_one_line_errors(tmp_path, capsys, monkeypatch):
    assert main(["run-bag", str(BAG), "--nodes", "replay,foo", "-o", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == ("quad-modelling run-bag: error: --nodes 'replay,foo': unknown node 'foo'; "
                                               "valid: replay, predictors, evaluator (comma-separated)")
    monkeypatch.delenv("ROS_DOMAIN_ID")
    assert main(["run-bag", str(BAG), "--nodes", "replay,predictors", "-o", str(tmp_path / "x")]) == 2
    assert "--nodes: evaluator run on another host; set ROS_DOMAIN_ID" in capsys.readouterr().err
    assert main(["run-bag", str(BAG), "--nodes", "replay", "--record", "-o", str(tmp_path / "x")]) == 2
    assert "--record with --nodes replay: the evaluator records; pass --record on its host" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_truth_model_live_equals_offline_on_a_simulated_bag_and_refuses_a_real_one(tmp_path, capsys):
    """``--models truth`` on a simulated bag (default effects: delay, motor lag, battery...): the predictor node gets the
    bag's simulator notes (truth_notes.json) and the battery topic, and scores as the offline evaluation; on a bag
    without simulator notes run-bag refuses in one line naming it, before any node starts."""
    bag = tmp_path / "sim"
    assert main(["simulate", "-o", str(bag), "--bag", "--duration", "7", "--seed", "8"]) == 0
    out = tmp_path / "live"
    code = main(["run-bag", str(bag), "--models", "truth", "--window", "2", "--train", "2:4", "--eval", "4:6", "--no-figures",
                 "-o", str(out)])
    assert code == 0, capsys.readouterr().out
    live = json.loads((out / "results.json").read_text())
    log = read_bag(bag)
    vehicle = load_vehicle(log.meta.vehicle)
    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="2:4", eval="4:6", window_s=2.0, warm_s=0.2)
    offline = evaluate([log], [make_model(m, vehicle) for m in ("truth", "dummy")], vehicle, config, multistep=False).to_json()
    assert live["windows"]["truth"] == offline["windows"]["truth"] == {"train": 1, "eval": 1}
    for span in ("train", "eval"):
        for var, entry in offline["models"]["truth"][span].items():
            assert live["models"]["truth"][span][var]["rms"] == pytest.approx(entry["rms"], rel=1e-6), (span, var)
    multistep = multistep_evaluation([resample_uniform(log)], [make_model("truth", vehicle)], vehicle, config)
    for group, entry in multistep["models"]["truth"].items():
        assert live["horizons"]["models"]["truth"][group]["sim_err"] == pytest.approx(entry["sim_err"], rel=1e-9), group
    assert json.loads((out / "truth_notes.json").read_text())["seed"] == 8
    capsys.readouterr()
    assert main(["run-bag", str(BAG), "--models", "truth", "-o", str(tmp_path / "real")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{BAG}: not a simulated flight" in err


@pytest.mark.slow
def test_a_contract_bag_under_another_namespace_is_replayed(tmp_path, capsys):
    """A bag written by convert --namespace is replayed in the contract (read, then rewritten under /quad), with the
    offline numbers of the same flight."""
    moved = tmp_path / "namespaced"
    assert main(["convert", str(BAG), "-o", str(moved), "--namespace", "/my_drone/cf1"]) == 0
    out = tmp_path / "live"
    code = main(["run-bag", str(moved), "--models", "still=naive", "--train", "0:20", "--eval", "20:40", "--no-figures",
                 "--no-multistep", "-o", str(out)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert f"{moved}: read through topic map quad (4227 samples); replaying it in the topic contract" in printed
    live = json.loads((out / "results.json").read_text())
    assert live["windows"]["still"] == {"train": 2, "eval": 2}
    # a named model's spec is kept for merge and said in tables.md, as evaluate's (it was lost)
    assert live["statistics"]["model_specs"] == {"still": "naive"}
    assert "Models: still (naive) = " in (out / "tables.md").read_text()
    # the flight is named by its numbers, as evaluate's: merge tells it from another and refuses it twice (every run-bag
    # result was the flight "live (None s)": two of different flights were refused, one beside evaluate's counted twice)
    [entry] = live["config"]["flights"]
    assert entry["source"] == str(moved) and entry["fingerprint"] == load_flight(moved).fingerprint()
    assert main(["evaluate", str(moved), "--drop", "0:0", "--train", "0:20", "--eval", "20:40", "--no-multistep", "--horizons", "1",
                 "--model", "still=naive", "-o", str(tmp_path / "offline")]) == 0
    capsys.readouterr()
    assert main(["merge", str(out), str(tmp_path / "offline"), "-o", str(tmp_path / "merged")]) == 2
    assert "is also in" in capsys.readouterr().err


@pytest.mark.slow
def test_a_mapped_bags_reader_warnings_are_printed_once_as_evaluate_prints_them(tmp_path, capsys):
    """A PX4 bag with a 0.3 s hole, read through a map whose commands range is in the wrong unit, with battery_status
    recorded without a message: run-bag printed none of the three warnings evaluate prints; now each once, evaluate's
    line (the gap named on the user's bag and its topic, not on the temporary contract bag run-bag replays)."""
    import dataclasses
    from functools import partial

    import numpy as np

    from quad_modelling.io.loader import load_flight
    from test.stack_bags import px4_messages, write_stack_bag

    cf = load_vehicle("crazyflie21")
    flight = load_flight(REPO / "test" / "fixtures" / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz")  # 10 s
    keep = np.r_[0:500, 530:len(flight)]  # no message of any topic for 5.00..5.29 s
    holed = dataclasses.replace(flight, **{f: v[keep] for f, v in vars(flight).items() if isinstance(v, np.ndarray)})
    bag = write_stack_bag(tmp_path / "px4", partial(px4_messages, log=holed, input_range=(cf.input_min, cf.input_max)),
                          empty=("/fmu/out/battery_status",))
    wrong = tmp_path / "px4_range.yaml"
    wrong.write_text((REPO / "config" / "topic_maps" / "px4.yaml").read_text().replace("range: [0, 1]", "range: [0, 100]"))
    expected = [f"warning: {bag}: topic /fmu/out/actuator_motors has no message for 0.31 s (t=4.990..5.300 s into the flight), "
                "longer than 0.05 s: marked as a measurement gap, not interpolated through; windows and training segments "
                "overlapping it are left out",
                f"warning: {bag}: the commands reach 0.9% of the input range [0, 65535] (99th percentile); a flying "
                "vehicle's commands reach 5% or more: check the commands' range: topic map px4",
                f"warning: {bag}: optional topic(s) /fmu/out/battery_status recorded with no message: read without them"]
    main(["evaluate", str(bag), "--topic-map", str(wrong), "--vehicle", "crazyflie21", "--window", "2", "--drop", "0:0",
          "-o", str(tmp_path / "offline")])
    assert sorted(line for line in capsys.readouterr().err.splitlines() if line in expected) == sorted(expected)
    code = main(["run-bag", str(bag), "--topic-map", str(wrong), "--vehicle", "crazyflie21", "--window", "2", "--no-figures",
                 "--no-multistep", "-o", str(tmp_path / "live")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert sorted(captured.err.splitlines()) == sorted(expected)
    assert json.loads((tmp_path / "live" / "results.json").read_text())["windows"]["naive"] == {"live": 4}
