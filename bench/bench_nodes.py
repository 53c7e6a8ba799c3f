"""Node suite benchmarks -> bench/results/nodes.json + nodes.md.

1. Predictor latency (input stamp published -> its prediction received), p50/p99 and drops,
   at 100 Hz and 400 Hz, with the evaluator running (a publisher in this process plays a
   synthetic flight; predictor and evaluator are their own processes), with the predictor
   under SCHED_FIFO (``realtime_priority``) and under normal scheduling, with the floor of a
   no-op echo node (bench/echo_node.py) answering the same inputs beside it in the same run.
2. Whole-graph throughput at rate 0: run-bag on the bundled bag with two predictors
   (naive, greybox) and the evaluator; samples/s of the replay, real-time factor, and
   loss (every prediction published and every window scored).
3. Memory: replay (rate 0, loop) of a synthetic 400 Hz flight through predictor + evaluator
   for a fixed wall time; RSS of each node sampled over time.

Usage: .venv/bin/python bench/bench_nodes.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import calibration_ms, write_results  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 90 + 10))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


def synthetic_flight(rate: float, seconds: float):
    from quad_modelling.core.flight_log import FlightLog, FlightMeta

    n = int(rate * seconds)
    rng = np.random.default_rng(0)
    t = np.arange(n) / rate
    phase = 2 * np.pi * 0.3 * t
    return FlightLog(
        t=t, u=40000 * (1 + 0.02 * rng.standard_normal((n, 4))),
        acc_b=np.column_stack([0.3 * np.sin(phase), 0.2 * np.cos(phase), -9.81 + 0.1 * rng.standard_normal(n)]),
        gyro_b=0.2 * rng.standard_normal((n, 3)),
        pos_n=np.column_stack([np.cos(phase), np.sin(phase), -1.0 + 0.1 * np.sin(phase)]),
        vel_n=np.column_stack([-np.sin(phase), np.cos(phase), 0.1 * np.cos(phase)]),
        euler=np.column_stack([0.1 * np.sin(phase), -0.08 * np.cos(phase), 0.5 * np.sin(0.2 * phase)]),
        meta=FlightMeta(vehicle="crazyflie21", source=f"synthetic {rate:g} Hz"),
    )


def start(module: str, *params: str, log: Path) -> subprocess.Popen:
    argv = [sys.executable, "-m", f"quad_modelling.nodes.{module}", "--ros-args"]
    for p in params:
        argv += ["-p", p]
    return subprocess.Popen(argv, stdout=log.open("w"), stderr=subprocess.STDOUT, start_new_session=True)


def stop(procs) -> None:
    import signal

    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            p.kill()


def small_narx(rate: float, workdir: Path) -> Path:
    """A NARX model file for the synthetic flight at ``rate`` (2 training epochs: its cost per step is the
    trained model's, its accuracy does not matter here)."""
    from quad_modelling.core.models.narx import NarxConfig
    from quad_modelling.core.training.narx import train_narx_on_flights

    path = workdir / f"narx_{rate:g}hz.npz"
    if not path.exists():
        train_narx_on_flights([synthetic_flight(rate, 30.0)], [None], NarxConfig(epochs=2, iterations_per_epoch=5)).save(path)
    return path


def small_hybrid(rate: float, workdir: Path) -> Path:
    """A hybrid model file (physics base of ``crazyflie21`` + default-size residual net, one short rollout epoch)
    for the synthetic flight at ``rate``: its cost per step is the trained model's, its accuracy does not matter."""
    from quad_modelling.core.training.hybrid import HybridTrainingConfig, train_hybrid_on_flights
    from quad_modelling.core.training.rollout import RolloutConfig
    from quad_modelling.core.vehicle import load_vehicle

    path = workdir / f"hybrid_{rate:g}hz.npz"
    if not path.exists():
        config = HybridTrainingConfig(rollout=RolloutConfig(horizon=5, batch_size=64, max_epochs=1, windows_per_epoch=128))
        train_hybrid_on_flights([synthetic_flight(rate, 30.0)], [None], load_vehicle("crazyflie21"), config, seed=0).save(path)
    return path


def small_direct(rate: float, workdir: Path) -> Path:
    """A direct model file (physics base of ``crazyflie21`` + the rate regression fitted on the synthetic flight at
    ``rate``): its cost per step is any direct model's (H = 50 rows), its accuracy does not matter here."""
    from quad_modelling.core.training.direct import train_direct
    from quad_modelling.core.vehicle import load_vehicle

    path = workdir / f"direct_{rate:g}hz.npz"
    if not path.exists():
        train_direct([synthetic_flight(rate, 30.0)], [None], load_vehicle("crazyflie21")).save(path)
    return path


MODEL_FILES = {"greybox": None, "physics": None, "narx": small_narx, "hybrid": small_hybrid, "direct": small_direct}
"""Latency models: kind -> builder of its model file for a rate (None: the spec needs no file)."""


def latency(rate: float, seconds: float, workdir: Path, model: str = "greybox", realtime: int = 0, echo: bool = False,
            horizon_s: float = 0.0, math_threads: int = 1, echo_beside: bool = False) -> dict:
    """Input-to-prediction latency of one predictor node with the evaluator running.

    ``horizon_s`` > 0: the predictor in receding-horizon mode (held inputs: the forecast) with ``sample_period_s``
    1 / ``rate``; every input from the first anchor on is answered by a forecast on ``<model>/horizon/odom`` stamped
    t_s + h dt, which maps it back to its input (h = round(horizon_s * rate)). ``math_threads``: the predictor's and
    evaluator's parameter (0: the math libraries' pools as they start, one thread per core).

    ``realtime`` > 0: the predictor runs with ``realtime_priority`` and this harness (standing in for the
    flight stack that consumes the predictions) under SCHED_FIFO at the same priority; the evaluator keeps
    normal scheduling (nice 10). ``echo``: instead of predictor and evaluator, a no-op rclpy node that
    answers each motor input with an empty Odometry of the same stamp (the floor of rclpy + Fast DDS
    + this harness on this machine). ``echo_beside``: that echo node runs *next to* the predictor and evaluator, on
    ``echo/odom``, answering the same inputs at the same moments; its latencies over the same rows are returned as
    ``echo_p50_ms`` / ``echo_p99_ms`` (the floor in the very same run, whatever the shared machine does meanwhile).
    """
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from sensor_msgs.msg import Imu, JointState

    from quad_modelling.io import topics
    from quad_modelling.io.topics import stamps_ns
    from quad_modelling.nodes import messages
    from quad_modelling.nodes.common import (
        data_qos,
        make_executor,
        set_realtime_priority,
        use_dds_profile,
    )

    window = "5.0"
    name = model.partition(":")[0]
    tag = f"{'echo' if echo else name}_{rate:g}_rt{realtime}_h{horizon_s:g}_m{math_threads}"
    steps = int(round(horizon_s * rate))
    period_ns = int(round(1e9 / rate))
    horizon = [f"horizon_s:={horizon_s}", f"sample_period_s:={1.0 / rate}"] if horizon_s > 0 else []
    topic = f"{name}/horizon/odom" if horizon_s > 0 else f"{name}/odom"
    if echo:
        procs = [subprocess.Popen([sys.executable, str(REPO / "bench" / "echo_node.py"), f"{name}/odom", str(realtime)],
                                  stdout=(workdir / f"echo_{tag}.log").open("w"), stderr=subprocess.STDOUT, start_new_session=True)]
    else:
        # no replay announces the vehicle here: the nodes are told, as next to a real flight
        procs = [start("predictor_node", f"window_s:={window}", f"model:={model}", f"model_name:={name}", "vehicle:=crazyflie21",
                       f"realtime_priority:={realtime}", f"math_threads:={math_threads}", *horizon, log=workdir / f"pred_{tag}.log"),
                 start("evaluator_node", f"window_s:={window}", f"models:=[{name}]", "vehicle:=crazyflie21",
                       f"math_threads:={math_threads}", *horizon[:1], log=workdir / f"eval_{tag}.log")]
        if echo_beside:
            procs.append(subprocess.Popen([sys.executable, str(REPO / "bench" / "echo_node.py"), "echo/odom", str(realtime)],
                                          stdout=(workdir / f"echo_beside_{tag}.log").open("w"), stderr=subprocess.STDOUT,
                                          start_new_session=True))
    log = synthetic_flight(rate, seconds)
    arrays = messages.measurement_messages(log)
    stamps = (stamps_ns(log.t) + time.time_ns()).tolist()
    calibration = float(np.median([calibration_ms() for _ in range(CALIBRATION_RUNS)]))  # the machine's speed now
    use_dds_profile()  # as the nodes do
    rclpy.init()
    node = Node("latency_bench", namespace="/quad")
    executor = make_executor("events", node)  # as the nodes: the harness's own receive path stays light
    if realtime and (refused := set_realtime_priority(realtime)):
        raise SystemExit(f"latency harness: {refused}")
    qos = data_qos()
    pubs = (node.create_publisher(JointState, "motor_input", qos), node.create_publisher(Odometry, "mocap/odom", qos),
            node.create_publisher(Imu, "imu", qos))
    sent: dict[int, float] = {}
    received: dict[int, float] = {}
    answered_ns = steps * period_ns  # a forecast's stamp - its input's
    node.create_subscription(Odometry, topic, lambda m: received.setdefault(topics.stamp_ns(m.header.stamp) - answered_ns,
                                                                            time.perf_counter()), qos)
    echoed: dict[int, float] = {}
    if echo_beside:
        node.create_subscription(Odometry, "echo/odom", lambda m: echoed.setdefault(topics.stamp_ns(m.header.stamp),
                                                                                  time.perf_counter()), qos)
    deadline = time.monotonic() + 60
    while (pubs[0].get_subscription_count() < len(procs) or node.count_publishers(topic) < 1
           or (echo_beside and node.count_publishers("echo/odom") < 1)) and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    period = 1.0 / rate
    t0 = time.perf_counter()
    for row, ns in enumerate(stamps):
        target = t0 + row * period
        while (left := target - time.perf_counter()) > 0:
            executor.spin_once(timeout_sec=left)
        # measurements first, the command last: the prediction is due when the command arrives
        pubs[1].publish(arrays.odometry(row, ns))
        pubs[2].publish(arrays.imu(row, ns))
        sent[ns] = time.perf_counter()
        pubs[0].publish(arrays.motor(row, ns))
        executor.spin_once(timeout_sec=0.0)
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    node.destroy_node()
    rclpy.shutdown()
    set_realtime_priority(0)  # else every process this one starts later inherits SCHED_FIFO
    stop(procs)
    warm_rows = int(round(0.2 * rate))
    window_rows = int(round(5.0 * rate))
    if horizon_s > 0:  # every input from the first anchor (the last warm row) on is answered by its forecast
        streamed = stamps[warm_rows - 1:]
        expected = streamed
    else:  # warm-start rows are predicted only once the warm start is complete: not a per-input latency
        streamed = [ns for i, ns in enumerate(stamps) if i % window_rows >= warm_rows + 1]
        expected = stamps
    lat = np.array([received[ns] - sent[ns] for ns in streamed if ns in received]) * 1e3
    drops = sum(ns not in received for ns in expected)
    out = {"model": "echo (no-op node)" if echo else name, "realtime_priority": realtime, "rate_hz": rate, "seconds": seconds,
           "math_threads": None if echo else math_threads, "calibration_median_ms": calibration,
           "inputs": len(stamps), "p50_ms": float(np.percentile(lat, 50)),
           "p99_ms": float(np.percentile(lat, 99)), "max_ms": float(lat.max()), "drops": int(drops)}
    if horizon_s > 0:
        out.update(horizon_s=horizon_s, steps=steps, forecasts_expected=len(expected))
    if echo_beside:  # the floor over the same rows, in the same run
        floor = np.array([echoed[ns] - sent[ns] for ns in streamed if ns in echoed]) * 1e3
        out.update(echo_p50_ms=float(np.percentile(floor, 50)), echo_p99_ms=float(np.percentile(floor, 99)),
                   echo_drops=sum(ns not in echoed for ns in streamed))
    return out


def throughput(workdir: Path, executor: str = "events", run: int = 0) -> dict:
    out = workdir / f"graph_{executor}_{run}"
    bag = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
    started = time.monotonic()
    run = subprocess.run([sys.executable, "-m", "quad_modelling.cli", "run-bag", str(bag), "--models", "naive,greybox",
                          "--no-figures", "--executor", executor, "-o", str(out)], capture_output=True, text=True, timeout=600)
    total = time.monotonic() - started
    if run.returncode != 0:
        raise SystemExit(run.stderr)
    replay_log = (out / "logs" / "replay.log").read_text()
    m = re.search(r"published (\d+) samples in \d+ pass\(es\) in ([\d.]+) s", replay_log)
    samples, seconds = int(m.group(1)), float(m.group(2))
    predictions = [int(x) for x in re.findall(r"published (\d+) predictions", "".join(p.read_text() for p in (out / "logs").glob("*_predictor.log")))]
    results = json.loads((out / "results.json").read_text())
    faults = re.findall(r"faults: (.*)", "".join(p.read_text() for p in (out / "logs").glob("*.log")))
    flight_s = samples / 100.0
    return {"executor": executor, "bag": bag.name, "models": ["naive", "greybox"], "samples": samples, "messages_published": samples * 5,
            "play_s": seconds, "samples_per_s": samples / seconds, "messages_per_s": samples * 5 / seconds,
            "real_time_factor": flight_s / seconds, "run_bag_total_s": total,
            "predictions_per_model": predictions, "lost": int(sum(samples - p for p in predictions)),
            "windows": results["windows"], "marked": len(results["live"]["marked"]), "faults": faults}


FORECAST_RATE_HZ = 400.0
FORECAST_HORIZON_S = 0.125
"""The receding-horizon runs: 400 Hz inputs, h = 50 steps (the issue's target)."""

FORECAST_MODELS = ("greybox", "narx", "physics", "hybrid", "direct")


def forecast_cost(spec: str, carried: bool, seconds: float) -> dict:
    """Per-input cost [ms] of a predictor node in receding-horizon mode (held inputs, h = 50 at 400 Hz), in this
    process: each input's measurements handed to the node, then its command; the wall time of the command's handler
    (anchor, forecast, bounds, message, publish) is the cost. ``carried`` False: the model's carried form switched off,
    the multi-step form re-run over ``horizon_history_s`` (2.5 s) per input, as before the carried forms."""
    from rclpy.parameter import Parameter

    from quad_modelling.io.topics import stamps_ns
    from quad_modelling.nodes import messages
    from quad_modelling.nodes.predictor_node import PredictorNode

    log = synthetic_flight(FORECAST_RATE_HZ, seconds)
    arrays = messages.measurement_messages(log)
    stamps = (stamps_ns(log.t) + 1_000_000_000_000).tolist()
    params = {"vehicle": "crazyflie21", "model": spec, "model_name": spec.partition(":")[0], "horizon_s": FORECAST_HORIZON_S,
              "sample_period_s": 1.0 / FORECAST_RATE_HZ}
    node = PredictorNode(parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    if not carried:
        node.horizon.carried_for = None
    costs, forecast = [], [0.0]
    ready = node.horizon.ready

    def timed_ready(*args):  # the forecast's share: the anchors' rows converted, added, rolled out
        started = time.perf_counter()
        events = list(ready(*args))
        forecast[0] += time.perf_counter() - started
        return iter(events)

    node.horizon.ready = timed_ready
    forecasts, calibration = [], []
    try:
        for row, ns in enumerate(stamps):
            calibration.append(calibration_ms())  # the machine's speed now (bench.common.calibration_ms)
            node.on_odom(arrays.odometry(row, ns))
            node.on_imu(arrays.imu(row, ns))
            motor = arrays.motor(row, ns)
            forecast[0] = 0.0
            started = time.perf_counter()
            node.on_motor(motor)
            costs.append(time.perf_counter() - started)
            forecasts.append(forecast[0])
        published, faults = node.published, dict(node.faults.counts)
        form = type(node.horizon.carried).__name__ if node.horizon.carried is not None else "history re-run"
    finally:
        node.destroy_node()
    warm = int(round(0.2 * FORECAST_RATE_HZ))
    cost = np.array(costs[warm + 20:]) * 1e3  # after the first anchors (one-time costs)
    share = np.array(forecasts[warm + 20:]) * 1e3
    return {"model": spec.partition(":")[0], "form": form, "rate_hz": FORECAST_RATE_HZ, "horizon_s": FORECAST_HORIZON_S,
            "steps": node.horizon.steps, "inputs": len(stamps), "published": published, "faults": faults,
            "median_ms": float(np.median(cost)), "p99_ms": float(np.percentile(cost, 99)), "mean_ms": float(cost.mean()),
            "forecast_median_ms": float(np.median(share)), "forecast_p99_ms": float(np.percentile(share, 99)),
            "calibration_median_ms": float(np.median(calibration[warm + 20:])),
            "relative_median": float(np.median(cost) / np.median(calibration[warm + 20:]))}


def forecast_markdown(costs: list[dict], keep_up: list[dict]) -> list[str]:
    md = ["## Receding-horizon forecasts: per-input cost (h = 50 at 400 Hz, held inputs)", "",
          "A predictor node in this process (no spinning: each input's measurements handed to it, then its command); the "
          "wall time of the command's handler (`handler`: the anchor's row converted from the messages, the anchor "
          "advanced, the h-step forecast, the bounds check, the message and its publication) and of the forecast alone "
          "(`forecast`: `RecedingHorizon.ready`, the row's conversion included). Form: the model's carried-state forecast "
          "(`core/live/forecast.py`, its class named), or `history re-run`: the model's multi-step form over "
          "`horizon_history_s` (2.5 s) of rows at every input, as before it.", "",
          "`calibration`: the median of a fixed workload run before each input (`bench/common.py` `calibration_ms`), the "
          "machine's speed meanwhile; `relative` = handler median / calibration median, what compares runs at other "
          "moments or on other machines.", "",
          "| model | form | inputs | forecasts | handler median [ms] | handler p99 [ms] | forecast median [ms] | forecast p99 [ms] | calibration [ms] | relative |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    md += [f"| {c['model']} | {c['form']} | {c['inputs']} | {c['published']} | {c['median_ms']:.3f} | {c['p99_ms']:.3f} | "
           f"{c['forecast_median_ms']:.3f} | {c['forecast_p99_ms']:.3f} | {c['calibration_median_ms']:.3f} | "
           f"{c['relative_median']:.2f} |" for c in costs]
    md += ["", "## Receding-horizon forecasts at 400 Hz over DDS (predictor and evaluator processes, SCHED_FIFO)", "",
           "Held inputs, h = 50 (0.125 s): every input from the first anchor on must be answered by its forecast "
           "(stamped t_s + h dt); `dropped` = inputs without one. Latency as in the table above the input's publication "
           f"to its forecast's reception. 400 Hz rows: the run of median p99 out of {LATENCY_RUNS}.", "",
           "| model | inputs | forecasts expected | dropped | p50 [ms] | p99 [ms] | max [ms] | p99 of each run [ms] | calibration [ms] |",
           "|---|---|---|---|---|---|---|---|---|"]
    md += [f"| {r['model']} | {r['inputs']} | {r['forecasts_expected']} | {r['drops']} | {r['p50_ms']:.2f} | {r['p99_ms']:.2f} | "
           f"{r['max_ms']:.2f} | {', '.join(f'{x:.2f}' for x in r.get('runs_p99_ms', [r['p99_ms']]))} | "
           f"{'-' if r.get('calibration_median_ms') is None else format(r['calibration_median_ms'], '.3f')} |" for r in keep_up]
    return md + [""]


def forecasts(seconds: float, workdir: Path, models: list[str]) -> tuple[list[dict], list[dict]]:
    """Per-input costs (carried and history re-run) of every model, then the 400 Hz DDS runs of every model."""
    import rclpy

    specs = {kind: kind if MODEL_FILES[kind] is None else f"{kind}:{MODEL_FILES[kind](FORECAST_RATE_HZ, workdir)}" for kind in models}
    rclpy.init()
    try:
        # the history re-run costs up to ~60 ms per input here: 2 s of inputs are enough for its median
        costs = [forecast_cost(specs[kind], carried, seconds if carried else 2.0) for kind in models for carried in (True, False)]
    finally:
        rclpy.shutdown()
    keep_up = []
    for kind in models:
        runs = [latency(FORECAST_RATE_HZ, seconds, workdir, specs[kind], realtime=LATENCY_REALTIME_PRIORITY,
                        horizon_s=FORECAST_HORIZON_S) for _ in range(LATENCY_RUNS)]
        median = dict(sorted(runs, key=lambda r: r["p99_ms"])[len(runs) // 2])
        median["runs_p99_ms"] = [r["p99_ms"] for r in runs]
        median["runs_drops"] = [r["drops"] for r in runs]
        keep_up.append(median)
    return costs, keep_up


LATENCY_REALTIME_PRIORITY = 10
"""SCHED_FIFO priority of the predictor (parameter ``realtime_priority``) and of the harness in the real-time runs."""

LATENCY_RUNS = 5
"""Runs per 400 Hz latency case; the table shows the run of median p99 (the machine is noisy)."""

CALIBRATION_RUNS = 200
"""Runs of ``bench.common.calibration_ms`` before each latency run (its median: the machine's speed then, which moved
the echo node's p99 from 4.6 ms in session 43 to 0.9 ms in session 44 on the same code)."""


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def memory(wall_s: float, workdir: Path) -> dict:
    from quad_modelling.io.bag_io import write_bag

    bag = write_bag(synthetic_flight(400.0, 60.0), workdir / "synthetic400")
    names = ("predictor", "evaluator", "replay")
    procs = [start("predictor_node", log=workdir / "mem_pred.log"),
             start("evaluator_node", "models:=[naive]", "figures:=false", log=workdir / "mem_eval.log"),
             start("replay_node", f"bag:={bag}", "rate:=0.0", "loop:=true", "wait_for_subscribers:=2", "publish_clock:=false",
                   log=workdir / "mem_replay.log")]
    samples = []
    started = time.monotonic()
    while time.monotonic() - started < wall_s:
        time.sleep(2.0)
        samples.append([round(time.monotonic() - started, 1)] + [rss_kib(p.pid) / 1024 for p in procs])
    stop(procs[2:])
    stop(procs[:2])
    text = (workdir / "mem_pred.log").read_text()
    m = re.search(r"published (\d+) predictions", text)
    predicted = int(m.group(1)) if m else 0
    rows = samples[len(samples) // 4:]  # after start-up
    growth = {n: float(rows[-1][i + 1] - rows[0][i + 1]) for i, n in enumerate(names)}
    return {"rate_hz": 400, "wall_s": wall_s, "flight_s_replayed": predicted / 400.0, "rss_mib_samples": samples,
            "names": list(names), "rss_growth_mib_after_startup": growth,
            "rss_mib_end": {n: float(samples[-1][i + 1]) for i, n in enumerate(names)}}


def latency_markdown(lat: list[dict]) -> list[str]:
    """The latency section of the results (one row per model, scheduling and rate)."""
    md = [
          "## Predictor latency (input published -> prediction received), evaluator running", "",
          f"Scheduling `SCHED_FIFO {LATENCY_REALTIME_PRIORITY}`: the predictor with `realtime_priority:={LATENCY_REALTIME_PRIORITY}` "
          "and this harness (standing in for the flight stack that reads the predictions) under SCHED_FIFO; the evaluator "
          "keeps normal scheduling (nice 10). `normal`: every process under the default scheduler. In every run a no-op "
          "rclpy node (`bench/echo_node.py`, same scheduling as the predictor) answers the same inputs beside the "
          "predictor: `echo p99` is the floor of rclpy + Fast DDS + this harness over the same rows *in the same run*, "
          "and `p99 - echo` the predictor's p99 minus it, the median over the runs (the machine is shared: its load "
          f"moves the floor from run to run, not between the two nodes of one run). 400 Hz rows: the run of median p99 "
          f"out of {LATENCY_RUNS}; the last column lists every run's p99 - echo.", "",
          "`math threads`: the nodes' parameter `math_threads` (1: numpy's and scipy's OpenBLAS pools on one thread, "
          "the default; 0: the pools as the libraries start them, one thread per core, as before the parameter).", "",
          "`calibration`: the median of a fixed workload (`bench/common.py` `calibration_ms`) run before that run, the "
          "machine's speed then (0.14-0.26 ms in sessions 40-43, 0.05 ms in session 44).", "",
          "| model | scheduling | math threads | rate | inputs | p50 [ms] | p99 [ms] | echo p99, same run [ms] | "
          "p99 - echo, median of runs [ms] | max [ms] | drops | p99 - echo of each run [ms] | calibration [ms] |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    md += [f"| {r['model']} | {'SCHED_FIFO ' + str(r['realtime_priority']) if r['realtime_priority'] else 'normal'} | "
           f"{'-' if r.get('math_threads') is None else r['math_threads']} | {r['rate_hz']:g} Hz | "
           f"{r['inputs']} | {r['p50_ms']:.2f} | {r['p99_ms']:.2f} | "
           f"{'-' if r.get('echo_p99_ms') is None else format(r['echo_p99_ms'], '.2f')} | "
           f"{'-' if r.get('p99_minus_echo_ms') is None else format(r['p99_minus_echo_ms'], '+.2f')} | "
           f"{r['max_ms']:.2f} | {r['drops']} | "
           f"{', '.join(f'{x:+.2f}' for x in r.get('runs_p99_minus_echo_ms', []))} | "
           f"{'-' if r.get('calibration_median_ms') is None else format(r['calibration_median_ms'], '.3f')} |" for r in lat]
    return md + ["", "Streamed rows only: a warm-start row's prediction exists only once the warm start is complete (then it is "
                 "queued behind the live ones), so it has no per-input latency.", ""]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("--models", default="greybox,narx,physics,hybrid,direct",
                        help=f"predictor models of the latency runs, comma-separated (of {', '.join(MODEL_FILES)})")
    parser.add_argument("--latency-only", action="store_true",
                        help="only the latency runs (results in nodes_latency.{json,md}); no graph or memory runs")
    parser.add_argument("--schedulers", default="fifo,normal", help="latency runs: fifo (SCHED_FIFO), normal, or both")
    parser.add_argument("--math-threads", default="1", help="latency runs: the nodes' math_threads, comma-separated (e.g. 0,1)")
    parser.add_argument("--rates", default="100,400", type=lambda v: [float(x) for x in v.split(",")],
                        help="latency runs: input rates [Hz], comma-separated")
    parser.add_argument("--forecast-only", action="store_true",
                        help="only the receding-horizon runs (results in nodes_forecast.{json,md})")
    parser.add_argument("--memory-wall", type=float, default=None,
                        help="run only the memory test for this many wall seconds (results in nodes_memory.{json,md})")
    args = parser.parse_args()
    load_before = os.getloadavg()  # the machine is shared: the results say how busy it was
    if args.memory_wall:
        with tempfile.TemporaryDirectory() as tmp:
            mem = memory(args.memory_wall, Path(tmp))
        md = ["# Node memory over a long 400 Hz run (predictor + evaluator + replay, rate 0, looped bag)", "",
              f"{mem['wall_s']:g} s wall, {mem['flight_s_replayed']:.0f} s of 400 Hz flight replayed. RSS [MiB] over time:", "",
              "| t [s] | " + " | ".join(mem["names"]) + " |", "|---|" + "---|" * len(mem["names"])]
        md += ["| " + " | ".join(f"{v:.1f}" for v in row) + " |" for row in mem["rss_mib_samples"][::5]]
        md += ["", "Growth after start-up [MiB]: " + ", ".join(f"{k} {v:+.1f}" for k, v in mem["rss_growth_mib_after_startup"].items())]
        write_results("nodes_memory", {"memory": mem}, "\n".join(md))
        return 0
    seconds = 8.0 if args.quick else 20.0
    if args.forecast_only:
        with tempfile.TemporaryDirectory() as tmp:
            costs, keep_up = forecasts(seconds, Path(tmp), args.models.split(","))
        write_results("nodes_forecast", {"forecast_cost": costs, "forecast_400hz": keep_up, "argv": sys.argv[1:],
                                         "load_average_before": load_before},
                      "\n".join(["# Receding-horizon forecasts", "", f"`bench/bench_nodes.py {' '.join(sys.argv[1:])}`; "
                                  f"load average (1 min) {load_before[0]:.2f} before the run.", "",
                                  *forecast_markdown(costs, keep_up)]))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        lat = []
        schedulers = {"fifo": LATENCY_REALTIME_PRIORITY, "normal": 0}
        threads = [int(x) for x in args.math_threads.split(",")]
        for realtime in (schedulers[name] for name in args.schedulers.split(",")):
            for kind in args.models.split(","):
                for rate in args.rates:
                    spec = kind if MODEL_FILES[kind] is None else f"{kind}:{MODEL_FILES[kind](rate, work)}"
                    # the echo node runs beside the predictor in every run (echo_beside): the floor of the same run,
                    # the same inputs at the same moments, whatever the shared machine does meanwhile
                    runs: dict = {n: [] for n in threads}
                    for _ in range(LATENCY_RUNS if rate == 400.0 else 1):
                        for n in threads:
                            runs[n].append(latency(rate, seconds, work, spec, realtime=realtime, math_threads=n, echo_beside=True))
                    for n, group in runs.items():
                        median = dict(sorted(group, key=lambda r: r["p99_ms"])[len(group) // 2])
                        median["runs_p99_ms"] = [r["p99_ms"] for r in group]
                        median["runs_p99_minus_echo_ms"] = [r["p99_ms"] - r["echo_p99_ms"] for r in group]
                        median["p99_minus_echo_ms"] = float(np.median(median["runs_p99_minus_echo_ms"]))
                        lat.append(median)
        if args.latency_only:
            write_results("nodes_latency", {"latency": lat, "argv": sys.argv[1:], "load_average_before": load_before},
                          "\n".join(["# Predictor node latency", "", f"`bench/bench_nodes.py {' '.join(sys.argv[1:])}`; "
                                      f"load average (1 min) {load_before[0]:.2f} before the run.", "",
                                      *latency_markdown(lat)]))
            return 0
        graphs = [throughput(work, executor, run) for run in range(3) for executor in ("events", "single")]
        events = sorted((g for g in graphs if g["executor"] == "events"), key=lambda g: g["samples_per_s"])
        graph = events[len(events) // 2]  # the median run
        mem = memory(40.0 if args.quick else 120.0, work)
    data = {"latency": lat, "graph_rate0": graph, "graph_runs": graphs, "memory": mem}
    md = ["# Node suite benchmarks", "",
          *latency_markdown(lat),
           "## Whole graph at rate 0 (replay + naive + greybox predictors + evaluator, bundled 42 s bag)", "",
          "Three runs per executor, alternated (the machine is noisy): " + ", ".join(
              f"{g['executor']} {g['real_time_factor']:.1f}x" for g in graphs) + ". The median EventsExecutor run:", "",
           f"{graph['samples']} samples ({graph['messages_published']} messages) in {graph['play_s']:.2f} s: "
           f"{graph['samples_per_s']:.0f} samples/s, {graph['messages_per_s']:.0f} replayed messages/s, "
           f"**{graph['real_time_factor']:.1f}x real time**; predictions per model {graph['predictions_per_model']}, "
           f"lost {graph['lost']}; windows {graph['windows']}, marked {graph['marked']}; run-bag total {graph['run_bag_total_s']:.1f} s "
           "(process start-up, discovery and the report included).", "",
           "## Memory, 400 Hz synthetic flight looped at rate 0 (predictor + evaluator + replay)", "",
           f"{mem['wall_s']:g} s wall, {mem['flight_s_replayed']:.0f} s of 400 Hz flight replayed. RSS [MiB] over time:", "",
           "| t [s] | " + " | ".join(mem["names"]) + " |", "|---|" + "---|" * len(mem["names"])]
    md += ["| " + " | ".join(f"{v:.1f}" for v in row) + " |" for row in mem["rss_mib_samples"]]
    md += ["", "Growth after start-up [MiB]: " + ", ".join(f"{k} {v:+.1f}" for k, v in mem["rss_growth_mib_after_startup"].items())]
    write_results("nodes", data, "\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
