"""``quad-modelling train``: writes loadable NARX/hybrid/direct model files, refuses bad requests."""

from __future__ import annotations

from pathlib import Path

import pytest

from quad_modelling.cli import main
from quad_modelling.core.models.direct import HORIZON, load_direct
from quad_modelling.core.models.hybrid import load_hybrid
from quad_modelling.core.models.narx import load_narx
from quad_modelling.core.vehicle import load_vehicle

BAG = str(Path(__file__).resolve().parents[2] / "bags" / "nanobench_B7_oval_medium_rep2")
SMALL = ["--preset", "short", "--epochs", "2", "--hidden", "3", "--delays", "4", "--input-delays", "3", "--quiet"]
QUICK_ROLLOUT = ["--horizon", "10", "--rollout-epochs", "2", "--patience", "1"]


def test_train_thesis_writes_the_thesis_narx_model_with_its_settings_and_span(tmp_path, capsys):
    out = tmp_path / "narx.npz"
    assert main(["train", BAG, "-o", str(out), "--seed", "3", "--training", "thesis", *SMALL]) == 0
    model = load_narx(out, vehicle="crazyflie21")
    assert (model.config.hidden, model.config.output_delays, model.config.input_delays, model.config.epochs) == (3, 4, (0, 1, 2), 2)
    assert model.training["seed"] == 3
    (segment,) = model.training["segments"]
    # preset short: drop 5 s at both ends of the 42.3 s flight, train on the first 60 % of the rest
    assert abs(segment["span"][0] - 5.0) < 0.011
    assert abs(segment["span"][1] - (5.0 + 0.6 * 32.3)) < 0.1
    assert abs(model.dt - 0.01) < 1e-4
    assert not model.config.incremental and model.config.noise_snr_db == (None, None, None, 10.0, 10.0, 10.0)
    assert "rollout" not in model.training
    assert "narx:" in capsys.readouterr().out


def test_train_default_is_rollout_training_early_stopped_on_held_back_data(tmp_path, capsys):
    out = tmp_path / "narx.npz"
    assert main(["train", BAG, "-o", str(out), *SMALL, *QUICK_ROLLOUT]) == 0
    model = load_narx(out, vehicle="crazyflie21")
    assert model.config.incremental and model.config.noise_snr_db == (None,) * 6
    rollout = model.training["rollout"]
    assert rollout["horizon"] == 10 and rollout["epochs_run"] <= 2 and rollout["val_windows"] > 0
    (train,), (val,) = model.training["segments"], rollout["validation"]
    # one flight: its span's last 20 % (of 5.0 .. 24.4 s) is held back for validation
    assert abs(train["span"][1] - val["span"][0]) < 0.011 and abs(val["span"][0] - (5.0 + 0.8 * 19.38)) < 0.1
    printed = capsys.readouterr().out
    assert f"best epoch {rollout['best_epoch']} of {rollout['epochs_run']}" in printed and "validation loss" in printed


def test_training_without_validation_windows_or_on_few_rows_says_so(tmp_path, capsys):
    """--val-fraction 0 stopped on the training loss while saying 'validation loss ... on 0 windows'; 100 rows for
    6126 weights trained without a word."""
    out = tmp_path / "narx.npz"
    assert main(["train", BAG, "-o", str(out), *SMALL, *QUICK_ROLLOUT, "--val-fraction", "0", "--train", "0%:1%"]) == 0
    model = load_narx(out, vehicle="crazyflie21")
    printed = capsys.readouterr()
    assert model.training["rollout"]["val_windows"] == 0
    assert "no validation window (--val-fraction 0, or a held-back part shorter than one): stopped on the training loss" in printed.out
    rows, weights = model.training["samples"], model.training["weights"]
    assert rows * 6 < weights and f"warning: {rows} training rows x 6 outputs for {weights} weights" in printed.err


@pytest.mark.slow
def test_train_val_flights_are_used_for_early_stopping_only(tmp_path, capsys):
    from quad_modelling.core.diagnosis.injection import Injection
    from quad_modelling.io.bag_io import write_bag
    from quad_modelling.io.loader import load_flight

    out = tmp_path / "narx.npz"
    other = tmp_path / "other_flight"  # another flight's numbers: the same flight as both is refused (test_evaluate)
    write_bag(Injection("gain", motor=1, factor=1.1).apply(load_flight(BAG)), other)
    assert main(["train", BAG, "-o", str(out), "--val-flights", str(other), *SMALL, *QUICK_ROLLOUT]) == 0
    model = load_narx(out, vehicle="crazyflie21")
    (train,), (val,) = model.training["segments"], model.training["rollout"]["validation"]
    assert train["span"] == val["span"]  # the whole training span of the validation flight, not a part of the training one
    assert " samples of 1 flight(s) in " in capsys.readouterr().out  # the validation flight is not counted as trained on
    hybrid = ["train", BAG, "-o", str(tmp_path / "hybrid.npz"), "--val-flights", str(other), "--hybrid", "--preset", "short",
              "--horizon", "5", "--rollout-epochs", "1", "--hybrid-hidden", "4", "--quiet"]
    assert main(hybrid) == 0  # the hybrid's record has no segments: it said "of 2 flight(s)"
    printed = capsys.readouterr().out  # and the images it trained on too, counted apart
    assert "trained hybrid model on " in printed and " samples of 1 flight(s) and their 3 mirror images in " in printed, printed


def test_train_refuses_to_overwrite_and_empty_spans(tmp_path, capsys):
    out = tmp_path / "narx.npz"
    out.write_bytes(b"keep")
    assert main(["train", BAG, "-o", str(out), *SMALL]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert out.read_bytes() == b"keep"
    assert main(["train", BAG, "-o", str(tmp_path / "other.npz"), "--epochs", "1", "--quiet"]) == 2
    assert "training span 30:150 is empty" in capsys.readouterr().err
    assert not (tmp_path / "other.npz").exists()
    assert main(["train", BAG, "-o", str(tmp_path / "other.npz"), "--val-fraction", "1", *SMALL]) == 2
    assert "--val-fraction 1.0: must lie in [0, 1)" in capsys.readouterr().err
    assert main(["train", BAG, "-o", str(tmp_path / "other.npz"), "--horizon", "0", *SMALL]) == 2
    assert "--horizon 0: must lie in [1, " in capsys.readouterr().err
    assert main(["train", BAG, "-o", str(tmp_path / "other.npz"), *SMALL, "--delays", "-1"]) == 2
    assert "--delays -1: must lie in [1, " in capsys.readouterr().err  # it listed every option's range, naming none


def test_train_hybrid_writes_a_physics_plus_residual_net_model(tmp_path, capsys):
    out = tmp_path / "hybrid.npz"
    args = ["train", BAG, "-o", str(out), "--hybrid", "--preset", "short", "--horizon", "5", "--rollout-epochs", "1",
            "--hybrid-hidden", "6,4", "--seed", "2", "--quiet"]
    assert main(args) == 0
    model = load_hybrid(out, load_vehicle("crazyflie21"))
    assert model.net.hidden == (6, 4) and model.net.n_inputs == 21 + 12 and model.net.n_outputs == 6  # 3 command filters
    assert model.filters == (0.03, 0.1, 0.3)
    assert model.training["seed"] == 2 and model.training["config"]["rollout"]["horizon"] == 5
    assert model.training["rollout"]["epochs_run"] == 1
    (span,) = model.training["spans"]  # preset short: drop 5 s, train on the first 60 % of the rest
    assert abs(span[0] - 5.0) < 0.011 and abs(span[1] - (5.0 + 0.6 * 32.3)) < 0.1
    printed = capsys.readouterr().out
    assert "hybrid:" in printed
    assert "rollout fine-tuning: best epoch" in printed and "(one flight, none held back: in-sample)" in printed  # not 'validation'
    assert model.training["mirror_images"] == ["turn 180°", "mirror x -> -x", "mirror y -> -y"]
    alone = tmp_path / "alone.npz"
    assert main([*args[:2], "-o", str(alone), *args[4:], "--no-mirror-images"]) == 0
    record = load_hybrid(alone, load_vehicle("crazyflie21")).training
    assert record["mirror_images"] == [] and record["config"]["mirror_images"] is False
    assert record["samples"] == model.training["samples"] and record["windows"] * 4 == model.training["windows"]
    assert "mirror images" not in capsys.readouterr().out
    assert main(["train", BAG, "-o", str(tmp_path / "bad.npz"), "--hybrid", "--preset", "short", "--hybrid-hidden", "0,x"]) == 2
    assert "--hybrid-hidden '0,x'" in capsys.readouterr().err
    unfiltered = tmp_path / "unfiltered.npz"
    assert main([*args[:2], "-o", str(unfiltered), *args[4:], "--command-filters", "none"]) == 0
    plain = load_hybrid(unfiltered, load_vehicle("crazyflie21"))
    assert plain.filters == () and plain.net.n_inputs == 21 and plain.training["config"]["command_filters_s"] == []
    capsys.readouterr()
    for text, message in (("30,x", "expected time constants in ms such as 30,100,300, or none"),
                          ("0,100", "one to 6 different time constants in (0, 10000] ms, or none"),
                          ("30,30", "one to 6 different time constants"), ("nan", "one to 6 different time constants")):
        assert main(["train", BAG, "-o", str(tmp_path / "bad.npz"), "--hybrid", "--preset", "short", "--command-filters", text]) == 2
        err = capsys.readouterr().err
        assert f"--command-filters {text!r}: {message}" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad.npz").exists()


@pytest.mark.slow
def test_train_direct_fits_the_rate_regression_and_evaluate_scores_it(tmp_path, capsys):
    out = tmp_path / "direct.npz"
    assert main(["train", BAG, "-o", str(out), "--direct", "--preset", "short", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "trained direct model on" in printed and f"--model direct:{out}" in printed
    assert "vertical map (down velocity): fitted" in printed
    model = load_direct(out, load_vehicle("crazyflie21"))
    assert model.regression.horizon == HORIZON and abs(model.dt - 0.01) < 1e-4
    assert model.vertical is not None and model.vertical.horizon == HORIZON
    # preset short: the first 60 % of the flying part, every anchor with 10 rows before and 50 after it
    assert 1800 < model.training["samples"] < 1950
    report = tmp_path / "report"
    assert main(["evaluate", BAG, "--model", f"direct:{out}", "--preset", "short", "-o", str(report)]) == 0
    assert (report / "results.json").exists()


def test_train_direct_refuses_a_second_model_kind_and_validation_flights_in_one_line(tmp_path, capsys):
    out = tmp_path / "direct.npz"
    assert main(["train", BAG, "-o", str(out), "--direct", "--hybrid", "--preset", "short"]) == 2
    err = capsys.readouterr().err
    assert "--hybrid and --direct: choose one model to train" in err and len(err.strip().splitlines()) == 1
    assert main(["train", BAG, "-o", str(out), "--direct", "--val-flights", BAG, "--preset", "short"]) == 2
    assert "--val-flights: the direct model's fit is closed-form" in capsys.readouterr().err
    assert not out.exists()



@pytest.mark.parametrize("option, kind, message", [
    (["--hidden", "5"], "--direct", "--hidden 5: the direct model does not read it (it reads no model option"),
    (["--hybrid-hidden", "8"], "--direct", "--hybrid-hidden 8: the direct model does not read it"),
    (["--seed", "3"], "--direct", "--seed 3: the direct model does not read it"),
    (["--delays", "5"], "--hybrid", "--delays 5: the hybrid model does not read it (it reads --horizon, --rollout-epochs"),
    (["--training", "thesis"], "--hybrid", "--training thesis: the hybrid model does not read it"),
    (["--hybrid-hidden", "8"], None, "--hybrid-hidden 8: the narx model does not read it"),
    (["--no-mirror-images"], "--direct", "--no-mirror-images: the direct model does not read it"),
    (["--command-filters", "50"], None, "--command-filters 50: the narx model does not read it"),
])
def test_train_refuses_an_option_the_chosen_model_does_not_read_in_one_line(option, kind, message, tmp_path, capsys):
    out = tmp_path / "model.npz"
    assert main(["train", BAG, "-o", str(out), "--preset", "short", *option, *([kind] if kind else [])]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_train_refuses_a_model_file_name_that_is_not_npz(tmp_path, capsys):
    for name in ("direct.yaml", "direct"):
        assert main(["train", BAG, "-o", str(tmp_path / name), "--direct", "--preset", "short"]) == 2
        assert f"-o {tmp_path / name}: a model file is an .npz archive" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_train_direct_on_starting_values_says_so_in_one_warning_line(tmp_path, capsys):
    out = tmp_path / "direct.npz"
    assert main(["train", BAG, "-o", str(out), "--direct", "--preset", "short", "--quiet"]) == 0  # crazyflie21.yaml: never identified
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "the direct model's physics base holds starting values, never identified (" in warnings[0]
    assert "rotor_thrust_constant" in warnings[0] and "pass --vehicle FILE" in warnings[0]


def test_training_reads_rows_of_one_period_as_evaluate_scores_them(tmp_path, capsys):
    """train counted a 110 ms logging hole as one 10 ms row (the direct model's maps count rows); it now trains on the
    resampled flight, the hole a marked gap no training segment crosses, said in one warning."""
    import gzip

    from test.conftest import FIXTURES

    lines = gzip.open(FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", "rt").read().splitlines()
    holed = tmp_path / "holed.csv"
    holed.write_text("\n".join([lines[0], *(line for i, line in enumerate(lines[1:]) if not 600 <= i < 610)]) + "\n")
    whole = tmp_path / "whole.csv"
    whole.write_text("\n".join(lines) + "\n")
    spans = ["--drop", "1:0", "--train", "0%:100%", "--vehicle", "crazyflie21", "--direct", "--quiet"]
    assert main(["train", str(whole), *spans, "-o", str(tmp_path / "whole.npz")]) == 0
    assert main(["train", str(holed), *spans, "-o", str(tmp_path / "holed.npz")]) == 0
    err = capsys.readouterr().err
    assert "topic time base has no message for 0.11 s" in err and "marked as a measurement gap" in err, err
    whole_model = load_direct(tmp_path / "whole.npz", load_vehicle("crazyflie21"))
    holed_model = load_direct(tmp_path / "holed.npz", load_vehicle("crazyflie21"))
    # two gap-free parts around the 10 filled rows: each loses the 10 rows of history and the 50 of horizon at its
    # edges, so 10 + 60 anchors fewer (the span's row bounds move by a row or two with the hole)
    assert abs(whole_model.training["samples"] - holed_model.training["samples"] - 70) <= 2


@pytest.mark.slow
def test_a_seconds_training_span_overlapping_the_presets_percent_eval_span_is_warned(tmp_path, capsys):
    """--train 10:30 with --preset short's eval 60%:100% shares time on a 42 s flight: the kinds differ, so the spans
    alone could not tell, and nothing was said (review); judged on the flight, one warning naming it."""
    assert main(["train", BAG, "--preset", "short", "--train", "10:30", "--direct", "--quiet", "-o", str(tmp_path / "d.npz")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "in-sample" in line]
    assert len(warnings) == 1 and f"{BAG}: the training span 10:30 (10.0-30.0 s of this flight) and the evaluation span " \
                                  "60%:100%" in warnings[0], warnings
    assert main(["train", BAG, "--preset", "short", "--train", "5:15", "--direct", "--quiet", "-o", str(tmp_path / "e.npz")]) == 0
    assert "in-sample" not in capsys.readouterr().err
    # spans of one kind: the evaluation span is evaluate's, which train has no flag for: the warning says whose it is
    assert main(["train", BAG, "--preset", "short", "--train", "0%:80%", "--direct", "--quiet", "-o", str(tmp_path / "f.npz")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "in-sample" in line]
    assert warnings == ["warning: the training span 0%:80% and the evaluation span 60%:100% share 60%:80%: what is fitted "
                        "there is scored partly in-sample if `evaluate --preset short` scores these flights; evaluate the "
                        "model on other flights, or give evaluate an --eval span after the training one"], warnings
