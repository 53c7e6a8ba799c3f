r"""The one fitting engine: bounded nonlinear least squares over named parameters, with parameters held at given
values, several starts, HAC 1-sigma, at-bound flags and a *poorly determined* verdict per parameter.

Used by the identification of the linear greybox's constants
(:func:`~quad_modelling.core.identification.greybox_fit.identify_base`) and by the diagnosis's effect fits
(:func:`~quad_modelling.core.diagnosis.fitting.fit_effects`). The physics model's linear identification
(:mod:`~quad_modelling.core.identification.physics_fit`, normal equations) reports through the same record
(:class:`~quad_modelling.core.identification.constants_report.ConstantEstimate`), whose verdict is
:func:`poorly_determined` here.

Problem. Parameters :math:`x_i` (each a :class:`Parameter`: name, start, bounds
:math:`l_i \le x_i \le h_i`) are searched in *search coordinates* :math:`u_i = \phi_i(x_i)`:

* ``linear``: :math:`u = x`;
* ``log``: :math:`u = \ln x` (:math:`0 < l`): for a positive scale searched over decades;
* ``unit``: :math:`u = (x - l) / (h - l)`, the bounds mapped to [0, 1]: every parameter weighs alike in the
  trust region whatever its unit.

The engine minimises :math:`\tfrac12 \sum_{w,t,v} r_{w,t,v}(x)^2` over the free :math:`u` within
:math:`[\phi(l), \phi(h)]` by :func:`scipy.optimize.least_squares` (trust-region reflective, finite-difference
Jacobian), the held parameters fixed at their start. ``r`` is the caller's residual, shaped
(windows, samples, variables): windows are independent blocks, samples ``sample_period_s`` apart. A non-finite
residual (a prediction that diverged) counts as :data:`NON_FINITE_RESIDUAL`. With several starts the lowest
cost wins (the first on a tie).

Uncertainty (1 sigma). At the optimum, the HAC (Newey-West) sandwich of
:func:`~quad_modelling.core.identification.uncertainty.hac_covariance` in search coordinates, windows as blocks,
Bartlett bandwidth :data:`~quad_modelling.core.identification.uncertainty.HAC_BANDWIDTH_S`, over the free
parameters whose Jacobian column *moves* the residual (norm above :data:`MOVING_COLUMN_FRACTION` of the
largest): a parameter on a bound where its term vanishes has no column, and with it :math:`J^T J` would be
singular and every sigma NaN. To the parameters' own units to first order,
:math:`\mathrm{cov}(x) = D\, \mathrm{cov}(u)\, D`, :math:`D = \mathrm{diag}(\partial x / \partial u)`
(1, :math:`x`, :math:`h - l`). A held parameter, one that does not move the residual, or a singular
:math:`J^T J` has sigma NaN.

At a bound (:func:`bound_side`): a free parameter within :data:`AT_BOUND_FRACTION` of its search range (in
search coordinates) from a bound; its value is then the bound's, not the data's, and its sigma the
unconstrained curvature's. Poorly determined (:func:`poorly_determined`): held, not finite, at a bound, sigma
unknown, or sigma above :data:`POOR_RELATIVE_SIGMA` of the value or above :data:`POOR_RANGE_FRACTION` of
the search range.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from quad_modelling.core.identification.uncertainty import bandwidth_samples, hac_covariance

TRANSFORMS = ("linear", "log", "unit")
"""Search coordinates of a parameter (module docstring)."""

AT_BOUND_FRACTION = 1e-3
"""A fitted parameter within this fraction of its search range (in search coordinates: a relative distance for
a ``log`` parameter) from a bound is *at* the bound. The trust-region search stops a few 1e-6 of the range
short of a bound it presses on; 0.1 % of the range is a value no data put there."""

LOG_JUDGED_DECADES = 2
"""Decades of a positive search range beyond which :func:`bound_side` judges in log coordinates."""

POOR_RELATIVE_SIGMA = 0.5
"""sigma / |value| above which a parameter is poorly determined: its 1-sigma interval reaches half way to zero
(the 50 % rule the constants report of ``identify`` has used since it was written)."""

POOR_RANGE_FRACTION = 0.5
"""sigma / (search range) above which a parameter is poorly determined: its 2-sigma interval is as wide as the
whole range searched, so the data did not narrow the search (a value far from zero in a narrow range, which
the relative rule would pass)."""

MOVING_COLUMN_FRACTION = 1e-9
"""A Jacobian column whose norm is below this fraction of the largest column's does not move the residual
(a parameter on a bound where its term vanishes: drag's c_v at 0 on the NanoBench shape split); it is left
out of the covariance."""

NON_FINITE_RESIDUAL = 1e6
"""What a NaN or infinite residual counts as (with its sign; residuals are normalised to ~1): a diverged
prediction costs more than any finite fit, and the search backs off instead of stopping."""

RANDOM_START_SPREAD = 0.15
"""Standard deviation of a random start's offset from the declared start, as a fraction of each parameter's
search range (in search coordinates), clipped to the range: 15 % reaches a neighbouring valley without
scattering the starts over the whole range."""

RANDOM_START_SEED = 0
"""Seed of the random starts (the fit is reproducible)."""


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter: ``name``, ``start`` value and search bounds ``lower`` < ``upper`` in its own unit,
    its search coordinates (``transform``, one of :data:`TRANSFORMS`) and ``step``, its typical change in search
    coordinates (scipy's ``x_scale``). A held parameter keeps its start."""

    name: str
    start: float
    lower: float
    upper: float
    transform: str = "linear"
    step: float = 1.0

    def __post_init__(self) -> None:
        if self.transform not in TRANSFORMS:
            raise ValueError(f"parameter {self.name}: transform {self.transform!r} is none of {', '.join(TRANSFORMS)}")
        if not (math.isfinite(self.lower) and math.isfinite(self.upper) and self.lower < self.upper):
            raise ValueError(f"parameter {self.name}: bounds [{self.lower:g}, {self.upper:g}] are not finite and increasing")
        if self.transform == "log" and self.lower <= 0:
            raise ValueError(f"parameter {self.name}: a log parameter needs a positive lower bound, not {self.lower:g}")
        if not math.isfinite(self.start):
            raise ValueError(f"parameter {self.name}: start {self.start} is not finite")
        if not self.step > 0:
            raise ValueError(f"parameter {self.name}: step {self.step:g} is not positive")

    def to_search(self, value: float) -> float:
        """u = phi(x) (module docstring)."""
        if self.transform == "log":
            return math.log(value)
        if self.transform == "unit":
            return (value - self.lower) / (self.upper - self.lower)
        return float(value)

    def from_search(self, u: float) -> float:
        """x = phi^-1(u)."""
        if self.transform == "log":
            return math.exp(u)
        if self.transform == "unit":
            return self.lower + u * (self.upper - self.lower)
        return float(u)

    def slope(self, u: float) -> float:
        """dx/du at ``u``."""
        if self.transform == "log":
            return math.exp(u)
        if self.transform == "unit":
            return self.upper - self.lower
        return 1.0

    @property
    def search_bounds(self) -> tuple[float, float]:
        return self.to_search(self.lower), self.to_search(self.upper)


def bound_side(value: float, lower: float, upper: float, transform: str = "linear") -> str | None:
    """'lower' or 'upper' when ``value`` lies within :data:`AT_BOUND_FRACTION` of the search range of that bound
    (in the search coordinates of ``transform``; a ``unit`` parameter's fraction is the same as a ``linear``
    one's), else None. An infinite bound is reached only by the value itself. A positive range of more than
    :data:`LOG_JUDGED_DECADES` decades is judged in log coordinates whatever the search's: the greybox's yaw drag
    ratio searched linearly over four decades put a torque constant 9 times its lower bound 'AT BOUND' (0.08 % of
    the linear range; NanoBench B2_circle_slow_rep2, a review, session 29)."""
    wide = 0 < lower <= value and math.isfinite(upper) and upper > lower * 10**LOG_JUDGED_DECADES
    u, lo, hi = (math.log(value), math.log(lower), math.log(upper)) if transform == "log" or wide else (value, lower, upper)
    tolerance = AT_BOUND_FRACTION * (hi - lo) if math.isfinite(hi - lo) else 0.0
    if u <= lo + tolerance:
        return "lower"
    if u >= hi - tolerance:
        return "upper"
    return None


def poorly_determined(value: float, sigma: float, unit: str = "", bounds: tuple[float, float] | None = None,
                      at_bound: bool = False, held: str = "") -> str:
    """Why a fitted value is poorly determined, '' when it is not (module docstring; ``held``: why it was held,
    '' when fitted; ``bounds``: its search range in its unit, None when not searched directly)."""
    if held:
        return f"held at {value:.3g} ({held})"
    if not math.isfinite(value):
        return "not identifiable from these flights"
    if at_bound:
        return f"ended on its search bound [{bounds[0]:.3g}, {bounds[1]:.3g}]" if bounds else "ended on a bound"
    if not math.isfinite(sigma):
        return "no uncertainty (the fit cannot separate it)"
    if sigma > POOR_RELATIVE_SIGMA * abs(value):
        if value == 0:
            return f"sigma {sigma:.2g} {unit} about a value of 0".replace("  ", " ")
        return f"sigma {100.0 * sigma / abs(value):.0f} % of the value"
    if bounds is not None and math.isfinite(bounds[1] - bounds[0]) and sigma > POOR_RANGE_FRACTION * (bounds[1] - bounds[0]):
        return f"sigma {100.0 * sigma / (bounds[1] - bounds[0]):.0f} % of the search range [{bounds[0]:.3g}, {bounds[1]:.3g}]"
    return ""


@dataclass(frozen=True, kw_only=True)
class LeastSquaresFit:
    """The result of :func:`fit_least_squares`, parameters in declaration order.

    ``values`` [each parameter's unit] and ``search_values`` (search coordinates) at the optimum;
    ``held``: kept at the start; ``moving``: free and its Jacobian column moves the residual;
    ``search_covariance`` / ``covariance`` (P, P): HAC, in search coordinates / the parameters' units, NaN rows
    and columns where not moving (all NaN when :math:`J^T J` is singular); ``sigma`` (P,) 1-sigma in the
    parameters' units; ``residuals`` (windows, samples, variables) at the optimum; ``cost`` = half the sum of
    squared residuals; ``evaluations`` of the residual over all starts (without the Jacobian's); ``success``
    and ``message`` of the best start's search."""

    parameters: tuple[Parameter, ...]
    values: np.ndarray
    search_values: np.ndarray
    held: np.ndarray
    moving: np.ndarray
    search_covariance: np.ndarray
    covariance: np.ndarray
    sigma: np.ndarray
    residuals: np.ndarray
    cost: float
    evaluations: int
    success: bool
    message: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def value(self, name: str) -> float:
        return float(self.values[self.index(name)])

    def sigma_of(self, name: str) -> float:
        return float(self.sigma[self.index(name)])

    def at_bound(self, name: str) -> str | None:
        """'lower' / 'upper' when the free parameter ``name`` ended on that bound (:func:`bound_side`), else None."""
        i = self.index(name)
        p = self.parameters[i]
        return None if self.held[i] else bound_side(float(self.values[i]), p.lower, p.upper, p.transform)

    def advice(self, name: str, held_reason: str = "held") -> str:
        """Why ``name`` is poorly determined ('' when it is not; :func:`poorly_determined`)."""
        i = self.index(name)
        p = self.parameters[i]
        return poorly_determined(float(self.values[i]), float(self.sigma[i]), bounds=(p.lower, p.upper),
                                 at_bound=self.at_bound(name) is not None, held=held_reason if self.held[i] else "")


Residuals = Callable[[np.ndarray], np.ndarray]
"""values (P,) in the parameters' units, declaration order -> residuals (windows, samples, variables)."""


def fit_least_squares(
    residuals: Residuals, parameters: Sequence[Parameter], *, sample_period_s: float, max_evaluations: int,
    held: Collection[str] = (), starts: Sequence[Mapping[str, float]] = (), random_starts: int = 0,
    diff_step: float | None = None, tolerance: float = 1e-8,
) -> LeastSquaresFit:
    """Minimise the squared ``residuals`` over ``parameters`` within their bounds (module docstring).

    ``held``: names kept at their start; ``starts``: further starts, each overriding some free parameters' start
    values [their units]; ``random_starts``: further starts offset at random from the declared one
    (:data:`RANDOM_START_SPREAD`, :data:`RANDOM_START_SEED`); ``sample_period_s`` [s]: the spacing of the
    residuals' samples (the HAC bandwidth in samples follows from it); ``max_evaluations`` per start;
    ``diff_step`` (scipy's relative finite-difference step, None: its default) and ``tolerance`` (scipy's xtol
    and ftol) of the search. Raises ValueError on an unknown or duplicate name, a start of a held parameter, or
    when every parameter is held.
    """
    parameters = tuple(parameters)
    names = [p.name for p in parameters]
    if len(set(names)) != len(names):
        raise ValueError(f"fit_least_squares: a parameter name is repeated in {', '.join(names)}")
    for name in [*held, *(n for s in starts for n in s)]:
        if name not in names:
            raise ValueError(f"fit_least_squares: {name!r} is none of the parameters {', '.join(names)}")
    is_held = np.array([p.name in held for p in parameters])
    free = ~is_held
    if not free.any():
        raise ValueError(f"fit_least_squares: every parameter of {', '.join(names)} is held")
    started_held = [n for n in names if n in held and any(n in s for s in starts)]
    if started_held:
        raise ValueError(f"fit_least_squares: a start names {started_held[0]!r}, which is held")
    lower, upper = (np.array(b, dtype=float) for b in zip(*(p.search_bounds for p in parameters)))
    declared = np.clip([p.to_search(p.start) for p in parameters], lower, upper)

    def values_of(u: np.ndarray) -> np.ndarray:
        return np.array([p.from_search(float(x)) for p, x in zip(parameters, u)])

    def full(u_free: np.ndarray) -> np.ndarray:
        u = declared.copy()
        u[free] = u_free
        return u

    shape: list[tuple[int, ...]] = [()]

    def flat_residuals(u_free: np.ndarray) -> np.ndarray:
        r = np.asarray(residuals(values_of(full(u_free))), dtype=float)
        if r.ndim != 3:
            raise ValueError(f"fit_least_squares: residuals must be shaped (windows, samples, variables), not {r.shape}")
        shape[0] = r.shape
        return np.nan_to_num(r, nan=NON_FINITE_RESIDUAL, posinf=NON_FINITE_RESIDUAL, neginf=-NON_FINITE_RESIDUAL).ravel()

    best, evaluations = None, 0
    scale = np.array([p.step for p in parameters])[free]
    for u0 in _starts(parameters, declared, free, lower, upper, starts, random_starts):
        fit = optimize.least_squares(flat_residuals, u0, bounds=(lower[free], upper[free]), method="trf", x_scale=scale,
                                     diff_step=diff_step, xtol=tolerance, ftol=tolerance, max_nfev=max_evaluations)
        evaluations += int(fit.nfev)
        if best is None or fit.cost < best.cost:
            best = fit
    u = full(best.x)
    values = values_of(u)
    moving, search_cov = _hac(best, free, shape[0], sample_period_s)  # every call returns the same shape
    slopes = np.array([p.slope(float(x)) for p, x in zip(parameters, u)])
    covariance = search_cov * np.outer(slopes, slopes)
    diagonal = np.diag(covariance)
    sigma = np.sqrt(np.where(diagonal >= 0, diagonal, np.nan))
    return LeastSquaresFit(parameters=parameters, values=values, search_values=u, held=is_held, moving=moving,
                           search_covariance=search_cov, covariance=covariance, sigma=sigma,
                           residuals=np.asarray(best.fun).reshape(shape[0]), cost=float(best.cost), evaluations=evaluations,
                           success=bool(best.success), message=str(best.message))


def _starts(parameters: tuple[Parameter, ...], declared: np.ndarray, free: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            starts: Sequence[Mapping[str, float]], random_starts: int) -> list[np.ndarray]:
    """The free search coordinates of every start: the declared one, the caller's, then the random ones."""
    out = [declared[free]]
    for overrides in starts:
        u = declared.copy()
        for i, p in enumerate(parameters):
            if p.name in overrides:
                u[i] = np.clip(p.to_search(overrides[p.name]), lower[i], upper[i])
        out.append(u[free])
    rng = np.random.default_rng(RANDOM_START_SEED)
    width = (upper - lower)[free]
    for _ in range(random_starts):
        offset = rng.normal(0.0, RANDOM_START_SPREAD, size=int(free.sum())) * width
        out.append(np.clip(declared[free] + offset, lower[free], upper[free]))
    return out


def _hac(fit: optimize.OptimizeResult, free: np.ndarray, shape: tuple[int, ...], sample_period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(moving (P,), HAC covariance (P, P) in search coordinates) at the optimum ``fit`` (module docstring)."""
    size = free.size
    covariance = np.full((size, size), np.nan)
    jac = np.asarray(fit.jac)
    norms = np.linalg.norm(jac, axis=0)
    moves = norms > MOVING_COLUMN_FRACTION * max(float(norms.max()), 1e-300)
    moving = np.zeros(size, dtype=bool)
    moving[np.flatnonzero(free)[moves]] = True
    if not moves.any():
        return moving, covariance  # no parameter moves the residual at the optimum: every sigma stays NaN
    try:
        cov = hac_covariance(jac[:, moves].reshape(*shape, -1), np.asarray(fit.fun).reshape(shape), bandwidth_samples(sample_period_s))
        covariance[np.ix_(moving, moving)] = cov
    except np.linalg.LinAlgError:
        pass  # a singular J^T J: the parameters are not separable on these data, their sigmas stay NaN
    return moving, covariance
