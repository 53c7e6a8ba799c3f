"""Would the training data alone have chosen the direct model's inputs? (nested leave-one-shape-out, issue #28 item 1)

Session 20 gave the direct model (:mod:`quad_modelling.core.models.direct`) two anchor inputs (the body velocity
v_B and the physics observer's angular disturbance) and a reweighted refit, chosen among variants scored on the six
held-out shapes of ``bench/bench_models.py``. A choice made on the held-out folds makes their scores optimistic.
This benchmark repeats the choice inside each fold's *training* shapes only: for each held-out shape (outer fold),
the vehicle is identified on the other five shapes, and each variant is scored by leave-one-shape-out over those
five (inner folds: fit on four, score the fifth). The variant with the lowest pooled inner score is the one the
training data would pick; its outer held-out score is what an honest selection gets.

Variants (:data:`VARIANTS`): the session-19 maps (rates and commands, least squares); with v_B and one reweighted
refit; with v_B, the observer's disturbance and the refit (the model ``train --direct`` fits).

Score: the body-rate vector's error norm summed over h = 1..50 and every start of the flying part
(:func:`bench.bench_command_limit.flying_starts`: the same starts for every variant and naive), as a ratio to naive
(holding ω_s). These starts differ slightly from ``bench_models.py``'s protocol starts (their rate history must fit
before the start), so the outer numbers are within about 0.01 of ``models.md``'s.

Run: ``.venv/bin/python bench/bench_direct_inputs.py [--data DIR] [--folds B2,B3]``. Writes
bench/results/direct_inputs.json and .md.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_command_limit import flying_starts  # noqa: E402
from bench.bench_models import SHAPES, SPANS, fold_parser, readable_flights, run_cli, shape_of  # noqa: E402
from bench.common import write_results  # noqa: E402
from quad_modelling.core.models import physics  # noqa: E402
from quad_modelling.core.models.direct import HORIZON, ROBUST_STEPS  # noqa: E402
from quad_modelling.core.training.direct import fit_rate_regression  # noqa: E402
from quad_modelling.core.preprocess import resample_uniform  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.io.reports.formatting import markdown_table  # noqa: E402

VARIANTS = {
    "rates + commands, least squares (session 19)": ((), 0),
    "+ body velocity, reweighted": (("body_velocity",), ROBUST_STEPS),
    "+ body velocity + observer disturbance, reweighted (train --direct)": (("body_velocity", "angular_disturbance"), ROBUST_STEPS),
}
"""name -> (anchor inputs, reweighted refits)."""

FLYING_DROP_S = 5.0
"""Training spans: each flight without its first and last 5 s (take-off, landing), as ``bench_models.py``'s SPANS."""


def flying_spans(logs) -> list[tuple[float, float]]:
    return [(FLYING_DROP_S, float(log.t[-1] - log.t[0]) - FLYING_DROP_S) for log in logs]


def error_sums(regression, logs, disturbance_of) -> tuple[float, float]:
    """(Σ model error norms, Σ naive error norms) over h = 1..H and every flying start of ``logs``."""
    model = naive = 0.0
    for log in logs:
        starts = flying_starts(log)
        disturbance = disturbance_of(log, starts) if "angular_disturbance" in regression.anchor_inputs else None
        predicted = regression.rates(log, starts, HORIZON, disturbance)
        truth = log.gyro_b[starts[:, None] + np.arange(HORIZON + 1)[None, :]]
        model += float(np.linalg.norm(truth[:, 1:] - predicted[:, 1:], axis=2).sum())
        naive += float(np.linalg.norm(truth[:, 1:] - truth[:, :1], axis=2).sum())
    return model, naive


def observer_disturbance(vehicle):
    """(flight, anchors) -> the physics observer's angular disturbance (S, 3) at the anchors, as ``train --direct``."""
    model = physics.PhysicsPredictor(vehicle)

    def disturbance_of(log, anchors):
        return physics.anchor_state(model.params, log, anchors, model.observer)[1].angular_b

    return disturbance_of


def scores(train, test, vehicle) -> dict[str, tuple[float, float]]:
    """variant -> error sums on ``test`` of its maps fitted on ``train`` (the observer's disturbance from ``vehicle``'s
    physics model, as ``train --direct``)."""
    disturbance_of = observer_disturbance(vehicle)
    out = {}
    for name, (inputs, steps) in VARIANTS.items():
        regression = fit_rate_regression(train, flying_spans(train), robust_steps=steps, anchor_inputs=inputs,
                                         angular_disturbance=disturbance_of if "angular_disturbance" in inputs else None)[0]
        out[name] = error_sums(regression, test, disturbance_of)
    return out


def nested_fold(shape: str, logs: dict, work: Path, scores) -> dict:
    """One outer fold: the vehicle identified on the other shapes, ``scores(train, test, vehicle)`` (variant -> (model,
    naive) error sums) summed over the inner leave-one-shape-out folds and on the held-out shape, the pick."""
    paths = [p for p in logs if shape_of(p) != shape]
    vehicle_file = work / f"vehicle_{shape}.yaml"
    run_cli(["identify", *[str(p) for p in paths], "--vehicle", "crazyflie21", *SPANS, "-o", str(vehicle_file)])
    vehicle = load_vehicle(str(vehicle_file))
    inner: dict[str, list[float]] = {}
    for inner_shape in sorted({shape_of(p) for p in paths}):
        train = [logs[p] for p in paths if shape_of(p) != inner_shape]
        test = [logs[p] for p in paths if shape_of(p) == inner_shape]
        for name, (e, n) in scores(train, test, vehicle).items():
            total = inner.setdefault(name, [0.0, 0.0])
            total[0] += e
            total[1] += n
    inner_ratio = {name: e / n for name, (e, n) in inner.items()}
    outer = scores([logs[p] for p in paths], [log for p, log in logs.items() if shape_of(p) == shape], vehicle)
    picked = min(inner_ratio, key=inner_ratio.get)
    return {"held_out": shape, "shape": SHAPES[shape], "inner_ratio": inner_ratio, "picked": picked,
            "outer_sums": {name: list(v) for name, v in outer.items()},
            "outer_ratio": {name: e / n for name, (e, n) in outer.items()}}


def markdown(folds: list[dict], pooled: dict[str, float], names: list[str], run: str, title: str, score: str) -> str:
    """The nested choice's table: inner and outer score of every variant per held-out shape, the pick, pooled."""
    short = {name: f"v{i}" for i, name in enumerate(names)}
    lines = [f"# {title} (nested leave-one-shape-out)", "",
             f"Generated by `{run}`. Per held-out shape: the vehicle identified on the other five, each "
             "variant scored by leave-one-shape-out over those five (inner), the lowest inner score picked, and every "
             f"variant's held-out (outer) score. {score}", "",
             "Variants: " + "; ".join(f"{short[n]} = {n}" for n in names) + ".", ""]
    rows = [[f"{f['held_out']} {f['shape']}", *[f"{f['inner_ratio'][n]:.3f}" for n in names], short[f["picked"]],
             *[f"{f['outer_ratio'][n]:.3f}" for n in names], f"{f['outer_ratio'][f['picked']]:.3f}"] for f in folds]
    rows.append(["pooled", *[""] * len(names), "", *[f"{pooled[n]:.3f}" for n in names],
                 f"{pooled['picked']:.3f}"])
    lines += markdown_table(["held out", *[f"inner {short[n]}" for n in names], "picked",
                             *[f"outer {short[n]}" for n in names], "outer, picked"], rows)
    return "\n".join(lines)


def nested_main(argv: list[str] | None, doc: str, script: str, output: str, scores, names: list[str], title: str, score: str,
                details: dict) -> int:
    """The command line of a nested choice (``--data``, ``--folds``, ``--output``): :func:`nested_fold` with ``scores``
    per held-out shape, then the pooled outer scores (sums over folds) and the results files."""
    parser = fold_parser(doc, output)
    args = parser.parse_args(argv)
    flights, skipped = readable_flights(args.data, load_vehicle("crazyflie21"))
    logs = {path: resample_uniform(log) for path, log in flights.items()}
    work = Path(tempfile.mkdtemp(prefix=f"{output}_"))
    folds = []
    for shape in args.folds.split(","):
        started = time.perf_counter()
        folds.append(nested_fold(shape, logs, work, scores))
        print(f"{shape}: picked {folds[-1]['picked']!r}, outer {folds[-1]['outer_ratio']} ({time.perf_counter() - started:.0f} s)",
              file=sys.stderr, flush=True)
    pooled = {name: sum(f["outer_sums"][name][0] for f in folds) / sum(f["outer_sums"][name][1] for f in folds) for name in names}
    pooled["picked"] = (sum(f["outer_sums"][f["picked"]][0] for f in folds) / sum(f["outer_sums"][f["picked"]][1] for f in folds))
    run = script if args.folds == ",".join(SHAPES) else f"{script} --folds {args.folds}"
    write_results(args.output, {**details, "skipped": skipped, "folds": folds, "pooled_outer": pooled},
                  markdown(folds, pooled, names, run, title, score))
    return 0


def main(argv: list[str] | None = None) -> int:
    return nested_main(argv, __doc__, "bench/bench_direct_inputs.py", "direct_inputs", scores, list(VARIANTS),
                       "Choosing the direct model's inputs on the training shapes only",
                       "AV SimErr ratio to naive over h = 1..50 on the flying starts.",
                       {"variants": {n: {"anchor_inputs": list(i), "robust_steps": s} for n, (i, s) in VARIANTS.items()},
                        "horizon": HORIZON})


if __name__ == "__main__":
    raise SystemExit(main())
