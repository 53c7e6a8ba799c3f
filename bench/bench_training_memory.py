"""Training on fleets: peak memory and time of NARX, hybrid and physics identification against the number of flights.

Each case runs the real command (``quad-modelling train``, ``train --hybrid``, ``identify``) in a child
process on N flights and records the child's peak resident set (``ru_maxrss`` of :func:`os.wait4`), wall
and CPU time (user + system). N = 3 and 12 NanoBench flights (the first N by name), with the ratio
12/3 of the peak RSS (issue #19: at most 1.15), and N = 100: the 18 NanoBench files plus 82 simulated
flights of the same vehicle (``quad-modelling simulate`` flies ``crazyflie21``: 42 s, seeds 1..82, default
effects; written once as MCAP bags into a temporary directory or ``--fleet-dir``). Training is kept
short (``--rollout-epochs 2``); the series-parallel pre-training and the validation run in full.

``--code DIR`` runs the commands from another checkout of the package (e.g. the commit before the
streaming, for the before column) and ``--label NAME`` names the run; the results of every label are
kept in ``bench/results/training_memory.json`` and tabulated side by side in ``training_memory.md``.
``--quality`` instead runs bench_models' leave-one-shape-out fold :data:`QUALITY_FOLD` (identify, train NARX
and hybrid with their defaults, score the held-out shape) with that code, ``--narx-seeds 1,2,3`` NARX with
several seeds on the same fold (the seed-to-seed spread).

Run: .venv/bin/python bench/bench_training_memory.py [--label after] [--code DIR] [--counts 3,12,100]
     [--quality | --narx-seeds S,S,...]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import RESULTS, SHARED_DATA, write_results  # noqa: E402

NANOBENCH = SHARED_DATA / "nanobench"
VEHICLE = "crazyflie21"
SIM_DURATION_S = 42.0
FLEET = 100
CASES = {
    "narx": ["train", "--preset", "short", "--rollout-epochs", "2", "--quiet"],
    "hybrid": ["train", "--hybrid", "--preset", "short", "--rollout-epochs", "2", "--quiet"],
    "identify": ["identify", "--vehicle", VEHICLE, "--preset", "short", "--skip-bad"],
}
OUTPUT_SUFFIX = {"narx": ".npz", "hybrid": ".npz", "identify": ".yaml"}


def simulated_flights(directory: Path, count: int) -> list[Path]:
    """``count`` simulated crazyflie21 flights as MCAP bags in ``directory`` (seeds 1..count)."""
    from tqdm import tqdm

    from quad_modelling.core.effect_names import SIM_DEFAULT_EFFECTS
    from quad_modelling.core.sim.simulate import run_simulation
    from quad_modelling.io.bag_io import write_bag

    paths = []
    for seed in tqdm(range(1, count + 1), desc="simulating the fleet", unit="flight", disable=not sys.stderr.isatty()):
        path = directory / f"sim_{VEHICLE}_seed{seed}"
        if not path.exists():
            write_bag(run_simulation(VEHICLE, SIM_DEFAULT_EFFECTS, seed, SIM_DURATION_S).log, path)
        paths.append(path)
    return paths


def run_case(case: str, flights: list[Path], code: Path, work: Path) -> dict:
    """Run one case in a child process reaped by ``os.wait4`` (its own rusage, not the running maximum of all
    children): peak RSS [MiB], wall and CPU time [s], the command's summary lines."""
    output = work / f"{case}_{len(flights)}{OUTPUT_SUFFIX[case]}"
    verb, *options = CASES[case]
    command = [sys.executable, "-m", "quad_modelling.cli", verb, *map(str, flights), *options, "-o", str(output), "--force"]
    env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"}
    log = work / f"{case}_{len(flights)}.log"
    started = time.perf_counter()
    with open(log, "w") as stream:
        child = subprocess.Popen(command, cwd=work, env=env, stdout=stream, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - started
    text = log.read_text()
    if child.returncode != 0:
        raise RuntimeError(f"{case} on {len(flights)} flights failed ({child.returncode}):\n{text[-3000:]}")
    return {"flights": len(flights), "peak_rss_mib": round(usage.ru_maxrss / 1024, 1), "wall_s": round(wall, 1),
            "cpu_s": round(usage.ru_utime + usage.ru_stime, 1),
            "output": [line.split(" -> ")[0] for line in text.splitlines()
                       if line.startswith(("trained", "rollout", "physics model constants"))]}


QUALITY_FOLD = "B7"
"""Held-out shape of the quality check (B7 oval): identify and train on the other five shapes' flights."""

QUALITY_SCRIPT = """
import json, sys, tempfile
from pathlib import Path
from bench.bench_models import MODELS, pooled, readable_flights, run_fold, BASE_VEHICLE
from quad_modelling.core.vehicle import load_vehicle
shape, stride, data = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3])
flights, _ = readable_flights(data, load_vehicle(BASE_VEHICLE))
models = tuple(m for m in MODELS if m.name in ("naive", "physics", "narx", "hybrid"))
with tempfile.TemporaryDirectory() as tmp:
    fold = run_fold(shape, flights, Path(tmp), None, models, stride)
pool = pooled([fold])
print(json.dumps({"held_out": shape, "stride": stride, "starts": fold["starts"], "train_s": fold["train_s"],
                  "ratio": {m: {g: e[g]["ratio_sim_err"] for g in ("angular_velocity", "velocity")} for m, e in pool.items()},
                  "mae_1": {m: {g: e[g]["mae"]["1"] for g in ("angular_velocity", "velocity")} for m, e in pool.items()}}))
"""
"""Run in a child with the chosen code: bench_models' fold (identify, train NARX and hybrid with their defaults, score
the held-out shape with the multi-step protocol), SimErr ratios to naive and MAE at one step per model."""


SEEDS_SCRIPT = """
import json, sys, tempfile
from pathlib import Path
from bench.bench_models import CONFIG, SPANS, BASE_VEHICLE, readable_flights, run_cli, shape_of
from quad_modelling.core.evaluation.multistep import multistep_evaluation
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.preprocess import resample_uniform
from quad_modelling.core.vehicle import load_vehicle
shape, stride, data, seeds = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3]), [int(s) for s in sys.argv[4].split(",")]
vehicle = load_vehicle(BASE_VEHICLE)
flights, _ = readable_flights(data, vehicle)
train = [str(p) for p in flights if shape_of(p) != shape]
held_out = [resample_uniform(flights[p]) for p in flights if shape_of(p) == shape]
predictors = []
with tempfile.TemporaryDirectory() as tmp:
    for seed in seeds:
        path = Path(tmp) / f"narx{seed}.npz"
        run_cli(["train", *train, "--vehicle", BASE_VEHICLE, *SPANS, "--seed", str(seed), "--quiet", "-o", str(path)])
        predictor = make_model(f"narx:{path}", vehicle)
        predictor.name = f"seed {seed}"
        predictors.append(predictor)
    table = multistep_evaluation(held_out, predictors, vehicle, CONFIG, start_stride=stride)
print(json.dumps({"held_out": shape, "stride": stride, "starts": table["starts"],
                  "ratio": {p.name: {g: table["models"][p.name][g]["ratio_sim_err"] for g in ("angular_velocity", "velocity")}
                            for p in predictors}}))
"""
"""Run in a child with the chosen code: NARX trained with each seed (``train``'s defaults) on the other shapes and
scored on the held-out one: the seed-to-seed spread that a change of rounding in training falls within."""


def seed_spread(code: Path, stride: int, seeds: str) -> dict:
    """:data:`SEEDS_SCRIPT` run with the package at ``code``."""
    env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", SEEDS_SCRIPT, QUALITY_FOLD, str(stride), str(NANOBENCH), seeds], cwd=code,
                          env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"seed spread failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def quality(code: Path, stride: int) -> dict:
    """The leave-one-shape-out fold :data:`QUALITY_FOLD` of bench_models run with the package at ``code``."""
    env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", QUALITY_SCRIPT, QUALITY_FOLD, str(stride), str(NANOBENCH)], cwd=code, env=env,
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"quality fold failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _rss(rows: list[dict], flights: int) -> float | None:
    return next((r["peak_rss_mib"] for r in rows if r["flights"] == flights), None)


def table(runs: dict) -> str:
    """Markdown: one row per (case, flights), one column group per label."""
    labels = list(runs)
    head = "| case | flights | " + " | ".join(f"{l}: peak RSS MiB | {l}: wall s | {l}: CPU s" for l in labels) + " |"
    lines = [head, "|" + "---|" * (2 + 3 * len(labels))]
    keys = sorted({(c, r["flights"]) for run in runs.values() for c, rows in run["cases"].items() for r in rows},
                  key=lambda k: (list(CASES).index(k[0]), k[1]))
    for case, n in keys:
        cells = []
        for label in labels:
            row = next((r for r in runs[label]["cases"].get(case, []) if r["flights"] == n), None)
            cells += ["-"] * 3 if row is None else [f"{row['peak_rss_mib']:.0f}", f"{row['wall_s']:.1f}", f"{row['cpu_s']:.1f}"]
        lines.append(f"| {case} | {n} | " + " | ".join(cells) + " |")
    lines += ["", "Peak RSS ratio 12 / 3 flights (target <= 1.15):", ""]
    for label in labels:
        ratios = ", ".join(f"{case} {value:.3f}" for case, value in runs[label].get("ratio_12_over_3", {}).items())
        lines.append(f"- {label} (code {runs[label].get('code', '?')}, {runs[label].get('date', '?')}): {ratios}")
    return "\n".join(lines)


def quality_table(runs: dict) -> str:
    """Markdown: the quality fold's SimErr ratios to naive (AV / Vel) and MAE at one step per label and model."""
    rows = [(label, run["quality"]) for label, run in runs.items() if "quality" in run]
    if not rows:
        return ""
    lines = ["", "", f"Quality: leave-one-shape-out fold {QUALITY_FOLD} held out (bench_models' protocol, every "
                     f"{rows[0][1]['stride']}-th start, {rows[0][1]['starts']} starts); SimErr ratio to naive AV / Vel, "
                     "MAE@1 AV [rad/s] / Vel [m/s]; training time [s]:", "",
             "| run | model | ratio AV | ratio Vel | MAE@1 AV | MAE@1 Vel | train s |", "|---|---|---|---|---|---|---|"]
    for label, q in rows:
        for model, r in q["ratio"].items():
            if model == "naive":
                continue
            m = q["mae_1"][model]
            lines.append(f"| {label} | {model} | {r['angular_velocity']:.4f} | {r['velocity']:.4f} | "
                         f"{m['angular_velocity']:.5f} | {m['velocity']:.5f} | {q['train_s'].get(model, 0):.0f} |")
    seeds = [(label, run["narx_seeds"]) for label, run in runs.items() if "narx_seeds" in run]
    if seeds:
        lines += ["", f"NARX seed to seed, the same fold ({seeds[0][1]['starts']} starts): SimErr ratio to naive AV / Vel per seed, "
                      "and the mean:", ""]
        for label, q in seeds:
            av = [r["angular_velocity"] for r in q["ratio"].values()]
            vel = [r["velocity"] for r in q["ratio"].values()]
            each = ", ".join(f"{name.split()[-1]}: {r['angular_velocity']:.3f} / {r['velocity']:.3f}" for name, r in q["ratio"].items())
            lines.append(f"- {label}: {each}; mean {np.mean(av):.3f} / {np.mean(vel):.3f} "
                         f"(range AV {min(av):.3f}-{max(av):.3f}, Vel {min(vel):.3f}-{max(vel):.3f})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--label", default="after", help="name of this run in the results (default after)")
    parser.add_argument("--code", type=Path, default=ROOT, help="checkout whose quad_modelling the commands run (default this one)")
    parser.add_argument("--code-name", help="name of --code's version in the results (default: its git commit)")
    parser.add_argument("--counts", default=f"3,12,{FLEET}", help="numbers of flights (default 3,12,100)")
    parser.add_argument("--cases", default=",".join(CASES), help="cases (default narx,hybrid,identify)")
    parser.add_argument("--quality", action="store_true",
                        help=f"instead: the quality check (leave {QUALITY_FOLD} out, bench_models' scoring) of --code")
    parser.add_argument("--narx-seeds", metavar="S,S,...",
                        help="instead: NARX trained with these seeds on the quality fold (seed-to-seed spread) with --code")
    parser.add_argument("--stride", type=int, default=5, help="quality check: score every N-th start (default 5)")
    parser.add_argument("--fleet-dir", type=Path, help="directory for the simulated flights (default: a temporary one)")
    args = parser.parse_args(argv)
    nanobench = sorted(NANOBENCH.glob("*.csv.gz"))
    if len(nanobench) < 12:
        print(f"needs the NanoBench flights in {NANOBENCH}", file=sys.stderr)
        return 1
    if args.narx_seeds:
        measured = seed_spread(args.code.resolve(), args.stride, args.narx_seeds)
        previous = stored_runs()
        previous.setdefault(args.label, {"cases": {}})["narx_seeds"] = measured
        return save(previous, len(nanobench))
    if args.quality:
        measured = quality(args.code.resolve(), args.stride)
        previous = stored_runs()
        previous.setdefault(args.label, {"cases": {}})["quality"] = measured
        return save(previous, len(nanobench))
    counts = [int(c) for c in args.counts.split(",")]
    cases = args.cases.split(",")
    with tempfile.TemporaryDirectory(prefix="training_memory_") as tmp:
        work = Path(tmp)
        fleet_dir = args.fleet_dir or work / "fleet"
        fleet_dir.mkdir(parents=True, exist_ok=True)
        sim = simulated_flights(fleet_dir, max(counts) - len(nanobench)) if max(counts) > len(nanobench) else []
        flights = nanobench + sim
        results: dict[str, list] = {case: [] for case in cases}
        for case in cases:
            for n in counts:
                row = run_case(case, flights[:n], args.code.resolve(), work)
                print(f"{args.label} {case} {n} flights: {row['peak_rss_mib']:.0f} MiB, {row['wall_s']:.1f} s wall, "
                      f"{row['cpu_s']:.1f} s CPU", flush=True)
                results[case].append(row)
    git = args.code_name or code_version(args.code)
    previous = stored_runs()  # read now: another label may have been written meanwhile
    run = previous.setdefault(args.label, {"cases": {}})
    for case, rows in results.items():  # a run of some counts keeps the label's rows of the others
        kept = [r for r in run["cases"].get(case, []) if r["flights"] not in counts]
        run["cases"][case] = sorted(kept + rows, key=lambda r: r["flights"])
    run.update(code=git, date=time.strftime("%Y-%m-%d %H:%M"))
    run["ratio_12_over_3"] = {case: round(_rss(rows, 12) / _rss(rows, 3), 3) for case, rows in run["cases"].items()
                              if _rss(rows, 3) and _rss(rows, 12)}
    return save(previous, len(nanobench))


def code_version(code: Path) -> str:
    """The short commit of the checkout at ``code``, with "+changes" when its package differs from that commit."""
    head = subprocess.run(["git", "-C", str(code), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        return code.name
    dirty = subprocess.run(["git", "-C", str(code), "diff", "--quiet", "HEAD", "--", "quad_modelling"]).returncode != 0
    return head.stdout.strip() + ("+changes" if dirty else "")


def stored_runs() -> dict:
    """The runs of every label in bench/results/training_memory.json (empty when there is none)."""
    path = RESULTS / "training_memory.json"
    return json.loads(path.read_text()).get("runs", {}) if path.exists() else {}


def save(runs: dict, nanobench: int) -> int:
    """Write training_memory.{json,md} with every label's ``runs``."""
    flights_note = (f"3 and 12: the first NanoBench flights by name; {FLEET}: the {nanobench} NanoBench flights and "
                    f"{FLEET - nanobench} simulated {VEHICLE} flights ({SIM_DURATION_S:g} s, seeds 1..{FLEET - nanobench}, "
                    f"default effects)")
    markdown = ("# Training on fleets: peak RSS and time against the number of flights\n\n"
                f"Commands: `quad-modelling {' '.join(CASES['narx'])}`, `{' '.join(CASES['hybrid'])}`, "
                f"`{' '.join(CASES['identify'])}`; peak RSS of the child process (os.wait4), one torch thread. "
                f"Flights: {flights_note}.\n\n" + table(runs) + quality_table(runs))
    write_results("training_memory", {"flights": flights_note, "runs": runs}, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
