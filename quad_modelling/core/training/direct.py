r"""Fitting the direct model's per-horizon linear maps (:mod:`quad_modelling.core.models.direct`): ridge regression
on moments, then reweighted refits for the mean absolute error.

Both maps -- the body rates' (:class:`~quad_modelling.core.models.direct.RateRegression`) and the down velocity's
(:class:`~quad_modelling.core.models.direct.VerticalRegression`) -- take inputs
:math:`z = (a_s, u_{s-L}, \dots, u_{s+H})`, an anchor block :math:`a_s` and the commands, and predict the change of
their outputs y (K of them) h rows after the anchor s. Per h, on every anchor of the training spans' gap-free parts
with room for the history before it and H rows after it, each anchor weighted by :math:`c_s`:

.. math::

    \min_{w}\ \frac{\sum_s c_s \lVert \Delta y_{s,h} - b_h - w^T z_{s,h} \rVert^2}{\sum_s c_s}
        + \lambda \sum_j \sigma_j^2 w_j^2,
    \qquad w = (C_{zz} + \lambda\, \mathrm{diag}\, \sigma^2)^{-1} C_{z\Delta y}, \qquad b_h = \mu_{\Delta y} - w^T \mu_z

(C the c-weighted covariances, σ² their diagonal, λ = :data:`~quad_modelling.core.models.direct.RATE_RIDGE` for the
rates', :data:`~quad_modelling.core.models.direct.VERTICAL_RIDGE` for the down velocity's), from the
moments of z accumulated over the flights: no design matrix held. Every h's inputs are a leading block of z, so one
Gram matrix serves all of them. The score is a mean *absolute* error, so after the least-squares fit (c = 1)
:data:`~quad_modelling.core.models.direct.ROBUST_STEPS` reweighted refits (IRLS for the absolute error) give each anchor
:math:`c_s = 1 / \max(r_s, \delta)`, :math:`r_s` its mean error norm over h = 1..H in the previous fit and δ =
:data:`~quad_modelling.core.models.direct.ROBUST_FLOOR` times their median: a few violent anchors (a gust, a propeller
strike) no longer pull every map.

**The airframe's symmetries** (:mod:`quad_modelling.core.physics.symmetry`; :func:`fit_rate_regression`'s
``symmetries``, not the default): the rate maps can be fitted on the training anchors and their images under every symmetry g of the airframe (for the Crazyflie the mirror images across x and y
and the turn by 180°), as if each training flight had also been flown mirrored. An image maps the inputs linearly,
:math:`z' = T_g z` (the rates and the observer's disturbance by :math:`\det(M) M`, the body velocity by M, the commands
permuted), and the rate changes by :math:`S_g = \det(M) M`, so the images' moments are those of the flights
transformed, :math:`C'_{zz} = T_g C_{zz} T_g^T`, :math:`C'_{z\Delta y} = T_g C_{z\Delta y} S_g^T`, and no image is
built. The symmetries form a group, so the fitted maps are equivariant and an image's error equals its original's:
the reweighting needs no image either. Equal to fitting on mirrored copies of the flights (test).
:func:`train_direct` does not: held out by shape the images leave the pooled AV ratio at 0.488 (the figure-8 0.573 ->
0.559, the helix 0.490 -> 0.499; ``bench/bench_direct_symmetry.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.linalg import block_diag

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models import physics
from quad_modelling.core.models.direct import (
    ACCELERATION_ROWS,
    ANCHOR_INPUTS,
    COMMAND_LEAD,
    HORIZON,
    RATE_HISTORY,
    RATE_RIDGE,
    ROBUST_FLOOR,
    ROBUST_STEPS,
    VELOCITY_HISTORY,
    VERTICAL_RIDGE,
    DirectModel,
    HorizonMaps,
    RateRegression,
    VerticalRegression,
    anchor_features,
    check_period,
    feature_count,
    vertical_feature_count,
    vertical_features,
)
from quad_modelling.core.models.physics import PhysicsPredictor
from quad_modelling.core.physics.symmetry import Symmetry, airframe_symmetries
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import gap_free_runs, rows_between
from quad_modelling.errors import ConfigError, DataError

Part = tuple[FlightLog, np.ndarray, "np.ndarray | None"]
"""One gap-free part of a training span: (flight, anchors (S,), the observer's angular disturbance (S, 3) or None)."""


def training_parts(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], horizon: int,
                   angular_disturbance: Callable[[FlightLog, np.ndarray], np.ndarray] | None,
                   acceleration_rows: int = ACCELERATION_ROWS) -> list[Part]:
    """Every gap-free part of the ``spans`` [s from each flight's start; None: the whole flight] with the history
    before (the inputs' rows and ``acceleration_rows`` of down acceleration) and ``horizon`` rows after each anchor,
    with ``angular_disturbance(flight, anchors)`` if given. DataError when a flight lacks the gyro."""
    parts = []
    for log, span in zip(logs, spans):
        log.require(("gyro_b",), "the direct model's training (its regression predicts the gyro rates)")
        start, stop = (0, len(log)) if span is None else rows_between(log, *span)
        for a, b in gap_free_runs(log, start, stop):
            anchors = np.arange(a + max(COMMAND_LEAD, RATE_HISTORY - 1, VELOCITY_HISTORY - 1, acceleration_rows - 1), b - horizon)
            if anchors.size:
                parts.append((log, anchors, None if angular_disturbance is None else angular_disturbance(log, anchors)))
    return parts


def rate_changes(log: FlightLog, anchors: np.ndarray, horizon: int) -> np.ndarray:
    """(S, horizon, 3) measured Δω_{s,h} = ω_{s+h} - ω_s [rad/s] for h = 1..horizon."""
    return log.gyro_b[anchors[:, None] + np.arange(1, horizon + 1)[None, :]] - log.gyro_b[anchors][:, None, :]


def down_velocity_changes(log: FlightLog, anchors: np.ndarray, horizon: int) -> np.ndarray:
    """(S, horizon, 1) measured Δv_{D,s,h} = v_D(s+h) - v_D(s) [m/s] for h = 1..horizon."""
    down = log.vel_n[:, 2]
    return (down[anchors[:, None] + np.arange(1, horizon + 1)[None, :]] - down[anchors][:, None])[..., None]


Inputs = Callable[[Part], np.ndarray]
"""z (S, D_H) of a part's anchors."""
Targets = Callable[[Part], np.ndarray]
"""Δy (S, H, K) of a part's anchors."""


Image = tuple[np.ndarray, np.ndarray]
"""(T (D_H, D_H), S (K, K)): how one symmetry of the airframe maps the inputs z and the output changes Δy."""


def ridge_maps(parts: Sequence[Part], weights: Sequence[np.ndarray], horizon: int, ridge: float, inputs: Inputs,
               targets: Targets, count: Callable[[int], int], images: Sequence[Image] = ()) -> tuple[np.ndarray, np.ndarray]:
    """(weights (H, D_H, K), bias (H, K)) minimising the c-weighted squared error plus the ridge (module docstring),
    from moments accumulated over ``parts`` with anchor weights ``weights`` (one array per part); ``count(h)`` = D_h.
    With ``images`` (a group of the airframe's symmetries, the identity among them), the moments of every anchor's
    images too. DataError without a part."""
    if not parts:
        raise DataError("direct model: no gap-free part of the training spans holds an anchor with its history and horizon")
    n, sum_z, sum_zz, sum_y, sum_zy = 0.0, 0.0, 0.0, 0.0, 0.0
    for part, c in zip(parts, weights):
        z, change = inputs(part), targets(part)
        cz = z * c[:, None]
        n += c.sum()
        sum_z = sum_z + cz.sum(axis=0)
        sum_zz = sum_zz + cz.T @ z
        sum_y = sum_y + np.einsum("s,shk->hk", c, change)
        sum_zy = sum_zy + np.einsum("sd,shk->hdk", cz, change)
    if images:
        n, sum_z, sum_zz, sum_y, sum_zy = (
            n * len(images), sum(t @ sum_z for t, _ in images), sum(t @ sum_zz @ t.T for t, _ in images),
            sum(sum_y @ s.T for _, s in images), sum(np.einsum("ed,hdk,lk->hel", t, sum_zy, s) for t, s in images))
    mean_z, mean_y = sum_z / n, sum_y / n
    covariance = sum_zz / n - np.outer(mean_z, mean_z)
    variance = np.maximum(np.diag(covariance), 1e-12)
    out, bias = np.zeros((horizon, len(mean_z), mean_y.shape[1])), np.zeros_like(mean_y)
    for h in range(1, horizon + 1):
        d = count(h)
        cross = sum_zy[h - 1, :d] / n - np.outer(mean_z[:d], mean_y[h - 1])
        out[h - 1, :d] = np.linalg.solve(covariance[:d, :d] + ridge * np.diag(variance[:d]), cross)
        bias[h - 1] = mean_y[h - 1] - mean_z[:d] @ out[h - 1, :d]
    return out, bias


def robust_maps(parts: Sequence[Part], horizon: int, ridge: float, robust_steps: int, inputs: Inputs, targets: Targets,
                count: Callable[[int], int], make: Callable[[np.ndarray, np.ndarray], HorizonMaps],
                images: Sequence[Image] = ()) -> HorizonMaps:
    """``make(weights, bias)`` of the least-squares maps, then of ``robust_steps`` reweighted refits (module docstring),
    with the anchors' ``images`` under the airframe's symmetries."""
    weights = [np.ones(len(anchors)) for _, anchors, _ in parts]
    maps = make(*ridge_maps(parts, weights, horizon, ridge, inputs, targets, count, images))
    for _ in range(robust_steps):
        errors = [np.linalg.norm(targets(part) - maps.changes(inputs(part), horizon), axis=2).mean(axis=1) for part in parts]
        floor = ROBUST_FLOOR * float(np.median(np.concatenate(errors)))
        weights = [1.0 / np.maximum(r, max(floor, 1e-12)) for r in errors]
        maps = make(*ridge_maps(parts, weights, horizon, ridge, inputs, targets, count, images))
    return maps


def rate_images(symmetries: Sequence[Symmetry], horizon: int, anchor_inputs: Sequence[str]) -> list[Image]:
    """(T_g, S_g) of each symmetry for the rate maps' inputs z (:func:`~quad_modelling.core.models.direct.anchor_features`'
    layout: n_ω rate rows, the ``anchor_inputs``, L + horizon + 1 command rows) and their rate changes."""
    images = []
    for symmetry in symmetries:
        axial = symmetry.axial
        anchor = {"body_velocity": symmetry.matrix, "angular_disturbance": axial}
        permutation = np.eye(len(symmetry.source))[symmetry.source]  # (Π u)_j = u_source[j]
        blocks = [np.kron(np.eye(RATE_HISTORY), axial), *[anchor[name] for name in anchor_inputs],
                  np.kron(np.eye(COMMAND_LEAD + horizon + 1), permutation)]
        images.append((block_diag(*blocks), axial))
    return images


def fit_rate_regression(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], horizon: int = HORIZON,
                        ridge: float = RATE_RIDGE, robust_steps: int = ROBUST_STEPS,
                        angular_disturbance: Callable[[FlightLog, np.ndarray], np.ndarray] | None = None,
                        anchor_inputs: Sequence[str] | None = None,
                        symmetries: Sequence[Symmetry] = ()) -> tuple[RateRegression, int]:
    """(the rate maps fitted on the ``spans`` [s from each flight's start; None: the whole flight] of ``logs``, number
    of anchors): ridge per horizon, then ``robust_steps`` reweighted refits (module docstring). The ``anchor_inputs``
    (default: the body velocity, and the observer's angular disturbance when ``angular_disturbance(flight, anchors)``
    (S, 3) gives it, as :func:`train_direct` does with the physics model's observer); with ``symmetries`` (a group, the
    identity among them: :func:`~quad_modelling.core.physics.symmetry.airframe_symmetries`) fitted on the anchors'
    images under them too (module docstring). DataError when no gap-free part
    of a span holds the lead and ``horizon`` rows after an anchor, or a flight lacks the gyro."""
    if horizon < 1:
        raise ConfigError(f"direct model: horizon {horizon} must be >= 1")
    if anchor_inputs is None:
        inputs = tuple(i for i in ANCHOR_INPUTS if i != "angular_disturbance" or angular_disturbance is not None)
    else:
        inputs = tuple(anchor_inputs)
    if "angular_disturbance" in inputs and angular_disturbance is None:
        raise ConfigError("direct model: the angular_disturbance input needs the observer's disturbance (angular_disturbance=)")
    parts = training_parts(logs, spans, horizon, angular_disturbance)
    n, size = sum(len(anchors) for _, anchors, _ in parts), feature_count(horizon, anchor_inputs=inputs)
    if n < size:
        raise DataError(f"direct model: {n} training anchors for {size} inputs; the training spans need more gap-free rows "
                        f"({COMMAND_LEAD} before and {horizon} after each anchor)")

    regression = robust_maps(parts, horizon, ridge, robust_steps,
                             lambda part: anchor_features(part[0], part[1], horizon, part[2], anchor_inputs=inputs),
                             lambda part: rate_changes(part[0], part[1], horizon),
                             lambda h: feature_count(h, anchor_inputs=inputs),
                             lambda weights, bias: RateRegression(weights, bias, anchor_inputs=inputs),
                             rate_images(symmetries, horizon, inputs))
    return regression, n


def fit_vertical_regression(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], horizon: int = HORIZON,
                            ridge: float = VERTICAL_RIDGE, robust_steps: int = ROBUST_STEPS,
                            acceleration_rows: int = ACCELERATION_ROWS) -> VerticalRegression:
    """The down-velocity maps (:class:`~quad_modelling.core.models.direct.VerticalRegression`) fitted on the ``spans``
    of ``logs`` as :func:`fit_rate_regression` fits the rates', the down acceleration averaged over
    ``acceleration_rows`` rows. DataError when a flight lacks the accelerometer (an input) or no gap-free part holds
    an anchor."""
    for log in logs:
        log.require(("acc_b",), "the direct model's vertical map (the accelerometer's down acceleration is an input)")
    parts = training_parts(logs, spans, horizon, None, acceleration_rows)
    if sum(len(anchors) for _, anchors, _ in parts) < vertical_feature_count(horizon):
        raise DataError(f"direct model: too few training anchors for the vertical map's {vertical_feature_count(horizon)} inputs")
    return robust_maps(parts, horizon, ridge, robust_steps,
                       lambda part: vertical_features(part[0], part[1], horizon, acceleration_rows=acceleration_rows),
                       lambda part: down_velocity_changes(part[0], part[1], horizon),
                       vertical_feature_count,
                       lambda weights, bias: VerticalRegression(weights, bias, acceleration_rows=acceleration_rows))


def train_direct(logs: Sequence[FlightLog], spans: Sequence[tuple[float, float] | None], vehicle: VehicleConfig) -> DirectModel:
    """A direct model of ``vehicle`` with its maps fitted on ``spans`` of ``logs``, which must share one sample
    period (the first flight's median; DataError naming a flight of another). The vertical map is fitted when every
    flight has an accelerometer (its training record says so). Its training record names the vehicle file
    (``vehicle_file``), so a load with other constants can say which file to pass."""
    if not logs or len(logs) != len(spans):
        raise DataError(f"direct model: {len(logs)} training flights for {len(spans)} spans")
    dt = float(np.median(np.diff(logs[0].t))) if len(logs[0]) > 1 else 0.0
    if not dt > 0:
        raise DataError(f"{logs[0].meta.source}: too few rows to train the direct model")
    for log in logs:
        check_period(log, dt)
    model = PhysicsPredictor(vehicle)

    def observed(log: FlightLog, anchors: np.ndarray) -> np.ndarray:  # as the multi-step form anchors (horizon_inputs)
        return physics.anchor_state(model.params, log, anchors, model.observer)[1].angular_b

    regression, anchors = fit_rate_regression(logs, spans, angular_disturbance=observed)
    without = [log.meta.source for log in logs if log.acc_b is None]
    vertical = None if without else fit_vertical_regression(logs, spans)
    training = {"samples": anchors, "flights": [log.meta.source for log in logs], "ridge": RATE_RIDGE,
                "vertical_ridge": VERTICAL_RIDGE,
                "vehicle_file": vehicle.file_path,
                "vertical_map": "fitted" if vertical is not None else f"not fitted: no accelerometer in {without[0]}"}
    return DirectModel(vehicle, regression, dt, training, vertical)
