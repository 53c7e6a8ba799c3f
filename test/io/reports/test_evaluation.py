"""Evaluation report text: the run-bag summary table and the evaluate console lines from a known results.json."""

from quad_modelling.core.variables import EVAL_VARIABLES
from quad_modelling.io.reports.evaluation import (
    headline_scores,
    live_summary_table,
    windows_text,
)


def _results():
    """greybox scored on train and eval (TIC 0.25, RMS 0.1 SI), the dummy on both (TIC 1, RMS 0.2 SI)."""
    def span(tic, rms):
        return {v: {"tic": tic, "rms": rms} for v in EVAL_VARIABLES}

    return {"models": {"greybox": {"train": span(0.25, 0.1), "eval": span(0.25, 0.1)}, "dummy": {"train": span(1.0, 0.2), "eval": span(1.0, 0.2)}},
            "windows": {"greybox": {"train": 4, "eval": 2}, "dummy": {"train": 4, "eval": 2}},
            "live": {"marked": [{"reason": "predictor stale"}]}}


def test_live_summary_table_is_aligned_markdown_in_display_units():
    lines = live_summary_table(_results(), ["greybox"]).splitlines()
    assert lines[:4] == [
        "TIC / RMS per variable (mean over windows; RMS in display units)",
        "",
        "| variable   | unit   | greybox (train) | greybox (eval) | dummy (eval) |",
        "|------------|--------|----------------:|---------------:|-------------:|",
    ]
    assert lines[4] == "| vel_x      | m/s    |      0.25 / 0.1 |     0.25 / 0.1 |   1.00 / 0.2 |"
    # 0.1 rad/s = 5.73 deg/s, 0.2 rad/s = 11.5 deg/s
    assert lines[10] == "| roll_rate  | deg/s  |     0.25 / 5.73 |    0.25 / 5.73 |  1.00 / 11.5 |"
    assert lines[-3] == "windows scored: greybox train: 4, greybox eval: 2, dummy eval: 2; marked: 1"
    assert lines[-1].startswith("Models: greybox = linear greybox, the thesis reproduction (Sonntag 2011 ch. 3")
    assert lines[-1].endswith("; dummy = predicts zero deviation from the trim (thesis Fig 5.2 baseline, TIC 1).")


def test_live_summary_without_a_scored_window_names_the_first_reason():
    assert live_summary_table({"models": {}, "windows": {}, "live": {"marked": [{"reason": "input ended"}]}}, ["naive"]) == \
        "no window was scored; marked: input ended"


def test_console_lines_of_evaluate():
    assert windows_text(_results()) == "windows train 4, eval 2"
    assert headline_scores(_results(), ["greybox", "dummy"]) == ["  greybox: TIC acc_z 0.25, roll_rate 0.25, vel_z 0.25",
                                                                 "  dummy: TIC acc_z 1.00, roll_rate 1.00, vel_z 1.00"]


def test_the_headline_names_its_span_when_the_eval_span_holds_no_window():
    """With no eval window the lines came from the train span unlabelled, read as held-out scores (review)."""
    data = _results()
    for model in data["models"].values():
        model.pop("eval")
    assert headline_scores(data, ["greybox"]) == ["  greybox (span train: no eval window): TIC acc_z 0.25, roll_rate 0.25, vel_z 0.25"]


def test_live_tables_name_the_live_spans_not_empty_train_and_eval():
    """A live result (the evaluator node, run-bag without spans) has named seconds spans and no drops: the header
    says them (it read 'spans train , eval  (drop 0 s / 0 s) ... Windows per span: .')."""
    from quad_modelling.io.reports.evaluation import tables_text

    document = {**_results(), "models": {"greybox": {}, "dummy": {}}, "windows": {"greybox": {}, "dummy": {}},
                "config": {"flights": [], "train": "", "eval": "", "drop_start": 0.0, "drop_end": 0.0, "window_s": 5.0,
                           "warm_s": 0.2},
                "live": {"spans": [{"name": "live", "start_s": 0.0, "end_s": None}], "marked": []}}
    header = tables_text(document, "Live evaluation").splitlines()[2]
    assert header == ("0 flight(s) (0 skipped); spans live 0:inf (seconds from the first motor input); 5 s windows, "
                      "0.2 s warm start. Windows per span: none scored.")


def test_live_tables_count_the_marked_windows_and_say_why():
    """Windows closed without a score (predictor late, incomplete, ...) were only in results.json: tables.md
    counts them per model and names the reasons, most frequent first."""
    from quad_modelling.io.reports.evaluation import tables_text

    late, cut = "predictor late: its predictions stopped", "incomplete: the engine inputs stopped"
    marked = [{"model": "greybox", "reason": late}, {"model": "narx", "reason": late}, {"model": "narx", "reason": cut},
              {"model": "narx", "reason": "a"}, {"model": "narx", "reason": "b"}]
    document = {**_results(), "models": {"greybox": {}, "dummy": {}}, "windows": {"greybox": {}, "dummy": {}},
                "config": {"flights": [], "train": "", "eval": "", "drop_start": 0.0, "drop_end": 0.0, "window_s": 5.0,
                           "warm_s": 0.2},
                "live": {"spans": [{"name": "live", "start_s": 0.0, "end_s": None}], "marked": marked}}
    line = tables_text(document, "Live evaluation").splitlines()[4]
    assert line == (f"Marked, not scored: 5 window result(s) (greybox 1, narx 4), not in the tables below: {late} (x2); "
                    f"{cut} (x1); a (x1); 1 other reason(s) (each in results.json live.marked).")
    document["live"]["marked"] = []
    assert "Marked" not in tables_text(document, "Live evaluation")


def test_every_model_of_a_figure_has_its_own_line_style():
    from quad_modelling.io.reports.evaluation import model_style

    assert len({model_style(k) for k in range(21)}) == 21  # seven models shared five styles (greybox and direct alike)


def test_the_models_line_lists_named_models_with_their_specs():
    """`evaluate --model a=narx:a.npz` listed the dummy alone on tables.md's Models: line (a name has no note): a named
    model is listed as NAME (SPEC) with its spec's note, beside the unnamed ones as before."""
    from quad_modelling.io.reports.evaluation import MODEL_NOTES, model_notes, tables_text

    names = ["a", "greybox:euler", "b", "dummy"]
    specs = {"a": "narx:a.npz", "b": "greybox"}
    assert model_notes(names) == [f"Models: greybox:euler = {MODEL_NOTES['greybox']}; dummy = {MODEL_NOTES['dummy']}.", ""]
    assert model_notes(names, specs) == [f"Models: a (narx:a.npz) = {MODEL_NOTES['narx']}; greybox:euler = {MODEL_NOTES['greybox']}; "
                                         f"b (greybox) = {MODEL_NOTES['greybox']}; dummy = {MODEL_NOTES['dummy']}.", ""]
    document = {**_results(), "models": {name: {} for name in names}, "windows": {name: {} for name in names},
                "config": {"flights": [], "train": "0%:50%", "eval": "50%:100%", "drop_start": 1.0, "drop_end": 1.0,
                           "window_s": 2.0, "warm_s": 0.2}, "live": {}}
    assert tables_text(document, "Evaluation", specs).splitlines()[4] == model_notes(names, specs)[0]


def test_samples_sent_and_received_give_one_loss_line_per_stream_that_differs():
    """run-bag's live.samples: what the replay played and each predictor published against what each node's summary
    (or the evaluator's live.received) says it received; a line only for a stream some node is short of."""
    from quad_modelling.io.reports.evaluation import received_text, sample_accounting, summary_counts, tables_text

    predictor_log = ("[INFO] [1.0] [quad.naive_predictor]: predicting with 'naive' as 'naive' ...\n"
                     "[INFO] [9.5] [quad.naive_predictor]: published 4180 predictions over 4 windows; "
                     f"{received_text({'motor_input': 4227, 'mocap_odom': 4227, 'imu': 4200})}; faults: none\n")
    assert summary_counts(predictor_log) == (4180, {"motor_input": 4227, "mocap_odom": 4227, "imu": 4200})
    assert summary_counts("killed before its summary") == (None, None)
    assert received_text({}) == "received nothing" and summary_counts("]: closed 0 windows; received nothing; faults: none") == (None, {})
    played = {"motor_input": 4227, "mocap_odom": 4227, "imu": 4227, "battery": 4227}
    evaluator = {"motor_input": 4227, "mocap_odom": 4227, "imu": 4101, "naive/odom": 4180, "naive/accel": 4179}
    samples = sample_accounting(played, evaluator, {"naive_predictor": predictor_log})
    assert samples["sent"]["imu"] == {"count": 4227, "by": "replay"}
    assert samples["sent"]["naive/accel"] == {"count": 4180, "by": "naive_predictor"}
    assert samples["received"]["naive_predictor"] == {"motor_input": 4227, "mocap_odom": 4227, "imu": 4200}
    assert samples["loss"] == ["imu: 4227 replayed, received 4101 by evaluator (126 lost), 4200 by naive_predictor (27 lost)",
                               "naive/accel: 4180 published by naive_predictor, received 4179 by evaluator (1 lost)"]
    # every sample received (the battery, which no node here reads, is not compared): no line
    whole = sample_accounting(played, {**evaluator, "imu": 4227, "naive/accel": 4180},
                              {"naive_predictor": predictor_log.replace("imu 4200", "imu 4227")})
    assert whole["loss"] == []
    document = {"models": {"naive": {}}, "windows": {"naive": {}}, "live": {"marked": [], "samples": samples},
                "config": {"flights": [], "train": "", "eval": "", "drop_start": 0.0, "drop_end": 0.0, "window_s": 5.0,
                           "warm_s": 0.2}}
    lines = tables_text(document, "Live evaluation").splitlines()
    at = lines.index("Samples lost between sender and node (the live scores rest on incomplete input; results.json live.samples):")
    assert lines[at + 2:at + 4] == [f"- {line}" for line in samples["loss"]]
    document["live"]["samples"] = whole
    assert "Samples lost" not in tables_text(document, "Live evaluation")
