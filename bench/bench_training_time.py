"""`quad-modelling train --hybrid` on every NanoBench flight: wall time, where it goes, accuracy next to it (#28 item 7).

Target: the hybrid trains in under 120 s on all 18 NanoBench flights on the 2-core machine.

1. ``quad-modelling identify`` on every flight (``--vehicle crazyflie21 --preset short``) once: the physics base the
   hybrid is trained on (a command of its own; its time is reported, not counted in the training's).
2. ``quad-modelling train FLIGHTS --vehicle IDENTIFIED --preset short --hybrid -o MODEL`` as a user runs it (a whole
   process: start-up, reading the CSV files, training, writing), ``--runs`` times per training span: the preset's
   (0 %:60 % of the flying part, the command's default) and the whole flying part (``--train 0%:100%``, what each
   fold of ``bench_models.py`` trains on). With ``--baseline DIR`` (a checkout of another commit, run with this
   venv and ``PYTHONPATH=DIR``) the two checkouts alternate, so a load change hits both alike.
   Per run: wall time, CPU time (user + system of the process: less noisy than wall time on a shared machine),
   the 1-minute load average before and after, and from the model file's training record where the time went:
   preparing the training segments (rotor speeds, observer, statistics), the Adam steps, the validation losses;
   the rest of the wall time is start-up, reading the flights and writing the model.
3. The accuracy the time is bought with: the hybrid's (and the physics model's) held-out SimErr ratios by shape,
   read from a ``bench_models.py --models naive,physics,hybrid --output NAME`` run of this checkout (``--accuracy``)
   and of the baseline (``--accuracy-baseline``); they are not re-measured here (20-40 min on 2 cores). ``--render``
   re-reads them into an existing training_time.json (a bench_models run that ends after the timing).

Writes bench/results/training_time.{json,md}.

Run: ``.venv/bin/python -m bench.bench_training_time [--runs 3] [--baseline DIR --label main@abc1234]
[--accuracy bench/results/models.json] [--accuracy-baseline FILE] [--render]``
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.common import RESULTS, SHARED_DATA, write_results  # noqa: E402
from quad_modelling.io.reports.formatting import markdown_table  # noqa: E402

NANOBENCH = SHARED_DATA / "nanobench"
TARGET_S = 120.0
"""Issue #28 item 7: the hybrid's training on all 18 NanoBench flights, 2 cores."""

SPANS = {"preset short (0%:60%)": ["--preset", "short"], "whole flying part (0%:100%)": ["--preset", "short", "--train", "0%:100%"]}
"""Training spans timed: the command's default with --preset short, and bench_models' (every fold's) span."""

TRAINED = re.compile(r"trained hybrid model on (\d+) samples of (\d+) flight\(s\)(?: and their \d+ mirror images)? in ([0-9.]+) s")


def command(checkout: Path, argv: list[str]) -> tuple[list[str], dict]:
    """The quad-modelling command line running ``checkout``'s package, and its environment."""
    return [sys.executable, "-m", "quad_modelling.cli", *argv], {**os.environ, "PYTHONPATH": str(checkout)}


def run_timed(checkout: Path, argv: list[str]) -> dict:
    """One process: wall and CPU seconds, load averages before/after, its stdout."""
    cmd, env = command(checkout, argv)
    load_before = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=checkout, capture_output=True, text=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"quad-modelling {argv[0]} failed ({done.returncode}): {done.stderr.strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "load_before": load_before, "load_after": os.getloadavg()[0], "stdout": done.stdout}


def model_record(path: Path) -> dict:
    """The training record of a hybrid model file (JSON header; no pickle)."""
    with np.load(path, allow_pickle=False) as contents:
        return json.loads(str(contents["header"]))["training"]


def train_run(checkout: Path, flights: list[str], vehicle: Path, span: list[str], output: Path) -> dict:
    """Time one ``train --hybrid`` and split its wall time into phases (module docstring)."""
    run = run_timed(checkout, ["train", *flights, "--vehicle", str(vehicle), *span, "--hybrid", "--quiet", "-o", str(output), "--force"])
    match = TRAINED.search(run.pop("stdout"))
    record = model_record(output)
    rollout = record["rollout"]
    training_s = float(match.group(3)) if match else float("nan")
    prepare = record.get("prepare_seconds")  # absent in checkouts before this benchmark
    validation = rollout.get("validation_seconds")
    phases = {"start-up, reading, writing": run["wall_s"] - training_s}
    if prepare is not None and validation is not None:
        phases.update({"segments and statistics": prepare, "Adam steps": rollout["seconds"] - validation, "validation": validation})
    else:
        phases["training (not split: older checkout)"] = training_s
    return {**run, "training_s": training_s, "samples": int(match.group(1)) if match else None,
            "flights": int(match.group(2)) if match else None, "phases": phases, "epochs_run": rollout["epochs_run"],
            "best_epoch": rollout["best_epoch"], "stopped_early": rollout["stopped_early"],
            "val_loss_best": rollout["val_loss"][rollout["best_epoch"]], "config": record.get("config", {}).get("rollout")}


def summary(runs: list[dict]) -> dict:
    """Medians of the runs (wall, CPU, each phase) and the load range."""
    phases = {k: statistics.median(r["phases"][k] for r in runs) for k in runs[0]["phases"]}
    loads = [r[k] for r in runs for k in ("load_before", "load_after")]
    return {"runs": len(runs), "wall_s": statistics.median(r["wall_s"] for r in runs), "cpu_s": statistics.median(r["cpu_s"] for r in runs),
            "wall_s_all": [round(r["wall_s"], 1) for r in runs], "phases_s": phases, "load_min": min(loads), "load_max": max(loads),
            "epochs": sorted({f"{r['best_epoch']}/{r['epochs_run']}" for r in runs}), "val_loss_best": runs[0]["val_loss_best"]}


def accuracy(path: Path | None) -> dict | None:
    """Pooled and per-fold SimErr ratios of hybrid and physics from a bench_models JSON (None: not given or absent)."""
    if path is None or not path.is_file():
        return None
    data = json.loads(path.read_text())
    out = {"file": str(path.relative_to(REPO) if path.is_relative_to(REPO) else path), "date": data.get("date"),
           "start_stride": data.get("start_stride"), "pooled": {}, "folds": {}}
    for name in ("physics", "hybrid"):
        if name in data["pooled"]:
            e = data["pooled"][name]
            out["pooled"][name] = {g: e[g]["ratio_sim_err"] for g in ("angular_velocity", "velocity")}
    for fold in data["folds"]:
        models = fold["multistep"]["models"]
        out["folds"][fold["held_out"]] = {name: {g: models[name][g]["ratio_sim_err"] for g in ("angular_velocity", "velocity")}
                                          for name in ("physics", "hybrid") if name in models}
        out["folds"][fold["held_out"]]["hybrid_train_s"] = fold["train_s"].get("hybrid")
    return out


def _pair(entry: dict | None, model: str) -> str:
    return "-" if not entry or model not in entry else f"{entry[model]['angular_velocity']:.3f} / {entry[model]['velocity']:.3f}"


def accuracy_lines(baseline: dict | None, this: dict | None, label: str) -> list[str]:
    """The by-shape accuracy table: physics and hybrid of the baseline's and this checkout's bench_models runs."""
    runs = [(name, acc) for name, acc in ((label, baseline), ("this", this)) if acc is not None]
    if not runs:
        return ["No by-shape accuracy given (--accuracy FILE of a bench_models run).", ""]
    lines = ["## Accuracy: held-out SimErr ratio to naive by shape (AV / Vel)", ""]
    for name, acc in runs:
        stride = acc["start_stride"]
        lines.append(f"- {name}: `{acc['file']}` ({acc['date']}; bench_models leave-one-shape-out, "
                     f"{'every start' if stride == 1 else f'every {stride}-th start'}).")
    lines.append("")
    header = ["held out"] + [f"{model} ({name})" for name, _ in runs for model in ("physics", "hybrid")]
    header += [f"hybrid train [s] ({name}, fold of 14-16 flights)" for name, _ in runs]
    rows = [["pooled", *(_pair(acc["pooled"], m) for _, acc in runs for m in ("physics", "hybrid")), *("" for _ in runs)]]
    for shape in runs[0][1]["folds"]:
        folds = [acc["folds"].get(shape) for _, acc in runs]
        rows.append([shape, *(_pair(f, m) for f in folds for m in ("physics", "hybrid")),
                     *(f"{f['hybrid_train_s']:.0f}" if f and f.get("hybrid_train_s") else "-" for f in folds)])
    lines += markdown_table(header, rows)
    lines += ["", "The folds' training times are those of the bench_models runs, under their load (not a timing).", ""]
    return lines


def markdown(data: dict) -> str:
    lines = ["# Hybrid training time on every NanoBench flight (issue #28 item 7)", "",
             f"Generated by `bench/bench_training_time.py{data['argv']}` on {data['cpus']} cores. "
             f"`quad-modelling train <{data['flights']} NanoBench flights> --vehicle <identified> --preset short [--train 0%:100%] "
             f"--hybrid` as a user runs it (a whole process), {data['runs']} run(s) per span and checkout, median; "
             f"the vehicle identified once before (`identify --vehicle crazyflie21 --preset short`: {data['identify_s']:.1f} s wall, "
             "not counted). Target: under 120 s.", ""]
    rows = []
    for label, by_checkout in data["spans"].items():
        for checkout, s in by_checkout.items():
            rows.append([label, checkout, f"**{s['wall_s']:.1f}**", f"{s['cpu_s']:.1f}", ", ".join(f"{w:g}" for w in s["wall_s_all"]),
                         f"{s['load_min']:.1f}-{s['load_max']:.1f}", " ".join(s["epochs"]), f"{s['val_loss_best']:.4f}",
                         "yes" if s["wall_s"] < TARGET_S else "no"])
    lines += markdown_table(["span", "checkout", "wall [s]", "CPU [s]", "runs [s]", "load average", "best/run epochs",
                             "val loss", "< 120 s"], rows)
    lines += ["", "Load average: the 1-minute load before and after each run (2 cores; other work on the machine slows "
              "a run by about the load above 1). CPU = user + system time of the process.", "", "## Where the time goes (medians)", ""]
    rows = []
    for label, by_checkout in data["spans"].items():
        for checkout, s in by_checkout.items():
            rows.append([label, checkout, "; ".join(f"{k} {v:.1f}" for k, v in s["phases_s"].items())])
    lines += markdown_table(["span", "checkout", "phases [s]"], rows)
    lines += ["", "Segments and statistics: the training flights' gap-free parts with rotor speeds, the observer's disturbance "
              "at every row, the net's input statistics and scales. Adam steps: the rollouts through the torch twin and their "
              "gradients. Validation: the loss on the held-back flights after every epoch (and before the first).", ""]
    lines += accuracy_lines(data.get("accuracy_baseline"), data.get("accuracy"), data.get("baseline") or "baseline")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=NANOBENCH, help=f"NanoBench directory (default {NANOBENCH})")
    parser.add_argument("--runs", type=int, default=3, help="runs per span and checkout (median; default 3)")
    parser.add_argument("--baseline", type=Path, help="a checkout of the baseline commit (git worktree add DIR REV)")
    parser.add_argument("--label", default="baseline", help="what the baseline is (e.g. main@abc1234)")
    parser.add_argument("--accuracy", type=Path, default=RESULTS / "models.json",
                        help="bench_models JSON of this checkout (--models naive,physics,hybrid --output NAME)")
    parser.add_argument("--accuracy-baseline", type=Path, help="bench_models JSON of the baseline")
    parser.add_argument("--render", action="store_true",
                        help="no timing: re-read the accuracy files into the existing training_time.json and rewrite the .md")
    args = parser.parse_args(argv)
    if args.render:
        data = json.loads((RESULTS / "training_time.json").read_text())
        data["measured"] = data.get("measured") or data.get("date")
        data["accuracy"] = accuracy(args.accuracy)
        if args.accuracy_baseline is not None:
            data["accuracy_baseline"] = accuracy(args.accuracy_baseline)
        for key in ("benchmark", "machine", "date"):
            data.pop(key, None)
        write_results("training_time", data, markdown(data))
        return 0
    flights = sorted(str(p) for p in args.data.glob("*.csv.gz"))
    if not flights or args.runs < 1:
        print(f"bench_training_time: no NanoBench flights (*.csv.gz) in {args.data} (--data DIR), or --runs < 1", file=sys.stderr)
        return 2
    checkouts = {"this": REPO, **({args.label: args.baseline.resolve()} if args.baseline else {})}
    with tempfile.TemporaryDirectory(prefix="bench_training_time_") as tmp:
        vehicle = Path(tmp) / "crazyflie21_identified.yaml"
        identify = run_timed(REPO, ["identify", *flights, "--vehicle", "crazyflie21", "--preset", "short", "-o", str(vehicle)])
        spans = {}
        for label, span in SPANS.items():
            runs = {name: [] for name in checkouts}
            for i in range(args.runs):
                for name, checkout in reversed(checkouts.items()):  # baseline first, then this, alternating
                    runs[name].append(train_run(checkout, flights, vehicle, span, Path(tmp) / f"hybrid_{name}.npz"))
                    print(f"{label} {name} run {i + 1}: {runs[name][-1]['wall_s']:.1f} s wall", file=sys.stderr, flush=True)
            spans[label] = {name: summary(r) for name, r in runs.items()}
            spans[label]["_runs"] = runs
    data = {"argv": "".join(f" {a}" for a in (argv if argv is not None else sys.argv[1:])), "cpus": os.cpu_count(),
            "flights": len(flights), "runs": args.runs, "target_s": TARGET_S, "identify_s": identify["wall_s"],
            "baseline": args.label if args.baseline else None,
            "spans": {label: {k: v for k, v in s.items() if k != "_runs"} for label, s in spans.items()},
            "all_runs": {label: s["_runs"] for label, s in spans.items()},
            "accuracy": accuracy(args.accuracy), "accuracy_baseline": accuracy(args.accuracy_baseline)}
    write_results("training_time", data, markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
