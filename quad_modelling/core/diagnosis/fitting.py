"""Fitting effect parameters on training windows (least squares within bounds, by the one fitting engine of
:mod:`quad_modelling.core.identification.least_squares`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from quad_modelling.core.diagnosis.catalogue import Effect
from quad_modelling.core.evaluation.metrics import rms, root_mean_square
from quad_modelling.core.identification.base_model import BaseModel, predict_batch
from quad_modelling.core.identification.least_squares import LeastSquaresFit, Parameter, fit_least_squares
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import INDEX, VARIABLES
from quad_modelling.errors import ConfigError

FIT_STRIDE = 4
"""Residual rows used when fitting: every 4th sample (25 Hz at 100 Hz, above the 5 Hz smoothing cutoff)."""

MAX_EVALUATIONS = 60
"""Model evaluations per start of an effect fit (each one predicts every training window)."""

DIFF_STEP = 1e-3
"""Relative finite-difference step of the Jacobian on parameters scaled to [0, 1] by their bounds (0.1 % of the
range): chosen with the catalogue (no study recorded); an effect's prediction goes through integration, smoothing
and a per-window trim, and a step this size keeps the difference far above their rounding."""

TOLERANCE = 1e-6
"""Relative change of the parameters and of the cost at which an effect fit stops (scipy's xtol and ftol; chosen
with the catalogue: a 1e-6 change of a [0, 1]-scaled parameter is far below its sigma on any flight)."""


# ----------------------------------------------------------------------------- fitting


@dataclass
class FitResult:
    """Identified parameters of a set of effects (training windows only): the fitting engine's record
    (``engine``: values, HAC sigmas and covariance, held and at-bound flags, advice) split per effect.
    ``evaluations``: model evaluations of this fit and of any fit it was seeded from."""

    effects: list[Effect]
    engine: LeastSquaresFit
    evaluations: int

    def _per_effect(self, values: np.ndarray) -> list[np.ndarray]:
        return np.split(values, np.cumsum([len(e.parameters) for e in self.effects])[:-1])

    @property
    def thetas(self) -> list[np.ndarray]:
        """The parameters of each effect, in the catalogue's order and units."""
        return self._per_effect(self.engine.values)

    @property
    def sigmas(self) -> list[np.ndarray]:
        """1-sigma of each effect's parameters (HAC, windows as blocks); NaN where held or not separable."""
        return self._per_effect(self.engine.sigma)

    @property
    def covariance(self) -> np.ndarray:
        """(P, P) HAC covariance of all parameters in order (NaN rows where held or not separable)."""
        return self.engine.covariance

    @property
    def cost(self) -> float:
        """Half the sum of the squared normalised residuals at the optimum."""
        return self.engine.cost

    @property
    def held(self) -> tuple[str, ...]:
        """The parameters held at their initial value."""
        return tuple(name for name, held in zip(self.engine.names, self.engine.held) if held)

    def params(self) -> dict[str, dict[str, float]]:
        return {e.name: {k: float(v) for k, v in zip(e.parameters, th)} for e, th in zip(self.effects, self.thetas)}


def variable_scales(batch: WindowBatch, predicted: np.ndarray) -> np.ndarray:
    """(18,) scale of each variable's residual: its RMS over the batch's scored rows (>0)."""
    scale = rms(batch.measured[:, batch.warm :], predicted[:, batch.warm :], axis=(0, 1))
    floor = 1e-9 + 1e-6 * root_mean_square(batch.measured[:, batch.warm :], axis=(0, 1))
    return np.maximum(scale, floor)


def fit_effects(
    base: BaseModel, batch: WindowBatch, effects: Sequence[Effect], scales: np.ndarray, variables: Sequence[str] | None = None,
    fixed: Sequence[tuple[Effect, np.ndarray]] = (), smooth_cutoff_hz: float | None = None, starts: int = 1,
    held: Sequence[str] = (),
) -> FitResult:
    """Identify the parameters of ``effects`` on ``batch`` (with ``fixed`` effects held at their values).

    Minimises :math:`\\sum_{w,k,v} ((y_m - y_p)_{w,k,v} / s_v)^2` over the
    scored rows (every :data:`FIT_STRIDE`-th) of the effects' affected
    variables (or ``variables``), :math:`s_v` = ``scales`` (the base model's
    training residual RMS, so each variable weighs by its share of the gap),
    with the one fitting engine (:func:`~quad_modelling.core.identification.least_squares.fit_least_squares`:
    bounds from the catalogue, each parameter searched on its range scaled to [0, 1], ``starts`` - 1 random
    starts besides the catalogue's initial values). ``held``: parameter names (of any of ``effects``) kept at their
    ``initial`` value. The 1-sigma of each free parameter is the engine's HAC sandwich (windows as blocks) at the
    optimum, over the parameters whose Jacobian column is not zero (one on a bound where its term vanishes, drag's
    c_v at 0 on the NanoBench shape split, made J^T J singular and every sigma NaN); the others' stay NaN.
    """
    effects = list(effects)
    if not effects:
        raise ConfigError("fit_effects: no effect to fit")
    names = variables or sorted({v for e in effects for v in e.variables}, key=VARIABLES.index)
    cols = np.array([INDEX[v] for v in names])
    sizes = [len(e.parameters) for e in effects]
    searched = [Parameter(name, float(start), float(low), float(high), transform="unit")
                for e in effects for name, start, low, high in zip(e.parameters, e.initial, e.lower, e.upper)]
    if all(p.name in held for p in searched):
        raise ConfigError(f"fit_effects: every parameter of {', '.join(e.name for e in effects)} is held")
    all_effects = [f[0] for f in fixed] + effects
    rows = slice(batch.warm, None, FIT_STRIDE)
    target = batch.measured[:, rows][:, :, cols]

    def residuals(theta: np.ndarray) -> np.ndarray:
        thetas = [f[1] for f in fixed] + np.split(theta, np.cumsum(sizes)[:-1])
        pred = predict_batch(base, batch, all_effects, thetas, columns=cols, smooth_cutoff_hz=smooth_cutoff_hz)
        return (target - pred[:, rows][:, :, cols]) / scales[cols]

    fit = fit_least_squares(residuals, searched, held=held, random_starts=max(starts, 1) - 1,
                            sample_period_s=batch.dt * FIT_STRIDE, max_evaluations=MAX_EVALUATIONS,
                            diff_step=DIFF_STEP, tolerance=TOLERANCE)
    return FitResult(effects, fit, fit.evaluations)
