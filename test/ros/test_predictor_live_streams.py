"""The predictor over real DDS next to a flight stack's streams: own clocks, jitter, best-effort QoS; receding horizon.

A small in-test publisher plays the bundled NanoBench flight as a real stack would: commands at 100 Hz with
+-2 ms jitter, motion capture at 120 Hz, IMU at 500 Hz, each on its own phase (no stamp shared), best-effort
writers. The flight is resampled to each stream's stamps (commands held, measurements interpolated).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, JointState

from quad_modelling.core.evaluation.multistep import multistep_form
from quad_modelling.core.models.bounds import MARGIN, PhysicalBounds
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io import topics
from quad_modelling.io.bag_io import read_bag
from quad_modelling.nodes import messages
from quad_modelling.nodes.model_factory import make_streaming_predictor
from quad_modelling.nodes.predictor_node import PredictorNode

BAG = "bags/nanobench_B7_oval_medium_rep2"
CHUNK_S = 0.05


def resampled(log, t):
    """The flight at times ``t`` (inside it): commands held (the last one at or before t), the rest linear (yaw unwrapped)."""
    rows = np.clip(np.searchsorted(log.t, t, side="right") - 1, 0, len(log) - 1)
    lin = lambda a: np.column_stack([np.interp(t, log.t, a[:, i]) for i in range(a.shape[1])])  # noqa: E731
    euler = log.euler.copy()
    euler[:, 2] = np.unwrap(euler[:, 2])
    return dataclasses.replace(log, t=t, u=log.u[rows], acc_b=lin(log.acc_b), gyro_b=lin(log.gyro_b), pos_n=lin(log.pos_n),
                               vel_n=lin(log.vel_n), euler=lin(euler), vbat=None, omega=None)


class Stack:
    """In-test flight stack: best-effort publishers of the contract topics and a reliable subscriber of the predictions."""

    def __init__(self, rclpy, predictor, odom_topic):
        self.node = rclpy.create_node("stack", namespace=topics.DEFAULT_NAMESPACE)
        best_effort = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=1000)
        self.pubs = {"motor": self.node.create_publisher(JointState, "motor_input", best_effort),
                     "odom": self.node.create_publisher(Odometry, "mocap/odom", best_effort),
                     "imu": self.node.create_publisher(Imu, "imu", best_effort)}
        self.received: list[Odometry] = []
        self.accel = []
        reliable = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=10000)
        self.node.create_subscription(Odometry, odom_topic, self.received.append, reliable)
        if not odom_topic.endswith("horizon/odom"):
            from geometry_msgs.msg import AccelStamped
            self.node.create_subscription(AccelStamped, odom_topic.replace("/odom", "/accel"), self.accel.append, reliable)
        self.predictor = predictor
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.executor.add_node(predictor)

    def progress(self) -> int:
        p = self.predictor
        return len(self.received) + len(self.accel) + len(p.odom) + len(p.imu) + p.published + len(p.pending)

    def settle(self, quiet: int = 8, limit: int = 2000) -> None:
        """Spin until nothing has happened for ``quiet`` consecutive 1 ms turns."""
        idle = 0
        for _ in range(limit):
            before = self.progress()
            self.executor.spin_once(timeout_sec=0.001)
            idle = idle + 1 if self.progress() == before else 0
            if idle >= quiet:
                return

    def wait_for_match(self) -> None:
        """Until the predictor subscribes to every stream and publishes to every subscription of the stack."""
        for _ in range(2000):
            if all(pub.get_subscription_count() > 0 for pub in self.pubs.values()) and \
                    all(self.node.count_publishers(s.topic_name) > 0 for s in self.node.subscriptions):
                return
            self.executor.spin_once(timeout_sec=0.005)
        raise AssertionError("the predictor and the in-test stack did not discover each other")

    def play(self, events) -> None:
        """``events``: (stamp ns, stream, message factory) in stamp order, published chunk by chunk of CHUNK_S."""
        start = 0
        while start < len(events):
            end = start
            while end < len(events) and events[end][0] - events[start][0] < CHUNK_S * 1e9:
                end += 1
            for ns, stream, make in events[start:end]:
                self.pubs[stream].publish(make())
            self.settle()
            start = end
        self.settle(quiet=30)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.predictor.destroy_node()


def stream_stamps(t_start: float, t_end: float, rate: float, phase_s: float, jitter_s: float, rng) -> np.ndarray:
    t = t_start + phase_s + np.arange(int((t_end - t_start - phase_s) * rate)) / rate
    return np.sort(t + rng.uniform(-jitter_s, jitter_s, len(t))) if jitter_s else t


def make_predictor(**params):
    overrides = [Parameter(k, value=v) for k, v in {"vehicle": "crazyflie21", **params}.items()]
    return PredictorNode(parameter_overrides=overrides)


@pytest.fixture(scope="module")
def direct_spec(tmp_path_factory) -> str:
    """``direct:FILE``: the direct model's regression fitted on the bundled flight's 5-25 s (a second)."""
    from quad_modelling.core.training.direct import train_direct

    path = train_direct([read_bag(BAG)], [(5.0, 25.0)], load_vehicle("crazyflie21")).save(tmp_path_factory.mktemp("direct") / "direct.npz")
    return f"direct:{path}"


@pytest.mark.slow
@pytest.mark.parametrize("model", ["greybox", "physics", "direct"])
def test_predictions_for_99_percent_of_jittered_independent_streams_with_increasing_stamps_and_a_continuous_pose(ros, model, request):
    model = request.getfixturevalue("direct_spec") if model == "direct" else model
    log = read_bag(BAG)
    rng = np.random.default_rng(15)
    t0, t1 = log.t[300], log.t[300] + 11.0  # two 5 s windows and the start of a third
    cmd_t = stream_stamps(t0, t1, 100.0, 0.0, 0.002, rng)
    mocap_t = stream_stamps(t0 - 0.05, t1 + 0.05, 120.0, 0.00137, 0.0, rng)
    imu_t = stream_stamps(t0 - 0.05, t1 + 0.05, 500.0, 0.00071, 0.0, rng)
    commands, mocap, imu = (messages.measurement_messages(resampled(log, t)) for t in (cmd_t, mocap_t, imu_t))
    ns = {name: topics.stamps_ns(t) for name, t in (("motor", cmd_t), ("odom", mocap_t), ("imu", imu_t))}
    assert not (set(ns["motor"].tolist()) & set(ns["odom"].tolist()) or set(ns["motor"].tolist()) & set(ns["imu"].tolist()))
    steps = np.diff(cmd_t)
    assert steps.min() < 0.0075 and steps.max() > 0.0125  # real jitter: beyond the offline 25 % uniformity check
    events = sorted([(int(s), "motor", (lambda i=i, s=int(s): commands.motor(i, s))) for i, s in enumerate(ns["motor"])]
                    + [(int(s), "odom", (lambda i=i, s=int(s): mocap.odometry(i, s))) for i, s in enumerate(ns["odom"])]
                    + [(int(s), "imu", (lambda i=i, s=int(s): imu.imu(i, s))) for i, s in enumerate(ns["imu"])],
                    key=lambda e: e[0])

    predictor = make_predictor(model=model, window_s=5.0)
    stack = Stack(ros, predictor, f"{model.partition(':')[0]}/odom")
    try:
        stack.wait_for_match()
        stack.play(events)
        odom_stamps = [topics.stamp_ns(m.header.stamp) for m in stack.received]
        accel_stamps = [topics.stamp_ns(m.header.stamp) for m in stack.accel]
        first_anchor = odom_stamps[0]
        inputs = ns["motor"][ns["motor"] >= first_anchor]
        answered = np.isin(inputs, odom_stamps)
        coverage = answered.mean()
        print(f"coverage {coverage:.4f} of {len(inputs)} inputs after the first anchor; faults {predictor.faults.summary()}")
        assert coverage >= 0.99
        assert np.all(np.diff(odom_stamps) > 0) and np.all(np.diff(accel_stamps) > 0)  # strictly increasing, as received
        assert predictor.windows_started == 3 and "warm_gap" not in predictor.faults.counts

        # the pose is integrated continuously: between consecutive predictions of a window the position moves by the
        # predicted velocity (trapezoid), up to what the predicted (or the vehicle's full-thrust) acceleration can add
        # in one step, plus 2 mm for the anchor's smoothing -- a held pose that catches up later breaks this at once
        assert accel_stamps == odom_stamps
        predicted = topics.predictions_from_fields([topics.predicted_odometry_fields(m) for m in stack.received],
                                                   [topics.accel_fields(m) for m in stack.accel])
        got = np.array(odom_stamps)
        a_max = PhysicalBounds.from_vehicle(load_vehicle("crazyflie21")).max_acceleration / MARGIN
        window = np.array([predictor.clock_.locate(int(g))[0] for g in got])
        same = window[1:] == window[:-1]
        dt = np.diff(got) / 1e9
        moved = np.diff(predicted[:, 0:3], axis=0)
        step = np.linalg.norm(moved - 0.5 * (predicted[1:, 3:6] + predicted[:-1, 3:6]) * dt[:, None], axis=1)
        acc = np.maximum(np.linalg.norm(predicted[:, 6:9], axis=1), a_max)
        reach = 0.5 * np.maximum(acc[1:], acc[:-1]) * dt ** 2 + 0.002
        worst = int(np.argmax(np.where(same, step / reach, 0)))
        print(f"largest step / reach within a window: {np.max((step / reach)[same]):.3f} at pair {worst}: "
              f"{(got[worst] - got[0]) / 1e9:.3f} s, off the velocity by {step[worst]:.5f} m, allowed {reach[worst]:.5f} m")
        assert np.all((step <= reach)[same])
        assert np.count_nonzero(np.linalg.norm(moved, axis=1)[same] == 0.0) == 0  # never a frozen pose
    finally:
        stack.close()


def replay_events():
    """360 rows of the bundled flight as a replay sends them: each row's measurements, then its command (one stamp)."""
    log = read_bag(BAG).slice(200, 560)
    stamps = topics.stamps_ns(log.t)
    arrays = messages.measurement_messages(log)
    events = []
    for row, s in enumerate(stamps.tolist()):
        events += [(s, "odom", lambda r=row, s=s: arrays.odometry(r, s)), (s, "imu", lambda r=row, s=s: arrays.imu(r, s)),
                   (s, "motor", lambda r=row, s=s: arrays.motor(r, s))]
    return log, stamps, events


FLOWN_RUNS: dict[str, tuple] = {}
""":func:`flown_horizon_run` by model: the greybox run is read by two tests (the horizon messages and the live MAE)."""


def flown_horizon_run(ros, model):
    """The replayed rows through a ``model`` predictor in receding-horizon mode (flown inputs, horizon_s 0.1 s):
    (log, stamps [ns], predictor, stack holding the received <model>/horizon/odom messages). Run once per model in
    this process (:data:`FLOWN_RUNS`); the tests only read what it received."""
    if model not in FLOWN_RUNS:
        FLOWN_RUNS[model] = _fly_horizon(ros, model)
    return FLOWN_RUNS[model]


def _fly_horizon(ros, model):
    log, stamps, events = replay_events()
    predictor = make_predictor(model=model, horizon_s=0.1, horizon_history_s=2.0, horizon_inputs="flown")
    stack = Stack(ros, predictor, f"{model.partition(':')[0]}/horizon/odom")
    try:
        stack.wait_for_match()
        stack.play(events)
    finally:
        stack.close()
    return log, stamps, predictor, stack


@pytest.mark.parametrize("model", ["greybox", "physics", "direct"])
def test_horizon_mode_publishes_the_offline_multistep_prediction_of_each_anchor(ros, model, request):
    """horizon_inputs flown, horizon_s = 0.1 s at 100 Hz: h = 10. Each published <model>/horizon/odom equals, to 1e-9,
    the offline multi-step form's prediction (core/evaluation/multistep.py) from the same start over the same rows,
    stamped t_{s+h}. The direct model's carried forecast included (its compiled step with the regression's rates)."""
    model = request.getfixturevalue("direct_spec") if model == "direct" else model
    log, stamps, predictor, stack = flown_horizon_run(ros, model)
    h, warm = 10, 20
    assert predictor.horizon.steps == h
    got = np.array([topics.stamp_ns(m.header.stamp) for m in stack.received])
    starts = np.arange(warm - 1, len(log) - h)
    assert np.array_equal(got, stamps[starts + h])  # one per command from the first anchor on, stamped t_{s+h}
    form = multistep_form(make_streaming_predictor(model, load_vehicle("crazyflie21")), warm)
    expected, _ = topics.prediction_fields(form.predict_horizons(log, starts, h)[:, h])
    fields = np.array([topics.predicted_odometry_fields(m) for m in stack.received])
    error = np.abs(fields - expected).max()
    print(f"{model.partition(':')[0]}: {len(got)} horizon predictions, max |live - offline| = {error:.2e}")
    assert error < 1e-9


@pytest.mark.parametrize("model", ["greybox", "physics"])
def test_held_horizon_mode_forecasts_each_input_before_the_next_command_is_sent(ros, model):
    """horizon_inputs hold (the default), horizon_s = 0.1 s at 100 Hz: h = 10. The stack sends one row at a time and
    waits for the answer before the next command: every input s from the first anchor on gets its prediction (stamped
    t_s + h dt, the time it predicts) while command s + 1 is not sent yet; the two anchors before dt is known (the
    median of the first 20 steps) come with input 20. Counts and ordering only, no wall-clock bound."""
    log, stamps, events = replay_events()
    predictor = make_predictor(model=model, horizon_s=0.1, horizon_history_s=2.0)
    stack = Stack(ros, predictor, f"{model}/horizon/odom")
    h, warm = 10, 20
    answered = []  # predictions received after each command, before the next is sent
    try:
        stack.wait_for_match()
        for row in range(len(log)):
            for _, stream, make in events[3 * row:3 * row + 3]:
                stack.pubs[stream].publish(make())
            expected = 0 if row < warm else row - warm + 2  # anchors warm - 1 .. row
            for _ in range(3000):  # until the answer arrives (bounded turns, not a time limit)
                if len(stack.received) >= expected:
                    break
                stack.executor.spin_once(timeout_sec=0.001)
            answered.append(len(stack.received))
        stack.settle(quiet=30)
    finally:
        stack.close()
    assert predictor.horizon.inputs == "hold" and predictor.horizon.steps == h
    dt_ns = predictor.horizon.period_ns
    assert abs(dt_ns - 10_000_000) < 100_000
    anchors = np.arange(warm - 1, len(log))
    assert answered == [0] * warm + list(range(2, len(anchors) + 1))  # input s answered before command s + 1 was sent
    got = np.array([topics.stamp_ns(m.header.stamp) for m in stack.received])
    assert np.array_equal(got, stamps[anchors] + h * dt_ns)  # one per input from the first anchor on, at t_s + h dt
    assert np.all(np.diff(got) > 0) and not predictor.faults.counts
    print(f"{model}: {len(got)} held-input forecasts, each before the next command; dt {dt_ns} ns")


def test_live_mae_at_h_from_the_predictor_over_dds_equals_the_offline_multistep_mae(ros):
    """End to end: the greybox predictor (horizon_inputs flown, h = 10) publishes its horizon states over DDS; the
    evaluator (horizon_s 0.1) scores what arrived against the replayed measurements; its live MAE@h per group equals
    the offline multi-step MAE_h (core/evaluation/multistep.py, IDSIA protocol) of the same starts to 1e-9 relative."""
    from quad_modelling.core.evaluation.multistep import multistep_mae
    from test.ros.test_evaluator_streams import make_node as make_evaluator

    log, stamps, predictor, stack = flown_horizon_run(ros, "greybox")
    h, warm = 10, 20
    vehicle = load_vehicle("crazyflie21")
    offline, starts = multistep_mae(multistep_form(make_streaming_predictor("greybox", vehicle), warm), log, h, vehicle,
                                    first_start=warm - 1)
    assert starts == len(stack.received) == len(log) - h - (warm - 1)
    evaluator = make_evaluator(models=["greybox"], horizon_s=0.1)
    arrays = messages.measurement_messages(log)
    arrived = {topics.stamp_ns(m.header.stamp): m for m in stack.received}
    for row, ns in enumerate(stamps.tolist()):
        evaluator.on_motor(arrays.motor(row, ns))
        evaluator.on_odom(arrays.odometry(row, ns))
        evaluator.on_imu(arrays.imu(row, ns))
        if ns in arrived:  # what came over DDS, fed to the evaluator when its stamp's measurements are in
            evaluator.on_horizon("greybox", arrived[ns])
    evaluator.finish()
    live = evaluator.scores.horizon_mae()["models"]["greybox"]
    evaluator.destroy_node()
    assert live["predictions"] == starts and live["unreached"] == 0
    for g, group in enumerate(("position", "velocity", "orientation", "angular_velocity")):
        assert abs(live["mae"][group] - offline[g, h - 1]) <= 1e-9 * offline[g, h - 1], group
