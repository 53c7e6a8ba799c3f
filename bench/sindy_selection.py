"""Sparse regression over the physics base's candidate terms (PySINDy's STLSQ): the comparison of issue #26 item 1.

The joint forward/backward selection of ``diagnose`` (:mod:`quad_modelling.core.diagnosis.physics_base`) refits
the physics model with each set of terms and scores it on held-out flights. The sparse-regression alternative here
works on the *same* regression the fit solves, on the training flights only: per channel (velocity, roll, pitch, yaw
rate) the observer-corrected multi-step error rows of
:func:`~quad_modelling.core.identification.physics_fit._design_blocks` (horizons 0.1, 0.25, 0.5 s), whose columns
are the one physics' wrench per unit constant -- the base's thrust (yaw: torque) column and every candidate's
columns (:data:`EFFECT_COLUMNS`, named by
:func:`~quad_modelling.core.identification.physics_terms.channel_columns`) -- at the base fit's rotor time constant,
delay and observer (the base rung of the diagnosis run). Motor-imbalance columns are the Gauss-Newton columns at gains
1 (its first step), ground effect at the middle offset of its grid (not searched), battery about the mean training
voltage.

Each channel's columns are scaled to unit RMS and its target to unit RMS, so a coefficient is the share of the
target's RMS one unit-RMS column carries; STLSQ (sequentially thresholded least squares, ``pysindy.STLSQ``, ridge
:data:`RIDGE`) zeroes coefficients below the threshold and refits. An effect is *selected* when any of its columns
keeps a nonzero coefficient in any channel. No threshold is privileged by the physics, so every threshold of
:data:`THRESHOLDS` is reported, and :data:`HEADLINE` (fixed before any run) is the one compared in the tables.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from quad_modelling.core.identification.physics_fit import (
    OBSERVERS,
    PhysicsFit,
    _design_blocks,
    _term_design,
    training_segments,
)
from quad_modelling.core.identification.physics_terms import FITTABLE, channel_columns
from quad_modelling.core.physics.parameters import PhysicsParameters

EFFECT_COLUMNS = {
    "rotor_drag": ("drag_xy", "drag_z", "drag_moment"),
    "ground_effect": ("ground_effect",),
    "battery": ("battery",),
    "gyroscopic": ("gyro_body", "gyro_rotor"),
    "motor_imbalance": ("imbalance", "cg_offset"),
}
"""The regressor columns of each candidate (module docstring)."""

THRESHOLDS = (0.003, 0.01, 0.03, 0.1)
"""STLSQ thresholds on the standardised coefficients."""

HEADLINE = 0.01
"""The threshold compared in the tables (fixed before the first run: 1 % of the target's RMS per unit-RMS column)."""

RIDGE = 1e-6
"""STLSQ's ridge weight (``alpha``) on the standardised problem: only a guard against exactly collinear columns."""


def candidate_rows(train: Sequence, vehicle, config, base_fit: PhysicsFit, candidates: Sequence[str]) -> tuple[dict, dict]:
    """Per channel (X (rows, k), y (rows,)) of the training flights and the column names (module docstring)."""
    observer = base_fit.observer
    p = PhysicsParameters.from_vehicle(vehicle)
    segments = training_segments(train, config, observer, min_history_s=max(o.linear_s for o in OBSERVERS.values()))
    terms = tuple(c for c in candidates if c in FITTABLE)
    design = replace(_term_design(terms, segments, vehicle), drag="rotor_drag" in candidates)
    tau, delay = base_fit.values["rotor_time_constant"], base_fit.values["rotor_delay"]
    blocks: dict[str, tuple[list, list]] = {}
    for name, x, y in _design_blocks(p, segments, tau, delay, observer, design):
        xs, ys = blocks.setdefault(name, ([], []))
        xs.append(x)
        ys.append(y)
    rows = {name: (np.vstack(xs), np.concatenate(ys)) for name, (xs, ys) in blocks.items()}
    return rows, channel_columns(design)


def sindy_selection(rows: dict, columns: dict, thresholds: Sequence[float] = THRESHOLDS) -> dict:
    """STLSQ on every channel at each threshold: the selected effects, and the largest standardised coefficient of
    each effect on the unthresholded least squares (how far from any threshold it sits)."""
    import pysindy as ps

    standardised = {}
    for channel, (x, y) in rows.items():
        keep = np.all(np.isfinite(x), axis=1) & np.isfinite(y)
        x, y = x[keep], y[keep]
        scale = np.sqrt(np.mean(x**2, axis=0))
        scale[scale == 0] = 1.0
        standardised[channel] = (x / scale, y / np.sqrt(np.mean(y**2)))
    owner = {col: effect for effect, cols in EFFECT_COLUMNS.items() for col in cols}

    def coefficients(threshold: float) -> dict[str, np.ndarray]:
        out = {}
        for channel, (x, y) in standardised.items():
            optimizer = ps.STLSQ(threshold=threshold, alpha=RIDGE, max_iter=50)
            optimizer.fit(x, y[:, None])
            out[channel] = np.asarray(optimizer.coef_).ravel()
        return out

    def selected(coefs: dict[str, np.ndarray]) -> list[str]:
        found = {owner[col] for channel, c in coefs.items() for col, value in zip(columns[channel], c)
                 if col in owner and value != 0.0}
        return [e for e in EFFECT_COLUMNS if e in found]

    full = {}
    for channel, (x, y) in standardised.items():
        full[channel] = np.linalg.lstsq(x, y, rcond=None)[0]
    largest = {}
    for channel, c in full.items():
        for col, value in zip(columns[channel], c):
            if col in owner:
                largest[owner[col]] = max(largest.get(owner[col], 0.0), float(abs(value)))
    return {"selected": {f"{t:g}": selected(coefficients(t)) for t in thresholds},
            "largest_coefficient": largest,
            "coefficients_lstsq": {ch: dict(zip(columns[ch], map(float, c))) for ch, c in full.items()},
            "rows": {ch: int(len(y)) for ch, (_, y) in standardised.items()}}


def sindy_for(train: Sequence, vehicle, config, base_fit: PhysicsFit, candidates: Sequence[str]) -> dict:
    """:func:`candidate_rows` then :func:`sindy_selection`, with its wall time [s]."""
    import time

    began = time.perf_counter()
    rows, columns = candidate_rows(train, vehicle, config, base_fit, candidates)
    result = sindy_selection(rows, columns)
    result["headline"] = result["selected"][f"{HEADLINE:g}"]
    result["seconds"] = time.perf_counter() - began
    return result


def agreement(pairs: Sequence[tuple[Sequence[str], dict]]) -> str:
    """One line: at each threshold, in how many of the (diagnosis found, sindy result) pairs STLSQ selects exactly
    the diagnosis's effects."""
    if not pairs:
        return ""
    counts = {t: sum(sorted(s["selected"][t]) == sorted(found) for found, s in pairs) for t in pairs[0][1]["selected"]}
    return ("STLSQ selects exactly the diagnosis's effects in " + ", ".join(f"{n} of {len(pairs)} runs at {t}"
                                                                          for t, n in counts.items()) + ".")
