"""The predictor node: known sequence -> known prediction, windows, faults, bad parameters."""

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from rclpy.parameter import Parameter

from quad_modelling.core.frames import geodesic_angle
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io import topics
from quad_modelling.io.topics import stamps_ns
from quad_modelling.nodes import messages
from quad_modelling.nodes.model_factory import make_streaming_predictor
from quad_modelling.nodes.predictor_node import PredictorNode
from test.ros.conftest import Capture, feed, hover_log, interrupted_node


def make_node(**params):
    overrides = [Parameter(k, value=v) for k, v in {"window_s": 5.0, "vehicle": "crazyflie21", **params}.items()]
    node = PredictorNode(parameter_overrides=overrides)
    node.odom_pub, node.accel_pub = Capture(node.odom_pub.msg_type), Capture(node.accel_pub.msg_type)
    return node


def published(node, stamps):
    odom, accel = node.odom_pub.by_stamp(), node.accel_pub.by_stamp()
    got = [s for s in stamps.tolist() if s in odom]
    o = [topics.predicted_odometry_fields(odom[s]) for s in got]
    a = [topics.accel_fields(accel[s]) for s in got]
    return got, topics.predictions_from_fields(o, a) if got else np.zeros((0, 18))


@pytest.mark.parametrize("model", ["naive", "greybox"])
def test_node_publishes_exactly_the_offline_stream_of_each_window(ros, model):
    log = hover_log(1200)
    node = make_node(model=model)
    stamps = feed(node, log, range(len(log)))
    vehicle = load_vehicle("crazyflie21")
    for k in (0, 1):  # 5 s windows of 500 rows; warm start 0.2 s = 20 rows
        window = log.slice(500 * k, 500 * (k + 1))
        expected = predict_window_by_stream(make_streaming_predictor(model, vehicle), window, 20)
        got, predicted = published(node, stamps[500 * k:500 * (k + 1)])
        assert len(got) == 500
        # every variable; the attitude travels as a quaternion, so compare it as a rotation (the open-loop
        # greybox drifts to angles beyond +-pi, whose Euler form the quaternion does not keep)
        columns = [c for c in range(18) if c not in (9, 10, 11)]
        assert np.allclose(predicted[:, columns], expected[:, columns], atol=1e-9)
        assert np.max(geodesic_angle(predicted[:, 9:12], expected[:, 9:12])) < 1e-9
        if model == "naive":  # held after the warm start: the measurement of warm row 19
            assert np.allclose(predicted[20:, 3:6], window.vel_n[19], atol=1e-9)
    odom = node.odom_pub.messages[0]
    assert odom.child_frame_id == f"{model}/base_link" and odom.header.frame_id == "world"
    assert node.faults.counts == {}
    node.destroy_node()


def test_faults_are_dropped_with_one_warning_each_and_nothing_non_finite_is_published(ros):
    log = hover_log(1100)
    node = make_node()
    arrays = messages.measurement_messages(log)
    stamps = stamps_ns(log.t)
    feed(node, log, range(0, 300), arrays)
    node.on_motor(arrays.motor(100, int(stamps[100])))  # out of order
    node.on_motor(arrays.motor(299, int(stamps[299])))  # duplicate
    bad = arrays.motor(300, int(stamps[300]))
    bad.effort = [float("nan")] * 4
    node.on_motor(bad)  # NaN command
    nan_odom = arrays.odometry(301, int(stamps[301]))
    nan_odom.pose.pose.position.x = float("nan")
    node.on_odom(nan_odom)
    for _ in range(3):
        node.on_motor(arrays.motor(100, int(stamps[100])))
    # a motion-capture gap across the warm start of window 1 (rows 500..509)
    feed(node, log, range(301, 1100), arrays, skip_odom=set(range(500, 510)))
    # 4 stamps back in time and 1 duplicate: each a single outlier (a regular stamp follows), dropped one by one
    assert node.faults.counts["stamp_outlier_motor_input"] == 5 and "clock_jump_motor_input" not in node.faults.counts
    assert node.faults.counts["nan_motor_input"] == 1 and node.faults.counts["nan_mocap_odom"] == 1
    assert node.faults.counts["warm_gap"] == 1
    got, predicted = published(node, stamps)
    assert np.isfinite(predicted).all()
    assert stamps[300] not in got  # the NaN command got no prediction
    assert all(s in got for s in stamps[510:1000].tolist())  # window 1 started from its warm rows with a measurement (14: 500, 501 and 508, 509 take the nearest sample within 20 ms)
    node.destroy_node()


def test_restarted_node_waits_for_the_next_window_aligned_to_the_shared_origin(ros):
    from rosgraph_msgs.msg import Clock

    log = hover_log(1200)
    stamps = stamps_ns(log.t)
    node = make_node()
    node.on_origin(Clock(clock=messages.ns_stamp(int(stamps[0]))))  # what window_origin delivers to a late joiner
    feed(node, log, range(250, 1200))
    got, _ = published(node, stamps)
    assert got[0] == stamps[500]  # nothing for the half window it joined; window 1 from its start
    assert node.faults.counts["joined_mid_window"] == 1
    node.destroy_node()


def run_node(args, timeout=60):
    env = {**os.environ}
    return subprocess.run([sys.executable, "-m", "quad_modelling.nodes.predictor_node", "--ros-args", *args],
                          capture_output=True, text=True, timeout=timeout, env=env)


@pytest.mark.slow
def test_bad_parameters_exit_with_code_2_and_the_reason():
    # The five start-ups run side by side (each process exits on its own bad parameter): a fifth of the wall time.
    with ThreadPoolExecutor(max_workers=5) as pool:
        runs = [pool.submit(run_node, ["-p", p]) for p in ("window_s:=-1.0", "executor:=multi", "realtime_priority:=150",
                                                            "model:=nosuchmodel")]
        narx_run = pool.submit(subprocess.run, [sys.executable, "-m", "quad_modelling.nodes.narx_predictor_node"],
                               capture_output=True, text=True, timeout=60)
        bad_window, bad_executor, bad_priority, unknown = (run.result() for run in runs)
        narx = narx_run.result()
    assert bad_window.returncode == 2
    assert "window_s" in bad_window.stderr and "must be at least 1e-06 s" in bad_window.stderr
    assert bad_executor.returncode == 2 and "executor" in bad_executor.stderr and "events, single" in bad_executor.stderr
    assert bad_priority.returncode == 2 and "realtime_priority" in bad_priority.stderr and "1 to 99" in bad_priority.stderr
    assert unknown.returncode == 2 and "unknown model" in unknown.stderr and "nosuchmodel" in unknown.stderr
    assert narx.returncode == 2 and "narx" in narx.stderr


@pytest.mark.parametrize("executor", ["events", "single"])
def test_ctrl_c_ends_a_spinning_node_cleanly_with_its_summary(executor):
    """SIGINT while spinning: exit code 0 and the closing summary (EventsExecutor.spin() would busy-loop here)."""
    code, out = interrupted_node("quad_modelling.nodes.predictor_node", ["-p", f"executor:={executor}"], "predicting with", 0.5, 10)
    assert code == 0, out
    assert "published 0 predictions over 0 windows" in out


def test_warm_rows_are_published_at_the_start_in_stamp_order_and_stamps_strictly_increase(ros):
    """The warm rows' predictions (available only at the end of the warm start) go out all at once, in stamp order,
    before the next live one: no stamp on <model>/odom or <model>/accel ever goes back, across windows too."""
    log = hover_log(1100)
    node = make_node(model="greybox")
    stamps = feed(node, log, range(1100))  # 5 s windows at 100 Hz: warm rows 0..19 and 500..519
    for publisher in (node.odom_pub, node.accel_pub):
        order = [topics.stamp_ns(m.header.stamp) for m in publisher.messages]
        assert order == stamps[:1100].tolist()  # every input answered once, in stamp order
    node.destroy_node()


def test_window_waits_for_late_measurements_of_its_warm_rows(ros, monkeypatch):
    """At rate 0 the IMU may trail the commands by many rows: the window waits (wall-time bound), then uses every
    warm row; past MEASUREMENT_WAIT_S it starts from the complete rows (a real gap)."""
    import quad_modelling.nodes.predictor_node as predictor_node

    log = hover_log(600)
    arrays = messages.measurement_messages(log)
    node = make_node(model="greybox")
    stamps = stamps_ns(log.t)
    for row in range(60):  # warm rows 0..19; the IMU of rows 10..59 is 40+ rows late
        ns = int(stamps[row])
        node.on_motor(arrays.motor(row, ns))
        node.on_odom(arrays.odometry(row, ns))
        if row < 10:
            node.on_imu(arrays.imu(row, ns))
    assert node.published == 0 and len(node.deferred) == 40  # held back, not started from 10 of 20 warm rows
    for row in range(10, 60):
        node.on_imu(arrays.imu(row, int(stamps[row])))
    assert node.state == "stream" and "warm_gap" not in node.faults.counts
    assert node.published == 60  # the 20 warm rows, then the 40 held commands
    node.destroy_node()

    monkeypatch.setattr(predictor_node, "MEASUREMENT_WAIT_S", 0.0)
    node = make_node(model="greybox")
    warned = []  # the warning names the stream (it said 'motion-capture/IMU gap' whichever it was)
    node.faults.logger = type("Logger", (), {"warning": lambda self, text: warned.append(text)})()
    feed(node, log, range(30), skip_odom=set(range(15, 20)))
    assert node.faults.counts["warm_gap"] == 1 and node.state == "stream"
    assert "3 warm-start rows have no measurement within tolerance (mocap_odom (a gap))" in warned[0]  # 2 interpolated
    node.destroy_node()


def feed_measurements_first(node, arrays, rows, stamps):
    """As a flight stack or the latency bench publishes: a row's measurements, then its command."""
    for row in rows:
        ns = int(stamps[row])
        node.on_odom(arrays.odometry(row, ns))
        node.on_imu(arrays.imu(row, ns))
        node.on_motor(arrays.motor(row, ns))


def test_window_starts_at_its_last_warm_row_once_its_measurements_are_in(ros):
    """The start's cost falls between two inputs: at 100 Hz the last warm row (19) starts the window, so the
    first live command (20) is answered from a running stream -- with exactly the offline numbers."""
    log = hover_log(600)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="greybox")
    feed_measurements_first(node, arrays, range(19), stamps)
    assert node.state == "warm" and not node.warm_closed  # row 18: row 19 is still warm
    feed_measurements_first(node, arrays, [19], stamps)
    assert node.state == "stream" and node.published == 20  # the warm rows' predictions, at once, in stamp order
    feed_measurements_first(node, arrays, range(20, 500), stamps)
    expected = predict_window_by_stream(make_streaming_predictor("greybox", load_vehicle("crazyflie21")), log.slice(0, 500), 20)
    got, predicted = published(node, stamps[:500])
    assert len(got) == 500
    assert np.allclose(predicted[:, :9], expected[:, :9], atol=1e-9) and np.allclose(predicted[:, 12:], expected[:, 12:], atol=1e-9)
    assert node.faults.counts == {}
    node.destroy_node()


def test_a_warm_row_after_an_early_start_is_reported_and_predicted_as_streamed(ros):
    """Irregular stamps: an extra row 8 ms after row 18 looks like the last warm row (its successor at +10 ms would
    be past 0.2 s); the real row 19 then arrives after the start: one warning, and it is still answered."""
    log = hover_log(600)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="greybox")
    feed_measurements_first(node, arrays, range(19), stamps)
    extra = int(stamps[18]) + 8_000_000
    node.on_odom(arrays.odometry(18, extra))
    node.on_imu(arrays.imu(18, extra))
    node.on_motor(arrays.motor(18, extra))
    assert node.state == "stream" and node.published == 20  # rows 0..18 and the extra one
    feed_measurements_first(node, arrays, range(19, 30), stamps)
    assert node.faults.counts == {"late_warm_row": 1}
    assert set(stamps[19:30].tolist()) <= set(node.odom_pub.by_stamp())  # every command answered
    node.destroy_node()


def test_realtime_priority_runs_every_thread_of_the_node_under_sched_fifo():
    """realtime_priority:=3 -> SCHED_FIFO 3 on all threads (the DDS ones too); without the privilege, a warning."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        permitted = True
    except PermissionError:
        permitted = False
    node = subprocess.Popen([sys.executable, "-m", "quad_modelling.nodes.predictor_node", "--ros-args", "-p", "realtime_priority:=3"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any("SCHED_FIFO" in line for line in lines):
            line = node.stdout.readline()
            if not line:
                break
            lines.append(line)
        text = "".join(lines)
        if permitted:
            assert "running under SCHED_FIFO priority 3" in text, text
            threads = [int(t) for t in os.listdir(f"/proc/{node.pid}/task")]
            assert len(threads) > 1  # the executor and Fast DDS's own threads
            assert {os.sched_getscheduler(t) for t in threads} == {os.SCHED_FIFO}
            assert {os.sched_getparam(t).sched_priority for t in threads} == {3}
        else:
            assert "realtime_priority=3" in text and "not permitted" in text, text
    finally:
        time.sleep(0.5)  # spinning by now: Ctrl-C during start-up may end the process by the signal itself
        node.send_signal(signal.SIGINT)
        node.communicate(timeout=20)
    assert node.returncode == 0


def test_serialised_measurements_are_decoded_after_the_answer_and_still_checked(ros):
    """Motion capture and IMU arrive serialised (raw subscriptions); they are decoded once the command that follows is
    answered. A NaN in them, or bytes that are no message, is still reported, once per kind, and dropped."""
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu

    log = hover_log(600)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="greybox")
    for row in range(25):
        ns = int(stamps[row])
        odom = arrays.odometry(row, ns)
        if row == 21:
            odom.pose.pose.position.x = float("nan")
        node._receive(node.on_odom, Odometry, "mocap_odom", serialize_message(odom))
        node._receive(node.on_imu, Imu, "imu", b"\x00\x01" if row == 23 else serialize_message(arrays.imu(row, ns)))
        if row == 22:
            assert len(node.pending) == 2  # held while command 22 is not yet answered
        node.on_motor(arrays.motor(row, ns))
        assert not node.pending
    assert node.faults.counts == {"nan_mocap_odom": 1, "bad_imu": 1}
    assert int(stamps[21]) not in node.odom.stamps and int(stamps[23]) not in node.imu.stamps
    assert int(stamps[22]) in node.odom.stamps
    assert node.state == "stream" and node.published == 20 + 5  # the 20 warm rows at the start, then commands 20..24
    node.destroy_node()


def test_without_a_vehicle_inputs_wait_for_the_replays_announcement(ros):
    from std_msgs.msg import String

    log = hover_log(1200)
    node = make_node(model="naive", vehicle="")
    assert node.model is None
    feed(node, log, range(0, 10))
    assert node.faults.counts == {"no_vehicle": 10} and node.odom_pub.messages == []
    node.on_vehicle(String(data="crazyflie21"))  # what the replay publishes (transient-local)
    assert node.vehicle.name == "crazyflie21" and node.model is not None
    stamps = feed(node, log, range(500, 1000))  # window 1 (5 s windows from the first input's t0)
    window = log.slice(500, 1000)
    expected = predict_window_by_stream(make_streaming_predictor("naive", load_vehicle("crazyflie21")), window, 20)
    got, predicted = published(node, stamps[500:1000])
    assert len(got) == 500 and np.allclose(predicted[:, 3:6], expected[:, 3:6], atol=1e-9)
    node.destroy_node()


def test_a_stamp_from_the_future_costs_one_sample_not_the_flight(ros):
    log = hover_log(1100)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="greybox")
    feed(node, log, range(0, 300), arrays)
    node.on_motor(arrays.motor(300, int(stamps[300]) + 10 ** 15))  # 1e6 s ahead
    node.on_imu(arrays.imu(300, int(stamps[300]) + 10 ** 15))
    feed(node, log, range(301, 1100), arrays)
    got, predicted = published(node, stamps)
    assert node.faults.counts["stamp_outlier_motor_input"] == 1 and node.faults.counts["stamp_outlier_imu"] == 1
    assert got == [s for s in stamps[:1100].tolist() if s != stamps[300]]  # everything else answered, windows 0 and 1
    assert node.windows_started == 3
    node.destroy_node()


def test_a_restarted_publisher_resets_cleanly_and_the_predictor_resumes_at_the_next_window(ros):
    """The flight stack restarts: stamps jump back to an earlier flight time (here the flight's start again). The
    first two stamps are held as suspects, the third confirms the new time base: windows and buffers restart,
    output stamps restart with them, and the window the stamps land in is predicted from its own warm rows."""
    log = hover_log(1100)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="naive")
    feed(node, log, range(0, 700), arrays)
    first = len(node.odom_pub.messages)
    feed(node, log, range(0, 1100), arrays)
    assert node.faults.counts["clock_jump_motor_input"] == 1
    assert node.faults.counts["clock_jump_mocap_odom"] == 1 and node.faults.counts["clock_jump_imu"] == 1
    again = [topics.stamp_ns(m.header.stamp) for m in node.odom_pub.messages[first:]]
    assert again == stamps[2:1100].tolist()  # rows 0 and 1 were the suspects; window 0 from row 2, window 1 whole
    assert np.all(np.diff(again) > 0)
    window = log.slice(500, 1000)
    expected = predict_window_by_stream(make_streaming_predictor("naive", load_vehicle("crazyflie21")), window, 20)
    odom = {topics.stamp_ns(m.header.stamp): m for m in node.odom_pub.messages[first:]}
    accel = {topics.stamp_ns(m.header.stamp): m for m in node.accel_pub.messages[first:]}
    second = topics.predictions_from_fields([topics.predicted_odometry_fields(odom[s]) for s in stamps[500:1000].tolist()],
                                            [topics.accel_fields(accel[s]) for s in stamps[500:1000].tolist()])
    assert np.allclose(second[:, 3:9], expected[:, 3:9], atol=1e-9)  # window 1 of the second pass: the offline numbers
    node.destroy_node()


def test_a_zero_quaternion_in_a_warm_row_is_dropped_and_the_window_goes_on(ros):
    log = hover_log(1100)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="greybox")
    feed(node, log, range(0, 505), arrays)
    node.on_motor(arrays.motor(505, int(stamps[505])))
    broken = arrays.odometry(505, int(stamps[505]))
    q = broken.pose.pose.orientation
    q.x = q.y = q.z = q.w = 0.0
    node.on_odom(broken)
    node.on_imu(arrays.imu(505, int(stamps[505])))
    feed(node, log, range(506, 1100), arrays)
    assert node.faults.counts == {"zero_quaternion": 1}  # no warm_gap: row 505 is interpolated between 504 and 506
    got, predicted = published(node, stamps)
    assert got == stamps[:1100].tolist()
    midway = 0.5 * (log.euler[504] + log.euler[506])  # the warm row's measurement: half-way between its neighbours
    assert geodesic_angle(predicted[505:506, 9:12], midway[None, :])[0] < 1e-4
    node.destroy_node()


class AbsurdAfter:
    """A streaming model that predicts the window's anchor state until push ``n``, then 1e30 m (finite, absurd)."""

    name = "absurd"

    def __init__(self, n):
        self.n = n

    def start_window(self, warm):
        from quad_modelling.core.preprocess import measured_variables

        measured = measured_variables(warm)
        outer = self

        class Stream:
            count = 0

            def push(self, command):
                self.count += 1
                y = measured[-1].copy()
                if self.count >= outer.n:
                    y[0] = 1e30
                return y

        return measured, Stream()


def test_a_prediction_beyond_the_physical_bounds_abandons_the_window_with_one_warning(ros):
    log = hover_log(1100)
    stamps = stamps_ns(log.t)
    node = make_node(model="naive")
    node.model = AbsurdAfter(100)
    feed(node, log, range(1100))
    got, predicted = published(node, stamps)
    assert node.faults.counts == {"out_of_bounds": 2}  # once per window (windows 0 and 1); one warning line
    # each window: its 20 warm rows and 99 pushes, nothing from the absurd one on; window 2 (rows 1000..) as well
    expected = stamps[0:119].tolist() + stamps[500:619].tolist() + stamps[1000:1100].tolist()
    assert got == expected and np.abs(predicted[:, 0:3]).max() < 100.0
    node.destroy_node()


def test_a_clock_jump_forward_resets_the_windows_and_prediction_resumes_in_the_window_the_stamps_land_in(ros):
    """The stack's clock (wall or simulated) jumps 1000 s ahead mid-flight (200 windows of 5 s): three consistent
    stamps make the new time base; the predictor never reads its own ROS clock, only stamps, and goes on."""
    log = hover_log(1100)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="naive")
    feed(node, log, range(0, 600), arrays)
    jump = 1000 * 10 ** 9
    for row in range(600, 1100):
        ns = int(stamps[row]) + jump
        node.on_motor(arrays.motor(row, ns))
        node.on_odom(arrays.odometry(row, ns))
        node.on_imu(arrays.imu(row, ns))
    assert node.faults.counts["clock_jump_motor_input"] == 1 and node.clock_.origin_ns == int(stamps[0])
    got = [topics.stamp_ns(m.header.stamp) for m in node.odom_pub.messages]
    assert got[:600] == stamps[:600].tolist()
    # rows 600, 601 were suspects; row 602 landed 102 ms into window 201, after its warm start: window 202 from its start
    assert got[600:] == (stamps[1000:1100] + jump).tolist() and node.faults.counts["joined_mid_window"] == 1
    node.destroy_node()


@pytest.mark.slow
def test_parameters_ros_refuses_or_a_number_too_big_exit_2_in_one_line_without_a_traceback(tmp_path):
    """An unreadable params file and a malformed -p are rclpy's start-up errors (a traceback before); infinite or
    absurd numbers and names that cannot be topics are refused by their checks (an OverflowError, a 1.5 TiB
    allocation or rclpy's topic-name traceback before)."""
    cases = {
        "params-file": (["--params-file", str(tmp_path / "nonexistent.yaml")], "error: cannot start ROS 2 with these arguments: "),
        "override": (["-p", "window_s:=[a:5:2]"], "error: cannot start ROS 2 with these arguments: "),
        "inf": (["-p", "measurement_tolerance_s:=inf"], "parameter measurement_tolerance_s=inf: must be finite and at most 1e+06"),
        "period": (["-p", "sample_period_s:=1e-12"], "parameter sample_period_s=1e-12: must be 0 (measured) or at least 0.0001 s"),
        "name": (["-p", "model_name:=bad-name"], "parameter model_name='bad-name': 'bad-name' cannot prefix a topic"),
        "topic": (["-p", "odom_topic:=bad topic"], "parameter odom_topic='bad topic': not a ROS 2 topic name"),
    }
    with ThreadPoolExecutor(max_workers=3) as pool:
        runs = {key: pool.submit(run_node, args) for key, (args, _) in cases.items()}
        results = {key: run.result() for key, run in runs.items()}
    for key, (_, expected) in cases.items():
        run = results[key]
        assert run.returncode == 2 and "Traceback" not in run.stderr, (key, run.stderr)
        errors = [line for line in run.stderr.splitlines() if line.startswith("error: ")]
        assert len(errors) == 1 and expected in errors[0], (key, run.stderr)


def test_an_impossible_finite_measurement_is_dropped_as_a_nan_is(ros):
    """A gyro of 1e300 rad/s or a position of 1e300 m is finite but impossible: dropped with its fault kind (it broke
    2.5 s of forecasts before), the window goes on from the neighbouring rows."""
    from quad_modelling.nodes.common import IMU, MOCAP_ODOM
    from quad_modelling.nodes.messages import beyond_bounds

    assert beyond_bounds(IMU, [0.0, 0.0, -9.8, 1e300, 0.0, 0.0]) == "rate 1e+300 rad/s beyond ±34.91 rad/s"
    assert beyond_bounds(MOCAP_ODOM, [1e300, 0, 1, 0, 0, 0, 1, 0, 0, 0]) == "position 1e+300 m beyond ±1e+05 m"
    assert beyond_bounds(IMU, [float("nan")] * 3 + [0.1, 0.2, 0.3]) is None  # an unmeasured vector is not out of range
    log = hover_log(1100)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="greybox")
    feed(node, log, range(0, 505), arrays)
    node.on_motor(arrays.motor(505, int(stamps[505])))
    node.on_odom(arrays.odometry(505, int(stamps[505])))
    broken = arrays.imu(505, int(stamps[505]))
    broken.angular_velocity.x = 1e300
    node.on_imu(broken)
    feed(node, log, range(506, 1100), arrays)
    assert node.faults.counts == {"range_imu": 1}
    got, _ = published(node, stamps)
    assert got == stamps[:1100].tolist()
    node.destroy_node()


def test_a_command_far_beyond_the_input_range_is_dropped_one_just_beyond_is_clipped(ros):
    """Live as offline (flight_log.saturate_commands): within 5 % of the range past an end the actuator saturates
    (clipped, predicted as the end), further out the message is impossible (dropped, range_motor_input)."""
    log = hover_log(700)
    arrays, stamps = messages.measurement_messages(log), stamps_ns(log.t)
    node = make_node(model="greybox")
    feed(node, log, range(0, 505), arrays)
    far = arrays.motor(505, int(stamps[505]))
    far.effort = [-1e6, 30000.0, 30000.0, 30000.0]
    node.on_motor(far)
    assert node.faults.counts == {"range_motor_input": 1}
    node.on_odom(arrays.odometry(505, int(stamps[505])))
    node.on_imu(arrays.imu(505, int(stamps[505])))
    near = arrays.motor(506, int(stamps[506]))
    near.effort = [66000.0, 30000.0, 30000.0, 30000.0]  # 0.7 % past 65535: saturation, clipped
    node.on_motor(near)
    node.on_odom(arrays.odometry(506, int(stamps[506])))
    node.on_imu(arrays.imu(506, int(stamps[506])))
    feed(node, log, range(507, 700), arrays)
    assert node.faults.counts == {"range_motor_input": 1}
    got, _ = published(node, stamps)
    assert int(stamps[505]) not in got and int(stamps[506]) in got and len(got) == 699
    node.destroy_node()


def test_a_battery_reading_at_zero_volts_or_not_finite_is_dropped_with_one_warning_each(ros):
    from sensor_msgs.msg import BatteryState

    node = make_node(model="naive", battery_topic="/quad/battery")
    for volts in (0.0, 0.0, -1.0, float("nan"), 3.9):
        msg = BatteryState(voltage=volts)
        msg.header.stamp.sec = 5
        node.on_battery(msg)
    assert node.faults.counts == {"range_battery": 3, "nan_battery": 1}
    assert node.battery.stamps == [5 * 10**9]  # the 3.9 V reading only
    node.destroy_node()


def test_a_late_node_adopts_the_earlier_latched_origin_even_when_its_own_reaches_its_reader_after_it(ros):
    """window_origin's readers keep each writer's latched origin: a predictor that joins a running graph, receives the
    earlier origin into its reader and publishes its own (at its first input) before its executor takes the two, still
    adopts the earlier t0. With a reader of depth 1 its own sample replaced the earlier one and it cut its own windows,
    unaligned with the others' and unmarked (a review over DDS: a late predictor 0.81 s off the evaluator's windows)."""
    from rosgraph_msgs.msg import Clock

    from quad_modelling.nodes.common import latched_qos

    early = ros.create_node("origin_of_a_running_graph", namespace="/quad")  # the nodes' namespace
    early.create_publisher(Clock, topics.ORIGIN_TOPIC, latched_qos()).publish(messages.clock_message(1_000_000_000))
    node = make_node()
    deadline = time.monotonic() + 20
    while node.count_publishers(topics.ORIGIN_TOPIC) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)  # the early writer's latched sample reaches the node's reader; the node is not spun
    node.origin_pub.publish(messages.clock_message(5_000_000_000))  # its own, later origin, as at its first input
    for _ in range(20):
        ros.spin_once(node, timeout_sec=0.05)
    assert node.clock_.origin_ns == 1_000_000_000
    node.destroy_node()
    early.destroy_node()


def test_a_horizon_of_more_steps_than_a_live_rollout_takes_is_refused_at_start(ros):
    """horizon_s 30 at sample_period_s 2.5 ms is 12 000 steps: each parameter passed on its own and the predictor then
    faulted at every input without a prediction (a review, session 44); refused at start, one line."""
    from quad_modelling.nodes.common import BadParameter

    overrides = [Parameter(k, value=v) for k, v in {"vehicle": "crazyflie21", "model": "physics", "horizon_s": 30.0,
                                                     "sample_period_s": 0.0025}.items()]
    with pytest.raises(BadParameter, match=r"^predictor: parameters horizon_s=30.0 and sample_period_s=0.0025 make 12000 steps, "
                                           r"more than 10000$"):
        PredictorNode(parameter_overrides=overrides)


def test_a_baseline_s_name_on_another_model_and_names_no_evaluator_can_list_are_refused(ros):
    """A naive predictor named dummy filled the evaluator's zero baseline with its own scores (TIC 0.88 for 1); a name
    with a '/' makes topics the evaluator's ``models`` refuses; ``spans:=[]`` was a traceback."""
    from quad_modelling.nodes.common import BadParameter, model_name_check, spans_check

    with pytest.raises(BadParameter, match=r"parameter model_name='dummy': dummy is the name of a baseline every "
                                           r"evaluation holds; name the naive model otherwise"):
        make_node(model="naive", model_name="dummy")
    assert model_name_check("a/b") == "'a/b' cannot prefix a topic: use letters, digits and '_'"
    assert model_name_check("m_2") is None and model_name_check("") is None
    assert spans_check(None) == spans_check([]) == "give at least one span, e.g. spans:=[live:0:inf]"
