"""Would the training data alone have chosen to fit the rate maps on the airframe's mirror images? (nested
leave-one-shape-out, #28 item 1)

The direct model's rate maps (:mod:`quad_modelling.core.models.direct`) can be fitted on the training anchors and
their images under the airframe's symmetries (:mod:`quad_modelling.core.physics.symmetry`; for the Crazyflie the
mirror images across x and y and the turn by 180°), as if every training flight had also been flown mirrored: a
prior that the vehicle is as symmetric as its geometry, which a shape flown one way round cannot teach. Session 41's
scratch run of three held-out folds found the figure-8 (which turns both ways) 0.573 -> 0.559, the trefoil unchanged
and the circle 0.417 -> 0.419. This benchmark makes the choice inside each fold's *training* shapes only, as
``bench/bench_direct_inputs.py`` does for the inputs: per held-out shape (outer fold) the vehicle is identified on the
other five, both variants scored by leave-one-shape-out over those five (inner folds), the lower inner score picked.

Every variant has the inputs, λ and the reweighted refit of ``train --direct``; only the images differ.

Score: :func:`bench.bench_direct_inputs.error_sums`, the body-rate error norm summed over h = 1..50 and every flying
start, as a ratio to naive (within about 0.01 of ``models.md``'s AV ratio).

Run: ``.venv/bin/python -m bench.bench_direct_symmetry [--data DIR] [--folds B2,B3]``. Writes
bench/results/direct_symmetry.json and .md.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_direct_inputs import error_sums, flying_spans, nested_main, observer_disturbance  # noqa: E402
from quad_modelling.core.physics.symmetry import airframe_symmetries  # noqa: E402
from quad_modelling.core.training.direct import fit_rate_regression  # noqa: E402

VARIANTS = ("the flights alone", "the flights and their images under the airframe's symmetries")


def symmetry_sums(train, test, vehicle) -> dict[str, tuple[float, float]]:
    """variant -> error sums on ``test`` of the rate maps fitted on ``train`` without and with the images."""
    disturbance_of = observer_disturbance(vehicle)
    group = airframe_symmetries(vehicle.motor_positions, vehicle.yaw_signs, vehicle.inertia)
    return {name: error_sums(fit_rate_regression(train, flying_spans(train), angular_disturbance=disturbance_of,
                                                 symmetries=symmetries)[0], test, disturbance_of)
            for name, symmetries in zip(VARIANTS, ((), group))}


def main(argv: list[str] | None = None) -> int:
    return nested_main(argv, __doc__, "bench/bench_direct_symmetry.py", "direct_symmetry", symmetry_sums, list(VARIANTS),
                       "Fitting the rate maps on the airframe's mirror images, chosen on the training shapes only",
                       "AV SimErr ratio to naive over h = 1..50 on the flying starts.", {})


if __name__ == "__main__":
    raise SystemExit(main())
