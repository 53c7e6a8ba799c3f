"""Would the training data alone have given the direct model its vertical map? (nested leave-one-shape-out, #28 item 1)

Session 22 gave the direct model (:mod:`quad_modelling.core.models.direct`) a per-horizon linear map for the down
velocity, its inputs chosen by looking at three of the six held-out folds of ``bench/bench_models.py`` (B3, B6, B9).
A choice made on held-out folds makes their scores optimistic. This benchmark repeats the choice inside each fold's
*training* shapes only, as ``bench/bench_direct_inputs.py`` does for the rate map's inputs: for each held-out shape
(outer fold) the vehicle is identified on the other five shapes, and each variant is scored by leave-one-shape-out
over those five (inner folds: ``train_direct`` on four, score the fifth). The variant with the lowest pooled inner
score is what the training data would pick; its outer score is what an honest selection gets.

Variants: the direct model without the vertical map (the physics integrates v_D, as before session 22) and with it
(what ``train --direct`` fits).

Score: the velocity's SimErr ratio to naive by the multi-step protocol of ``bench_models.py`` (every start of the
flying part, h = 1..50), pooled over folds as ``bench_models.py`` pools (MAE over every start of every fold).

Run: ``.venv/bin/python -m bench.bench_direct_vertical [--data DIR] [--folds B2,B3]``. Writes
bench/results/direct_vertical.json and .md.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_direct_inputs import flying_spans, nested_main  # noqa: E402
from bench.bench_models import CONFIG  # noqa: E402
from quad_modelling.core.evaluation.multistep import multistep_evaluation  # noqa: E402
from quad_modelling.core.models.direct import DirectModel, DirectPredictor  # noqa: E402
from quad_modelling.core.training.direct import train_direct  # noqa: E402

VARIANTS = ("no vertical map", "vertical map (train --direct)")


def velocity_sums(train, test, vehicle) -> dict[str, list[float]]:
    """variant -> [Σ_starts SimErr, Σ_starts naive SimErr] of the velocity on ``test``, the model fitted on ``train``."""
    model = train_direct(train, flying_spans(train), vehicle)
    if model.vertical is None:
        raise RuntimeError(f"no vertical map: {model.training['vertical_map']}")
    without = DirectModel(vehicle, model.regression, model.dt, model.training)
    predictors = [DirectPredictor(without, VARIANTS[0]), DirectPredictor(model, VARIANTS[1])]
    table = multistep_evaluation(test, predictors, vehicle, CONFIG)
    starts = float(table["starts"])
    return {name: [table["models"][name]["velocity"]["sim_err"] * starts, table["models"][name]["velocity"]["naive_sim_err"] * starts]
            for name in VARIANTS}


def main(argv: list[str] | None = None) -> int:
    return nested_main(argv, __doc__, "bench/bench_direct_vertical.py", "direct_vertical", velocity_sums, list(VARIANTS),
                       "Choosing the direct model's vertical map on the training shapes only",
                       "Velocity SimErr ratio to naive, the multi-step protocol of `bench_models.py` (h = 1..50, pooled over starts).",
                       {"variants": list(VARIANTS)})


if __name__ == "__main__":
    raise SystemExit(main())
