"""Would the training data alone have chosen the rate maps' ridge penalty? (nested leave-one-shape-out, #28 item 1)

The direct model's rate maps (:mod:`quad_modelling.core.models.direct`) were fitted with λ = 1e-2 from session 19 to
22 (``bench_command_limit.py``'s). A scratch scan of the six held-out folds of ``bench/bench_models.py``
(session 23) found the held-out AV error lower at λ = 1e-3 in five folds. A choice made on the held-out folds makes
their scores optimistic, so this benchmark repeats it inside each fold's *training* shapes only, as
``bench/bench_direct_inputs.py`` does for the inputs: per held-out shape (outer fold) the vehicle is identified on
the other five, each λ of :data:`RIDGES` scored by leave-one-shape-out over those five (inner folds: the rate maps
fitted on four, scored on the fifth); the λ with the lowest pooled inner score is the one the training data pick, and
its outer score is what an honest selection gets.

Every variant has the inputs and the reweighted refit of ``train --direct`` (``fit_rate_regression``'s defaults with
the physics observer's disturbance); only λ differs.

Score: :func:`bench.bench_direct_inputs.error_sums`, the body-rate error norm summed over h = 1..50 and every flying
start, as a ratio to naive (within about 0.01 of ``models.md``'s AV ratio).

Run: ``.venv/bin/python -m bench.bench_direct_ridge [--data DIR] [--folds B2,B3]``. Writes
bench/results/direct_ridge.json and .md.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_direct_inputs import error_sums, flying_spans, nested_main, observer_disturbance  # noqa: E402
from quad_modelling.core.training.direct import fit_rate_regression  # noqa: E402

RIDGES = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2)
"""λ scanned: half-decades from 1e-4 to the value used before (1e-2)."""


def name_of(ridge: float) -> str:
    return f"λ = {ridge:g}"


def ridge_sums(train, test, vehicle) -> dict[str, tuple[float, float]]:
    """λ -> error sums on ``test`` of the rate maps fitted on ``train`` with that λ."""
    disturbance_of = observer_disturbance(vehicle)
    return {name_of(ridge): error_sums(fit_rate_regression(train, flying_spans(train), ridge=ridge,
                                                           angular_disturbance=disturbance_of)[0], test, disturbance_of)
            for ridge in RIDGES}


def main(argv: list[str] | None = None) -> int:
    return nested_main(argv, __doc__, "bench/bench_direct_ridge.py", "direct_ridge", ridge_sums, [name_of(r) for r in RIDGES],
                       "Choosing the rate maps' ridge penalty on the training shapes only",
                       "AV SimErr ratio to naive over h = 1..50 on the flying starts.",
                       {"ridges": list(RIDGES)})


if __name__ == "__main__":
    raise SystemExit(main())
