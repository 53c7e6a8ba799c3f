"""Fitting effect parameters on training windows (least squares within bounds)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from quad_modelling.core.diagnosis.catalogue import Effect
from quad_modelling.core.evaluation.metrics import rms, root_mean_square
from quad_modelling.core.identification.base_model import BaseModel, predict_batch
from quad_modelling.core.identification.uncertainty import bandwidth_samples, hac_covariance
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import INDEX, VARIABLES
from quad_modelling.errors import ConfigError

FIT_STRIDE = 4
"""Residual rows used when fitting: every 4th sample (25 Hz at 100 Hz, above the 5 Hz smoothing cutoff)."""


# ----------------------------------------------------------------------------- fitting


@dataclass
class FitResult:
    """Identified parameters of a set of effects (training windows only)."""

    effects: list[Effect]
    thetas: list[np.ndarray]
    cost: float
    evaluations: int
    success: bool
    message: str
    sigmas: list[np.ndarray] | None = None  # 1-sigma per parameter (HAC, windows as blocks); NaN where held or singular
    held: tuple[str, ...] = ()  # parameters held at their initial value
    covariance: np.ndarray | None = None  # (P, P) HAC covariance of all parameters in order (NaN rows where held)

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
    with :func:`scipy.optimize.least_squares` (trust-region reflective, bounds
    from the catalogue, parameters scaled by their bound widths). ``held``: parameter names (of any of
    ``effects``) kept at their ``initial`` value. The 1-sigma of each free parameter is the HAC sandwich of
    :func:`~quad_modelling.core.identification.uncertainty.hac_covariance` (windows as blocks) at the optimum,
    over the parameters whose Jacobian column is not zero (one on a bound where its term vanishes, drag's c_v at
    0 on the NanoBench shape split, made J^T J singular and every sigma NaN); the others' stay NaN.
    """
    effects = list(effects)
    if not effects:
        raise ConfigError("fit_effects: no effect to fit")
    names = variables or sorted({v for e in effects for v in e.variables}, key=VARIABLES.index)
    cols = np.array([INDEX[v] for v in names])
    sizes = [len(e.parameters) for e in effects]
    lower = np.concatenate([e.lower for e in effects]).astype(float)
    upper = np.concatenate([e.upper for e in effects]).astype(float)
    x0 = np.clip(np.concatenate([e.initial for e in effects]).astype(float), lower, upper)
    width = upper - lower
    all_effects = [f[0] for f in fixed] + effects
    rows = slice(batch.warm, None, FIT_STRIDE)
    target = batch.measured[:, rows][:, :, cols]

    def split(z: np.ndarray) -> list[np.ndarray]:
        theta = lower + z * width
        return np.split(theta, np.cumsum(sizes)[:-1])

    def residuals(z: np.ndarray) -> np.ndarray:
        thetas = [f[1] for f in fixed] + split(z)
        pred = predict_batch(base, batch, all_effects, thetas, columns=cols, smooth_cutoff_hz=smooth_cutoff_hz)
        r = (target - pred[:, rows][:, :, cols]) / scales[cols]
        r = np.nan_to_num(r, nan=1e6, posinf=1e6, neginf=-1e6)
        return r.ravel()

    z0 = (x0 - lower) / width
    names_all = [name for e in effects for name in e.parameters]
    free = np.array([name not in held for name in names_all])
    if not free.any():
        raise ConfigError(f"fit_effects: every parameter of {', '.join(e.name for e in effects)} is held")

    def full(z_free: np.ndarray) -> np.ndarray:
        z = z0.copy()
        z[free] = z_free
        return z

    candidates = [z0[free]]
    rng = np.random.default_rng(0)
    for _ in range(max(starts, 1) - 1):
        candidates.append(np.clip(z0[free] + rng.normal(0.0, 0.15, size=int(free.sum())), 0.0, 1.0))
    best = None
    evaluations = 0
    for z in candidates:
        fit = optimize.least_squares(lambda zf: residuals(full(zf)), z, bounds=(0.0, 1.0), method="trf", diff_step=1e-3,
                                     xtol=1e-6, ftol=1e-6, max_nfev=60)
        evaluations += fit.nfev
        if best is None or fit.cost < best.cost:
            best = fit
    cov_theta = np.full((z0.size, z0.size), np.nan)
    shape = target.shape
    jac = np.asarray(best.jac)
    norms = np.linalg.norm(jac, axis=0)
    moving = norms > 1e-9 * max(float(norms.max()), 1e-300)  # a parameter on a bound where it does nothing: no column
    covered = np.flatnonzero(free)[moving]
    try:
        if moving.any():  # else no parameter moves the prediction at the optimum: every sigma stays NaN
            cov = hac_covariance(jac[:, moving].reshape(*shape, -1), best.fun.reshape(shape), bandwidth_samples(batch.dt, FIT_STRIDE))
            cov_theta[np.ix_(covered, covered)] = cov * np.outer(width[covered], width[covered])
    except np.linalg.LinAlgError:
        pass  # a singular J^T J: the parameters are not separable on these windows, their sigmas stay NaN
    sigma = np.sqrt(np.clip(np.diag(cov_theta), 0.0, None))
    return FitResult(effects, split(full(best.x)), float(best.cost), evaluations, bool(best.success), str(best.message),
                     sigmas=np.split(sigma, np.cumsum(sizes)[:-1]), held=tuple(n for n in names_all if n in held),
                     covariance=cov_theta)
