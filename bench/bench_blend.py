"""The direct model's and NARX's body rates averaged (issue #28 item 1: a forecast combination, held out by shape).

The direct model (``train --direct``) has the best angular velocity in every fold (AV ratio 0.42-0.57) and NARX the
second best (0.56-0.67, ``bench/results/models.md``); their errors come from different model forms (per-horizon
linear maps of the commands against a recurrent net), so an average may beat both. The blend's body rates are

    ω̂_h = w ω̂_h^direct + (1 − w) ω̂_h^NARX,    h = 1..50,

and its velocity the physics translation of those rates with the direct model's vertical map (as
``bench_controller_oracle.py``'s ``GivenRates``): one scalar w per fold.

w is chosen on the training shapes only: for each held-out shape, the direct model and NARX are trained on four of the
five other shapes and score the fifth (inner leave-one-shape-out, the outer fold's identified vehicle, every
``--stride``-th flying start), and the w of ``WEIGHTS`` with the least inner AV error sum (Σ over starts and h = 1..50
of ‖ω − ω̂_h‖) is the fold's. The held-out shape is then scored by the multi-step protocol
(:func:`~quad_modelling.core.evaluation.multistep.multistep_evaluation`) for the chosen w and, for information only,
every w of ``WEIGHTS`` (a w read off that row would be chosen on the held-out shape).

Run: ``.venv/bin/python -m bench.bench_blend [--data DIR] [--folds B3,B9] [--stride 3]``. Writes
bench/results/blend.json and .md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_command_limit import flying_starts  # noqa: E402
from bench.bench_models import (  # noqa: E402
    CONFIG, SHAPES, SPANS, fold_parser, group_scores, ratio_table, readable_flights, run_cli, shape_of, study_folds,
)
from bench.common import write_results  # noqa: E402
from quad_modelling.core.evaluation.multistep import multistep_evaluation  # noqa: E402
from quad_modelling.core.models import physics  # noqa: E402
from quad_modelling.core.models.direct import HORIZON, load_direct  # noqa: E402
from quad_modelling.core.models.registry import make_model  # noqa: E402
from quad_modelling.core.preprocess import resample_uniform  # noqa: E402
from quad_modelling.core.variables import columns  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402

WEIGHTS = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5)
"""The direct model's weights w tried (1: the direct model alone)."""

RATES = columns(("roll_rate", "pitch_rate", "yaw_rate"))


class Blend:
    """Body rates w · direct + (1 − w) · NARX for h = 1..HORIZON, translated by the direct model's physics with its
    vertical map; a multi-step predictor (``predict_horizons``). Both models' predictions are kept per (segment,
    starts) so every w of a fold costs one rollout."""

    def __init__(self, direct, narx, weight: float, cache: dict):
        self.direct, self.narx, self.weight, self.cache = direct, narx, weight, cache
        self.name = f"blend w={weight:g}"

    def rates(self, segment, starts: np.ndarray, horizon: int) -> np.ndarray:
        key = (id(segment), starts.tobytes(), horizon)
        if key not in self.cache:
            self.cache[key] = (self.direct.predict_horizons(segment, starts, horizon)[..., RATES],
                               self.narx.predict_horizons(segment, starts, horizon)[..., RATES])
        direct, narx = self.cache[key]
        return self.weight * direct + (1.0 - self.weight) * narx

    def predict_horizons(self, segment, starts: np.ndarray, horizon: int) -> np.ndarray:
        starts = np.asarray(starts, dtype=int)
        model = self.direct
        state, disturbance, commands, intervals = model.physics.horizon_inputs(segment, starts, horizon)
        rates = self.rates(segment, starts, horizon)[:, :min(horizon, HORIZON) + 1]
        down = model.vertical.velocities(segment, starts, horizon) if model.vertical is not None else None
        return physics.rollout(model.params, state, disturbance, commands, intervals, True, rates, down)


def train_pair(paths: list[Path], vehicle_file: Path, work: Path, tag: str):
    """(direct model, NARX predictor) trained on ``paths`` with ``vehicle_file``."""
    direct_file, narx_file = work / f"direct_{tag}.npz", work / f"narx_{tag}.npz"
    common = [*map(str, paths), "--vehicle", str(vehicle_file), *SPANS, "--quiet"]
    run_cli(["train", *common, "--direct", "-o", str(direct_file)])
    run_cli(["train", *common, "-o", str(narx_file)])
    vehicle = load_vehicle(str(vehicle_file))
    return load_direct(direct_file, vehicle), make_model(f"narx:{narx_file}", vehicle)


def inner_errors(train_paths: list[Path], flights: dict, vehicle_file: Path, work: Path, stride: int, outer: str) -> np.ndarray:
    """Σ ‖ω − ω̂_h‖ over h = 1..HORIZON and every ``stride``-th flying start of each inner held-out shape, per w."""
    sums = np.zeros(len(WEIGHTS))
    for inner in sorted({shape_of(p) for p in train_paths}):
        direct, narx = train_pair([p for p in train_paths if shape_of(p) != inner], vehicle_file, work, f"{outer}_inner_{inner}")
        cache: dict = {}
        for path in (p for p in train_paths if shape_of(p) == inner):
            log = resample_uniform(flights[path])
            starts = flying_starts(log)[::stride]
            truth = log.gyro_b[starts[:, None] + np.arange(1, HORIZON + 1)[None, :]]
            for k, weight in enumerate(WEIGHTS):
                predicted = Blend(direct, narx, weight, cache).rates(log, starts, HORIZON)[:, 1:]
                sums[k] += float(np.linalg.norm(truth - predicted, axis=2).sum())
    return sums


def fold(shape: str, flights: dict, work: Path, stride: int) -> dict:
    train_paths = [p for p in flights if shape_of(p) != shape]
    vehicle_file = work / f"vehicle_{shape}.yaml"
    run_cli(["identify", *map(str, train_paths), "--vehicle", "crazyflie21", *SPANS, "-o", str(vehicle_file)])
    inner = inner_errors(train_paths, flights, vehicle_file, work, stride, shape)
    chosen = WEIGHTS[int(np.argmin(inner))]
    direct, narx = train_pair(train_paths, vehicle_file, work, shape)
    vehicle = load_vehicle(str(vehicle_file))
    cache: dict = {}
    narx.name = "narx"
    predictors = [make_model("naive", vehicle), narx, *[Blend(direct, narx, w, cache) for w in WEIGHTS]]
    held = [resample_uniform(flights[p]) for p in flights if shape_of(p) == shape]
    table = multistep_evaluation(held, predictors, vehicle, CONFIG, start_stride=stride)
    return {"held_out": shape, "shape": SHAPES[shape], "starts": table["starts"], "inner_av_error": inner.tolist(),
            "chosen_weight": chosen, "scores": group_scores(table)}


def markdown(folds: list[dict], run: str, stride: int) -> str:
    names = [("direct (w = 1)", lambda f: "blend w=1"), ("NARX", lambda f: "narx"),
             ("blend, w chosen on the training shapes", lambda f: f"blend w={f['chosen_weight']:g}")]
    names += [(f"blend w = {w:g} (every fold; for information)", lambda f, w=w: f"blend w={w:g}") for w in WEIGHTS[1:]]
    lines = ["# The direct model's and NARX's body rates averaged (held out by shape)", "",
             f"Generated by `{run}`. ω̂ = w ω̂_direct + (1 − w) ω̂_NARX for h = 1..50, the velocity the direct model's "
             "physics translation of those rates with its vertical map; w chosen per fold by inner leave-one-shape-out "
             f"over the five training shapes (module docstring). SimErr ratio to naive over h = 1..50 on one flying "
             f"start in {stride}. #28's targets: AV <= 0.5 pooled and in five folds of six, Vel <= 0.25 pooled.", "",
             "Chosen w per fold: " + ", ".join(f"{f['held_out']} {f['chosen_weight']:g}" for f in folds) + ".", ""]
    for group, title in (("angular_velocity", "AV ratio"), ("velocity", "Vel ratio")):
        lines += [f"## {title}", ""] + ratio_table(folds, group, names) + [""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = fold_parser(__doc__, "blend")
    parser.add_argument("--stride", type=int, default=3, help="score every N-th start (default 3)")
    args = parser.parse_args(argv)
    flights, skipped = readable_flights(args.data, load_vehicle("crazyflie21"))
    folds, run = study_folds(args, lambda shape, work: fold(shape, flights, work, args.stride), "bench/bench_blend.py")
    write_results(args.output, {"stride": args.stride, "weights": WEIGHTS, "skipped": skipped, "folds": folds},
                  markdown(folds, run, args.stride))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
