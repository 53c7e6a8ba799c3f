"""A real flight with one motion-capture dropout is usable: the gap is marked, warned about once, kept as a gap
through conversion, and nothing (window, multi-step segment, training segment) uses a row inside it."""

from __future__ import annotations

import json

from rosbags.rosbag2 import Reader

from quad_modelling.cli import main
from quad_modelling.core.preprocess import resample_uniform
from quad_modelling.core.windows import EvaluationConfig, gap_rows, plan_windows
from quad_modelling.io.bag_io import read_bag
from test.io.test_bag_io import GAP_WARNING, _write_gap_bag

SPANS = ["--drop", "0:0", "--train", "0:30", "--eval", "0:30", "--window", "2"]


def test_evaluate_scores_only_the_windows_clear_of_the_gap_and_warns_once(tmp_path, capsys):
    bag = _write_gap_bag(tmp_path / "bag")
    assert main(["evaluate", str(bag), *SPANS, "-o", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    # the spans overlap, but evaluate fits nothing on them: no overlap warning (it said "scored partly in-sample")
    assert captured.err.count(GAP_WARNING) == 1 and captured.err.splitlines() == [f"warning: {bag}: {GAP_WARNING}"]
    assert "windows train 10, eval 10" in captured.out
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    # 2 s windows of the 29.99 s flight: 14; the four of 4..12 s hold rows inside the gap (4.00..10.68 s)
    assert results["windows"]["greybox"] == {"train": 10, "eval": 10}
    # multi-step: the eval rows 0..2998 split at the gap into 401 and 1931 rows, each start 50 steps before its end
    assert results["horizons"]["starts"] == (401 - 50 - 19) + (1931 - 50 - 19)  # each segment: starts from its 20th row (warm start)
    log = resample_uniform(read_bag(bag))
    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="0:30", eval="0:30", window_s=2.0)
    windows = plan_windows([log], config)["eval"]
    inside = gap_rows(log)
    assert len(windows) == 10 and inside.sum() == 667
    assert not any(inside[w.start:w.stop].any() for w in windows)
    starts = [round(float(log.t[w.start] - log.t[0]), 2) for w in windows]
    assert starts == [0.0, 2.0, 12.0, 14.0, 16.0, 18.0, 20.0, 22.0, 24.0, 26.0]


def test_convert_keeps_the_gap_in_the_new_bag_and_refuses_a_mat_log(tmp_path, capsys):
    bag = _write_gap_bag(tmp_path / "bag")
    assert main(["convert", str(bag), "-o", str(tmp_path / "copy")]) == 0
    assert capsys.readouterr().err.splitlines() == [f"warning: {bag}: {GAP_WARNING}"]
    with Reader(tmp_path / "copy") as reader:
        odom = next(c for c in reader.connections if c.topic == "/quad/mocap/odom")
        stamps = [ns for _, ns, _ in reader.messages(connections=[odom])]
    assert len(stamps) == 3000 - 667 and not [ns for ns in stamps if 5_000_000_000 < ns < 11_680_000_000]
    copy = read_bag(tmp_path / "copy")
    assert copy.meta.notes["measurement_gaps"] == [
        {"topic": "/quad/mocap/odom", "start_s": 5.0, "end_s": 11.68, "fields": ["pos_n", "vel_n", "euler"]}]
    assert copy.meta.notes["warnings"] == [f"{tmp_path / 'copy'}: {GAP_WARNING}"]

    assert main(["convert", str(bag), "-o", str(tmp_path / "flight.mat")]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [f"quad-modelling convert: error: {bag} has measurement gaps (/quad/mocap/odom 4.00..10.68 s): "
                                "a .mat log has one time base; convert to a bag"]
    assert not (tmp_path / "flight.mat").exists()


def test_train_splits_its_segments_at_the_gap(tmp_path, capsys):
    bag = _write_gap_bag(tmp_path / "bag")
    assert main(["train", str(bag), "--drop", "0:0", "--train", "0:30", "--epochs", "1", "--hidden", "2", "--training", "thesis", "--quiet",
                 "-o", str(tmp_path / "narx.npz")]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"warning: {bag}: {GAP_WARNING}"]
    # rows 0..400 and 1068..2998, each less its NARX warm-up samples: no training row inside or across the gap
    from quad_modelling.core.models.narx import NarxConfig

    warm = NarxConfig(hidden=2, epochs=1).warm_samples
    assert f"trained narx model on {(401 - warm) + (1931 - warm)} samples" in captured.out


def test_each_hole_of_a_bag_is_said_once_by_the_rule_that_marked_it(tmp_path, capsys):
    """Three holes in every topic of a 30 s bag: at 5 s 0.6 s (the reader marks the time base, 0.5 s rule), at 12 s 0.3 s
    (resampling marks it, 50 ms rule), at 20 s 0.3 s with the odometry (stamped 3 ms later from 15 s on) silent 0.25 s
    longer (the reader marks the odometry). The first was restated "longer than 0.05 s" and the third said twice (the reader's
    odometry gap and resampling's time base hole): now each once, by the rule that marked it."""
    from test.io.test_bag_io import GAP_STAMPS, _imu, _motor, _odom, _write_raw_bag

    def without(stamps, *holes):  # holes [start, end) in ms from the first stamp
        return [s for s in stamps if not any(GAP_STAMPS[0] + a * 10**6 <= s < GAP_STAMPS[0] + b * 10**6 for a, b in holes)]

    every = ((5000, 5600), (12000, 12300), (20000, 20300))
    later = [s + 3 * 10**6 if s >= GAP_STAMPS[0] + 15 * 10**9 else s for s in GAP_STAMPS]
    bag = tmp_path / "holes"
    _write_raw_bag(bag, {"motor_input": [(s, _motor(s)) for s in without(GAP_STAMPS, *every)],
                         "mocap/odom": [(s, _odom(s)) for s in without(later, *every[:2], (20000, 20550))],
                         "imu": [(s, _imu(s)) for s in without(GAP_STAMPS, *every)]})
    assert main(["evaluate", str(bag), *SPANS, "--no-multistep", "-o", str(tmp_path / "out")]) == 0
    tail = "marked as a measurement gap, not interpolated through; windows and training segments overlapping it are left out"
    assert capsys.readouterr().err.splitlines() == [
        f"warning: {bag}: topic /quad/motor_input has no message for 0.61 s (t=4.990..5.600 s into the flight), longer than 0.5 s: {tail}",
        f"warning: {bag}: topic /quad/mocap/odom has no message for 0.56 s (t=19.993..20.553 s into the flight), longer than 0.5 s: {tail}",
        f"warning: {bag}: topic time base has no message for 0.31 s (t=11.990..12.300 s into the flight), longer than 0.05 s: {tail}"]
