"""The physics-base diagnosis on REAL held-out flights, with known answers injected (issue #26 items 6 and 1).

Folds by shape (never tuned to one split): for each fold one NanoBench shape's flights are the held-out ``--test``
flights and the medium and fast flights of the other shapes (:data:`TRAIN_SHAPES`) the ``--train`` flights
(``../shared/data/nanobench``, vehicle ``crazyflie21``; files the reader refuses are skipped and listed, as in
``bench_models.py``). Per fold the diagnosis runs as ``quad-modelling diagnose --train ... --test ...
[--inject SPEC]`` runs it (:func:`~quad_modelling.core.diagnosis.physics_base.diagnose_physics` with the CLI's
``PHYSICS_CONFIG``, every flight's commands changed by
:meth:`~quad_modelling.core.diagnosis.injection.Injection.apply`, compared by
:func:`~quad_modelling.core.diagnosis.injection.injection_checks`): un-injected, then with each of
:data:`INJECTIONS`. ``none`` is run again in full (what a user gets: the same answer twice).

Reported per fold and injection: the effects found, the checks (delay rise vs MS +- 5 ms, the motor's relative
command gain ratio vs K +- 5 %, the swap named by the motor-order check, nothing newly found), the held-out J
(base -> final), the velocity and angular-velocity SimErr ratios to naive, the wall time, and the sparse-regression
comparison (:mod:`bench.sindy_selection`: PySINDy STLSQ over the same candidate columns on the same training
flights).

Writes bench/results/diagnose_real.json and .md. Run (about 15 min per fold on a loaded 2-core machine):
``nice -n 10 .venv/bin/python -m bench.bench_diagnose_real [--folds B2,B3,B5] [--injections LIST]``
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import RESULTS, SHARED_DATA, write_results  # noqa: E402
from bench.sindy_selection import HEADLINE, agreement, sindy_for  # noqa: E402
from quad_modelling.commands.diagnose import PHYSICS_CONFIG  # noqa: E402
from quad_modelling.core.diagnosis.injection import injection_checks, parse_injection, relative_gain  # noqa: E402
from quad_modelling.core.diagnosis.physics_base import CANDIDATES, diagnose_physics  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.errors import DataError  # noqa: E402

NANOBENCH = SHARED_DATA / "nanobench"
VEHICLE = "crazyflie21"
FOLDS = ("B2", "B3", "B5")
"""Held-out shapes (circle, figure8, helix): each has slow, medium and fast flights."""
TRAIN_SHAPES = ("B2", "B3", "B5", "B7", "B9")
"""Shapes whose medium and fast flights train (the held-out one excepted); B6 linear_ramp has no speed label."""
EXCLUDED = {"B9_trefoil_fast_rep2": "motors 2 and 4 logged at the PWM ceiling 65535 (saturated), 12.5 s long; the brief "
                                   "and bench_models.py count it refused, the reader of this tree accepts it"}
"""Readable files left out of every fold, with the reason."""
INJECTIONS = ("delay:20", "gain:1:1.25", "gain:3:0.8", "swap:1:2", "none")


def readable(paths: list[Path], vehicle) -> tuple[list, list[str]]:
    """The flights the reader accepts, and one line per refused file (B9_trefoil_fast_rep2's commands are far above
    the PWM range)."""
    from quad_modelling.io.loader import load_flight

    flights, refused = [], []
    for path in paths:
        try:
            flights.append(load_flight(path, vehicle))
        except DataError as err:
            refused.append(str(err))
    return flights, refused


def fold_flights(shape: str, data: Path = NANOBENCH) -> tuple[list[Path], list[Path]]:
    """(train, test) files of the fold holding ``shape`` out (module docstring)."""
    files = [p for p in sorted(data.glob("*.csv.gz")) if p.name.removesuffix(".csv.gz") not in EXCLUDED]
    test = [p for p in files if p.name.startswith(shape + "_")]
    train = [p for p in files if p.name.split("_")[0] in TRAIN_SHAPES and p.name.split("_")[0] != shape
             and ("_medium_" in p.name or "_fast_" in p.name)]
    return train, test


def run_summary(result, seconds: float) -> dict:
    steps = [{"on_top_of": s["on_top_of"], "best": s["best"], "joined": s["joined"],
              "shrink": {c: round(t["shrink"], 4) for c, t in s["trials"].items()}} for s in result.steps]
    return {"found": result.found, "J_base": result.base.score.j, "J_final": result.final.score.j,
            "ratio_base": result.base.score.ratios(), "ratio_final": result.final.score.ratios(),
            "delay_s": result.summary["delay_s"], "motor_command_gains": result.summary["motor_command_gains"],
            "motor_order": result.motor_order, "selection": steps, "dropped_shrink": result.dropped,
            "texts": {c: e.get("text") for c, e in result.effects.items()}, "seconds": seconds}


def diagnose_case(train, test, vehicle, injection, label: str) -> tuple[object, dict]:
    say = (lambda m: print(f"  [{label}] {m}", file=sys.stderr, flush=True))
    began = time.perf_counter()
    if injection is not None:
        train = [injection.apply(f) for f in train]
        test = [injection.apply(f) for f in test]
    result = diagnose_physics(train, test, vehicle, PHYSICS_CONFIG, CANDIDATES, progress=say)
    seconds = time.perf_counter() - began
    summary = run_summary(result, seconds)
    summary["sindy"] = sindy_for(train, vehicle, PHYSICS_CONFIG, result.base.fit, result.candidates)
    return result, summary


def check_text(check: dict) -> str:
    """One cell: the measured value against the expected, and by how much it misses."""
    if check["check"] == "the delay stays (its change)":
        return f"delay moves {check['measured_s'] * 1000:+.1f} ms (exp. 0 +- 5)"
    if "measured_s" in check:
        miss = check["measured_s"] - check["expected_s"]
        return f"rise {check['measured_s'] * 1000:.1f} ms (exp. {check['expected_s'] * 1000:.0f} +- 5; {miss * 1000:+.1f})"
    if "measured" in check and "expected" in check and "tolerance" in check:
        return f"ratio {check['measured']:.3f} (exp. {check['expected']:g} +- 5 %; {check['measured'] / check['expected'] - 1:+.1%})"
    if "named" in check:
        return f"named {check['named']} (exp. {check['expected']})"
    return f"newly found: {', '.join(check['newly_found']) or 'nothing'}"


def markdown(folds: list[dict], refused: list[str], wall: float, wall_label: str = "Whole bench") -> str:
    lines = ["# Diagnosis on real held-out flights, with known answers injected (physics base)", "",
             f"NanoBench Crazyflie 2.1 flights, vehicle `{VEHICLE}`; per fold one shape's flights held out (`--test`), "
             f"the medium and fast flights of the other shapes of {', '.join(TRAIN_SHAPES)} train. Each row is one "
             "`diagnose` run as the CLI runs it (injection applied to train and test flights; checks against the "
             "fold's un-injected run). J = mean over velocity and angular velocity of SimErr / naive SimErr "
             "(h = 1..50) on the held-out flights. SINDy: PySINDy STLSQ over the same candidate columns on the same "
             f"training rows (threshold {HEADLINE:g} on standardised coefficients; `bench/sindy_selection.py`).", ""]
    if refused:
        lines += [f"Refused by the reader (skipped): {'; '.join(refused)}", ""]
    lines += [f"Left out: {'; '.join(f'{k}: {v}' for k, v in EXCLUDED.items())}.", ""]
    total = passed = 0
    for fold in folds:
        lines += [f"## Fold: hold out {fold['shape']} ({len(fold['test'])} test, {len(fold['train'])} train flights)", "",
                  f"train: {', '.join(fold['train'])}; test: {', '.join(fold['test'])}", "",
                  "| run | found | checks | passed | J base -> final | vel / AV ratio base -> final | delay ms | gains | SINDy selects | s |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for run in fold["runs"]:
            s = run["summary"]
            checks = "; ".join(check_text(c) for c in run["checks"]["checks"]) if run.get("checks") else ""
            ok = "" if not run.get("checks") else ("yes" if run["checks"]["passed"] else "**NO**")
            if run.get("checks"):
                total += 1
                passed += run["checks"]["passed"]
            rb, rf = s["ratio_base"], s["ratio_final"]
            gains = " ".join(f"{g:.3f}" for g in s["motor_command_gains"]["value"])
            lines.append(
                f"| {run['spec']} | {', '.join(s['found']) or 'nothing'} | {checks} | {ok} | {s['J_base']:.4f} -> {s['J_final']:.4f} "
                f"({1 - s['J_final'] / s['J_base']:.1%}) | {rb['velocity']:.3f} / {rb['angular_velocity']:.3f} -> "
                f"{rf['velocity']:.3f} / {rf['angular_velocity']:.3f} | {s['delay_s']['value'] * 1000:.1f} +- "
                f"{s['delay_s']['sigma'] * 1000:.1f} | {gains} | {', '.join(s['sindy']['headline']) or 'nothing'} | {s['seconds']:.0f} |")
        lines.append("")
    lines += [f"Injection checks passed: **{passed} of {total}** fold x injection runs. {wall_label} {wall / 60:.1f} min "
              f"({os.getloadavg()[0]:.1f} load average at the end; folds in parallel processes on this 2-core machine).", ""]
    lines += ["SINDy selection at every threshold (standardised STLSQ), and the diagnosis's selection:", "",
              "| fold | run | diagnose found | " + " | ".join(f"STLSQ {t}" for t in folds[0]["runs"][0]["summary"]["sindy"]["selected"]) + " |",
              "|---|---|---|" + "---|" * len(folds[0]["runs"][0]["summary"]["sindy"]["selected"])]
    for fold in folds:
        for run in fold["runs"]:
            s = run["summary"]
            lines.append(f"| {fold['shape']} | {run['spec']} | {', '.join(s['found']) or 'nothing'} | "
                         + " | ".join(", ".join(v) or "nothing" for v in s["sindy"]["selected"].values()) + " |")
    lines += ["", agreement([(r["summary"]["found"], r["summary"]["sindy"]) for f in folds for r in f["runs"]])]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folds", default=",".join(FOLDS))
    parser.add_argument("--injections", default=",".join(INJECTIONS))
    parser.add_argument("--jobs", type=int, default=1, help="folds run in parallel processes")
    parser.add_argument("--data", type=Path, default=NANOBENCH, help="NanoBench folder (default ../shared/data/nanobench)")
    parser.add_argument("--reuse-plain", metavar="TAG", help="take each fold's un-injected run from its saved partial file "
                        "(an earlier run of this bench) and save these runs as partial/diagnose_real_<fold>_<TAG>.json")
    parser.add_argument("--assemble", action="store_true", help="write the results from the saved partial files")
    args = parser.parse_args(argv)
    if args.assemble:
        return assemble(args.folds.split(","), args.data)
    if not args.data.is_dir():
        print(f"no NanoBench data at {args.data}: pass --data DIR", file=sys.stderr)
        return 2
    if importlib.util.find_spec("pysindy") is None:  # needed after each fold's first diagnosis, minutes in
        print("bench_diagnose_real: pysindy is not installed: .venv/bin/pip install -r bench/requirements-bench.txt",
              file=sys.stderr)
        return 2
    began = time.perf_counter()
    shapes = args.folds.split(",")
    injections = args.injections.split(",")
    folds = []
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = {shape: pool.submit(run_fold, shape, injections, args.data, args.reuse_plain) for shape in shapes}
        for shape in shapes:  # in fold order; results so far written, so a stopped run still leaves numbers
            folds.append(futures[shape].result())
            refused = sorted({r for f in folds for r in f["refused"]})
            data = {"folds": folds, "refused": refused, "excluded": EXCLUDED, "vehicle": VEHICLE, "candidates": list(CANDIDATES),
                    "jobs": args.jobs, "wall_s": time.perf_counter() - began, "complete": len(folds) == len(shapes)}
            write_results("diagnose_real", _finite(data), markdown(folds, refused, time.perf_counter() - began))
    return 0


def run_fold(shape: str, injections: list[str], data: Path = NANOBENCH, reuse_plain: str | None = None) -> dict:
    """One fold: the un-injected run and every injection (module docstring). A module-level function: a worker task.
    ``reuse_plain``: the un-injected run read from the fold's partial file (its summary is all the checks compare)."""
    vehicle = load_vehicle(VEHICLE)
    train_paths, test_paths = fold_flights(shape, data)
    train, refused = readable(train_paths, vehicle)
    test, refused_test = readable(test_paths, vehicle)
    print(f"fold {shape}: {len(train)} train, {len(test)} test", file=sys.stderr, flush=True)
    if reuse_plain:
        import json

        plain_summary = json.loads((RESULTS / "partial" / f"diagnose_real_{shape}.json").read_text())[0]["summary"]
        plain_checked = plain_summary
        runs = []
    else:
        plain, plain_summary = diagnose_case(train, test, vehicle, None, f"{shape} un-injected")
        plain_checked = plain.summary
        runs = [{"spec": "un-injected", "summary": plain_summary}]
        _save_partial(shape, runs)
    for spec in injections:
        injection = parse_injection(spec, len(vehicle.motors))
        injected, summary = diagnose_case(train, test, vehicle, injection, f"{shape} {spec}")
        checks = injection_checks(injection, plain_checked, injected.summary)
        if injection.kind == "gain":
            summary["relative_gain"] = {
                "plain": relative_gain(plain_checked["motor_command_gains"]["value"], injection.motor),
                "injected": relative_gain(injected.summary["motor_command_gains"]["value"], injection.motor)}
        runs.append({"spec": spec, "summary": summary, "checks": checks})
        _save_partial(shape + (f"_{reuse_plain}" if reuse_plain else ""), runs)
        print(f"  {shape} {spec}: passed={checks['passed']} {checks['checks']}", file=sys.stderr, flush=True)
    return {"shape": shape, "train": [f.meta.source for f in train], "test": [f.meta.source for f in test],
            "refused": refused + refused_test, "runs": _finite(runs)}


def assemble(shapes: list[str], data: Path = NANOBENCH) -> int:
    """bench/results/diagnose_real.json and .md from the partial files of ``shapes`` (the fold's own runs first, then
    any ``_<TAG>`` files of --reuse-plain runs; a spec run twice is kept once, and whether the two agree is recorded)."""
    import json

    folder = RESULTS / "partial"
    folds = []
    for shape in shapes:
        main_file = folder / f"diagnose_real_{shape}.json"
        if not main_file.exists():
            continue
        runs = json.loads(main_file.read_text())
        for extra in sorted(folder.glob(f"diagnose_real_{shape}_*.json")):
            for run in json.loads(extra.read_text()):
                twin = next((r for r in runs if r["spec"] == run["spec"]), None)
                if twin is None:
                    runs.append(run)
                else:
                    twin["rerun_agrees"] = twin["summary"]["found"] == run["summary"]["found"] and twin["checks"]["passed"] == run["checks"]["passed"]
        order = ["un-injected", *INJECTIONS]
        runs.sort(key=lambda r: order.index(r["spec"]) if r["spec"] in order else len(order))
        train_paths, test_paths = fold_flights(shape, data)
        folds.append({"shape": shape, "train": [p.name for p in train_paths], "test": [p.name for p in test_paths],
                      "runs": runs, "refused": []})
    missing = {f["shape"]: [s for s in INJECTIONS if s not in {r["spec"] for r in f["runs"]}] for f in folds}
    wall = sum(r["summary"]["seconds"] for f in folds for r in f["runs"])
    data = {"folds": folds, "excluded": EXCLUDED, "vehicle": VEHICLE, "candidates": list(CANDIDATES),
            "not_run": missing, "diagnose_seconds_sum": wall}
    text = markdown(folds, [], wall, "Sum of the diagnosis runs' wall times")
    reruns = [(f["shape"], r["spec"], r["rerun_agrees"]) for f in folds for r in f["runs"] if "rerun_agrees" in r]
    if reruns:
        text += ("\n\nRun twice (separate processes), same found effects and check outcome: "
                 + "; ".join(f"{shape} {spec}: {'yes' if same else 'NO'}" for shape, spec, same in reruns) + "\n")
    if any(missing.values()):
        text += "\n\nNot run before the deadline: " + "; ".join(f"{k}: {', '.join(v)}" for k, v in missing.items() if v) + "\n"
    write_results("diagnose_real", _finite(data), text)
    return 0


def _save_partial(shape: str, runs: list[dict]) -> None:
    """The fold's runs so far (bench/results/partial/diagnose_real_<shape>.json): numbers survive a stopped run."""
    import json

    folder = RESULTS / "partial"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"diagnose_real_{shape}.json").write_text(json.dumps(_finite(runs), indent=1) + "\n")


def _finite(value):
    """JSON without NaN/inf (as null) and numpy scalars as floats."""
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


if __name__ == "__main__":
    sys.exit(main())
