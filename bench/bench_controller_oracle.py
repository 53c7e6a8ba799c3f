"""What an oracle that knows the controller gets (issue #28 item 1: the limit of what the commands explain).

#28 asks for an angular-velocity SimErr ratio <= 0.5 held out by shape, pooled and in five folds of six, and "if the
500 Hz closed loop's fast rate changes are beyond what 100 Hz commands can explain, measure that limit (what an oracle
that knows the controller gets)". The direct model (``train --direct``, :mod:`quad_modelling.core.models.direct`)
reaches 0.488 pooled but 0.573 on the figure-8 (B3) and 0.524 on the trefoil (B9) (``bench/results/models.md``).

The NanoBench flights log the Crazyflie controller's attitude setpoint (CSV columns ``pid_controller_roll`` and
``pid_controller_pitch`` [deg]: the position loop's output, which the attitude and rate loops follow; correlation
0.98 with the estimated attitude). No engine-input model can read it, but an oracle can. The direct model's rate maps
(per horizon h, ridge λ = RATE_RIDGE and one reweighted refit, the same anchor block: 10 rows of body rates, the body
velocity, the observer's angular disturbance) are refitted with one more input each:

* ``commands``: none -- the direct model's own maps (the commands u_{s-10} .. u_{s+h});
* ``+ setpoint history``: the attitude setpoint at rows s-10 .. s and the measured roll and pitch at the anchor
  (causal: what a model subscribed to the setpoint topic could read);
* ``+ setpoint to the target``: the attitude setpoint at every command row s-10 .. s+h and the measured roll and
  pitch at the anchor (the oracle that knows the controller: the reference it follows up to the predicted row);
* ``+ 0.1 s of commands after the target``: the commands of rows s+h+1 .. s+h+10 too (the controller's later
  answers; a command oracle, as ``bench_command_limit.py``'s but linear).

Each fold (as ``bench/bench_models.py``) identifies the vehicle and trains the direct model on the other five shapes;
every variant's maps are fitted on the same training anchors and scored on the held-out shape by the multi-step
protocol (:func:`~quad_modelling.core.evaluation.multistep.multistep_evaluation`, every ``--stride``-th flying start):
AV is the ratio of the rates the maps give, Vel the physics translation of those rates with the direct model's
vertical map (as ``bench_velocity_oracle.py``'s "rates ..., v_D direct" rows).

Run: ``.venv/bin/python -m bench.bench_controller_oracle [--data DIR] [--folds B3,B9] [--stride 3]``. Writes
bench/results/controller_oracle.json and .md.
"""

from __future__ import annotations

import gzip
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_direct_features import Maps  # noqa: E402
from bench.bench_direct_inputs import flying_spans, observer_disturbance  # noqa: E402
from bench.bench_models import CONFIG, SHAPES, SPANS, fold_parser, readable_flights, run_cli, shape_of  # noqa: E402
from bench.common import write_results  # noqa: E402
from quad_modelling.core import frames  # noqa: E402
from quad_modelling.core.evaluation.multistep import multistep_evaluation  # noqa: E402
from quad_modelling.core.models import physics  # noqa: E402
from quad_modelling.core.models.direct import COMMAND_LEAD, HORIZON, RATE_HISTORY, RATE_RIDGE, ROBUST_STEPS, load_direct  # noqa: E402
from quad_modelling.core.models.registry import make_model  # noqa: E402
from quad_modelling.core.preprocess import resample_uniform  # noqa: E402
from quad_modelling.core.training.direct import rate_changes, robust_maps, training_parts  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.io.reports.formatting import markdown_table  # noqa: E402

SETPOINT_COLUMNS = ("pid_controller_roll", "pid_controller_pitch")
"""The Crazyflie controller's attitude setpoint in the NanoBench CSV [deg] (its ``controller`` log group)."""

VARIANTS = {"commands": "none", "+ setpoint history": "history", "+ setpoint to the target": "setpoint",
            "+ 0.1 s of commands after the target": "commands_after"}
"""name -> the added input (module docstring)."""

AFTER = 10
"""Rows of commands after the target row the command oracle sees (0.1 s at 100 Hz)."""


class Setpoints:
    """The attitude setpoint [rad] (roll, pitch) of every flight, read at any times of it (flights are told apart by
    their epoch time base: a segment of a flight is a slice with its own rows)."""

    def __init__(self):
        self.flights: list[tuple[np.ndarray, np.ndarray]] = []

    def add(self, path: Path) -> None:
        with gzip.open(path, "rt") as file:
            header = file.readline().strip().split(",")
            table = np.loadtxt(file, delimiter=",", ndmin=2)
        columns = [header.index(name) for name in SETPOINT_COLUMNS]
        self.flights.append((table[:, 0], np.radians(table[:, columns])))

    def at(self, times: np.ndarray) -> np.ndarray:
        """(N, 2) setpoint at ``times`` [s, epoch] of one flight, linearly interpolated."""
        for t, values in self.flights:
            if t[0] <= times[0] <= t[-1]:
                return np.stack([np.interp(times, t, values[:, k]) for k in range(2)], axis=1)
        raise LookupError(f"no flight holds t = {times[0]:.3f}")


def layout(added: str, setpoints: Setpoints):
    """(features(log, anchors, horizon, disturbance) -> (S, D), anchor block size, inputs per command row)."""
    history, lead = RATE_HISTORY, COMMAND_LEAD

    def features(log, anchors, horizon, disturbance):
        anchors = np.asarray(anchors, dtype=int)
        count, last = len(anchors), len(log) - 1
        past = np.maximum(anchors[:, None] - np.arange(history)[None, :], 0)
        rows = np.clip(anchors[:, None] + np.arange(-lead, horizon + 1)[None, :], 0, last)
        blocks = [log.gyro_b[past].reshape(count, -1),
                  frames.nav_to_body(log.vel_n[anchors], log.euler[anchors]).reshape(count, 3), disturbance]
        per_row = [log.u[rows]]
        if added in ("history", "setpoint"):
            setpoint = setpoints.at(log.t)
            blocks.append(log.euler[anchors][:, :2])
            if added == "history":
                blocks.append(setpoint[np.maximum(anchors[:, None] - np.arange(lead + 1)[None, :], 0)].reshape(count, -1))
            else:
                per_row.append(setpoint[rows])
        if added == "commands_after":
            per_row.append(log.u[np.clip(rows + AFTER, 0, last)])
        return np.concatenate([*blocks, np.concatenate(per_row, axis=2).reshape(count, -1)], axis=1)

    anchor_size = 3 * history + 6 + {"none": 0, "history": 2 + 2 * (lead + 1), "setpoint": 2, "commands_after": 0}[added]
    return features, anchor_size, 4 + {"setpoint": 2, "commands_after": 4}.get(added, 0)


class GivenRates:
    """The direct model's physics translation and vertical map with body rates from a variant's maps; a multi-step
    predictor (``predict_horizons``)."""

    def __init__(self, model, maps, features, name: str):
        self.model, self.maps, self.features, self.name = model, maps, features, name

    def predict_horizons(self, segment, starts: np.ndarray, horizon: int) -> np.ndarray:
        starts = np.asarray(starts, dtype=int)
        state, disturbance, commands, intervals = self.model.physics.horizon_inputs(segment, starts, horizon)
        given = min(horizon, self.maps.horizon)
        rates = np.empty((len(starts), given + 1, 3))
        rates[:, 0] = segment.gyro_b[starts]
        rates[:, 1:] = rates[:, :1] + self.maps.changes(self.features(segment, starts, given, disturbance.angular_b), given)
        down = self.model.vertical.velocities(segment, starts, horizon)
        return physics.rollout(self.model.params, state, disturbance, commands, intervals, True, rates, down)


def fold(shape: str, flights: dict, setpoints: Setpoints, work: Path, stride: int) -> dict:
    """One held-out shape: vehicle and direct model from the other five, every variant's maps fitted there, scored."""
    train_paths = [p for p in flights if shape_of(p) != shape]
    vehicle_file, direct_file = work / f"vehicle_{shape}.yaml", work / f"direct_{shape}.npz"
    run_cli(["identify", *map(str, train_paths), "--vehicle", "crazyflie21", *SPANS, "-o", str(vehicle_file)])
    run_cli(["train", *map(str, train_paths), "--vehicle", str(vehicle_file), *SPANS, "--direct", "--quiet", "-o", str(direct_file)])
    vehicle = load_vehicle(str(vehicle_file))
    model = load_direct(direct_file, vehicle)
    disturbance_of = observer_disturbance(vehicle)
    train = [resample_uniform(flights[p]) for p in train_paths]
    parts = training_parts(train, flying_spans(train), HORIZON, disturbance_of)
    predictors = [make_model("naive", vehicle)]
    for name, added in VARIANTS.items():
        features, anchor_size, per_row = layout(added, setpoints)
        maps = robust_maps(parts, HORIZON, RATE_RIDGE, ROBUST_STEPS, lambda p, f=features: f(p[0], p[1], HORIZON, p[2]),
                           lambda p: rate_changes(p[0], p[1], HORIZON), lambda h, a=anchor_size, r=per_row: a + r * (COMMAND_LEAD + h + 1),
                           lambda w, b, a=anchor_size, r=per_row: Maps(w, b, a, COMMAND_LEAD, r))
        predictors.append(GivenRates(model, maps, features, name))
    held = [resample_uniform(flights[p]) for p in flights if shape_of(p) == shape]
    table = multistep_evaluation(held, predictors, vehicle, CONFIG, start_stride=stride)
    scores = {}
    for name, groups in table["models"].items():
        if name != "naive":
            scores[name] = {group: {key: groups[group][key] for key in ("ratio_sim_err", "sim_err", "naive_sim_err")}
                            for group in ("angular_velocity", "velocity")}
    return {"held_out": shape, "shape": SHAPES[shape], "starts": table["starts"], "scores": scores}


def pooled(folds: list[dict], group: str) -> dict[str, float]:
    """SimErr ratio pooled over every start of every fold (sums weighted by the fold's starts)."""
    return {n: sum(f["scores"][n][group]["sim_err"] * f["starts"] for f in folds)
            / sum(f["scores"][n][group]["naive_sim_err"] * f["starts"] for f in folds) for n in VARIANTS}


def markdown(folds: list[dict], pool: dict[str, dict[str, float]], run: str, stride: int) -> str:
    lines = ["# What an oracle that knows the controller gets (held out by shape)", "",
             f"Generated by `{run}`. The direct model's rate maps refitted with one more input (the Crazyflie "
             "controller's logged attitude setpoint, or later commands; the module docstring), each fold's vehicle, "
             "direct model and maps from the other five shapes; SimErr ratio to naive over h = 1..50 on one flying "
             f"start in {stride}. Vel: the physics translation of those rates with the direct model's vertical "
             "map. #28's targets: AV <= 0.5 pooled and in five folds of six, Vel <= 0.25 pooled. Only the first row "
             "is a model a flight's engine inputs allow.", ""]
    for group, title in (("angular_velocity", "AV ratio"), ("velocity", "Vel ratio")):
        rows = [[n, *[f"{f['scores'][n][group]['ratio_sim_err']:.3f}" for f in folds], f"{pool[group][n]:.3f}"]
                for n in VARIANTS]
        lines += [f"## {title}", ""] + markdown_table(["rate maps' inputs", *[f"{f['held_out']} {f['shape']}" for f in folds],
                                                      "pooled"], rows) + [""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = fold_parser(__doc__, "controller_oracle")
    parser.add_argument("--stride", type=int, default=3, help="score every N-th start (default 3)")
    args = parser.parse_args(argv)
    flights, skipped = readable_flights(args.data, load_vehicle("crazyflie21"))
    setpoints = Setpoints()
    for path in flights:
        setpoints.add(path)
    work = Path(tempfile.mkdtemp(prefix="controller_oracle_"))
    folds = []
    for shape in args.folds.split(","):
        started = time.perf_counter()
        folds.append(fold(shape, flights, setpoints, work, args.stride))
        print(f"{shape}: " + ", ".join(f"{n} {s['angular_velocity']['ratio_sim_err']:.3f} / {s['velocity']['ratio_sim_err']:.3f}"
                                       for n, s in folds[-1]["scores"].items()) + f" ({time.perf_counter() - started:.0f} s)",
              file=sys.stderr, flush=True)
    pool = {group: pooled(folds, group) for group in ("angular_velocity", "velocity")}
    run = "bench/bench_controller_oracle.py" + ("" if args.folds == ",".join(SHAPES) else f" --folds {args.folds}") \
        + ("" if args.stride == 3 else f" --stride {args.stride}")
    write_results(args.output, {"stride": args.stride, "setpoint_columns": SETPOINT_COLUMNS, "after_rows": AFTER,
                                "skipped": skipped, "folds": folds, "pooled": pool}, markdown(folds, pool, run, args.stride))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
