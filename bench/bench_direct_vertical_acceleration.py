"""How many rows of down acceleration should the direct model's vertical map average? (nested leave-one-shape-out, #28)

The vertical map (:mod:`quad_modelling.core.models.direct`) reads the down acceleration a_D = (R f_B)_D + g from the
accelerometer. Until session 24 it read the anchor's row alone; a scratch scan of the held-out folds found the map's
down-velocity error lower in every fold with the mean of the last 3 rows (the accelerometer's vibration noise). A
choice looked at on the held-out folds makes their scores optimistic, so this benchmark repeats it inside each
fold's *training* shapes only, as ``bench/bench_direct_inputs.py`` does for the rate maps' inputs: per held-out
shape (outer fold), each n_a of :data:`ROWS` is scored by leave-one-shape-out over the other five shapes (inner
folds: the map fitted on four, scored on the fifth); the lowest pooled inner score is what the training data pick.
(The outer fold identifies the vehicle as the other nested benchmarks do; the vertical map does not use it.)

Score: the down velocity's change error summed over h = 1..50 and every flying start
(:func:`bench.bench_command_limit.flying_starts`), |Δv_D - Δv̂_D|, as a ratio to naive's |Δv_D| (holding v_D).
The vertical map alone: ``bench/bench_models.py`` has the model's velocity SimErr.

Run: ``.venv/bin/python -m bench.bench_direct_vertical_acceleration [--data DIR] [--folds B2,B3]``. Writes
bench/results/direct_vertical_acceleration.json and .md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_command_limit import flying_starts  # noqa: E402
from bench.bench_direct_inputs import flying_spans, nested_main  # noqa: E402
from quad_modelling.core.models.direct import HORIZON  # noqa: E402
from quad_modelling.core.training.direct import down_velocity_changes, fit_vertical_regression  # noqa: E402

ROWS = (1, 3, 5, 10)
"""The candidate n_a [rows at 100 Hz]: the anchor alone (sessions 22-23), 30, 50 and 100 ms."""

NAMES = {n: f"n_a = {n}" for n in ROWS}


def vertical_sums(train, test, vehicle) -> dict[str, tuple[float, float]]:
    """variant -> (Σ |Δv_D - Δv̂_D|, Σ |Δv_D|) over h = 1..H and every flying start of ``test``, the map fitted on
    ``train`` (``vehicle`` unused: the vertical map has no physics)."""
    out = {}
    for rows in ROWS:
        vertical = fit_vertical_regression(train, flying_spans(train), acceleration_rows=rows)
        model = naive = 0.0
        for log in test:
            starts = flying_starts(log)
            truth = down_velocity_changes(log, starts, HORIZON)[..., 0]
            predicted = vertical.velocities(log, starts, HORIZON)
            model += float(np.abs(truth - (predicted[:, 1:] - predicted[:, :1])).sum())
            naive += float(np.abs(truth).sum())
        out[NAMES[rows]] = (model, naive)
    return out


def main(argv: list[str] | None = None) -> int:
    return nested_main(argv, __doc__, "bench/bench_direct_vertical_acceleration.py", "direct_vertical_acceleration", vertical_sums,
                       list(NAMES.values()), "Choosing the rows of down acceleration the vertical map averages on the training shapes only",
                       "Down-velocity change error over h = 1..50 on the flying starts, as a ratio to holding v_D.",
                       {"rows": list(ROWS), "horizon": HORIZON})


if __name__ == "__main__":
    raise SystemExit(main())
