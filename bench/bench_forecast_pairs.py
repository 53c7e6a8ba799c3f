"""Per-input cost of the receding-horizon forecast at two revisions, in alternated pairs (issue #28 item 2).

On a shared 2-core machine whose speed moves by up to 2x between runs, two figures taken minutes apart compare the
machine as much as the code. This benchmark checks out two revisions of this repository (temporary ``git worktree``s),
builds each model file once (this checkout's code: the file formats of both revisions must read it), then times
``bench_nodes.forecast_cost`` (carried forms, h = 50 at 400 Hz, a predictor node in-process, 4 s of inputs) of every
model at each revision in a fresh process, alternating which revision goes first, ``--pairs`` times. It reports each
revision's median of the per-run medians and their ratio, and the same of each run's median over a calibration
workload's run before each input (``bench/common.py``: the machine's speed meanwhile; session 40); the runs
themselves are in the JSON.

    python bench/bench_forecast_pairs.py BASE [HEAD] [--models greybox,physics] [--pairs 5] [--name forecast_pairs] [--window]

``--window``: the window mode's answer to an input instead (the thesis's mode, each input's prediction from the
window's live stream: :func:`window_cost`, this file's, run on each revision's node), 4 s of inputs after the warm
start. Issue #28 item 3's share of the predictor (the live step's p99 over DDS is the machine's as much as the model's).

HEAD defaults to this checkout's HEAD. Results: ``bench/results/<name>.{json,md}``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SECONDS = 4.0
"""Inputs per run [s of the 400 Hz synthetic flight]: 1600 inputs, the first 100 left out as bench_nodes does."""


def window_cost(bench_nodes, spec: str, seconds: float, calibrate) -> dict:
    """Per-input cost [ms] of a predictor node in window mode (``window_s`` 10 s: one window) at 400 Hz, in this
    process, as ``bench_nodes.forecast_cost`` times the receding horizon's: each input's measurements handed to the
    node, then its command; the command handler's wall time (the sample pushed through the window's stream, the
    bounds check, the messages published), a calibration workload's run (``calibrate``: ``bench/common.py``'s) before each input. The
    first 0.5 s (the warm start, its rows answered at once) left out."""
    from rclpy.parameter import Parameter

    from quad_modelling.io.topics import stamps_ns
    from quad_modelling.nodes import messages
    from quad_modelling.nodes.predictor_node import PredictorNode

    rate = bench_nodes.FORECAST_RATE_HZ
    log = bench_nodes.synthetic_flight(rate, seconds + 0.5)
    arrays = messages.measurement_messages(log)
    stamps = (stamps_ns(log.t) + 1_000_000_000_000).tolist()
    params = {"vehicle": "crazyflie21", "model": spec, "model_name": spec.partition(":")[0], "sample_period_s": 1.0 / rate, "window_s": 10.0}
    node = PredictorNode(parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    costs, calibration = [], []
    try:
        for row, ns in enumerate(stamps):
            calibration.append(calibrate())
            node.on_odom(arrays.odometry(row, ns))
            node.on_imu(arrays.imu(row, ns))
            motor = arrays.motor(row, ns)
            started = time.perf_counter()
            node.on_motor(motor)
            costs.append(time.perf_counter() - started)
        published, form = node.published, type(node.stream).__name__
    finally:
        node.destroy_node()
    first = int(round(0.5 * rate))
    cost, calibration = [c * 1e3 for c in costs[first:]], calibration[first:]
    return {"median_ms": statistics.median(cost), "forecast_median_ms": float("nan"), "p99_ms": sorted(cost)[int(0.99 * len(cost))],
            "published": published, "form": form, "calibration_median_ms": statistics.median(calibration),
            "relative_median": statistics.median(cost) / statistics.median(calibration)}


def one_run(root: str, spec: str, window: bool = False) -> None:
    """In a fresh process: ``forecast_cost`` of ``spec`` with the code at ``root``; prints its JSON. A revision whose
    ``forecast_cost`` does not run this checkout's ``calibration_ms`` before each input (before session 40's) gets it
    run there, before each input's measurements, as ``forecast_cost`` does."""
    loader = importlib.util.spec_from_file_location("this_checkouts_bench_common", Path(__file__).with_name("common.py"))
    common = importlib.util.module_from_spec(loader)
    loader.loader.exec_module(common)  # before the revision's code goes first on the path
    sys.path.insert(0, root)
    os.chdir(root)
    import rclpy

    from bench import bench_nodes

    calibration: list[float] = []
    if not hasattr(bench_nodes, "calibration_ms"):
        from quad_modelling.nodes.predictor_node import PredictorNode

        on_odom = PredictorNode.on_odom

        def calibrated_on_odom(self, msg):
            calibration.append(common.calibration_ms())
            return on_odom(self, msg)

        PredictorNode.on_odom = calibrated_on_odom
    rclpy.init()
    try:
        result = window_cost(bench_nodes, spec, SECONDS, common.calibration_ms) if window else bench_nodes.forecast_cost(spec, True, SECONDS)
    finally:
        rclpy.shutdown()
    if calibration:
        skipped = int(round(0.2 * bench_nodes.FORECAST_RATE_HZ)) + 20  # forecast_cost's first inputs left out
        result["calibration_median_ms"] = statistics.median(calibration[skipped:])
        result["relative_median"] = result["median_ms"] / result["calibration_median_ms"]
    keys = ("median_ms", "forecast_median_ms", "p99_ms", "published", "calibration_median_ms", "relative_median")
    print(json.dumps({key: result[key] for key in keys}))


def timed(root: Path, spec: str, domain: int, window: bool = False) -> dict:
    env = {**os.environ, "PYTHONPATH": str(root), "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    done = subprocess.run([sys.executable, __file__, "--one", str(root), spec, *(["--window"] if window else [])],
                          capture_output=True, text=True, env=env, cwd=root, timeout=600)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode or not lines:
        raise RuntimeError(f"{root} {spec}: exit {done.returncode}: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(lines[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("base", nargs="?", help="the earlier revision (a commit)")
    parser.add_argument("head", nargs="?", default="HEAD", help="the later revision (default HEAD)")
    parser.add_argument("--models", default="greybox,narx,physics,hybrid,direct")
    parser.add_argument("--pairs", type=int, default=5)
    parser.add_argument("--name", default="forecast_pairs", help="results file name under bench/results")
    parser.add_argument("--window", action="store_true", help="time the window mode's answer to an input (window_cost)")
    parser.add_argument("--one", nargs=2, metavar=("ROOT", "SPEC"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        one_run(*args.one, window=args.window)
        return 0
    if args.base is None:
        parser.error("BASE (a commit) is needed")
    sys.path.insert(0, str(ROOT))  # this checkout's bench (the --one runs import their revision's)
    from bench import bench_nodes
    from bench.common import write_results

    revisions = {name: subprocess.run(["git", "rev-parse", "--short", rev], capture_output=True, text=True, check=True,
                                      cwd=ROOT).stdout.strip() for name, rev in (("base", args.base), ("head", args.head))}
    models = args.models.split(",")
    runs: dict = {model: {"base": [], "head": []} for model in models}
    with tempfile.TemporaryDirectory(prefix="forecast_pairs_") as tmp:
        work = Path(tmp)
        trees = {name: work / name for name in revisions}
        for name, tree in trees.items():
            subprocess.run(["git", "worktree", "add", "--detach", "-q", str(tree), revisions[name]], cwd=ROOT, check=True)
        try:
            specs = {m: m if bench_nodes.MODEL_FILES[m] is None else
                     f"{m}:{bench_nodes.MODEL_FILES[m](bench_nodes.FORECAST_RATE_HZ, work)}" for m in models}
            for pair in range(args.pairs):
                for model in models:
                    for name in ("base", "head") if pair % 2 == 0 else ("head", "base"):
                        runs[model][name].append(timed(trees[name], specs[model], 40 + os.getpid() % 50, args.window))
                        print(f"pair {pair + 1}/{args.pairs} {model} {name}: {runs[model][name][-1]['median_ms']:.3f} ms", flush=True)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=False)
    summary = {}
    for model in models:
        medians = {name: statistics.median(r["median_ms"] for r in runs[model][name]) for name in revisions}
        relative = {name: statistics.median(r["relative_median"] for r in runs[model][name]) for name in revisions}
        calibration = statistics.median(r["calibration_median_ms"] for name in revisions for r in runs[model][name])
        summary[model] = {**{f"{name}_median_ms": value for name, value in medians.items()},
                          "ratio": medians["head"] / medians["base"],
                          **{f"{name}_relative": value for name, value in relative.items()},
                          "relative_ratio": relative["head"] / relative["base"], "calibration_median_ms": calibration}
    timed_what = ("`window_cost` (this file's: window mode, the window's live stream" if args.window else
                  "`bench_nodes.forecast_cost` (carried forms, h = 50")
    md = [f"# {'Window-mode answer' if args.window else 'Forecast cost'} per input at two revisions, alternated pairs ({args.name})", "",
          f"`bench/bench_forecast_pairs.py {' '.join(sys.argv[1:])}`: base {revisions['base']}, head {revisions['head']}; "
          f"{args.pairs} pairs, each run a fresh process timing {timed_what} at "
          f"400 Hz, {SECONDS:g} s of inputs, in-process handler median), the first of each pair alternating. "
          "`relative`: each run's handler median over the median of a fixed workload run before each of its inputs "
          "(`bench/common.py` `calibration_ms`: the machine's speed meanwhile), the median over the runs; `head / base` "
          "of the relatives is the comparison that the machine's changes of speed between runs leave alone.", "",
          "| model | base relative | head relative | **head / base (relative)** | base [ms] | head [ms] | head / base [ms] | "
          "calibration [ms] | base runs [ms] | head runs [ms] |", "|---|---|---|---|---|---|---|---|---|---|"]
    for model in models:
        s = summary[model]
        md.append(f"| {model} | {s['base_relative']:.2f} | {s['head_relative']:.2f} | **{s['relative_ratio']:.2f}** | "
                  f"{s['base_median_ms']:.3f} | {s['head_median_ms']:.3f} | {s['ratio']:.2f} | {s['calibration_median_ms']:.3f} | "
                  + " | ".join(", ".join(f"{r['median_ms']:.2f}" for r in runs[model][name]) for name in ("base", "head")) + " |")
    write_results(args.name, {"revisions": revisions, "pairs": args.pairs, "summary": summary, "runs": runs}, "\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
