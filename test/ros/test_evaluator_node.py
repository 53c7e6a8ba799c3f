"""The evaluator node: known prediction error -> known RMS/TIC; spans; marked windows; results files."""

import json
import time

import numpy as np
import pytest

from quad_modelling.core.preprocess import measured_variables
from quad_modelling.core.variables import INDEX
from quad_modelling.io import topics
from quad_modelling.nodes import messages
from test.ros.conftest import Capture, feed, hover_log, in_process_evaluator, interrupted_node


def make_node(**params):
    values = {"window_s": 5.0, "models": ["m"], "figures": False, "vehicle": "crazyflie21", **params}
    node = in_process_evaluator(**values)
    node.diag_pub = Capture()
    return node


def offset_prediction(log, column: str, offset: float):
    """The measurement itself, plus a constant error on one variable."""
    y = measured_variables(log)
    y[:, INDEX[column]] += offset
    return topics.prediction_fields(y)


def test_constant_velocity_error_gives_that_rms_and_the_matching_tic(ros):
    log = hover_log(1600)
    node = make_node(spans=["a:0:10", "b:10:15"])
    feed(node, log, range(len(log)), predictions={"m": offset_prediction(log, "vel_x", 0.25)})
    node.finish()
    scored = [r for r in node.scores.records if r.scored and r.model == "m"]
    assert [(r.span, r.index) for r in scored] == [("a", 0), ("a", 1), ("b", 2)]
    dummy = [r for r in node.scores.records if r.scored and r.model == "dummy"]
    assert len(dummy) == 3 and all(np.allclose(r.tic, 1.0) for r in dummy)  # the dummy is always scored too
    for r in scored:
        assert abs(r.rms[INDEX["vel_x"]] - 0.25) < 1e-9  # trimming and smoothing keep a constant error
        assert r.rms[INDEX["vel_y"]] < 1e-9 and r.tic[INDEX["acc_z"]] < 1e-9
        assert 0.0 < r.tic[INDEX["vel_x"]] < 1.0
    # the 16 s flight's last window [15, 20) lies in no span: neither scored nor marked
    assert [r for r in node.scores.records if not r.scored] == []
    diag = node.diag_pub.messages[0].status[0]
    values = {kv.key: float(kv.value) for kv in diag.values}
    assert diag.name == "evaluation/m/a/window_0" and abs(values["vel_x.rms"] - 0.25) < 1e-9
    node.destroy_node()


def test_tic_of_a_zero_prediction_is_one(ros):
    log = hover_log(1100)
    node = make_node(spans=["live:0:inf"])
    # predictions are absolute and trimmed by the measured trim values (mean of the first 1 s = 100 rows):
    # predicting those trim values is the thesis's dummy zero prediction, TIC = 1
    y = measured_variables(log)
    for k in (0, 1):
        rows = slice(500 * k, 500 * (k + 1))
        y[rows] = y[rows][:100].mean(axis=0)
    feed(node, log, range(len(log)), predictions={"m": topics.prediction_fields(y)})
    node.finish()
    r = node.scores.records[0]
    assert r.scored and np.allclose(r.tic[[INDEX["vel_x"], INDEX["acc_z"], INDEX["roll_rate"]]], 1.0)
    node.destroy_node()


def test_gap_restart_and_late_start_mark_windows_instead_of_failing(ros, tmp_path):
    log = hover_log(2100)
    prediction = offset_prediction(log, "vel_z", 0.1)
    node = make_node(spans=["live:0:inf"], output_dir=str(tmp_path / "out"))
    arrays = messages.measurement_messages(log)
    feed(node, log, range(0, 700), arrays, predictions={"m": prediction})
    feed(node, log, range(700, 1000), arrays, skip_odom=set(range(800, 830)), predictions={"m": prediction})  # mocap gap
    feed(node, log, range(1000, 1200), arrays)  # predictor down
    feed(node, log, range(1200, 2100), arrays, predictions={"m": prediction})  # restarted
    bad = arrays.imu(1500, 0)
    bad.linear_acceleration.x = float("nan")
    node.on_imu(bad)
    node.finish()
    by_window = {r.index: r for r in node.scores.records if r.model == "m"}
    assert by_window[0].scored and by_window[3].scored
    # the coverage rule names the stream, its coverage and its longest gap (rows 799 -> 830: 310 ms)
    assert not by_window[1].scored and ("mocap_odom: 94.0 % of 500 nominal samples (470 received), longest gap 310 ms at "
                                        "2.995 s into the window") in by_window[1].reason
    assert not by_window[2].scored and ("predictions: coverage below the rule (>= 95 % of nominal samples, gaps <= 50 ms): "
                                        "m/odom: 60.0 % of 500 nominal samples (300 received), longest gap 2005 ms at 0.000 s") in by_window[2].reason
    assert node.faults.counts["nan_imu"] == 1
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    marked_m = [m for m in data["live"]["marked"] if m["model"] == "m"]
    assert data["windows"]["m"]["live"] == 2 and len(marked_m) == 3  # windows 1, 2 and the partial 4
    assert data["windows"]["dummy"]["live"] == 3  # the dummy needs no predictor: only the gap and the partial window are marked
    assert abs(data["models"]["m"]["live"]["vel_z"]["rms"] - 0.1) < 1e-9
    assert "spans live 0:inf (seconds from the first motor input); 5 s windows" in (tmp_path / "out" / "tables.md").read_text()
    node.destroy_node()

    late = make_node(spans=["live:0:inf"])
    from rosgraph_msgs.msg import Clock

    from quad_modelling.io.topics import stamps_ns

    late.on_origin(Clock(clock=messages.ns_stamp(int(stamps_ns(log.t)[0]))))
    feed(late, log, range(700, 2100), predictions={"m": prediction})
    late.finish()
    records = [r for r in late.scores.records if r.model == "m"]
    assert records[0].index == 1 and not records[0].scored and records[1].scored and records[1].index == 2
    late.destroy_node()


def test_a_window_whose_first_inputs_no_measurement_reaches_names_the_stream_and_where(ros):
    """Mocap stopped for 1 s and resumed 10 ms into the next window: that window was marked "mocap or imu ends early"
    (the wrong end, no stream named); it names the stream and the rows it does not reach."""
    import re

    log = hover_log(1600)
    node = make_node(spans=["live:0:inf"])
    feed(node, log, range(0, 1600), skip_odom=set(range(400, 501)))
    node.finish()
    by_window = {r.index: r for r in node.scores.records if r.model == "dummy"}
    assert not by_window[0].scored and "longest gap" in by_window[0].reason  # the gap itself: the coverage rule
    assert not by_window[1].scored
    assert re.match(r"measurements do not reach every engine input of the window: mocap/odom none at (0\.00\d)\.\.\1 s "
                    "into the window", by_window[1].reason), by_window[1].reason  # its first input only
    node.destroy_node()


def test_record_bag_is_refused_when_it_exists_or_lies_in_output_dir(ros, tmp_path):
    import pytest

    from quad_modelling.nodes.common import BadParameter

    (tmp_path / "old").mkdir()
    with pytest.raises(BadParameter, match="parameter record=.*old' exists; set force:=true"):
        make_node(record=str(tmp_path / "old"))
    with pytest.raises(BadParameter, match="lies in output_dir"):
        make_node(record=str(tmp_path / "out" / "rec"), output_dir=str(tmp_path / "out"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]  # nothing staged


def test_an_output_dir_force_may_not_replace_is_refused_at_start(ros, tmp_path):
    """output_dir:= a directory of the user's files (or a regular file) with force:=true started, then refused to
    write at the end (the session's results lost, exit 0) or replaced the file: refused at start as the CLI refuses."""
    import pytest

    from quad_modelling.nodes.common import BadParameter

    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "precious.txt").write_text("mine")
    (tmp_path / "file.txt").write_text("mine")
    with pytest.raises(BadParameter, match="output_dir .*notes: an existing directory that is no earlier output"):
        make_node(output_dir=str(tmp_path / "notes"), force=True)
    with pytest.raises(BadParameter, match="output_dir .*file.txt: an existing file, not an output directory"):
        make_node(output_dir=str(tmp_path / "file.txt"), force=True)
    assert (tmp_path / "notes" / "precious.txt").read_text() == (tmp_path / "file.txt").read_text() == "mine"


def test_without_a_vehicle_windows_are_marked_not_scored(ros):
    log = hover_log(1200)
    node = make_node(vehicle="")
    y = measured_variables(log)
    feed(node, log, range(len(log)), predictions={"m": topics.prediction_fields(y)})
    node.finish()
    assert len(node.scores.records) == 6  # windows 0, 1 and the partial 2, of m and the dummy
    assert {r.reason for r in node.scores.records} == {"no vehicle: parameter vehicle is empty and no replay announced one "
                                                       "on topic vehicle"}
    assert node.faults.counts == {"no_vehicle": 3}  # one warning line (counted per window) says why nothing scored
    node.destroy_node()


def test_a_window_waits_for_a_delayed_stream_and_is_scored(ros):
    """The IMU stream lags (rows 490-599 arrive after the engine inputs, mocap and predictions of rows up to 599,
    as a lossy link delivers one writer's repaired samples late): window 0 stays open until the IMU passes its
    end, then is scored with the known error; nothing is marked or dropped."""
    log = hover_log(1100)
    prediction = offset_prediction(log, "vel_x", 0.25)
    node = make_node(spans=["live:0:inf"])
    arrays = messages.measurement_messages(log)
    stamps = feed(node, log, range(0, 490), arrays, predictions={"m": prediction})
    feed(node, log, range(490, 600), arrays, skip_imu=set(range(490, 600)), predictions={"m": prediction})
    node.on_close_timer()
    assert sorted(node.open) == [0, 1] and node.open[0].passed_at is not None  # every other stream passed window 0
    assert node.late_streams(0, time.monotonic()) == ["imu"]
    for row in range(490, 600):
        node.on_imu(arrays.imu(row, int(stamps[row])))
    assert sorted(node.open) == [1]  # closed the moment the IMU passed its end
    feed(node, log, range(600, 1100), arrays, predictions={"m": prediction})
    node.finish()
    records = {r.index: r for r in node.scores.records if r.model == "m"}
    assert records[0].scored and records[1].scored and abs(records[0].rms[INDEX["vel_x"]] - 0.25) < 1e-9
    assert [r for r in node.scores.records if not r.scored and r.index < 2] == []
    assert not any(kind.startswith("late_") for kind in node.faults.counts)
    node.destroy_node()


def test_a_stream_late_past_close_grace_marks_the_window_naming_it(ros):
    """The same IMU lag with close_grace_s 0.05 s: window 0 closes by the grace, marked naming imu and its last
    stamp (4.89 s after t0); the IMU rows that come afterwards are dropped as late; window 1 is scored."""
    log = hover_log(1100)
    prediction = offset_prediction(log, "vel_x", 0.25)
    node = make_node(spans=["live:0:inf"], close_grace_s=0.05)
    arrays = messages.measurement_messages(log)
    stamps = feed(node, log, range(0, 490), arrays, predictions={"m": prediction})
    feed(node, log, range(490, 600), arrays, skip_imu=set(range(490, 600)), predictions={"m": prediction})
    time.sleep(0.1)
    node.on_close_timer()
    assert sorted(node.open) == [1]
    for row in range(490, 600):
        node.on_imu(arrays.imu(row, int(stamps[row])))
    feed(node, log, range(600, 1100), arrays, predictions={"m": prediction})
    node.finish()
    window0 = [r for r in node.scores.records if r.index == 0]
    assert len(window0) == 2 and not any(r.scored for r in window0)  # m and the dummy
    assert window0[0].reason == ("closed by close_grace_s=0.05 s before every stream passed the window's end: "
                                 "late imu (last stamp 4.890 s after t0)")
    assert node.faults.counts["late_imu"] == 10  # rows 490-499 of the closed window; 500-599 belong to window 1
    assert [r.scored for r in node.scores.records if r.index == 1] == [True, True]
    node.destroy_node()


def test_an_output_dir_whose_parent_is_missing_is_refused_at_start(ros, tmp_path):
    """Found at start-up (one line), not after a flight when the results are written."""
    import pytest

    from quad_modelling.nodes.common import BadParameter

    with pytest.raises(BadParameter, match=r"output_dir=.*nope/out': its parent directory .*nope' does not exist"):
        make_node(output_dir=str(tmp_path / "nope" / "out"))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(BadParameter, match=r"output_dir='/proc/quad_out': cannot write in '/proc' \("):
        make_node(output_dir="/proc/quad_out")  # a directory no one (not even root) can make anything in
    make_node(output_dir=str(tmp_path / "out")).destroy_node()
    assert list(tmp_path.iterdir()) == []  # the write check leaves nothing behind


def test_an_empty_model_list_is_one_line_exit_2():
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "quad_modelling.nodes.evaluator_node", "--ros-args", "-p", "models:=[]",
                          "-p", "vehicle:=crazyflie21"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines()[-1] == "error: evaluator: parameter models=[] (empty: rclpy reads an empty list as no value): give at least one predictor name, e.g. models:=[greybox]"


@pytest.mark.parametrize("executor", ["events", "single"])
def test_ctrl_c_ends_the_evaluator_without_a_fatal_line_and_writes_its_results(executor, tmp_path):
    """SIGINT while its timers run: exit code 0, the results written, and no FATAL line or traceback (the signal
    raised inside a timer callback was logged as FATAL by the events executor)."""
    out = tmp_path / "results"
    code, text = interrupted_node("quad_modelling.nodes.evaluator_node", ["-p", f"executor:={executor}", "-p", "vehicle:=crazyflie21",
                                  "-p", f"output_dir:={out}", "-p", "figures:=false"], "scoring models", 1.5)
    assert code == 0, text  # its timers fired many times a second before the signal
    assert "FATAL" not in text and "Traceback" not in text and "Error occurred" not in text, text
    assert (out / "results.json").exists()
    assert "closed 0 windows; received motor_input 0, mocap_odom 0, imu 0, naive/odom 0, naive/accel 0; faults: none" in text
    # nothing was published: every stream it waits for is named (a flight without an IMU said "faults: none" alone)
    assert "; nothing usable received on motor_input, mocap_odom, imu, naive/odom, naive/accel" in text


def test_a_command_far_beyond_the_input_range_is_dropped_as_by_the_predictors(ros):
    """The predictors' intake rule (common.command_beyond_range): -1e6 PWM is impossible, dropped with its fault; the
    window is still scored from the other rows."""
    from quad_modelling.io.topics import stamps_ns

    log = hover_log(1200)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node()
    y = measured_variables(log)
    feed(node, log, range(0, 300), arrays, predictions={"m": topics.prediction_fields(y)})
    far = arrays.motor(300, int(stamps[300]))
    far.effort = [-1e6, 30000.0, 30000.0, 30000.0]
    node.on_motor(far)
    feed(node, log, range(301, 1200), arrays, predictions={"m": topics.prediction_fields(y)})
    node.finish()
    assert node.faults.counts.get("range_motor_input") == 1
    assert any(r.scored for r in node.scores.records if r.index == 0 and r.model == "m")
    node.destroy_node()


def test_a_model_two_nodes_publish_is_marked_naming_them(ros):
    """Two predictors given one model_name interleave their predictions on one topic: while the graph holds two
    publishers of m/odom, m's records are marked (the dummy still scored) and the fault said once; with one, scored."""
    import rclpy
    from nav_msgs.msg import Odometry

    log = hover_log(1100)
    node = make_node()
    others = [rclpy.create_node(f"predictor_{i}", namespace=node.get_namespace()) for i in range(2)]
    publishers = [other.create_publisher(Odometry, "m/odom", 10) for other in others]
    deadline = time.monotonic() + 10.0
    while node.count_publishers("m/odom") < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    node.on_close_timer()
    assert node.shared == {"m": 2} and node.faults.counts == {"shared_m": 1}
    feed(node, log, range(len(log)), predictions={"m": topics.prediction_fields(measured_variables(log))})
    node.finish()
    marked = [r for r in node.scores.records if r.model == "m" and r.index < 2]  # window 2: the flight ends in it
    assert len(marked) == 2 and all(not r.scored and r.reason.startswith("2 nodes publish m's predictions: two predictors share "
                                                                  "the model name m") for r in marked)
    assert all(r.scored for r in node.scores.records if r.model == "dummy" and r.index < 2)
    others[1].destroy_publisher(publishers[1])
    while node.count_publishers("m/odom") > 1 and time.monotonic() < deadline + 10.0:
        time.sleep(0.05)
    node.on_close_timer()
    assert node.shared == {}
    for other in others:
        other.destroy_node()
    node.destroy_node()


@pytest.mark.parametrize("zeroed, streams", [("imu", ["imu"]), ("mocap_odom", ["mocap_odom"]), ("m", ["m/odom", "m/accel"])])
def test_a_stream_whose_stamps_are_all_zero_is_named_in_the_exit_summary(ros, capfd, zeroed, streams):
    """A publisher that never sets its stamps (all zero) beside streams stamped in epoch time: none of its messages
    falls in a window, and the exit summary names the stream as delivering nothing usable. None of these was named: the
    summary judged a stream by its stamp gate, which the first message of valid numbers creates whatever its stamp
    (only a stream whose every message was dropped before the gate, e.g. JointStates without efforts, was named)."""
    from quad_modelling.io.topics import stamps_ns

    log = hover_log(1200)  # 12 s: windows 0-2 of 5 s
    arrays = messages.measurement_messages(log)
    odom, accel = topics.prediction_fields(measured_variables(log))
    node = make_node()
    for row, ns in enumerate((stamps_ns(log.t) + 1_700_000_000 * 10**9).tolist()):
        def stamp(stream):
            return 0 if stream == zeroed else ns

        node.on_motor(arrays.motor(row, ns))
        node.on_odom(arrays.odometry(row, stamp("mocap_odom")))
        node.on_imu(arrays.imu(row, stamp("imu")))
        o, a = messages.prediction_messages(stamp("m"), odom[row], accel[row], "m/base_link")
        node.on_pred_odom("m", o)
        node.on_pred_accel("m", a)
    node.finish()
    # the gate takes the first zero stamp, drops the next 1198 as outliers and holds the last as a suspect; none lies in
    # a window
    faults = ", ".join(f"stamp_outlier_{s} x1198" for s in sorted(streams))
    logged = capfd.readouterr().err.strip().splitlines()[-1]  # the node's last log line
    assert logged.endswith(f"; faults: {faults}; nothing usable received on {', '.join(streams)}"), logged
    node.destroy_node()


def test_an_in_process_evaluator_leaves_the_test_process_niceness_alone(ros):
    """The tests' in-process evaluators run at increment 0 (conftest.in_process_evaluator): the node's default of 10
    renices its own process, which here is the pytest worker's."""
    import os

    before = os.nice(0)
    make_node().destroy_node()
    assert os.nice(0) == before
