r"""A hybrid built on the direct model: does a residual net on the linear acceleration improve its velocity? (#28 item 1)

#28 asks the hybrid to be no worse than the better of its parts on both angular velocity and velocity, per fold. The
hybrid of ``train --hybrid`` is the physics model plus a residual net; held out by shape its AV is worse than NARX's in
five folds and its velocity worse than the physics model's on the figure-8 (``bench/results/models.md``). Built on the
direct model instead, its body rates (and down velocity) over the 50 rows would be the direct model's maps' -- better
than NARX's in every fold -- and a net would correct only the linear acceleration of the physics translation:

.. math::

    \dot v_N = a_{phys} + \hat d_v + R\,\mathrm{net}(f), \qquad \omega_{s+h} = \hat\omega^{direct}_{s+h},
    \quad v_{D,s+h} = \hat v^{direct}_{D,s+h}

(f the hybrid's 21 net inputs, :func:`~quad_modelling.core.models.hybrid.net_features`; the observer subtracts the
net's mean over its 0.5 s history as the hybrid's does). This benchmark asks whether the net earns its place: per
held-out shape, the vehicle identified and the direct model trained on the other five (as ``bench_models.py``), the
net (2 x 32 tanh, 3 outputs, last layer zero: epoch 0 is the direct model) trained through the torch physics step with
the maps' rates and down velocity given, Adam 2e-3, 32 batches of 256 windows (every 2nd anchor) per epoch, at most
12 epochs, early stopping (patience 3) on 20 % of the training flights held back, the best epoch kept; loss the
velocity error norm over h = 1..50 over naive's. Scored by the protocol (every ``--stride``-th flying start) next to
the direct model. A scratch variant of the hybrid's design, not a model the CLI trains.

Run: ``.venv/bin/python bench/bench_hybrid_on_direct.py --data DIR [--folds B3,B9] [--stride 3]``. Writes
bench/results/hybrid_on_direct.json and .md.
"""

from __future__ import annotations

import copy
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_models import CONFIG, SHAPES, SPANS, fold_parser, readable_flights, run_cli, shape_of  # noqa: E402
from bench.common import write_results  # noqa: E402
from quad_modelling.core.evaluation.multistep import multistep_evaluation  # noqa: E402
from quad_modelling.core.models import physics  # noqa: E402
from quad_modelling.core.models.direct import HORIZON, load_direct  # noqa: E402
from quad_modelling.core.models.hybrid import hybrid_commands, net_features  # noqa: E402
from quad_modelling.core.models.registry import make_model  # noqa: E402
from quad_modelling.core.physics import arrays, rigid_body, rotors  # noqa: E402
from quad_modelling.core.preprocess import resample_uniform, state_measurement  # noqa: E402
from quad_modelling.core.training import physics_torch as pt  # noqa: E402
from quad_modelling.core.training.hybrid import _features, _make_module  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.core.windows import gap_free_runs  # noqa: E402
from quad_modelling.io.reports.formatting import markdown_table  # noqa: E402

OBSERVER_ROWS = 50
"""Rows of the linear observer's history (0.5 s at 100 Hz, the physics model's default)."""
DROP_S = 1.0
"""Training anchors skip the first and last second of each flight (take-off, landing)."""


def anchor_inputs(model, log, starts: np.ndarray, horizon: int) -> dict[str, np.ndarray]:
    """Everything a rollout from each start needs: the physics anchor (state, observer), the commands (delayed and
    logged), the direct model's rates and down velocity over the horizon, the net inputs f at the observer's history
    rows and their attitudes (for the observer's subtraction of the net's mean), and the measured velocity."""
    p = model.params
    measured = state_measurement(log)
    commands = hybrid_commands(p, log.u, log.t, physics.battery_voltage(p, log))
    rotor = rotors.rotor_speeds(p, commands[:, :4], log.t)
    state, disturbance, delayed, intervals = model.physics.horizon_inputs(log, starts, horizon)
    rows = starts[:, None] + np.arange(horizon + 1)[None, :]
    history = np.maximum(starts[:, None] + np.arange(-OBSERVER_ROWS, 0)[None, :], 0)
    at_history = physics.measured_states(p, measured, rotor, history.ravel())
    given = min(horizon, HORIZON)
    down = model.vertical.velocities(log, starts, given) if model.uses_vertical(log) else np.full((len(starts), given + 1), np.nan)
    return {"pos": state.pos_n, "vel": state.vel_n, "rot": state.rot, "rates": state.rates, "rotor": state.rotor,
            "yaw": state.yaw, "d_lin": disturbance.linear_n, "d_ang": disturbance.angular_b,
            "u": np.concatenate([delayed, log.u[rows]], axis=-1), "dt": intervals,
            "given_rates": model.regression.rates(log, starts, given, disturbance.angular_b), "given_down": down,
            "history_f": net_features(at_history, commands[history.ravel()]).reshape(*history.shape, -1),
            "history_rot": at_history.rot.reshape(*history.shape, 3, 3), "target": log.vel_n[rows]}


def training_inputs(model, log, stride: int) -> dict[str, np.ndarray]:
    """:func:`anchor_inputs` at every ``stride``-th anchor of the gap-free flying rows of ``log``."""
    first, last = np.searchsorted(log.t, log.t[0] + DROP_S), np.searchsorted(log.t, log.t[-1] - DROP_S)
    parts = [anchor_inputs(model, log, starts, HORIZON) for a, b in gap_free_runs(log, first, last)
             if (starts := np.arange(a + OBSERVER_ROWS, b - HORIZON - 1, stride)).size]
    return {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}


def observer_linear(net, batch) -> torch.Tensor:
    """d_v minus the mean of the net's correction R Δa_B over the observer's history rows (the hybrid's observer)."""
    delta = net(batch["history_f"])
    return batch["d_lin"] - (batch["history_rot"] * delta[..., None, :]).sum(-1).mean(1)


def rollout_velocity(tp, net, batch) -> torch.Tensor:
    """(B, H, 3) velocities of the physics step with the net's linear correction, the direct rates and v_D given."""
    d_lin = observer_linear(net, batch)
    state = pt.TorchState(batch["pos"], batch["vel"], batch["rot"], batch["rates"], batch["rotor"], batch["yaw"])
    down_given = not bool(torch.isnan(batch["given_down"][0, 0]))
    velocities = []
    for k in range(HORIZON):
        u = batch["u"][:, k]
        linear = d_lin + arrays.rotate(state.rot, net(_features(state.vel_n, state.rot, state.rates, u, state.rotor)))
        state = rigid_body.step(tp, state, u[:, :4], batch["dt"][:, k], linear, batch["d_ang"], batch["given_rates"][:, k + 1],
                                batch["given_down"][:, k + 1] if down_given else None)
        velocities.append(state.vel_n)
    return torch.stack(velocities, 1)


def tensors(inputs: dict, rows: np.ndarray, dtype=torch.float32) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(v[rows], dtype=dtype) for k, v in inputs.items()}


class NetOnDirect:
    """The direct model with the trained net on its linear acceleration: a multi-step predictor for the protocol."""

    def __init__(self, model, net, name: str):
        self.model, self.net, self.name = model, net.double(), name

    def predict_horizons(self, segment, starts: np.ndarray, horizon: int) -> np.ndarray:
        starts = np.asarray(starts, dtype=int)
        p, x = self.model.params, anchor_inputs(self.model, segment, starts, horizon)
        with torch.no_grad():
            d_lin = observer_linear(self.net, tensors(x, slice(None), torch.float64)).numpy()
        state = rigid_body.PhysicsState(x["pos"], x["vel"], x["rot"], x["rates"], x["rotor"], x["yaw"])
        given, down_given = x["given_rates"].shape[1] - 1, not np.isnan(x["given_down"][0, 0])
        out = np.empty((len(starts), horizon + 1, 18))
        for h in range(horizon + 1):
            u = x["u"][:, h]
            with torch.no_grad():
                delta = self.net(torch.as_tensor(net_features(state, u))).numpy()
            disturbance = physics.Disturbance(d_lin + arrays.rotate(state.rot, delta), x["d_ang"])
            out[:, h] = physics.outputs(p, state, u[:, :4], disturbance)
            if h < horizon:
                state = physics.step(p, state, u[:, :4], x["dt"][:, h], disturbance, x["given_rates"][:, h + 1] if h < given else None,
                                     x["given_down"][:, h + 1] if h < given and down_given else None)
        return out


def train(model, logs, seed: int = 0, epochs: int = 12, windows: int = 8192, batch: int = 256, rate: float = 2e-3):
    """The net trained as the module docstring says; returns (net, validation loss per epoch, epoch 0 first)."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(logs))
    held = max(1, round(0.2 * len(logs)))
    train_x = [training_inputs(model, logs[i], 2) for i in order[held:]]
    val_x = [training_inputs(model, logs[i], 5) for i in order[:held]]
    train_x = {k: np.concatenate([x[k] for x in train_x]) for k in train_x[0]}
    val_x = {k: np.concatenate([x[k] for x in val_x]) for k in val_x[0]}
    features = train_x["history_f"][:, -1]
    naive = float(np.linalg.norm(train_x["target"][:, 1:] - train_x["target"][:, :1], axis=-1).mean())
    torch.manual_seed(seed)
    torch.set_num_threads(1)
    net = _make_module(features.mean(0), np.maximum(features.std(0), 1e-6), np.full(3, 0.5), (32, 32))
    tp = pt.TorchParameters.from_params(model.params, torch.float32)
    optimiser = torch.optim.Adam(net.parameters(), lr=rate)
    eps = 1e-3 * naive

    def loss(b) -> torch.Tensor:
        e = rollout_velocity(tp, net, b) - b["target"][:, 1:]
        return (torch.sqrt((e * e).sum(-1) + eps**2) - eps).mean() / naive

    def validation() -> float:
        n = len(val_x["pos"])
        with torch.no_grad():
            return sum(float(loss(tensors(val_x, np.arange(i, min(n, i + 2048))))) * min(2048, n - i) for i in range(0, n, 2048)) / n

    history = [validation()]
    best_state, since = copy.deepcopy(net.state_dict()), 0
    for _ in range(epochs):
        for _ in range(windows // batch):
            optimiser.zero_grad()
            loss(tensors(train_x, rng.integers(0, len(train_x["pos"]), batch))).backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            optimiser.step()
        history.append(validation())
        if history[-1] < min(history[:-1]):
            best_state, since = copy.deepcopy(net.state_dict()), 0
        elif (since := since + 1) >= 3:
            break
    net.load_state_dict(best_state)
    return net, history


def markdown(folds: dict, run: str, stride: int) -> str:
    lines = ["# A hybrid built on the direct model (held out by shape)", "",
             f"Generated by `{run}`. Velocity / angular velocity SimErr ratio to naive over h = 1..50, every {stride}-th "
             "flying start; per fold the vehicle, the direct model and the net from the other five shapes (the net's "
             "early stopping on training flights held back). What is trained: the module docstring.", ""]
    rows = []
    for shape, f in folds.items():
        d, n = f["scores"]["direct"], f["scores"]["net_on_direct"]
        rows.append([f"{shape} {SHAPES[shape]}", f"{d[0]:.3f}", f"{d[1]:.3f}", f"{n[1]:.3f}", f"{n[1] - d[1]:+.3f}",
                     f"{f['val'][0]:.4f} -> {min(f['val']):.4f} (epoch {int(np.argmin(f['val']))})"])
    vel = {k: sum(f["scores"][k][2] * f["starts"] for f in folds.values()) / sum(f["scores"][k][3] * f["starts"] for f in folds.values())
           for k in ("direct", "net_on_direct")}
    rows.append(["pooled", "", f"{vel['direct']:.3f}", f"{vel['net_on_direct']:.3f}", f"{vel['net_on_direct'] - vel['direct']:+.3f}", ""])
    lines += markdown_table(["held out", "AV (both)", "Vel direct", "Vel direct + net", "change", "validation loss (kept epoch)"], rows)
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = fold_parser(__doc__, "hybrid_on_direct")
    parser.add_argument("--stride", type=int, default=3, help="score every N-th start (default 3)")
    args = parser.parse_args(argv)
    flights, _ = readable_flights(args.data, load_vehicle("crazyflie21"))
    work = Path(tempfile.mkdtemp(prefix="hybrid_on_direct_"))
    res = {}
    for shape in args.folds.split(","):
        t0 = time.time()
        train_paths = [p for p in flights if shape_of(p) != shape]
        vf, df = work / f"v_{shape}.yaml", work / f"d_{shape}.npz"
        run_cli(["identify", *map(str, train_paths), "--vehicle", "crazyflie21", *SPANS, "-o", str(vf)])
        run_cli(["train", *map(str, train_paths), "--vehicle", str(vf), *SPANS, "--direct", "--quiet", "-o", str(df)])
        vehicle = load_vehicle(str(vf)); model = load_direct(df, vehicle)
        net, hist = train(model, [resample_uniform(flights[p]) for p in train_paths])
        held = [resample_uniform(flights[p]) for p in flights if shape_of(p) == shape]
        preds = [make_model("naive", vehicle), make_model(f"direct:{df}", vehicle), NetOnDirect(model, net, "net_on_direct")]
        table = multistep_evaluation(held, preds, vehicle, CONFIG, start_stride=args.stride)
        sc = {n: [g["angular_velocity"]["ratio_sim_err"], g["velocity"]["ratio_sim_err"], g["velocity"]["sim_err"],
                  g["velocity"]["naive_sim_err"]] for n, g in table["models"].items()}
        res[shape] = {"scores": sc, "starts": table["starts"], "val": hist, "seconds": round(time.time() - t0, 1)}
        print(shape, {n: (round(a, 4), round(v, 4)) for n, (a, v, _, _) in sc.items()}, f"{time.time() - t0:.0f} s",
              file=sys.stderr, flush=True)
    run = "bench/bench_hybrid_on_direct.py" + ("" if args.folds == ",".join(SHAPES) else f" --folds {args.folds}")
    write_results(args.output, {"stride": args.stride, "folds": res}, markdown(res, run, args.stride))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
