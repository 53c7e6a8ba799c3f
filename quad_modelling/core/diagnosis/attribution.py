"""Which effect: each effect assessed on held-out windows, greedy ranking, confounding, the ladder."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from quad_modelling.core.diagnosis.catalogue import Effect
from quad_modelling.core.diagnosis.fitting import FitResult, fit_effects
from quad_modelling.core.diagnosis.statistics import (
    bootstrap_shrink,
    correction_correlation,
    normalised_window_gap,
    shrink_of,
    sign_test,
    variable_scores,
    window_rms,
    window_tic,
)
from quad_modelling.core.diagnosis.verdicts import (
    DETERMINED_SIGMAS,
    VERDICTS,
    ParameterCheck,
    fold_stability,
    material_parameters,
    parameter_checks,
    parameter_failure,
    total_error,
)
from quad_modelling.core.evaluation.metrics import root_mean_square
from quad_modelling.core.evaluation.windowed import window_mean
from quad_modelling.core.identification.base_model import (
    BaseModel,
    predict_batch,
)
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import EVAL_VARIABLES, INDEX, VARIABLES

FOUND_MIN_SHRINK = 0.05
"""Smallest held-out shrink of an effect's affected-variable gap to call it found (5 %)."""


FOUND_MIN_WINDOW_FRACTION = 0.6
"""Fraction of held-out windows an effect must improve to be found."""


EXCITED_MIN_CORRECTION = 0.05
"""A held-out window *excites* an effect when the effect's correction of the prediction there,
sum over V_e of RMS(correction_v) / s_v, is at least this fraction of the window's base gap g_w:
an effect that leaves a window's prediction unchanged can neither help nor fail there (ground
effect away from the ground, drag in hover), so such windows are left out of its score."""


AFFECTED_MIN_CORRECTION = math.sqrt(1.0 - (1.0 - FOUND_MIN_SHRINK) ** 2)
"""A candidate variable v of an effect is *affected* when the effect's fitted correction there, RMS(Δŷ_v) over
the training windows the effect excites, is at least this fraction of the base model's training residual RMS
s_v (0.312). A correction of relative size ρ that explained the residual perfectly would leave
sqrt(1 - ρ²) of it: below 0.312 it could not shrink even that variable's own gap by
:data:`FOUND_MIN_SHRINK`, so scoring the variable would only dilute the effect's shrink with a gap it cannot
touch (the gyroscopic yaw term on the LinkQuad, whose I_xx and I_yy differ by 3 %: rho < 0.01 on yaw acceleration).
Decided on the training windows and the fitted effect only (:func:`affected_variables`), one bound for all effects."""


EXCITED_MIN_WINDOWS = 3
"""Fewest excited held-out windows an effect needs to be scored at all."""


CONFOUND_CORRELATION = 0.8
"""|correlation| of two effects' held-out corrections above which they may be confounded."""


CONFOUND_SHRINK_RATIO = 0.5
"""... and the weaker effect must reach this fraction of the stronger one's shrink."""


LADDER_MAX_RUNGS = 4

NUISANCE_MIN_COST_DROP = 0.01
"""A nuisance parameter (the wind of rotor drag) is kept free only when freeing it lowers the training cost by
at least this fraction and every nuisance estimate is at least :data:`NUISANCE_MIN_SIGMAS` sigma from zero:
otherwise the data shows no wind and it is held at zero (an indoor flight)."""

NUISANCE_MIN_SIGMAS = DETERMINED_SIGMAS
"""3 sigma, as a determined parameter: at 2 sigma a simulated flight with no wind freed a wind moment of 2.2 sigma
(a wind of 1 cm/s)."""


# ----------------------------------------------------------------------------- which effect


@dataclass
class EffectOutcome:
    effect: Effect
    theta: np.ndarray | None
    shrink: float
    train_shrink: float
    before: dict[str, float]
    after: dict[str, float]
    after_tic: dict[str, float]
    evidence: dict
    verdict: str
    confounded_with: list[str]
    correction: np.ndarray | None  # (W, N, 18) held-out prediction change
    note: str = ""
    given: list[str] = field(default_factory=list)  # effects held fixed (ranked above) when this outcome was assessed
    alone: EffectOutcome | None = None  # the effect's assessment on its own, when ``given`` is not empty
    variables: tuple[str, ...] = ()  # the affected variables it is scored on (:func:`affected_variables`); () = its candidates
    variable_correction: dict[str, float] = field(default_factory=dict)  # candidate -> training RMS(correction) / s_v
    reason: str = ""  # why the verdict (verdicts module docstring)
    parameters: list[ParameterCheck] = field(default_factory=list)
    stability: dict = field(default_factory=dict)  # fold_stability(), {} when not reached
    total: dict = field(default_factory=dict)  # {"before", "after", "change"}: total held-out error (verdicts.total_error)
    shrink_by_variable: dict = field(default_factory=dict)  # {"train": {v: s}, "held_out": {v: s}}

    def __post_init__(self) -> None:
        if not self.variables:
            self.variables = tuple(self.effect.variables)

    def to_json(self) -> dict:
        e = self.effect
        return {
            "name": e.name,
            "summary": e.summary,
            "variables": list(self.variables),
            "candidate_variables": list(e.variables),
            "variable_correction": self.variable_correction,
            "shrink": self.shrink,
            "train_shrink": self.train_shrink,
            "before": self.before,
            "after": self.after,
            "after_tic": self.after_tic,
            "params": {} if self.theta is None else {k: float(v) for k, v in zip(e.parameters, self.theta)},
            "param_units": dict(zip(e.parameters, e.units)),
            "parameters": [c.to_json(e.plausible_source) for c in self.parameters],
            **({"derived": e.derived(self.theta, np.array([c.sigma for c in self.parameters]))}
               if e.derived is not None and self.theta is not None and self.parameters else {}),
            "shrink_by_variable": self.shrink_by_variable,
            "total_error": self.total,
            "fold_stability": self.stability,
            "evidence": self.evidence,
            "confounded_with": self.confounded_with,
            "verdict": self.verdict,
            "reason": self.reason,
            "given": list(self.given),
            "alone": self._alone_json(),
            **({"note": self.note} if self.note else {}),
        }

    def _alone_json(self) -> dict:
        """The effect assessed on its own against the base model (the shrink that defines the per-effect score)."""
        a = self.alone or self
        return {"shrink": a.shrink, "train_shrink": a.train_shrink, "verdict": a.verdict, "reason": a.reason,
                "params": {} if a.theta is None else {k: float(v) for k, v in zip(a.effect.parameters, a.theta)}}


def affected_variables(batch: WindowBatch, correction: np.ndarray, candidates: Sequence[str], scales: np.ndarray,
                       gap_before: np.ndarray) -> tuple[tuple[str, ...], dict[str, float]]:
    """The effect's affected variables among ``candidates`` and every candidate's relative correction.

    ``batch`` holds the *training* windows, ``correction`` (W, N, 18) the fitted effect's change of the
    prediction there (valid on the candidate columns), ``gap_before`` (W,) the base gap on the candidates.
    Per candidate v, ρ_v = RMS of the correction over the scored rows of the training windows the effect
    excites on its candidates (:func:`excited_windows`; all windows when it excites fewer than
    :data:`EXCITED_MIN_WINDOWS`) divided by s_v. Affected: ρ_v >= :data:`AFFECTED_MIN_CORRECTION`. When no
    candidate reaches it the fitted correction is immaterial everywhere and the effect is judged on all its
    candidates: concentrating it on the variable where it moved most picked the variable where a fit to
    nothing moved most (in a null validation run thrust nonlinearity, ρ <= 0.16 on all four, was *found*
    with 6 % on acc_z alone).
    """
    cols = np.array([INDEX[v] for v in candidates])
    excited = excited_windows(batch, correction, cols, scales, gap_before)
    rows = excited if excited.any() else np.ones(len(batch), dtype=bool)
    moved = root_mean_square(correction[rows][:, batch.warm :][:, :, cols], axis=(0, 1)) / scales[cols]
    ratios = {v: float(moved[i]) for i, v in enumerate(candidates)}
    keep = [v for v in candidates if ratios[v] >= AFFECTED_MIN_CORRECTION]
    return tuple(keep or candidates), ratios


def excited_windows(batch: WindowBatch, correction: np.ndarray, cols: np.ndarray, scales: np.ndarray, gap_before: np.ndarray) -> np.ndarray:
    """(W,) bool: windows whose prediction the effect changes by at least :data:`EXCITED_MIN_CORRECTION`
    of their base gap (normalised as the gap); all False when fewer than :data:`EXCITED_MIN_WINDOWS`."""
    moved = (root_mean_square(correction[:, batch.warm :][:, :, cols], axis=1) / scales[cols]).sum(axis=1)
    excited = moved >= EXCITED_MIN_CORRECTION * gap_before
    return excited if excited.sum() >= EXCITED_MIN_WINDOWS else np.zeros_like(excited)


def held_out_failure(shrink: float, train_shrink: float, ci_low: float, improved: int, windows: int) -> str | None:
    """Why the held-out test of the verdict rules fails (rule 1 of :mod:`~quad_modelling.core.diagnosis.verdicts`),
    or None when it passes: shrink >= :data:`FOUND_MIN_SHRINK`, bootstrap 5 % bound > 0, at least
    :data:`FOUND_MIN_WINDOW_FRACTION` of the excited held-out windows improved, a positive training shrink
    (a held-out gain the fitted flights do not show is chance)."""
    if windows == 0:
        return f"it changes the prediction materially in fewer than {EXCITED_MIN_WINDOWS} held-out windows"
    if shrink < FOUND_MIN_SHRINK:
        if train_shrink >= FOUND_MIN_SHRINK:
            return (f"it fits the training flights ({train_shrink:.0%} shrink) but not the held-out ones "
                    f"({shrink:.1%} < {FOUND_MIN_SHRINK:.0%})")
        return f"held-out shrink {shrink:.1%} < {FOUND_MIN_SHRINK:.0%}"
    if train_shrink <= 0.0:
        return f"it does not shrink the training gap ({train_shrink:.1%}): the held-out gain is chance"
    if ci_low <= 0.0:
        return f"the 90% interval of its held-out shrink reaches {ci_low:.1%}"
    if improved < FOUND_MIN_WINDOW_FRACTION * windows:
        return f"only {improved}/{windows} held-out windows improve (< {FOUND_MIN_WINDOW_FRACTION:.0%})"
    return None


def ranking_key(outcome: EffectOutcome) -> tuple[int, float]:
    """Sort key of the ranking: found effects first, then weak, then not supported, each group by held-out
    shrink (largest first): an effect that failed a rule never outranks one that passed it."""
    return (VERDICTS.index(outcome.verdict), -outcome.shrink)


def assess_effect(
    effect: Effect, base: BaseModel, train: WindowBatch, test: WindowBatch, scales: np.ndarray,
    base_train: np.ndarray, base_test: np.ndarray, fixed: Sequence[tuple[Effect, np.ndarray]] = (),
    reference: dict[str, dict[str, float]] | None = None,
) -> EffectOutcome:
    """Identify one effect on ``train``, score it on ``test`` and give its verdict with the reason (module
    docstring; rules in :mod:`~quad_modelling.core.diagnosis.verdicts`).

    ``fixed``: effects held at their identified parameters (the ones ranked above, :func:`greedy_ranking`);
    ``base_train``/``base_test`` are then the predictions of base + ``fixed`` and the shrink is the
    effect's contribution on top of them. ``reference``: the base model's held-out scores
    (:func:`~quad_modelling.core.diagnosis.statistics.variable_scores`), the unit of the total error
    (default: those of ``base_test``).
    """
    fixed = list(fixed)
    fixed_effects, fixed_thetas = [f[0] for f in fixed], [f[1] for f in fixed]
    candidates = np.array([INDEX[v] for v in effect.variables])
    reason = effect.applicable(train) or effect.applicable(test)
    eval_cols = np.array([INDEX[v] for v in EVAL_VARIABLES])
    before_rms = window_mean(window_rms(test, base_test, eval_cols))
    before = {v: float(before_rms[i]) for i, v in enumerate(EVAL_VARIABLES)}
    if reason:
        return EffectOutcome(effect, None, 0.0, 0.0, before, before, {}, {}, "not supported", [], None, note=f"not evaluated: {reason}",
                             given=[e.name for e in fixed_effects], reason=f"not evaluated: {reason}")
    reference = reference if reference is not None else variable_scores(test, base_test)
    fit = _fit_with_nuisance(effect, base, train, scales, fixed)
    theta, sigma = fit.thetas[0], fit.sigmas[0] if fit.sigmas else None
    after_train = predict_batch(base, train, fixed_effects + [effect], fixed_thetas + [theta], columns=candidates)
    after_test = predict_batch(base, test, fixed_effects + [effect], fixed_thetas + [theta])
    variables, moved = affected_variables(train, after_train - base_train, effect.variables, scales,
                                          normalised_window_gap(train, base_train, candidates, scales))
    cols = np.array([INDEX[v] for v in variables])
    train_before = normalised_window_gap(train, base_train, cols, scales)
    train_excited = excited_windows(train, after_train - base_train, cols, scales, train_before)
    train_shrink = shrink_of(train_before[train_excited], normalised_window_gap(train, after_train, cols, scales)[train_excited])
    gap_before = normalised_window_gap(test, base_test, cols, scales)
    gap_after = normalised_window_gap(test, after_test, cols, scales)
    correction = after_test - base_test
    excited = excited_windows(test, correction, cols, scales, gap_before)
    shrink_all = shrink_of(gap_before, gap_after)
    scored_before, scored_after = gap_before[excited], gap_after[excited]
    shrink = shrink_of(scored_before, scored_after)
    ci = bootstrap_shrink(scored_before, scored_after) if len(scored_before) else (float("nan"), float("nan"))
    improved = int(np.sum(scored_after < scored_before))
    residual = test.measured - base_test
    signature = correction_correlation(test, residual, correction, cols, scales)
    per_window = 1.0 - scored_after / np.where(scored_before > 0, scored_before, 1.0)
    if not len(per_window):
        per_window = np.zeros(1)
    after_rms = window_mean(window_rms(test, after_test, eval_cols))
    after_tic = window_mean(window_tic(test, after_test, eval_cols))
    evidence = {
        "signature_correlation": signature,
        "train_shrink": train_shrink,
        "shrink_ci90": list(ci),
        "windows_improved": improved,
        "windows": int(len(scored_before)),
        "windows_held_out": len(test),
        "shrink_all_windows": shrink_all,
        "sign_test_p": sign_test(improved, len(scored_before)),
        "per_window_shrink_median": float(np.median(per_window)),
        "per_window_shrink_iqr": [float(np.quantile(per_window, 0.25)), float(np.quantile(per_window, 0.75))],
        "fit_evaluations": fit.evaluations,
        "nuisance": {"held": list(fit.held), "free": [n for n in effect.nuisance if n not in fit.held]},
    }
    total = {"before": total_error(test, base_test, reference), "after": total_error(test, after_test, reference)}
    total["change"] = total["after"] - total["before"]
    passes = held_out_failure(shrink, train_shrink, ci[0], improved, len(scored_before)) is None and total["after"] < total["before"]
    material = (material_parameters(effect, theta, base, train, cols, base_train, fixed, fit.held) if passes
                else np.full(len(theta), None))  # only the parameters rules 3-5 need (verdicts module docstring)
    checks = parameter_checks(effect, theta, sigma, base, material, fit.held)
    verdict, why, stability = verdict_with_reason(effect, theta, checks, shrink, train_shrink, ci[0], improved, len(scored_before), total,
                                                  lambda fold: _fit_with_nuisance(replace(effect, initial=tuple(float(v) for v in theta)),
                                                                                  base, fold, scales, fixed, held=fit.held).thetas[0],
                                                  train)
    return EffectOutcome(
        effect, theta, shrink, train_shrink, before, {v: float(after_rms[i]) for i, v in enumerate(EVAL_VARIABLES)},
        {v: float(after_tic[i]) for i, v in enumerate(EVAL_VARIABLES)}, evidence, verdict, [], correction,
        given=[e.name for e in fixed_effects], variables=variables, variable_correction=moved, reason=why,
        parameters=checks, stability=stability, total=total,
        shrink_by_variable={"train": _variable_shrinks(train, base_train, after_train, effect.variables),
                            "held_out": _variable_shrinks(test, base_test, after_test, effect.variables)},
    )


def verdict_with_reason(effect: Effect, theta: np.ndarray, checks: list[ParameterCheck], shrink: float, train_shrink: float, ci_low: float,
             improved: int, windows: int, total: dict, refit, train: WindowBatch) -> tuple[str, str, dict]:
    """(verdict, reason, fold stability) by the rules of :mod:`~quad_modelling.core.diagnosis.verdicts`, in order;
    the folds are fitted only when every earlier rule passes."""
    failure = held_out_failure(shrink, train_shrink, ci_low, improved, windows)
    if failure:
        return "not supported", failure, {}
    if not total["after"] < total["before"]:
        return "not supported", (f"its variables improve ({shrink:.0%}) but the total held-out error of the scored "
                                 f"variables does not fall ({total['before']:.3f} -> {total['after']:.3f})"), {}
    failure = parameter_failure(effect, checks)
    if failure:
        return "weak", failure, {}
    stability = fold_stability(effect, theta, checks, train, refit)
    if not stability["stable"]:
        return "weak", stability["reason"], stability
    return "found", (f"held-out shrink {shrink:.0%} ({improved}/{windows} windows better), total held-out error "
                     f"{total['before']:.3f} -> {total['after']:.3f}, parameters inside bounds and plausible, "
                     f"{stability['reason']}"), stability


def _fit_with_nuisance(effect: Effect, base: BaseModel, train: WindowBatch, scales: np.ndarray,
                       fixed: Sequence[tuple[Effect, np.ndarray]], held: Sequence[str] | None = None) -> FitResult:
    """Fit ``effect`` on ``train``; its nuisance parameters (``Effect.nuisance``) stay held at their initial value
    unless freeing them passes :data:`NUISANCE_MIN_COST_DROP` and :data:`NUISANCE_MIN_SIGMAS` (``held`` given:
    fit with exactly those held)."""
    if held is not None or not effect.nuisance:
        return fit_effects(base, train, [effect], scales, fixed=fixed, held=tuple(held or ()))
    without = fit_effects(base, train, [effect], scales, fixed=fixed, held=effect.nuisance)
    seeded = replace(effect, initial=tuple(float(v) for v in without.thetas[0]))
    with_nuisance = fit_effects(base, train, [seeded], scales, fixed=fixed)
    index = [effect.parameters.index(n) for n in effect.nuisance]
    values, sigmas = with_nuisance.thetas[0][index], with_nuisance.sigmas[0][index]
    significant = bool(np.all(np.abs(values) >= NUISANCE_MIN_SIGMAS * np.nan_to_num(sigmas, nan=np.inf)))
    if with_nuisance.cost <= (1.0 - NUISANCE_MIN_COST_DROP) * without.cost and significant:
        with_nuisance.evaluations += without.evaluations
        return with_nuisance
    without.evaluations += with_nuisance.evaluations
    return without


def _variable_shrinks(batch: WindowBatch, before: np.ndarray, after: np.ndarray, names: Sequence[str]) -> dict[str, float]:
    """Per variable: 1 - mean window RMS after / before, over every window of ``batch``."""
    cols = np.array([INDEX[v] for v in names])
    rms_before = window_mean(window_rms(batch, before, cols))
    rms_after = window_mean(window_rms(batch, after, cols))
    return {v: float(1.0 - rms_after[i] / rms_before[i]) if rms_before[i] > 0 else 0.0 for i, v in enumerate(names)}


def greedy_ranking(
    outcomes: list[EffectOutcome], base: BaseModel, train: WindowBatch, test: WindowBatch, scales: np.ndarray,
    base_train: np.ndarray, base_test: np.ndarray, max_rungs: int = LADDER_MAX_RUNGS,
) -> list[EffectOutcome]:
    """Rank by conditional contribution: the found effect of largest held-out shrink first; then every
    other effect is assessed again with the ones ranked above held at their identified parameters, and the
    found one of largest shrink *on top of them* comes next; until none is found (or ``max_rungs``).

    A twin of a ranked effect (input delay after motor lag) then explains nothing more and stops taking a
    place from a genuinely second effect; an effect is ranked only when it is found on top of the ones above
    (held-out confirmation: its conditional shrink passes and the total held-out error falls again).
    ``outcomes`` are the effects assessed alone (rank 1 is the same as ranking them alone). Returns the ranked outcomes, then the rest by :func:`ranking_key` of their last
    assessment; an outcome assessed on top of others keeps its lone assessment in ``alone``.
    """
    current = {o.effect.name: o for o in outcomes}
    alone = dict(current)
    reference = variable_scores(test, base_test)
    ranked: list[EffectOutcome] = []
    fixed: list[tuple[Effect, np.ndarray]] = []
    ref_train, ref_test = base_train, base_test
    while len(ranked) < max_rungs:
        found = [o for o in current.values() if o.verdict == "found"]
        if not found:
            break
        best = max(found, key=lambda o: o.shrink)
        ranked.append(best)
        del current[best.effect.name]
        fixed.append((best.effect, best.theta))
        if not current or len(ranked) == max_rungs:
            break
        effects, thetas = [f[0] for f in fixed], [f[1] for f in fixed]
        ref_train = predict_batch(base, train, effects, thetas)
        ref_test = predict_batch(base, test, effects, thetas)
        current = {name: assess_effect(o.effect, base, train, test, scales, ref_train, ref_test, fixed, reference)
                   if o.theta is not None else o for name, o in current.items()}
    rest = sorted(current.values(), key=ranking_key)
    for o in ranked + rest:
        if o.given:
            lone = alone[o.effect.name]
            o.alone = lone
            o.confounded_with = lone.confounded_with
            o.evidence.setdefault("correction_correlation", lone.evidence.get("correction_correlation", {}))
    return ranked + rest


def mark_confounded(outcomes: list[EffectOutcome], test: WindowBatch, scales: np.ndarray) -> None:
    """Fill ``confounded_with`` (module docstring rule) and record the correlations in the evidence."""
    for a in outcomes:
        a.evidence.setdefault("correction_correlation", {})
    for i, a in enumerate(outcomes):
        for b in outcomes[i + 1 :]:
            if a.correction is None or b.correction is None:
                continue
            shared = sorted(set(a.variables) & set(b.variables), key=VARIABLES.index)
            if not shared:
                continue
            cols = np.array([INDEX[v] for v in shared])
            rho = correction_correlation(test, a.correction, b.correction, cols, scales)
            a.evidence["correction_correlation"][b.effect.name] = rho
            b.evidence["correction_correlation"][a.effect.name] = rho
            strong, weak = max(a.shrink, b.shrink), min(a.shrink, b.shrink)
            if abs(rho) >= CONFOUND_CORRELATION and strong >= FOUND_MIN_SHRINK and weak >= CONFOUND_SHRINK_RATIO * strong:
                a.confounded_with.append(b.effect.name)
                b.confounded_with.append(a.effect.name)


def total_gap(batch: WindowBatch, predicted: np.ndarray, reference: dict[str, dict[str, float]]) -> float:
    """Mean over EVAL_VARIABLES of RMS_v / RMS_v(base): 1.0 for the base model."""
    scores = variable_scores(batch, predicted)
    ratios = [scores[v]["rms"] / reference[v]["rms"] for v in EVAL_VARIABLES if reference[v]["rms"] > 0]
    return float(np.mean(ratios)) if ratios else float("nan")


def build_ladder(outcomes: list[EffectOutcome], base: BaseModel, train: WindowBatch, test: WindowBatch, scales: np.ndarray,
                 base_test: np.ndarray) -> tuple[list[dict], np.ndarray]:
    """(ladder, best prediction): base -> +best -> +next found effect, each rung identified jointly on the
    training windows; ``normalised_gap`` is the total held-out error of the scored variables
    (:func:`~quad_modelling.core.diagnosis.verdicts.total_error`), ``normalised_gap_all`` the same over the
    12 variables. The best prediction (W, N, 18) is the last rung's (``base_test`` when nothing is found)."""
    reference = variable_scores(test, base_test)
    ladder = [{"effects": [], "gap": reference, "normalised_gap": 1.0, "normalised_gap_all": 1.0, "params": {}}]
    chosen: list[Effect] = []
    best = base_test
    for outcome in [o for o in outcomes if o.verdict == "found"][:LADDER_MAX_RUNGS]:
        seeded = replace(outcome.effect, initial=tuple(float(v) for v in outcome.theta))
        previous = ladder[-1]["params"]
        chosen = [replace(e, initial=tuple(previous[e.name][k] for k in e.parameters)) for e in chosen] + [seeded]
        held = tuple(n for o in outcomes if o.effect.name in {e.name for e in chosen} for n in o.evidence.get("nuisance", {}).get("held", []))
        fit = fit_effects(base, train, chosen, scales, held=held)
        best = predict_batch(base, test, fit.effects, fit.thetas)
        ladder.append({
            "effects": [e.name for e in chosen],
            "gap": variable_scores(test, best),
            "normalised_gap": total_error(test, best, reference),
            "normalised_gap_all": total_gap(test, best, reference),
            "params": fit.params(),
        })
    return ladder, best
