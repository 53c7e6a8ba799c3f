"""The thesis's 18 output variables, and the 12 the evaluation tables report.

Every model predicts, and the evaluation measures, an (N, 18) array whose
columns follow :data:`VARIABLES`, in the internal convention: positions,
velocities and accelerations in N (NED) [m, m/s, m/s²]; roll, pitch, yaw [rad];
their rates (gyro p, q, r, thesis "roll rate" etc.) [rad/s]; angular
accelerations [rad/s²]. Tables show them in display units (:data:`DISPLAY`).
"""

from __future__ import annotations

import numpy as np

VARIABLES: tuple[str, ...] = (
    "pos_x", "pos_y", "pos_z",
    "vel_x", "vel_y", "vel_z",
    "acc_x", "acc_y", "acc_z",
    "roll", "pitch", "yaw",
    "roll_rate", "pitch_rate", "yaw_rate",
    "roll_acc", "pitch_acc", "yaw_acc",
)

EVAL_VARIABLES: tuple[str, ...] = (
    "vel_x", "vel_y", "vel_z",
    "acc_x", "acc_y", "acc_z",
    "roll_rate", "pitch_rate", "yaw_rate",
    "roll_acc", "pitch_acc", "yaw_acc",
)
"""Rows of the thesis's Tables 5-1/5-2 and keys of results.json."""

INDEX: dict[str, int] = {name: i for i, name in enumerate(VARIABLES)}

SI_UNIT: dict[str, str] = {
    **{f"pos_{a}": "m" for a in "xyz"},
    **{f"vel_{a}": "m/s" for a in "xyz"},
    **{f"acc_{a}": "m/s2" for a in "xyz"},
    **{a: "rad" for a in ("roll", "pitch", "yaw")},
    **{f"{a}_rate": "rad/s" for a in ("roll", "pitch", "yaw")},
    **{f"{a}_acc": "rad/s2" for a in ("roll", "pitch", "yaw")},
}

DISPLAY: dict[str, tuple[str, float]] = {
    name: (unit.replace("rad", "deg"), float(np.rad2deg(1.0))) if unit.startswith("rad") else (unit, 1.0)
    for name, unit in SI_UNIT.items()
}
"""Display unit and factor from SI per variable (thesis tables: m/s, m/s², deg/s, deg/s²)."""


def columns(names: tuple[str, ...] | list[str]) -> list[int]:
    """Column indices of ``names`` in an (N, 18) variables array."""
    return [INDEX[name] for name in names]
