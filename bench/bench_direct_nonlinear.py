"""Would a nonlinear correction help the direct model's rate maps? (nested leave-one-shape-out, issue #28 item 1)

The direct model's body rates come from linear maps per horizon h (:mod:`quad_modelling.core.models.direct`):
ω̂_{s+h} = ω_s + W_h z_{s,h} + b_h, with z the anchor block (rates, body velocity, observer disturbance) and the
command rows up to the target. ``bench_direct_features.py`` found no *input* that brings the figure-8 (B3) or the
trefoil (B9) to #28's AV target; this benchmark asks whether a nonlinear function of what the anchor knows does:

    ω̂_{s+h} = ω_s + W_h z_{s,h} + b_h + σ ⊙ n_θ(a_s)_h

with a_s the anchor's inputs (20 rows of rates, body velocity v_B, the observer's angular disturbance, the gravity
direction R_s^T e_D, the 11 command rows u_{s-10..s} / 10^4; all standardised), n_θ a 2-layer tanh MLP (128 units)
with 3 x 50 outputs (every horizon's rate correction at once, in units of the training residuals' spread σ). Only
rows up to the anchor enter n_θ, so the correction is causal at every horizon. It is fitted to the residuals of the
linear maps on the training flights (every 2nd flying start, smooth-L1, Adam 1e-3, weight decay 1e-4, batch 512,
seed 0) after they are fitted.

Variants: the linear maps alone (``train --direct``) and with n_θ after 1, 3 and 8 epochs; the number of epochs is
what the nested choice picks (each variant scored by leave-one-shape-out over the training shapes, the lowest inner
score's held-out score reported). Score: the body-rate error norm over h = 1..50 on the flying starts, a ratio to
naive (:func:`bench.bench_direct_features.error_sums`' starts).

Run: ``.venv/bin/python bench/bench_direct_nonlinear.py [--data DIR] [--folds B2,B3]``. Writes
bench/results/direct_nonlinear.json and .md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_command_limit import flying_starts  # noqa: E402
from bench.bench_direct_features import fit  # noqa: E402
from bench.bench_direct_inputs import nested_main, observer_disturbance  # noqa: E402
from quad_modelling.core import frames  # noqa: E402
from quad_modelling.core.models.direct import HORIZON  # noqa: E402

EPOCHS = (1, 3, 8)
"""Snapshots of one training run: the variants ``+ net, N epochs``."""
VARIANTS = ["linear maps (train --direct)", *[f"+ net, {n} epochs" for n in EPOCHS]]

RATE_ROWS = 20
COMMAND_ROWS = 11
COMMAND_SCALE = 1e4
"""u / 10^4 (Crazyflie PWM 0..65535), as ``bench_direct_features``' squared commands."""
HIDDEN = 128
BATCH = 512
TRAIN_STRIDE = 2
"""Every 2nd flying start of the training flights feeds the net (neighbouring starts are nearly the same sample)."""


def anchor_inputs(log, starts: np.ndarray, disturbance: np.ndarray) -> np.ndarray:
    """(S, 3 * RATE_ROWS + 9 + 4 * COMMAND_ROWS) a_s: rows up to the anchor only."""
    past = np.maximum(starts[:, None] - np.arange(RATE_ROWS)[None, :], 0)
    lead = np.maximum(starts[:, None] - np.arange(COMMAND_ROWS)[None, :], 0)
    down = np.tile([0.0, 0.0, 1.0], (len(starts), 1))
    return np.concatenate([log.gyro_b[past].reshape(len(starts), -1),
                           frames.nav_to_body(log.vel_n[starts], log.euler[starts]).reshape(len(starts), 3), disturbance,
                           frames.nav_to_body(down, log.euler[starts]).reshape(len(starts), 3),
                           log.u[lead].reshape(len(starts), -1) / COMMAND_SCALE], axis=1)


def samples(maps, features, logs, disturbance_of, stride: int = 1):
    """(anchor inputs (S, A), the linear maps' rates (S, H, 3), the measured rates ω_{s..s+H} (S, H + 1, 3))."""
    inputs, linear, truth = [], [], []
    for log in logs:
        starts = flying_starts(log)[::stride]
        disturbance = disturbance_of(log, starts)
        inputs.append(anchor_inputs(log, starts, disturbance))
        linear.append(log.gyro_b[starts][:, None, :] + maps.changes(features(log, starts, HORIZON, disturbance), HORIZON))
        truth.append(log.gyro_b[starts[:, None] + np.arange(HORIZON + 1)[None, :]])
    return np.concatenate(inputs), np.concatenate(linear), np.concatenate(truth)


def error_sum(truth: np.ndarray, predicted: np.ndarray) -> float:
    return float(np.linalg.norm(truth[:, 1:] - predicted, axis=2).sum())


def scores(train, test, vehicle) -> dict[str, tuple[float, float]]:
    """variant -> (model, naive) error sums on ``test``, the maps and the net fitted on ``train``."""
    disturbance_of = observer_disturbance(vehicle)
    maps, features = fit(train, disturbance_of, {})
    a_train, linear_train, truth_train = samples(maps, features, train, disturbance_of, TRAIN_STRIDE)
    a_test, linear_test, truth_test = samples(maps, features, test, disturbance_of)
    naive = float(np.linalg.norm(truth_test[:, 1:] - truth_test[:, :1], axis=2).sum())
    out = {VARIANTS[0]: (error_sum(truth_test, linear_test), naive)}
    mean, spread = a_train.mean(axis=0), a_train.std(axis=0) + 1e-9
    residual = (truth_train[:, 1:] - linear_train).reshape(len(a_train), -1)
    sigma = residual.std(axis=0) + 1e-9
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(a_train.shape[1], HIDDEN), torch.nn.Tanh(), torch.nn.Linear(HIDDEN, HIDDEN),
                              torch.nn.Tanh(), torch.nn.Linear(HIDDEN, 3 * HORIZON))
    x = torch.tensor((a_train - mean) / spread, dtype=torch.float32)
    y = torch.tensor(residual / sigma, dtype=torch.float32)
    x_test = torch.tensor((a_test - mean) / spread, dtype=torch.float32)
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-3, weight_decay=1e-4)
    order = torch.Generator().manual_seed(0)
    for epoch in range(1, max(EPOCHS) + 1):
        permutation = torch.randperm(len(x), generator=order)
        for first in range(0, len(x), BATCH):
            batch = permutation[first:first + BATCH]
            loss = torch.nn.functional.smooth_l1_loss(net(x[batch]), y[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        if epoch in EPOCHS:
            with torch.no_grad():
                correction = (net(x_test).numpy() * sigma).reshape(len(a_test), HORIZON, 3)
            out[f"+ net, {epoch} epochs"] = (error_sum(truth_test, linear_test + correction), naive)
    return out


def main(argv: list[str] | None = None) -> int:
    torch.set_num_threads(1)
    return nested_main(argv, __doc__, "bench/bench_direct_nonlinear.py", "direct_nonlinear", scores, VARIANTS,
                       "A nonlinear correction of the direct model's rate maps, chosen on the training shapes only",
                       "AV SimErr ratio to naive over h = 1..50 on the flying starts.",
                       {"variants": VARIANTS, "horizon": HORIZON, "epochs": list(EPOCHS), "hidden": HIDDEN})


if __name__ == "__main__":
    raise SystemExit(main())
