import json

import pytest

from quad_modelling.cli import main
from test.conftest import REPO


def test_evaluate_writes_results_tables_and_figures(flights, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["evaluate", *flights, "--vehicle", "linkquad", "--preset", "short", "-o", str(out)])
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    assert set(results["models"]) == {"greybox", "dummy"}
    assert results["models"]["dummy"]["eval"]["acc_z"]["tic"] == pytest.approx(1.0)
    assert results["models"]["greybox"]["eval"]["acc_z"]["tic"] < 0.1
    assert set(results["models"]["greybox"]["eval"]) == {
        "vel_x", "vel_y", "vel_z", "acc_x", "acc_y", "acc_z", "roll_rate", "pitch_rate", "yaw_rate", "roll_acc", "pitch_acc", "yaw_acc"}
    assert results["config"]["train"] == "0%:60%" and results["windows"]["dummy"] == {"train": 2, "eval": 2}
    tables = (out / "tables.md").read_text()
    assert "| Z acceleration | m/s2 |" in tables and "deg/s2" in tables and "SimErr" in tables
    for fig in ("fig_z.png", "fig_roll.png", "fig_pitch.png", "fig_yaw.png"):
        assert (out / fig).read_bytes()[:4] == b"\x89PNG"
    # never overwrites without --force
    assert main(["evaluate", *flights, "--vehicle", "linkquad", "--preset", "short", "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err


def test_short_flights_with_thesis_spans_fail_with_advice(flights, tmp_path, capsys):
    assert main(["evaluate", *flights, "--vehicle", "linkquad", "-o", str(tmp_path / "x")]) == 2
    assert "--preset short" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_flights_of_different_vehicles_are_refused(tmp_path, capsys):
    from quad_modelling.cli import main
    from quad_modelling.io.matlog import write_matlog
    from test.conftest import synthetic_log

    write_matlog(synthetic_log(vehicle="linkquad"), tmp_path / "lq.mat")
    write_matlog(synthetic_log(vehicle="crazyflie21"), tmp_path / "cf.mat")
    assert main(["evaluate", str(tmp_path / "lq.mat"), str(tmp_path / "cf.mat"), "-o", str(tmp_path / "out")]) == 2
    assert "different vehicles ['crazyflie21', 'linkquad']" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_the_multistep_table_lists_every_model_evaluated(tmp_path):
    """naive, greybox and a NARX (each with its vectorised, causal predict_horizons) are all in the multi-step
    table of results.json and tables.md; only the dummy is left out, with the reason. (A model with only a live
    form is in the table too: test/core/evaluation/test_multistep.py.)"""
    from test.commands.test_train import BAG, SMALL

    assert main(["train", BAG, "-o", str(tmp_path / "narx.npz"), *SMALL]) == 0
    out = tmp_path / "out"
    assert main(["evaluate", BAG, "--preset", "short", "--model", "naive", "--model", "greybox",
                 "--model", f"narx:{tmp_path / 'narx.npz'}", "-o", str(out)]) == 0
    horizons = json.loads((out / "results.json").read_text())["horizons"]
    assert list(horizons["models"]) == ["naive", "greybox", "narx"]
    assert horizons["forms"] == {"naive": "predict_horizons", "greybox": "predict_horizons", "narx": "predict_horizons"}
    assert horizons["not_multistep"] == {"dummy": "no multi-step form: neither predict_horizons nor a live (streaming) form"}
    narx = horizons["models"]["narx"]["velocity"]
    assert narx["naive_sim_err"] == horizons["models"]["naive"]["velocity"]["sim_err"]
    assert narx["ratio_sim_err"] == pytest.approx(narx["sim_err"] / narx["naive_sim_err"])
    tables = (out / "tables.md").read_text()
    assert tables.count("| narx | ") == 4
    assert "Not in the multi-step table: dummy (no multi-step form" in tables
    assert "greybox = linear greybox, the thesis reproduction" in tables


@pytest.mark.slow
def test_a_horizon_beyond_50_says_the_starts_differ_and_too_long_a_horizon_says_why_no_table(tmp_path, capsys):
    """SimErr sums h = 1..50 whatever the horizons; a longer horizon leaves fewer starts (each needs its rows ahead),
    which the table says; one longer than every segment gives the note instead of a table, and a warning line (the
    table was dropped with a word in tables.md only)."""
    from test.commands.test_train import BAG

    for horizons, name in (("1,10,50", "default"), ("1,100", "long"), ("1,100000", "too_long")):
        capsys.readouterr()
        assert main(["evaluate", BAG, "--preset", "short", "--horizons", horizons, "-o", str(tmp_path / name)]) == 0
        warned = [line for line in capsys.readouterr().err.splitlines() if "no multi-step table" in line]
        assert warned == ([] if name != "too_long" else [
            "warning: no multi-step table: no eval segment longer than 100000 samples plus the warm start (the longest of the "
            "horizons 1,100000)"])
    default, long = (json.loads((tmp_path / n / "results.json").read_text())["horizons"] for n in ("default", "long"))
    assert long["sim_err_horizon"] == 100 and long["starts"] == default["starts"] - 50
    assert "Every start has 100 rows ahead" in (tmp_path / "long" / "tables.md").read_text()
    assert "rows ahead" not in (tmp_path / "default" / "tables.md").read_text()
    assert ("Multi-step table: no eval segment longer than 100000 samples plus the warm start."
            in (tmp_path / "too_long" / "tables.md").read_text())


def test_a_flight_the_reader_cut_is_said_by_evaluate_as_by_convert(tmp_path, capsys):
    """The NanoBench extrapolated tail: the reader cuts the flight with a warning, which evaluate prints too (it printed
    gap warnings only, so a flight scored over its first 0.5 s said nothing of the cut)."""
    from test.conftest import FIXTURES

    quirk = FIXTURES / "nanobench" / "B9_trefoil_fast_rep2_rows1199-1399.csv.gz"
    assert main(["evaluate", str(quirk), "--drop", "0:0", "--train", "0%:50%", "--eval", "50%:100%", "-o", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.splitlines()
    warnings = [line for line in err if line.startswith("warning:")]
    assert len(warnings) == 1 and warnings[0].startswith(f"warning: {quirk}: motor columns continue as one straight line")
    assert warnings[0].endswith("the flight is cut at t=0.53 s")
    # the 0.53 s left hold no window: the one error line says so (no warning line before it repeats it)
    assert len(err) == 2 and "no 10 s window fits the spans" in err[1] and "flight durations 0.5 s" in err[1]
    assert not (tmp_path / "e").exists()


def test_a_span_that_holds_no_window_is_said_in_one_warning_line(tmp_path, capsys):
    """--train 50:60 on a 42 s flight: the eval span is scored, the empty train span is said (exit 0 before, silently)."""
    from test.conftest import REPO

    bag = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
    assert main(["evaluate", str(bag), "--drop", "5:5", "--train", "50:60", "--eval", "10:30", "--window", "5",
                 "--no-multistep", "-o", str(tmp_path / "e")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings == ["warning: span train 50:60 holds no 5 s window of any flight after dropping 5 s/5 s: nothing scored there"]


def test_a_flight_with_no_window_in_either_span_is_said(flights, tmp_path, capsys):
    """Counted among the flights but scored nowhere: one warning line names it (it was silent)."""
    from quad_modelling.io.matlog import read_matlog, write_matlog

    short = read_matlog(flights[1], vehicle="linkquad")
    write_matlog(short.slice(0, int(8 * short.sample_rate)), tmp_path / "short.mat")
    assert main(["evaluate", flights[0], str(tmp_path / "short.mat"), "--vehicle", "linkquad", "--preset", "short",
                 "--drop", "0:0", "--no-multistep", "-o", str(tmp_path / "out")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: {tmp_path / 'short.mat'}: no window in either span (too short, or every window touches "
                        "the ground or a gap): not in the window scores"]


@pytest.mark.slow
def test_one_flight_in_two_formats_counts_once(tmp_path, capsys):
    """A bag and the .mat converted from it are one flight (the same recorded numbers, FlightLog.fingerprint):
    evaluate, identify and train refuse it given twice, one line, exit 2, nothing written (evaluate scored it twice
    and train early-stopped on its own training flight; a review, session 29)."""
    bag = str(REPO / "bags" / "nanobench_B7_oval_medium_rep2")
    mat = tmp_path / "b7.mat"
    assert main(["convert", bag, "-o", str(mat)]) == 0
    capsys.readouterr()
    runs = {"evaluate": ["evaluate", bag, str(mat), "--preset", "short", "-o", str(tmp_path / "e")],
            "identify": ["identify", bag, str(mat), "--preset", "short", "-o", str(tmp_path / "v.yaml")],
            "train": ["train", bag, "--val-flights", str(mat), "--preset", "short", "-o", str(tmp_path / "t.npz")]}
    for verb, argv in runs.items():
        assert main(argv) == 2, verb
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{mat}: the same flight as" in err[0] and bag in err[0], (verb, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b7.mat"]
    # refused when the second copy is scored, before a later flight is read (a broken one here: never reached)
    broken = tmp_path / "broken.mat"
    broken.write_bytes(b"not a MATLAB file")
    assert main(["evaluate", bag, str(mat), str(broken), "--preset", "short", "-o", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{mat}: the same flight as" in err[0], err
    broken.unlink()


def test_force_replaces_an_output_directory_not_another_file(tmp_path, capsys):
    """`evaluate -o model.npz --force` turned an existing model file into a directory of figures (the model lost; a
    review, session 29): an output directory's --force replaces an earlier output directory only."""
    bag = str(REPO / "bags" / "nanobench_B7_oval_medium_rep2")
    precious = tmp_path / "narx_copy.npz"
    precious.write_bytes(b"a model")
    assert main(["evaluate", bag, "--preset", "short", "-o", str(precious), "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "an existing file, not an output directory" in err[0]
    assert precious.read_bytes() == b"a model"


def test_the_physics_model_on_never_identified_constants_is_warned(tmp_path, capsys):
    """`evaluate --model physics` with the shipped vehicle (starting values) said nothing, where export refuses such a
    vehicle and train warns (a review, session 29): one warning line naming the constants and how to identify them."""
    bag = str(REPO / "bags" / "nanobench_B7_oval_medium_rep2")
    assert main(["evaluate", bag, "--model", "physics", "--preset", "short", "--no-multistep", "-o", str(tmp_path / "e")]) == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if "never identified" in line]
    assert len(warned) == 1 and "the physics model holds starting values" in warned[0]
    assert "quad-modelling identify FLIGHTS --vehicle crazyflie21 -o FILE" in warned[0]


@pytest.mark.slow
def test_two_model_files_of_one_kind_are_compared_by_naming_them(tmp_path, capsys):
    """`--model direct:a.npz --model direct:b.npz` were two models named direct, refused with no way out; NAME=SPEC
    names them as run-bag's --models does. A direct model file is an input too (-o onto it is refused)."""
    bag = str(REPO / "bags" / "nanobench_B7_oval_medium_rep2")
    first, second = tmp_path / "a.npz", tmp_path / "b.npz"
    assert main(["train", bag, "-o", str(first), "--direct", "--preset", "short", "--quiet"]) == 0
    second.write_bytes(first.read_bytes())
    capsys.readouterr()
    plain = ["evaluate", bag, "--preset", "short", "--no-multistep", "--model", f"direct:{first}", "--model", f"direct:{second}"]
    assert main([*plain, "-o", str(tmp_path / "out")]) == 2
    assert "model names must be unique, got ['direct', 'direct', 'dummy']: name them, --model NAME=SPEC" in capsys.readouterr().err
    named = ["evaluate", bag, "--preset", "short", "--no-multistep", "--model", f"a=direct:{first}", "--model", f"b=direct:{second}"]
    assert main([*named, "-o", str(tmp_path / "out")]) == 0
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert list(results["models"]) == ["a", "b", "dummy"] and results["models"]["a"] == results["models"]["b"]
    models_line = (tmp_path / "out" / "tables.md").read_text().splitlines()[4]  # it listed the dummy alone
    assert models_line.startswith(f"Models: a (direct:{first}) = physics base with the body rates of a ridge regression")
    assert f"; b (direct:{second}) = physics base with" in models_line and models_line.endswith("; dummy = predicts zero "
                                                                                                "deviation from the trim (thesis Fig 5.2 baseline, TIC 1).")
    assert main([*named, "-o", str(first), "--force"]) == 2
    assert f"the output is the input {first}" in capsys.readouterr().err
    for text, why in (("1a=greybox", "model name '1a' must be letters, digits and '_', not starting with a digit"),
                      (f"dummy=direct:{first}", "dummy is the name of a baseline every evaluation holds"),
                      ("naive=greybox", "naive is the name of a baseline every evaluation holds; name the greybox model otherwise")):
        assert main(["evaluate", bag, "--preset", "short", "--model", text, "-o", str(tmp_path / "bad")]) == 2
        assert why in capsys.readouterr().err


def test_a_logging_hole_in_a_csv_is_a_marked_gap_not_a_refused_flight(tmp_path, capsys):
    """110 ms of rows missing from a NanoBench CSV refused the whole flight ("gap of 110 ms ... exceeds the 50 ms"),
    while the same hole of 1 s was accepted once converted to a bag: now the hole is marked, said once, and the
    windows away from it are scored."""
    import gzip

    lines = gzip.open(REPO / "test" / "fixtures" / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", "rt").read().splitlines()
    holed = tmp_path / "holed.csv"
    holed.write_text("\n".join([lines[0], *(line for i, line in enumerate(lines[1:]) if not 600 <= i < 610)]) + "\n")
    spans = ["--drop", "0:0", "--train", "2:5.5", "--eval", "6.5:9.9", "--window", "2", "--no-multistep", "--vehicle", "crazyflie21"]
    assert main(["evaluate", str(holed), *spans, "-o", str(tmp_path / "e")]) == 0
    err = capsys.readouterr().err
    assert "topic time base has no message for 0.11 s" in err and "marked as a measurement gap" in err, err
    results = json.loads((tmp_path / "e" / "results.json").read_text())
    assert results["windows"]["greybox"] == {"train": 1, "eval": 1}


def test_one_name_spec_rule_for_evaluate_and_run_bag():
    """NAME=SPEC: run-bag refused a file path holding '=' (narx:/runs/lr=0.1.npz) that evaluate read as the spec."""
    from quad_modelling.commands.run_bag import ModelEntry, parse_models
    from quad_modelling.core.models.registry import named_spec
    from quad_modelling.errors import ConfigError

    assert named_spec("narx:/runs/lr=0.1.npz") == (None, "narx:/runs/lr=0.1.npz")
    assert named_spec("a=narx:/runs/lr=0.1.npz") == ("a", "narx:/runs/lr=0.1.npz")
    assert parse_models("naive, narx:/runs/lr=0.1.npz, b=narx:/runs/lr=0.2.npz") == [
        ModelEntry("naive", "naive"), ModelEntry("narx", "narx:/runs/lr=0.1.npz"), ModelEntry("b", "narx:/runs/lr=0.2.npz")]
    for text, why in (("1a=greybox", "model name '1a' must be letters"), ("naive=greybox", "naive is the name of a baseline"),
                      ("a=", "NAME= names no model")):
        with pytest.raises(ConfigError, match=why):
            named_spec(text)
        with pytest.raises(ConfigError, match=why):
            parse_models(text)
