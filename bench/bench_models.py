"""Every model, leave-one-shape-out on the NanoBench flights (issue #16 item 8).

The 17 readable NanoBench Crazyflie 2.1 flights (``../shared/data/nanobench``; ``--data DIR``
overrides) fly six shapes. Each fold holds one shape out (B2 circle, B3 figure8, B5 helix,
B6 linear_ramp, B7 oval, B9 trefoil) and, on the flights of the other five only:

1. identifies the vehicle (``quad-modelling identify``, from the ``crazyflie21`` file);
2. trains each learned model (``quad-modelling train``, ``--hybrid`` for the hybrid) with that vehicle;

then scores every model on the held-out flights with the multi-step (IDSIA) protocol of
``quad-modelling evaluate`` (:func:`~quad_modelling.core.evaluation.multistep.multistep_evaluation`:
every start of the flying part, horizons 1..50, each model by its own ``predict_horizons`` or its
live form). Reported per model, per fold and pooled over folds (MAE pooled over all starts of all
folds, ratio = pooled model SimErr / pooled naive SimErr):

* AV / Vel SimErr ratio to naive (AV = angular velocity, Vel = velocity), MAE at 1, 10, 50 steps;
* training time: wall time of the ``identify`` / ``train`` step the model needs (flights read included);
* inference time per step: median time of one live ``push`` after a ``start_window``.

Models are the :data:`MODELS` list, one line each; a model whose spec the registry does not know
yet (or that has no multi-step form) is listed as not available. Writes bench/results/models.json,
models.md and models_window.png (predicted vs measured over one held-out window).

Run: ``.venv/bin/python -m bench.bench_models [--quick] [--data DIR] [--models naive,...] [--output NAME]``
(``--quick``: 2 folds, 2 training epochs: a smoke run, not numbers to quote).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import RESULTS, SHARED_DATA, write_results  # noqa: E402
from quad_modelling.cli import main as cli  # noqa: E402
from quad_modelling.core.evaluation.multistep import GROUPS, multistep_evaluation  # noqa: E402
from quad_modelling.core.models.registry import make_model  # noqa: E402
from quad_modelling.core.models.streaming import StreamingPredictor, predict_window_by_stream  # noqa: E402
from quad_modelling.core.preprocess import measured_variables, resample_uniform  # noqa: E402
from quad_modelling.core.variables import DISPLAY, INDEX  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.core.windows import EvaluationConfig  # noqa: E402
from quad_modelling.errors import ConfigError, QuadModellingError  # noqa: E402
from quad_modelling.io.reports.formatting import markdown_table  # noqa: E402

NANOBENCH = SHARED_DATA / "nanobench"
SHAPES = {"B2": "circle", "B3": "figure8", "B5": "helix", "B6": "linear_ramp", "B7": "oval", "B9": "trefoil"}
"""Shape prefix of a NanoBench file name -> shape; one fold per shape."""

QUICK_FOLDS = ("B7", "B9")
BASE_VEHICLE = "crazyflie21"
SPANS = ["--preset", "short", "--train", "0%:100%"]
"""Training on the whole flying part of every training flight (drop 5 s / 5 s: take-off and landing)."""

CONFIG = EvaluationConfig.preset("short", train="0%:100%", eval="0%:100%", horizons=(1, 10, 50))
"""Scoring on the whole flying part of every held-out flight (the multi-step protocol's span ``eval``)."""

HORIZONS = CONFIG.horizons
PUSH_STEPS = 400
"""Live pushes timed per model (after one start_window on a held-out flight)."""


@dataclass(frozen=True)
class BenchModel:
    """One row of the benchmark: a name, its spec (``{file}`` = the model file trained in the fold) and the
    ``quad-modelling train`` options that make the file (None: nothing to train beyond ``identify``)."""

    name: str
    spec: str
    train: tuple[str, ...] | None = None
    note: str = ""


MODELS = (
    BenchModel("naive", "naive", note="baseline: the state at the start held"),
    BenchModel("greybox", "greybox", note="linear greybox, the thesis reproduction"),
    BenchModel("physics", "physics"),
    BenchModel("narx", "narx:{file}", ()),
    BenchModel("hybrid", "hybrid:{file}", ("--hybrid",)),
    BenchModel("direct", "direct:{file}", ("--direct",), note="physics with body rates from a direct regression per horizon"),
)
"""Adding a model is one line: its name, spec and the training options (identify's vehicle is passed to both)."""


def fold_parser(doc: str, output: str) -> argparse.ArgumentParser:
    """The command line every leave-one-shape-out study shares: ``--data`` (the NanoBench flights), ``--folds`` (the
    held-out shapes, default all six) and ``--output`` (the results' name); a study adds its own options."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--data", type=Path, default=NANOBENCH)
    parser.add_argument("--folds", default=",".join(SHAPES), help="held-out shapes (default: all six)")
    parser.add_argument("--output", default=output)
    return parser


def group_scores(table: dict, groups: tuple[str, ...] = ("angular_velocity", "velocity")) -> dict:
    """model -> group -> {ratio_sim_err, sim_err, naive_sim_err} of a multi-step table (naive left out)."""
    return {name: {group: {key: entry[group][key] for key in ("ratio_sim_err", "sim_err", "naive_sim_err")} for group in groups}
            for name, entry in table["models"].items() if name != "naive"}


def pooled_ratio(folds: list[dict], group: str, name: str) -> float:
    """SimErr ratio of model ``name`` pooled over every start of ``folds`` (each fold's ``scores`` and ``starts``)."""
    return (sum(f["scores"][name][group]["sim_err"] * f["starts"] for f in folds)
            / sum(f["scores"][name][group]["naive_sim_err"] * f["starts"] for f in folds))


def ratio_table(folds: list[dict], group: str, rows: list[tuple[str, Callable[[dict], str]]], first: str = "model") -> list[str]:
    """Markdown lines: one row per (label, fold -> model name) with its ``group`` ratio per fold and pooled."""
    from quad_modelling.io.reports.formatting import markdown_table

    body = [[label, *[f"{f['scores'][of(f)][group]['ratio_sim_err']:.3f}" for f in folds],
             f"{sum(f['scores'][of(f)][group]['sim_err'] * f['starts'] for f in folds) / sum(f['scores'][of(f)][group]['naive_sim_err'] * f['starts'] for f in folds):.3f}"]
            for label, of in rows]
    return markdown_table([first, *[f"{f['held_out']} {f['shape']}" for f in folds], "pooled"], body)


def study_folds(args: argparse.Namespace, fold: Callable[[str, Path], dict], script: str) -> tuple[list[dict], str]:
    """Run ``fold(shape, work)`` for every shape of ``args.folds`` (a line per fold on stderr); (folds, the command line
    for the results' "Generated by")."""
    work = Path(tempfile.mkdtemp(prefix=Path(script).stem + "_"))
    folds = []
    for shape in args.folds.split(","):
        started = time.perf_counter()
        folds.append(fold(shape, work))
        print(f"{shape}: " + ", ".join(f"{n} {s['angular_velocity']['ratio_sim_err']:.3f} / {s['velocity']['ratio_sim_err']:.3f}"
                                       for n, s in folds[-1]["scores"].items()) + f" ({time.perf_counter() - started:.0f} s)",
              file=sys.stderr, flush=True)
    run = script + ("" if args.folds == ",".join(SHAPES) else f" --folds {args.folds}") \
        + ("" if getattr(args, "stride", 3) == 3 else f" --stride {args.stride}")
    return folds, run


def shape_of(path: Path) -> str:
    return path.name.split("_")[0]


def readable_flights(data: Path, vehicle) -> tuple[dict[Path, object], list[str]]:
    """The NanoBench flights the reader accepts (path -> FlightLog), and one line per refused file."""
    from quad_modelling.errors import DataError
    from quad_modelling.io.loader import load_flight

    flights, skipped = {}, []
    for path in sorted(data.glob("*.csv.gz")):
        try:
            flights[path] = load_flight(path, vehicle)
        except DataError as err:  # B9_trefoil_fast_rep2 logs motor commands far above the PWM range
            skipped.append(str(err))
    return flights, skipped


def run_cli(argv: list[str]) -> float:
    """Run one quad-modelling command quietly; its wall time [s]. RuntimeError with its stderr when it fails."""
    out, err = io.StringIO(), io.StringIO()
    started = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli(argv)
    if code in (130, 143):  # the command was interrupted (SIGINT/SIGTERM): so is the benchmark
        raise KeyboardInterrupt
    if code != 0:
        raise RuntimeError(f"quad-modelling {' '.join(argv[:2])} ... failed: {err.getvalue().strip()}")
    return time.perf_counter() - started


def build(model: BenchModel, vehicle, files: dict[str, Path]):
    """(predictor, None) or (None, why it is not available)."""
    spec = model.spec.format(file=files.get(model.name, ""))
    try:
        predictor = make_model(spec, vehicle)
    except ConfigError as err:
        return None, f"not available: {err}"
    predictor.name = model.name
    return predictor, None


def push_time_s(predictor, flight, warm: int) -> float | None:
    """Median wall time [s] of one live ``push`` over PUSH_STEPS commands of ``flight`` (None without a live form)."""
    if not isinstance(predictor, StreamingPredictor):
        return None
    start = len(flight) // 3
    _, stream = predictor.start_window(flight.slice(start - warm, start))
    times = []
    for row in range(start, start + PUSH_STEPS):
        t0 = time.perf_counter()
        stream.push(flight.u[row])
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run_fold(shape: str, flights: dict[Path, object], work: Path, epochs: int | None, models: tuple[BenchModel, ...],
             stride: int) -> dict:
    """Identify and train on the other shapes, score ``models`` on ``shape``'s flights (every ``stride``-th start)."""
    train_files = [str(p) for p in flights if shape_of(p) != shape]
    test_paths = [p for p in flights if shape_of(p) == shape]
    vehicle_file = work / "vehicle.yaml"
    identify_s = run_cli(["identify", *train_files, "--vehicle", BASE_VEHICLE, *SPANS, "-o", str(vehicle_file)])
    vehicle = load_vehicle(str(vehicle_file))
    files, train_s = {}, {}
    not_available = {m.name: "not run (--models)" for m in MODELS if m not in models}
    for model in models:
        if model.train is None:
            train_s[model.name] = identify_s if model.name != "naive" else 0.0
            continue
        files[model.name] = work / f"{model.name}.npz"
        extra = ["--epochs", str(epochs)] if epochs is not None and model.name == "narx" else []  # NARX pre-training only
        try:
            train_s[model.name] = run_cli(["train", *train_files, "--vehicle", str(vehicle_file), *SPANS, *model.train, *extra,
                                           "--quiet", "-o", str(files[model.name])])
        except RuntimeError as err:
            not_available[model.name] = f"training failed: {err}"
    held_out = [resample_uniform(flights[p]) for p in test_paths]
    predictors = []
    for model in models:
        if model.name in not_available:
            continue
        predictor, why = build(model, vehicle, files)
        if predictor is None:
            not_available[model.name] = why
        else:
            predictors.append(predictor)
    config = CONFIG
    started = time.perf_counter()
    table = multistep_evaluation(held_out, predictors, vehicle, config, start_stride=stride)
    scoring_s = time.perf_counter() - started
    for name, why in (table.get("not_multistep") or {}).items():
        not_available[name] = f"not available: {why}"
    warm = round(config.warm_s * held_out[0].sample_rate)
    push = {p.name: push_time_s(p, held_out[0], warm) for p in predictors if p.name in table["models"]}
    return {"held_out": shape, "shape": SHAPES[shape], "train_flights": [Path(f).name for f in train_files],
            "test_flights": [p.name for p in test_paths], "starts": table["starts"], "multistep": table,
            "train_s": train_s, "push_s": push, "scoring_s": scoring_s, "not_available": not_available,
            "vehicle": str(vehicle_file), "predictors": predictors, "held_out_flights": held_out, "vehicle_config": vehicle}


def pooled(folds: list[dict]) -> dict:
    """MAE per model and group pooled over every start of every fold; ratios of the pooled SimErr to naive's."""
    out = {}
    names = [m.name for m in MODELS]
    for name in names:
        done = [f for f in folds if name in f["multistep"]["models"]]
        if not done:
            continue
        starts = sum(f["starts"] for f in done)
        entry = {"folds": len(done), "starts": starts}
        for group in GROUPS:
            def mean(key, h=None, model=name, group=group):
                values = [f["multistep"]["models"][model][group][key] if h is None else f["multistep"]["models"][model][group][key][h]
                          for f in done]
                return sum(v * f["starts"] for v, f in zip(values, done)) / starts
            sim_err, naive = mean("sim_err"), mean("naive_sim_err")
            entry[group] = {"mae": {str(h): mean("mae", str(h)) for h in HORIZONS}, "sim_err": sim_err,
                            "ratio_sim_err": sim_err / naive if naive > 0 else None}
        out[name] = entry
    return out


def _ratio(entry: dict, group: str) -> str:
    ratio = entry[group]["ratio_sim_err"]
    return "-" if ratio is None else f"{ratio:.3g}"


def markdown(folds: list[dict], pool: dict, skipped: list[str], run: str, figure: str = "models_window.png") -> str:
    lines = ["# Every model, leave-one-shape-out (NanoBench, Crazyflie 2.1)", "",
             f"Generated by `bench/bench_models.py{run}`. "
             "Each fold identifies the vehicle and trains the learned models on the flights of five shapes and scores the "
             "sixth (multi-step protocol: every start of the flying part, horizons 1..50, each model causal by its own "
             "predict_horizons or its live form). Ratio = model SimErr / naive SimErr (< 1 beats holding the state); "
             "AV = angular velocity [rad/s], Vel = velocity [m/s]. Pooled = MAE over all starts of all folds.", ""]
    strides = {f["multistep"].get("start_stride", 1) for f in folds}
    if strides != {1}:
        lines += [f"Starts: every {', '.join(map(str, sorted(strides)))}-th start only (--stride), not every start.", ""]
    if skipped:
        lines += [f"Flights refused by the reader: {'; '.join(skipped)}", ""]
    lines += ["## Pooled over folds", ""]
    rows = []
    for m in MODELS:
        if m.name not in pool:
            reasons = sorted({f["not_available"].get(m.name, "") for f in folds} - {""})
            rows.append([m.name, "not available", "", "", "", "", "", "", "; ".join(reasons)[:160]])
            continue
        e = pool[m.name]
        av, vel = e["angular_velocity"], e["velocity"]
        train = statistics.mean(f["train_s"][m.name] for f in folds if m.name in f["train_s"])
        push = [f["push_s"][m.name] for f in folds if f["push_s"].get(m.name) is not None]
        rows.append([m.name, _ratio(e, "angular_velocity"), _ratio(e, "velocity"),
                     " / ".join(f"{av['mae'][str(h)]:.3g}" for h in HORIZONS),
                     " / ".join(f"{vel['mae'][str(h)]:.3g}" for h in HORIZONS),
                     f"{train:.1f}", f"{statistics.median(push) * 1e6:.2g}" if push else "-", str(e["folds"]), m.note])
    lines += markdown_table(["model", "AV ratio", "Vel ratio", "AV MAE@1/10/50", "Vel MAE@1/10/50", "train [s]",
                             "step [us]", "folds", "note"], rows)
    lines += ["", "train = mean wall time of the fold's `identify` (naive: none; greybox/physics: identify) or `train` run, "
              "flights read included; step = median live push after start_window.", "", "## Per fold (held-out shape)", ""]
    rows = []
    for f in folds:
        for m in MODELS:
            e = f["multistep"]["models"].get(m.name)
            if e is None:
                rows.append([f"{f['held_out']} {f['shape']}", m.name, "not available", "", "", ""])
                continue
            rows.append([f"{f['held_out']} {f['shape']}", m.name, _ratio(e, "angular_velocity"), _ratio(e, "velocity"),
                         f"{e['angular_velocity']['mae']['1']:.3g} / {e['velocity']['mae']['1']:.3g}", str(f["starts"])])
    lines += markdown_table(["held out", "model", "AV ratio", "Vel ratio", "MAE@1 AV / Vel", "starts"], rows)
    lines += ["", f"![predicted vs measured]({figure})", ""]
    return "\n".join(lines)


WINDOW_S = 2.0
FIGURE_VARIABLES = ("vel_x", "vel_y", "vel_z", "roll_rate", "pitch_rate", "yaw_rate")


def window_figure(fold: dict, path: Path) -> None:
    """Measured vs every model over one held-out window: each model's live form from the window's warm start."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    flight = fold["held_out_flights"][0]
    rows = int(round(WINDOW_S * flight.sample_rate))
    start = len(flight) // 2
    window = flight.slice(start, start + rows)
    warm = round(CONFIG.warm_s * flight.sample_rate)
    measured = measured_variables(window)
    t = window.t - window.t[0]
    predicted = {p.name: predict_window_by_stream(p, window, warm) for p in fold["predictors"] if isinstance(p, StreamingPredictor)}
    fig, axes = plt.subplots(3, 2, figsize=(10, 8), sharex=True)
    styles = ["k:", "r--", "c-.", "m--", "g-."]
    for ax, var in zip(axes.T.ravel(), FIGURE_VARIABLES):
        unit, factor = DISPLAY[var]
        col = INDEX[var]
        ax.plot(t, measured[:, col] * factor, "b-", lw=1.6, label="measured")
        for k, (name, values) in enumerate(predicted.items()):
            ax.plot(t, values[:, col] * factor, styles[k % len(styles)], lw=1.1, label=name)
        ax.axvline(t[warm - 1], color="0.6", lw=0.8)
        span = np.ptp(measured[:, col] * factor)
        mid = np.mean(measured[:, col] * factor)
        ax.set_ylim(mid - 2 * span - 1e-3, mid + 2 * span + 1e-3)  # keep the measurement readable when a model runs away
        ax.set_ylabel(f"{var} [{unit}]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper left")
    for ax in axes[-1]:
        ax.set_xlabel("time in window [s]")
    fig.suptitle(f"held-out {fold['shape']} ({fold['test_flights'][0]}), {WINDOW_S:g} s from t = {window.t[0] - flight.t[0]:.1f} s; "
                 f"models from the fold trained without {fold['shape']}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=NANOBENCH, help=f"NanoBench directory (default {NANOBENCH})")
    parser.add_argument("--quick", action="store_true", help="2 folds, 2 training epochs: a smoke run")
    parser.add_argument("--epochs", type=int, help="training epochs of the learned models (default: train's own)")
    parser.add_argument("--folds", help=f"held-out shapes, comma-separated (default all: {','.join(SHAPES)})")
    parser.add_argument("--models", help=f"models to run, comma-separated (default all: {','.join(m.name for m in MODELS)})")
    parser.add_argument("--stride", type=int, default=1, help="score every N-th start only (default 1: every start, the protocol)")
    parser.add_argument("--output", default="models",
                        help="results name: bench/results/NAME.{json,md} and NAME_window.png (default models; give another "
                             "for a run of some models or folds, so the full table is not overwritten)")
    args = parser.parse_args(argv)
    names = args.models.split(",") if args.models else [m.name for m in MODELS]
    models = tuple(m for m in MODELS if m.name in names)
    unknown = sorted(set(names) - {m.name for m in MODELS} | ({"naive"} - set(names)))
    if unknown or args.stride < 1:
        print(f"bench_models: --models must name known models and include naive (bad: {unknown}); --stride >= 1", file=sys.stderr)
        return 2
    if not args.data.is_dir() or not any(args.data.glob("*.csv.gz")):
        print(f"bench_models: no NanoBench flights (*.csv.gz) in {args.data}; pass --data DIR", file=sys.stderr)
        return 2
    epochs = 2 if args.quick and args.epochs is None else args.epochs
    flights, skipped = readable_flights(args.data, load_vehicle(BASE_VEHICLE))
    shapes = [s for s in SHAPES if any(shape_of(p) == s for p in flights)]
    if args.quick or args.folds:
        chosen = args.folds.split(",") if args.folds else QUICK_FOLDS
        shapes = [s for s in shapes if s in chosen]
    folds = []
    with tempfile.TemporaryDirectory(prefix="bench_models_") as tmp:
        for shape in shapes:
            work = Path(tmp) / shape
            work.mkdir()
            try:
                fold = run_fold(shape, flights, work, epochs, models, args.stride)
            except (QuadModellingError, RuntimeError) as err:
                print(f"bench_models: fold {shape} failed: {err}", file=sys.stderr)
                return 1
            print(f"fold {shape} {SHAPES[shape]}: {fold['starts']} starts, scored in {fold['scoring_s']:.1f} s", file=sys.stderr)
            folds.append(fold)
        pool = pooled(folds)
        RESULTS.mkdir(parents=True, exist_ok=True)
        window_figure(folds[-1], RESULTS / f"{args.output}_window.png")
    data = {
        "quick": args.quick, "epochs": epochs, "start_stride": args.stride, "data": str(args.data), "flights": len(flights), "skipped": skipped,
        "models": [{"name": m.name, "spec": m.spec, "train": m.train} for m in MODELS],
        "pooled": pool,
        "folds": [{k: v for k, v in f.items() if k not in ("predictors", "held_out_flights", "vehicle_config", "vehicle")}
                  for f in folds],
    }
    run = "".join(f" {a}" for a in (argv if argv is not None else sys.argv[1:]))
    write_results(args.output, data, markdown(folds, pool, skipped, run, f"{args.output}_window.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
