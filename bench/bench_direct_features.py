"""Would other inputs help the direct model's rate maps? (nested leave-one-shape-out, issue #28 item 1)

The direct model (:mod:`quad_modelling.core.models.direct`) reaches an AV SimErr ratio of 0.488 pooled held out by
shape, but above 0.5 on the figure-8 (B3, 0.573) and the trefoil (B9, 0.524). Candidates for its anchor block and
command rows, each chosen (or not) on the training shapes only, as ``bench_direct_inputs.py`` chose the present ones:

- ``gravity``: the gravity direction in the body frame :math:`R_s^T e_D` at the anchor (roll and pitch: the position
  loop's tilt, which the rates' controller answers);
- ``acc``: the accelerometer's specific force :math:`f_B` averaged over the 5 rows up to the anchor;
- ``squares``: every command row also squared, :math:`(u / 10^4)^2` (a rotor's thrust grows with the square of its
  speed, so the torque of a command difference depends on the mean command);
- ``history 20`` / ``lead 20``: 20 rows of measured rates, or of commands before the anchor (0.2 s; 10 now).

Every variant keeps the present inputs (rates, body velocity, observer disturbance), λ = RATE_RIDGE and the
reweighted refit. Score: the body-rate error norm over h = 1..50 on the flying starts, as a ratio to naive
(:func:`bench.bench_direct_inputs.error_sums`' starts; within about 0.01 of ``models.md``).

Run: ``.venv/bin/python -m bench.bench_direct_features [--data DIR] [--folds B2,B3]``. Writes
bench/results/direct_features.json and .md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_command_limit import flying_starts  # noqa: E402
from bench.bench_direct_inputs import flying_spans, nested_main, observer_disturbance  # noqa: E402
from quad_modelling.core import frames  # noqa: E402
from quad_modelling.core.models.direct import HORIZON, RATE_RIDGE, ROBUST_STEPS, HorizonMaps  # noqa: E402
from quad_modelling.core.training.direct import rate_changes, robust_maps, training_parts  # noqa: E402

VARIANTS = {
    "train --direct": {},
    "+ gravity direction": {"extra": ("gravity",)},
    "+ specific force": {"extra": ("acc",)},
    "+ squared commands": {"squares": True},
    "20 rows of rates": {"history": 20},
    "20 command rows before": {"lead": 20},
}
"""name -> :func:`layout` arguments."""

COMMAND_SCALE = 1e4
"""u / 10^4 before squaring (Crazyflie PWM 0..65535): squares of order 1-40, as the ridge's standardisation wants."""


class Maps(HorizonMaps):
    """:class:`~quad_modelling.core.models.direct.HorizonMaps` with ``per_row`` inputs per command row (8: squared too)."""

    def __init__(self, weights, bias, anchor_size: int, lead: int, per_row: int):
        self.per_row = per_row
        super().__init__(weights, bias, anchor_size, lead, 3, "rate")

    def feature_count(self, horizon: int) -> int:
        return self.anchor_size + self.per_row * (self.lead + horizon + 1)


EXTRA_SIZES = {"gravity": 3, "acc": 3, "velocity_change": 3, "attitude_change": 2}
"""Anchor inputs :func:`layout` can add, and their sizes: the gravity direction R_s^T e_D; the specific force averaged
over 5 rows; the measured velocity's change over the last 5 rows (50 ms) in the anchor's body frame
R_s^T (v_s - v_{s-5}) [m/s]; the roll and pitch change over the last 10 rows (100 ms) [rad]."""

MIXER = np.array([[1, 1, 1, 1], [-1, -1, 1, 1], [1, -1, -1, 1], [1, -1, 1, -1]], dtype=float) / 4
"""Commands in mixer form (``mixed``): their mean and three +-1 sign patterns, the shapes of an X quadrotor's roll,
pitch and yaw torque differences (which pattern is which axis depends on the motor order; an invertible linear map of
the four, so it changes only what the ridge penalises)."""


def layout(extra=(), history: int = 10, lead: int = 10, squares: bool = False, mixed: bool = False):
    """(features(log, anchors, horizon, disturbance) -> (S, D), anchor block size, lead, inputs per command row)."""
    def features(log, anchors, horizon, disturbance):
        anchors = np.asarray(anchors, dtype=int)
        past = np.maximum(anchors[:, None] - np.arange(history)[None, :], 0)
        rows = np.maximum(anchors[:, None] + np.arange(-lead, horizon + 1)[None, :], 0)
        blocks = [log.gyro_b[past].reshape(len(anchors), -1),
                  frames.nav_to_body(log.vel_n[anchors], log.euler[anchors]).reshape(len(anchors), 3), disturbance]
        for name in extra:
            if name == "gravity":
                down = np.tile([0.0, 0.0, 1.0], (len(anchors), 1))
                blocks.append(frames.nav_to_body(down, log.euler[anchors]).reshape(len(anchors), 3))
            elif name == "acc":
                blocks.append(log.acc_b[np.maximum(anchors[:, None] - np.arange(5)[None, :], 0)].mean(axis=1))
            elif name == "velocity_change":
                change = log.vel_n[anchors] - log.vel_n[np.maximum(anchors - 5, 0)]
                blocks.append(frames.nav_to_body(change, log.euler[anchors]).reshape(len(anchors), 3))
            else:  # "attitude_change"
                blocks.append(log.euler[anchors, :2] - log.euler[np.maximum(anchors - 10, 0), :2])
        u = log.u[rows]
        if mixed:
            u = u @ MIXER.T
        if squares:
            u = np.concatenate([u, (u / COMMAND_SCALE) ** 2], axis=2)
        return np.concatenate([*blocks, u.reshape(len(anchors), -1)], axis=1)
    return features, 3 * history + 6 + sum(EXTRA_SIZES[name] for name in extra), lead, 8 if squares else 4


def fit(train, disturbance_of, spec: dict):
    """(the variant's rate maps fitted on the flying spans of ``train``, its features function)."""
    features, anchor_size, lead, per_row = layout(**spec)
    parts = training_parts(train, flying_spans(train), HORIZON, disturbance_of)
    maps = robust_maps(parts, HORIZON, RATE_RIDGE, ROBUST_STEPS, lambda p: features(p[0], p[1], HORIZON, p[2]),
                       lambda p: rate_changes(p[0], p[1], HORIZON), lambda h: anchor_size + per_row * (lead + h + 1),
                       lambda w, b: Maps(w, b, anchor_size, lead, per_row))
    return maps, features


def error_sums(maps, features, logs, disturbance_of) -> tuple[float, float]:
    """(Σ model error norms, Σ naive error norms) over h = 1..H and every flying start of ``logs``."""
    model = naive = 0.0
    for log in logs:
        starts = flying_starts(log)
        predicted = log.gyro_b[starts][:, None, :] + maps.changes(features(log, starts, HORIZON, disturbance_of(log, starts)), HORIZON)
        truth = log.gyro_b[starts[:, None] + np.arange(HORIZON + 1)[None, :]]
        model += float(np.linalg.norm(truth[:, 1:] - predicted, axis=2).sum())
        naive += float(np.linalg.norm(truth[:, 1:] - truth[:, :1], axis=2).sum())
    return model, naive


def scores(train, test, vehicle) -> dict[str, tuple[float, float]]:
    disturbance_of = observer_disturbance(vehicle)
    return {name: error_sums(*fit(train, disturbance_of, spec), test, disturbance_of) for name, spec in VARIANTS.items()}


def main(argv: list[str] | None = None) -> int:
    return nested_main(argv, __doc__, "bench/bench_direct_features.py", "direct_features", scores, list(VARIANTS),
                       "Other inputs for the direct model's rate maps, chosen on the training shapes only",
                       "AV SimErr ratio to naive over h = 1..50 on the flying starts.",
                       {"variants": VARIANTS, "horizon": HORIZON})


if __name__ == "__main__":
    raise SystemExit(main())
