"""How much of a real Crazyflie's body rates do its logged 100 Hz commands explain? (issue #28 item 1's limit)

Issue #28 asks for a model at half of naive on angular velocity (SimErr ratio <= 0.5) held out by shape, or a
measure of the limit when the closed loop's fast rate changes are beyond what the logged commands explain. This
benchmark measures that limit on the NanoBench flights with *direct* predictors, which need no model of the vehicle:
for each horizon h, a regression from what is known at the start s to the change of the measured body rates,

.. math::

    \\Delta\\hat\\omega(s, h) = f_h\\big(\\omega_{s-9}, \\dots, \\omega_s,\\ u_{s-L}, \\dots, u_{s+h+F}\\big) \\approx \\omega_{s+h} - \\omega_s

(ω the gyro's body rates [rad/s, FRD]; u the four logged motor commands, normalised; L = :data:`COMMAND_LEAD`
rows before the start). Three forms, each trained on the five other shapes and scored on the held-out one:

* ``linear, causal`` (F = 0): ridge regression, the commands up to the target row;
* ``MLP, causal`` (F = 0): a 2 x 64 tanh MLP on the same inputs: a causal predictor any model could be;
* ``MLP, oracle`` (F = :data:`ORACLE_AFTER`): the same MLP also sees the commands of the 0.1 s *after* the
  target row. The controller computes those from the rates at and after the target, so this oracle learns the
  controller from data and inverts it: the most the logged commands can tell about the rates.

Scores: MAE_h of the rate vector's error norm over every start of the held-out flights' flying part (the same starts
for every form and naive), and SimErr = the trapezoid over :data:`HORIZONS` in h of MAE_h (the protocol's SimErr
sums every h = 1..50; here 11 horizons stand for them), as a ratio to naive's on the same starts. The physics, NARX
and hybrid ratios of ``bench/results/models.json`` (the protocol's starts) are quoted beside them.

Velocity: how far the physics model's translation gets if the body rates were known
(:func:`velocity_with_measured_rates`: the measured rates given at every step of its rollout), next to the physics
model as it predicts and the direct model (``models.json``).

Run: ``.venv/bin/python -m bench.bench_command_limit [--data DIR] [--folds B2,B3] [--seed N]``. Writes
bench/results/command_limit.json and .md.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_models import CONFIG, SHAPES, fold_parser, readable_flights, shape_of  # noqa: E402
from bench.common import RESULTS, write_results  # noqa: E402
from quad_modelling.core.preprocess import resample_uniform  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.core.windows import span_segments  # noqa: E402
from quad_modelling.io.reports.formatting import markdown_table  # noqa: E402

HORIZONS = (1, 2, 3, 5, 7, 10, 15, 20, 30, 40, 50)
"""Horizons [rows of 10 ms] with a regression each; SimErr is their trapezoid in h."""
RATE_HISTORY = 10
"""Measured body-rate rows up to and including the start (0.1 s)."""
COMMAND_LEAD = 10
"""Command rows before the start (0.1 s; the identified command delay is 40 ms)."""
ORACLE_AFTER = 10
"""Command rows after the target the oracle sees (0.1 s: the controller's answer to the rates there)."""
TRAIN_STRIDE = 2
"""Every second start of the training flights (neighbouring starts are nearly the same sample)."""
RIDGE = 1e-2
"""Ridge penalty per training sample on the standardised inputs."""
MLP_WIDTH, MLP_EPOCHS, MLP_BATCH, MLP_LR, MLP_DECAY = 64, 30, 512, 1e-3, 1e-4
"""The MLP: two tanh layers of 64, Adam (learning rate 1e-3, weight decay 1e-4), 30 epochs of batches of 512."""
FORMS = (("linear, causal", "linear", 0), ("MLP, causal", "mlp", 0), ("MLP, oracle (+0.1 s of commands)", "mlp", ORACLE_AFTER))


def flying_starts(log) -> np.ndarray:
    """Start rows inside the flying part (the models benchmark's span) with room for the history, the longest
    horizon and the oracle's commands after it: the same starts for every form."""
    span = next(s for s in CONFIG.spans() if s.name == CONFIG.multistep_span)
    first = RATE_HISTORY + COMMAND_LEAD
    starts = [np.arange(a + first, b - max(HORIZONS) - ORACLE_AFTER) for a, b in span_segments(log, span, CONFIG)]
    return np.concatenate(starts) if starts else np.zeros(0, dtype=int)


def features(log, starts: np.ndarray, horizon: int, after: int, u_mean: np.ndarray, u_std: np.ndarray) -> np.ndarray:
    """(S, F) inputs of f_h: the normalised commands u_{s-L} .. u_{s+h+after} and the rates ω_{s-9} .. ω_s."""
    u = (log.u - u_mean) / u_std
    commands = u[starts[:, None] + np.arange(-COMMAND_LEAD, horizon + after + 1)[None, :]].reshape(len(starts), -1)
    rates = log.gyro_b[starts[:, None] + np.arange(-RATE_HISTORY + 1, 1)[None, :]].reshape(len(starts), -1)
    return np.hstack([commands, rates])


def fit_predict(kind: str, x: np.ndarray, y: np.ndarray, tests: list[np.ndarray], seed: int) -> list[np.ndarray]:
    """Train f_h on (x, y) (standardised inside) and return its predictions for each array of ``tests``."""
    x_mean, x_std, y_std = x.mean(0), x.std(0) + 1e-9, y.std(0)
    xn, yn = (x - x_mean) / x_std, y / y_std
    if kind == "linear":
        a = np.hstack([xn, np.ones((len(xn), 1))])
        w = np.linalg.solve(a.T @ a + RIDGE * len(a) * np.eye(a.shape[1]), a.T @ yn)
        return [np.hstack([(t - x_mean) / x_std, np.ones((len(t), 1))]) @ w * y_std for t in tests]
    import torch

    torch.manual_seed(seed)
    net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], MLP_WIDTH), torch.nn.Tanh(), torch.nn.Linear(MLP_WIDTH, MLP_WIDTH),
                              torch.nn.Tanh(), torch.nn.Linear(MLP_WIDTH, y.shape[1]))
    optimiser = torch.optim.Adam(net.parameters(), MLP_LR, weight_decay=MLP_DECAY)
    xt, yt = torch.tensor(xn, dtype=torch.float32), torch.tensor(yn, dtype=torch.float32)
    for _ in range(MLP_EPOCHS):
        order = torch.randperm(len(xt))
        for first in range(0, len(xt), MLP_BATCH):
            batch = order[first:first + MLP_BATCH]
            optimiser.zero_grad()
            loss = ((net(xt[batch]) - yt[batch]) ** 2).mean()
            loss.backward()
            optimiser.step()
    with torch.no_grad():
        return [net(torch.tensor((t - x_mean) / x_std, dtype=torch.float32)).numpy() * y_std for t in tests]


def sim_err(mae: np.ndarray) -> float:
    """SimErr from MAE at :data:`HORIZONS`: the trapezoid over h, per unit of h."""
    h = np.asarray(HORIZONS, dtype=float)
    return float(np.sum((mae[1:] + mae[:-1]) * np.diff(h)) / 2 / (h[-1] - h[0]))


def run_fold(shape: str, logs: dict, seed: int) -> dict:
    train = [log for path, log in logs.items() if shape_of(path) != shape]
    test = [log for path, log in logs.items() if shape_of(path) == shape]
    all_u = np.vstack([log.u for log in train])
    u_mean, u_std = all_u.mean(0), all_u.std(0) + 1e-9
    train_starts = [flying_starts(log)[::TRAIN_STRIDE] for log in train]
    test_starts = [flying_starts(log) for log in test]
    mae = {name: np.zeros(len(HORIZONS)) for name, _, _ in FORMS} | {"naive": np.zeros(len(HORIZONS))}
    for k, h in enumerate(HORIZONS):
        y = np.vstack([log.gyro_b[s + h] - log.gyro_b[s] for log, s in zip(train, train_starts)])
        truth = [log.gyro_b[s + h] - log.gyro_b[s] for log, s in zip(test, test_starts)]
        mae["naive"][k] = np.mean(np.concatenate([np.linalg.norm(t, axis=1) for t in truth]))
        for name, kind, after in FORMS:
            x = np.vstack([features(log, s, h, after, u_mean, u_std) for log, s in zip(train, train_starts)])
            tests = [features(log, s, h, after, u_mean, u_std) for log, s in zip(test, test_starts)]
            predicted = fit_predict(kind, x, y, tests, seed + k)
            mae[name][k] = np.mean(np.concatenate([np.linalg.norm(t - p, axis=1) for t, p in zip(truth, predicted)]))
    starts = int(sum(len(s) for s in test_starts))
    return {"held_out": shape, "shape": SHAPES[shape], "starts": starts, "train_starts": int(sum(len(s) for s in train_starts)),
            "mae": {name: values.tolist() for name, values in mae.items()},
            "ratio": {name: sim_err(values) / sim_err(mae["naive"]) for name, values in mae.items() if name != "naive"}}


VELOCITY_HORIZON = 50
"""Horizons of the velocity check: every h = 1..50, the protocol's SimErr."""


def velocity_with_measured_rates(shape: str, logs: dict, work: Path) -> dict:
    """Velocity SimErr ratio to naive on ``shape``'s flights (every h = 1..50, the same starts) of the physics model
    identified on the other shapes (``identify --vehicle crazyflie21``, the models benchmark's spans): as it predicts,
    and with the *measured* body rates given at the end of every step (``rigid_body.step``'s ``rates_next``, as the
    direct model gives its regression's): how far the translation gets if the rates were known."""
    from bench.bench_models import SPANS, run_cli
    from quad_modelling.core.models import physics

    vehicle_file = work / f"vehicle_{shape}.yaml"
    run_cli(["identify", *[str(p) for p in logs if shape_of(p) != shape], "--vehicle", "crazyflie21", *SPANS, "-o", str(vehicle_file)])
    model = physics.PhysicsPredictor(load_vehicle(str(vehicle_file)))
    sums = {"naive": 0.0, "physics": 0.0, "physics, measured rates": 0.0}
    rows = np.arange(VELOCITY_HORIZON + 1)
    for log in (log for path, log in logs.items() if shape_of(path) == shape):
        starts = flying_starts(log)
        state, disturbance, commands, intervals = model.horizon_inputs(log, starts, VELOCITY_HORIZON)
        truth = log.vel_n[starts[:, None] + rows[None, 1:]]
        own = physics.rollout(model.params, state, disturbance, commands, intervals, False)
        given = physics.rollout(model.params, state, disturbance, commands, intervals, False, log.gyro_b[starts[:, None] + rows[None, :]])
        sums["naive"] += np.linalg.norm(truth - log.vel_n[starts][:, None, :], axis=2).sum()
        sums["physics"] += np.linalg.norm(truth - own[:, 1:, 3:6], axis=2).sum()
        sums["physics, measured rates"] += np.linalg.norm(truth - given[:, 1:, 3:6], axis=2).sum()
    return {name: value / sums["naive"] for name, value in sums.items() if name != "naive"}


def models_ratios() -> dict:
    """shape -> model -> AV SimErr ratio from bench/results/models.json (the protocol's starts), if it is there."""
    path = RESULTS / "models.json"
    if not path.exists():
        return {}
    folds = json.loads(path.read_text())["folds"]
    return {f["held_out"]: {m: v["angular_velocity"]["ratio_sim_err"] for m, v in f["multistep"]["models"].items()
                            if m in ("physics", "narx", "hybrid")} for f in folds}


def markdown(folds: list[dict], pooled: dict, reference: dict, run: str) -> str:
    names = [name for name, _, _ in FORMS]
    lines = ["# What the logged commands explain of the body rates (NanoBench, held out by shape)", "",
             f"Generated by `bench/bench_command_limit.py{run}` (issue #28 item 1: the limit of what 100 Hz commands explain). "
             "Direct regressions, one per horizon, from the last 0.1 s of measured body rates and the logged commands "
             f"(from 0.1 s before the start) to the change of the body rates h rows later; trained on five shapes, scored on "
             "the sixth. AV SimErr ratio to naive on the same starts, SimErr the trapezoid over h = "
             f"{', '.join(map(str, HORIZONS))}. The oracle also sees the commands of the 0.1 s after the target row, which "
             "the controller computed from the rates there. Physics / NARX / hybrid: `bench/results/models.json` "
             "(the protocol's starts, every h).", ""]
    rows = []
    for fold in folds + [pooled]:
        ref = reference.get(fold["held_out"], {})
        rows.append([fold["held_out"] + (f" {fold['shape']}" if fold.get("shape") else ""), str(fold["starts"]),
                     *[f"{fold['ratio'][n]:.3f}" for n in names],
                     *[f"{ref[m]:.3f}" if m in ref else "-" for m in ("physics", "narx", "hybrid")]])
    lines += markdown_table(["held out", "starts", *names, "physics", "narx", "hybrid"], rows)
    velocity = json.loads((RESULTS / "models.json").read_text())["folds"] if (RESULTS / "models.json").exists() else []
    direct_vel = {f["held_out"]: f["multistep"]["models"]["direct"]["velocity"]["ratio_sim_err"] for f in velocity
                  if "direct" in f["multistep"]["models"]}
    lines += ["", "Velocity SimErr ratio to naive (every h = 1..50, the same starts): the physics model identified on the other "
              "shapes as it predicts, and with the measured body rates given at every step (what its translation reaches "
              "if the rates were known); the direct model's from `models.json` (the protocol's starts).", ""]
    lines += markdown_table(["held out", "physics", "physics, measured rates", "direct"],
                            [[f["held_out"], f"{f['velocity_ratio']['physics']:.3f}", f"{f['velocity_ratio']['physics, measured rates']:.3f}",
                              f"{direct_vel[f['held_out']]:.3f}" if f["held_out"] in direct_vel else "-"] for f in folds])
    lines += ["", "AV MAE by horizon, pooled [rad/s]:", ""]
    lines += markdown_table(["h", "naive", *names], [[str(h), f"{pooled['mae']['naive'][k]:.4f}", *[f"{pooled['mae'][n][k]:.4f}" for n in names]]
                                                     for k, h in enumerate(HORIZONS)])
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = fold_parser(__doc__, "command_limit")
    parser.add_argument("--seed", type=int, default=0, help="torch seed of the MLPs (+ the horizon's index)")
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(2)
    vehicle = load_vehicle("crazyflie21")
    flights, skipped = readable_flights(args.data, vehicle)
    logs = {path: resample_uniform(log) for path, log in flights.items()}
    folds = []
    work = Path(tempfile.mkdtemp(prefix="command_limit_"))
    for shape in args.folds.split(","):
        started = time.perf_counter()
        folds.append(run_fold(shape, logs, args.seed))
        folds[-1]["velocity_ratio"] = velocity_with_measured_rates(shape, logs, work)
        print(f"{shape}: {folds[-1]['ratio']} ({time.perf_counter() - started:.0f} s)", file=sys.stderr, flush=True)
    total = sum(f["starts"] for f in folds)
    pooled_mae = {name: (sum(np.asarray(f["mae"][name]) * f["starts"] for f in folds) / total).tolist() for name in folds[0]["mae"]}
    pooled = {"held_out": "pooled", "starts": total, "mae": pooled_mae,
              "ratio": {n: sim_err(np.asarray(v)) / sim_err(np.asarray(pooled_mae["naive"])) for n, v in pooled_mae.items() if n != "naive"}}
    reference = models_ratios()
    pooled_reference = json.loads((RESULTS / "models.json").read_text())["pooled"] if (RESULTS / "models.json").exists() else {}
    reference["pooled"] = {m: pooled_reference[m]["angular_velocity"]["ratio_sim_err"] for m in ("physics", "narx", "hybrid")
                           if m in pooled_reference}
    run = "" if args.folds == ",".join(SHAPES) else f" --folds {args.folds}"
    write_results(args.output, {"horizons": list(HORIZONS), "seed": args.seed, "skipped": skipped, "folds": folds, "pooled": pooled,
                                "models_json": reference}, markdown(folds, pooled, reference, run))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
