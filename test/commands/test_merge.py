"""quad-modelling merge: refuses what cannot be merged in one line (exit 2), writes atomically (#19).

(That a merge of per-flight evaluations equals one evaluation of all the flights, bit for bit, is
test/commands/test_fanout.py.)"""

from __future__ import annotations

import json

import pytest

from quad_modelling.cli import main

SHORT = ["--vehicle", "linkquad", "--preset", "short"]


@pytest.fixture(scope="module")
def results(flights, tmp_path_factory):
    """Per-flight evaluations of the two test flights (greybox, dummy), a third with other spans, a fourth with
    other models: {name: directory}."""
    root = tmp_path_factory.mktemp("results")
    runs = {"a": [flights[0]], "b": [flights[1]], "other_spans": [flights[1], "--eval", "50%:100%"],
            "other_models": [flights[1], "--model", "naive"]}
    for name, args in runs.items():
        assert main(["evaluate", *args, *SHORT, "-o", str(root / name)]) == 0
    return {name: root / name for name in runs}


def merge_error(args, capsys) -> str:
    assert main(["merge", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("quad-modelling merge: error: "), err
    return err[0]


@pytest.mark.slow
def test_merge_writes_results_and_tables_and_refuses_to_overwrite(results, tmp_path, capsys):
    out = tmp_path / "merged"
    assert main(["merge", str(results["a"]), str(results["b"]), "-o", str(out)]) == 0
    merged = json.loads((out / "results.json").read_text())
    one = [json.loads((results[k] / "results.json").read_text()) for k in "ab"]
    assert merged["windows"]["greybox"]["eval"] == one[0]["windows"]["greybox"]["eval"] + one[1]["windows"]["greybox"]["eval"]
    assert [f["source"] for f in merged["config"]["flights"]] == [one[0]["config"]["flights"][0]["source"], one[1]["config"]["flights"][0]["source"]]
    assert sorted(p.name for p in out.iterdir()) == ["results.json", "tables.md"]
    assert "2 flight(s) from 2 results" in capsys.readouterr().out
    assert "exists; pass --force" in merge_error([str(results["a"]), str(results["b"]), "-o", str(out)], capsys)
    assert main(["merge", str(results["a"]), "-o", str(out), "--force"]) == 0
    assert json.loads((out / "results.json").read_text())["models"] == one[0]["models"]  # one input: its own numbers


def test_merge_refuses_missing_foreign_and_incompatible_results(results, tmp_path, capsys):
    out = str(tmp_path / "out")
    empty = tmp_path / "empty"
    empty.mkdir()
    assert f"{empty}: no results.json" in merge_error([str(results["a"]), str(empty), "-o", out], capsys)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "results.json").write_text('{"rows": [1, 2]}')
    assert "not the results.json of quad-modelling evaluate" in merge_error([str(results["a"]), str(foreign), "-o", out], capsys)
    (foreign / "results.json").write_text("{not json")
    assert "not a JSON document" in merge_error([str(foreign), "-o", out], capsys)
    (foreign / "results.json").write_text("[" * 100_000 + "]" * 100_000)
    assert f"{foreign / 'results.json'}: nests deeper than JSON can be read" in merge_error([str(foreign), "-o", out], capsys)
    averages_only = json.loads((results["a"] / "results.json").read_text())
    del averages_only["statistics"]
    (foreign / "results.json").write_text(json.dumps(averages_only))
    assert "no 'statistics' to merge" in merge_error([str(foreign), "-o", out], capsys)
    live_only = json.loads((results["a"] / "results.json").read_text())  # run-bag without spans: live:0:inf
    live_only["config"].update(train="", eval="")
    live_only["live"] = {"spans": [{"name": "live", "start_s": 0.0, "end_s": None}]}
    (foreign / "results.json").write_text(json.dumps(live_only))
    assert "a run-bag result without both --train and --eval (its span is live:0:inf)" in merge_error([str(foreign), "-o", out], capsys)
    assert "models differs from" in (message := merge_error([str(results["a"]), str(results["other_models"]), "-o", out], capsys))
    assert "['naive', 'dummy'] (there ['greybox', 'dummy'])" in message
    message = merge_error([str(results["a"]), str(results["other_spans"]), "-o", out], capsys)
    assert "other_spans/results.json: configuration differs from" in message and "eval '50%:100%' (there " in message
    assert "EvaluationConfig(" not in message and len(message) < 400  # the field that differs, not two whole configurations
    assert "given twice" in merge_error([str(results["a"]), str(results["a"]), "-o", out], capsys)
    assert not (tmp_path / "out").exists()


def test_merge_refuses_an_input_as_output(results, capsys):
    assert "the output is the input" in merge_error([str(results["a"]), str(results["b"]), "-o", str(results["b"]), "--force"], capsys)
    assert (results["b"] / "results.json").exists()


def test_merge_refuses_evaluations_run_with_different_vehicle_files_of_one_airframe(results, flights, tmp_path, capsys):
    """Two vehicle files of the LinkQuad that differ in one constant predict differently: their evaluations do not
    merge, and the message names the constant; one without the numbers (written before they were kept) still does."""
    import yaml

    from quad_modelling.core.vehicle import load_vehicle

    document = yaml.safe_load(open(load_vehicle("linkquad").path))
    document["constants"]["mass"]["value"] *= 1.1
    heavier = tmp_path / "linkquad_heavier.yaml"
    heavier.write_text(yaml.safe_dump(document))
    other = tmp_path / "other_vehicle"
    assert main(["evaluate", flights[1], "--vehicle", str(heavier), "--preset", "short", "-o", str(other)]) == 0
    message = merge_error([str(results["a"]), str(other), "-o", str(tmp_path / "out")], capsys)
    mass = load_vehicle("linkquad").value("mass")
    assert f"other_vehicle/results.json: vehicle constants differ from {results['a']}/results.json's (mass {mass:.6g} vs {mass * 1.1:.6g})" in message
    older = tmp_path / "older"
    older.mkdir()
    document = json.loads((other / "results.json").read_text())
    del document["statistics"]["vehicle_numbers"]
    (older / "results.json").write_text(json.dumps(document))
    assert main(["merge", str(results["a"]), str(older), "-o", str(tmp_path / "out")]) == 0


@pytest.mark.slow
def test_merge_refuses_one_model_name_loaded_from_two_different_files(tmp_path, capsys):
    """Two NARX files are both the model `narx`: evaluations of each do not merge (by the files' contents); the same
    file under another path does."""
    import shutil

    from test.commands.test_train import BAG, SMALL

    assert main(["train", BAG, "-o", str(tmp_path / "a.npz"), *SMALL]) == 0
    assert main(["train", BAG, "-o", str(tmp_path / "b.npz"), *SMALL, "--hidden", "6"]) == 0
    shutil.copy(tmp_path / "a.npz", tmp_path / "a_copy.npz")
    from quad_modelling.io.bag_io import read_bag, write_bag

    flight = read_bag(BAG)  # another flight (the same flight twice, under any path, is refused): its last second cut
    write_bag(flight.slice(0, len(flight) - 100), tmp_path / "other_flight")
    for name, flight in (("a", BAG), ("b", BAG), ("a_copy", str(tmp_path / "other_flight"))):
        assert main(["evaluate", flight, "--preset", "short", "--no-multistep", "--model", f"narx:{tmp_path / name}.npz",
                     "-o", str(tmp_path / f"r_{name}")]) == 0
    message = merge_error([str(tmp_path / "r_a"), str(tmp_path / "r_b"), "-o", str(tmp_path / "out")], capsys)
    assert f"r_b/results.json: model narx was loaded from another file than in {tmp_path / 'r_a'}/results.json" in message
    assert main(["merge", str(tmp_path / "r_a"), str(tmp_path / "r_a_copy"), "-o", str(tmp_path / "out")]) == 0
    # a named model in one and not the other: their models differ (it blamed the named model's file)
    assert main(["evaluate", str(tmp_path / "other_flight"), "--preset", "short", "--no-multistep", "--model",
                 f"mine=narx:{tmp_path / 'a'}.npz", "-o", str(tmp_path / "r_named")]) == 0
    message = merge_error([str(tmp_path / "r_a"), str(tmp_path / "r_named"), "-o", str(tmp_path / "out2")], capsys)
    assert "models" in message and "another file" not in message, message
    # a named model's spec is kept in the statistics: the merged tables.md names it as evaluate's did (it lost it)
    assert main(["evaluate", BAG, "--preset", "short", "--no-multistep", "--model", f"mine=narx:{tmp_path / 'a_copy'}.npz",
                 "-o", str(tmp_path / "r_named2")]) == 0
    assert main(["merge", str(tmp_path / "r_named"), str(tmp_path / "r_named2"), "-o", str(tmp_path / "out3")]) == 0
    models_line = next(line for line in (tmp_path / "out3" / "tables.md").read_text().splitlines() if line.startswith("Models:"))
    assert models_line.startswith(f"Models: mine (narx:{tmp_path / 'a'}.npz) = "), models_line
    # one name for two models without files: their scores would be averaged as one model's (merged under the first spec)
    for name, spec, flight in (("g", "greybox", BAG), ("n", "naive", str(tmp_path / "other_flight"))):
        assert main(["evaluate", flight, "--preset", "short", "--no-multistep", "--model", f"m={spec}", "-o", str(tmp_path / f"r_{name}")]) == 0
    message = merge_error([str(tmp_path / "r_g"), str(tmp_path / "r_n"), "-o", str(tmp_path / "out4")], capsys)
    assert "model m (greybox vs naive) is another model in each" in message, message


@pytest.mark.slow
def test_model_specs_whose_argument_is_an_option_are_evaluated_and_merge(flights, tmp_path):
    """greybox:euler and physics:L,A take options, not files: nothing is read as a model file (a traceback before)."""
    for name, flight in (("x", flights[0]), ("y", flights[1])):
        assert main(["evaluate", flight, *SHORT, "--no-multistep", "--model", "greybox", "--model", "greybox:euler",
                     "--model", "physics:0.5,0.5", "-o", str(tmp_path / name)]) == 0
    assert "model_files" in json.loads((tmp_path / "x" / "results.json").read_text())["statistics"]
    assert main(["merge", str(tmp_path / "x"), str(tmp_path / "y"), "-o", str(tmp_path / "out")]) == 0


def test_merge_refuses_one_flight_in_two_results(results, tmp_path, capsys):
    """A copy of a result (or the same flight evaluated twice) would count its windows twice."""
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(results["a"], copy)
    message = merge_error([str(results["a"]), str(copy), "-o", str(tmp_path / "out")], capsys)
    assert f"{copy}/results.json: flight " in message and f"is also in {results['a']}/results.json" in message
    assert "its windows would count twice" in message and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_merge_tells_flights_by_their_numbers_not_their_paths(flights, tmp_path, capsys, monkeypatch):
    """The same flight evaluated by a relative and by an absolute path is one flight (it was merged, counted twice);
    two different flights both named flight.mat in their own directories are two (they were refused)."""
    import shutil
    from pathlib import Path

    for site, flight in (("site1", flights[0]), ("site2", flights[1])):
        (tmp_path / site).mkdir()
        shutil.copy(flight, tmp_path / site / ("flight" + Path(flight).suffix))
    name = "flight" + Path(flights[0]).suffix
    for site in ("site1", "site2"):
        monkeypatch.chdir(tmp_path / site)
        assert main(["evaluate", name, *SHORT, "--no-multistep", "-o", str(tmp_path / f"r_{site}")]) == 0
    monkeypatch.chdir(tmp_path)
    assert main(["merge", "r_site1", "r_site2", "-o", "both"]) == 0
    assert "2 flight(s) from 2 results" in capsys.readouterr().out
    assert main(["evaluate", str(tmp_path / "site1" / name), *SHORT, "--no-multistep", "-o", "absolute"]) == 0
    message = merge_error(["r_site1", "absolute", "-o", "twice"], capsys)
    assert f"absolute/results.json: flight {tmp_path / 'site1' / name} " in message
    assert f"is also in r_site1/results.json (as {name})" in message and not (tmp_path / "twice").exists()
