"""Diagnosis reports: report.md (plain-language verdict first), diagnosis.json and figures.

The tables show display units (:mod:`quad_modelling.io.reports.formatting`); diagnosis.json keeps
the SI units of :meth:`quad_modelling.core.diagnosis.diagnose.Diagnosis.to_json`. Every line of
report.md and of the console verdict is at most :data:`~quad_modelling.io.reports.formatting.REPORT_WIDTH`
characters: prose is wrapped, each effect gets a small block instead of a column of one wide table.
Figures use matplotlib's Agg backend (no display needed).

Verdicts are ``found``, ``weak`` and ``not supported``; documents written before that vocabulary
(``rejected``, ``insignificant``) are shown with it (:data:`LEGACY_VERDICTS`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from quad_modelling.core.diagnosis.diagnose import Diagnosis
from quad_modelling.core.diagnosis.localisation import (
    CONCENTRATION_MIN_RATIO,
    FREQUENCY_BANDS_HZ,
    SCORED_VARIABLES,
    band_labels,
    residual_psd,
    scaled_residual,
)
from quad_modelling.core.variables import DISPLAY, EVAL_VARIABLES, INDEX, SI_UNIT
from quad_modelling.io.reports.formatting import (
    display_number,
    display_value,
    json_text,
    narrow_table,
    percent,
    prose,
    tic_text,
    variable_label,
)

LEGACY_VERDICTS = {"rejected": "not supported", "insignificant": "not supported"}
"""Verdicts of older diagnosis.json documents and the one they are shown as."""


SUMMARY_COLUMNS = ("#", "effect", "verdict", "held-out", "training", "windows", "total error")
"""Columns of the ranked summary table of report.md (one block per effect follows it)."""


VERDICT_COLOURS = {"found": "tab:green", "weak": "tab:orange", "not supported": "0.6"}


REGIME_PHRASES = {"time_in_window": ("late in the window", "early in the window")}
"""How a concentration at the (high, low) end of a regime reads when ``at high <regime>`` would not."""


def verdict_of(effect: dict) -> str:
    """The effect's verdict in the current vocabulary (:data:`LEGACY_VERDICTS`)."""
    return LEGACY_VERDICTS.get(effect["verdict"], effect["verdict"])


def reason_of(effect: dict) -> str:
    """Why the effect got its verdict, as a sentence: its ``reason``, else (older documents) its note or its shrinks."""
    text = effect.get("reason") or effect.get("note") or (
        f"held-out shrink {percent(effect['shrink'])}, training shrink {percent(effect['train_shrink'])}")
    text = text.strip()
    names = set(effect.get("params", {}))
    first = text.split(" ", 1)[0]
    if first not in names:  # a parameter's name (g_ref, c_h) keeps its case
        text = text[0].upper() + text[1:]
    return text + ("" if text.endswith(".") else ".")


# ----------------------------------------------------------------------------- verdict


def verdict_text(data: dict) -> str:
    """Plain-language verdict, lines of at most 100 characters: where the gap lies (base model and after
    the best model), which effect explains it, how far it shrinks, the weak and unsupported effects."""
    effects = data["effects"]
    found = [e for e in effects if verdict_of(e) == "found"]
    weak = [e for e in effects if verdict_of(e) == "weak"]
    unsupported = [e for e in effects if verdict_of(e) == "not supported"]
    where = data.get("where")
    best = data.get("best_effects", [e["name"] for e in found])
    paragraphs = [_base_where(data)]
    if found:
        paragraphs += _which(data, found)
    elif where:
        paragraphs.append("Which: nothing in the catalogue explains the gap; it lies in " + _unexplained(where) + ".")
    else:
        paragraphs.append("Which: no catalogue effect shrinks the held-out gap consistently (none found).")
    if where and best:
        paragraphs.append(f"After the best model (base + {' + '.join(best)}) the unexplained held-out error lies in "
                          + _unexplained(where) + ".")
    lines = [line for text in paragraphs for line in prose(text)]
    if weak:
        lines += ["Weak (hints, not findings):"] + [line for e in weak for line in prose(f"{e['name']}: {reason_of(e)}", first="- ",
                                                                                           rest="  ")]
    if unsupported:
        lines += prose("Not supported: " + ", ".join(e["name"] for e in unsupported) + " (reasons under Effects in report.md).")
    lines += prose(_learnable(data))
    return "\n".join(line for line in lines if line)


def _base_where(data: dict) -> str:
    """The base model's held-out gap: the scored variables of largest TIC, a regime it concentrates in."""
    gap = data["gap"]
    scored = [v for v in (data.get("where") or {}).get("scored_variables", SCORED_VARIABLES) if v in gap]
    worst = sorted(scored, key=lambda v: gap[v]["tic"], reverse=True)[:3]
    text = "Where: the base model's largest held-out gap (TIC) is in " + ", ".join(f"{v} ({tic_text(gap[v]['tic'])})" for v in worst) + "."
    # time since the anchor left out: over the 12 variables it measures the open-loop drift of velocities and rates
    regimes = {k: r.get("ratio_top_to_bottom") for k, r in data["regimes"].get("regimes", {}).items() if k != "time_in_window"}
    ratios = {k: (max(r, 1.0 / r), "high" if r >= 1.0 else "low") for k, r in regimes.items() if r and math.isfinite(r) and r > 0}
    if ratios:
        k = max(ratios, key=lambda name: ratios[name][0])
        ratio, side = ratios[k]
        if ratio >= CONCENTRATION_MIN_RATIO:
            text += f" It concentrates {_regime_phrase(k, side)}: {ratio:.1f}x the opposite quartile's normalised RMS."
        else:
            text += (f" No regime concentrates it (largest quartile ratio {ratio:.2f}x, {k.replace('_', ' ')}; "
                     f"a concentration needs {CONCENTRATION_MIN_RATIO:g}x).")
    return text


def _which(data: dict, found: list[dict]) -> list[str]:
    """The found effects: the first with its shrink, interval, windows, best variable and reason; the rest."""
    base_rms = {v: data["gap"][v]["rms"] for v in EVAL_VARIABLES}
    top = found[0]
    ev = top["evidence"]
    best_var = max(top["variables"], key=lambda v: 1 - top["after"][v] / base_rms[v] if base_rms[v] > 0 else 0)
    low, high = ev["shrink_ci90"]
    out = [f"Which: {top['name']} ({top['summary']}) shrinks the held-out gap on {', '.join(top['variables'])} by "
           f"{top['shrink']:.0%} (90% interval {percent(low, 0)}..{percent(high, 0)}, {ev['windows_improved']}/{ev['windows']} "
           f"windows better); {best_var} RMS {display_value(best_var, base_rms[best_var])} -> "
           f"{display_value(best_var, top['after'][best_var])}. Why: {reason_of(top)}"]
    if len(found) > 1:
        out.append("Also found, each on top of the effects ranked above it: "
                   + ", ".join(f"{e['name']} ({e['shrink']:.0%}; alone {e['alone']['shrink']:.0%})" for e in found[1:]) + ".")
    twins = [e for e in data["effects"] if e.get("given") and verdict_of(e["alone"]) == "found" and verdict_of(e) != "found"]
    if twins:
        out.append("Found alone but adding nothing on top of the effects ranked above: "
                   + ", ".join(f"{e['name']} (alone {e['alone']['shrink']:.0%}, on top {e['shrink']:.0%})" for e in twins) + ".")
    if top["confounded_with"]:
        out.append(f"Warning: on this data {top['name']} cannot be told apart from {', '.join(top['confounded_with'])}.")
    if len(data["ladder"]) > 1:
        last = data["ladder"][-1]
        out.append(f"With all found effects ({' + '.join(last['effects'])}) the mean held-out RMS over the scored "
                   f"variables is {last['normalised_gap']:.0%} of the base model's.")
    return out


def _unexplained(where: dict) -> str:
    """``acc_z (41%), roll_acc (22%), at 1-3 Hz (52% of its power), at high speed (1.8x)`` from
    :func:`~quad_modelling.core.diagnosis.localisation.rank_unexplained`'s document: the variables that
    together hold half the error (at most 3), the leading band, the leading regime if concentrated."""
    picked, total = [], 0.0
    for row in where["variables"]:
        if len(picked) == 3 or (picked and total >= 0.5):
            break
        picked.append(f"{row['variable']} ({percent(row['share'], 0)})")
        total += row["share"]
    parts = [", ".join(picked)]
    if where["bands"]:
        band = where["bands"][0]
        parts.append(f"at {band['band']} ({percent(band['share'], 0)} of its power)")
    regime = next((r for r in where["regimes"] if r.get("concentrated")), None)
    if regime:
        parts.append(f"{_regime_phrase(regime['regime'], regime['side'])} ({regime['ratio']:.1f}x)")
    else:
        parts.append(f"in no particular regime (no quartile ratio >= {CONCENTRATION_MIN_RATIO:g}x)")
    return ", ".join(parts)


def _regime_phrase(name: str, side: str) -> str:
    if name in REGIME_PHRASES:
        return REGIME_PHRASES[name][0 if side == "high" else 1]
    return f"at {side} {name.replace('_', ' ')}"


def _learnable(data: dict) -> str:
    learnable = data.get("learnable")
    if not learnable:
        return ""
    if not learnable.get("gap"):
        return f"Learnable: {learnable['note']}."
    floor = learnable["gap"]
    better = [v for v in EVAL_VARIABLES if floor[v]["rms"] < data["gap"][v]["rms"]]
    return (f"Learnable: the NARX model beats the base model on {len(better)} of 12 variables"
            + (f" ({', '.join(better)})" if better else "") + ".")


# ----------------------------------------------------------------------------- report.md


def markdown_report(data: dict, vehicle: str, figures: list[str]) -> str:
    """report.md from diagnosis.json's document ``data``: verdict, data used, the effects (a ranked summary,
    then one block each), held-out gap per variable, ladder, where the error after the best model lies,
    the base residual by regime and frequency band, worst windows, then the ``figures`` (file names)."""
    out = [f"# Sim-to-real gap diagnosis ({vehicle})", "", "## Verdict", "", verdict_text(data), ""]
    out += ["## Data", ""] + _data_lines(data) + [""]
    out += ["## Effects", ""]
    out += prose("Ranked by conditional contribution: rank 1 is the found effect of largest held-out shrink; every later "
                 "rank is assessed with the effects above it held at their identified parameters ('on top of'), so its "
                 "shrink is what it adds to them; 'alone' is the effect assessed on its own against the base model. "
                 "Held-out and training: shrink of the gap on the effect's variables; windows: held-out windows "
                 "improved / scored; total error: change of the mean held-out RMS over the scored variables (accelerations "
                 "and angular accelerations), relative to "
                 "the base model (negative = better).") + [""]
    out += narrow_table(SUMMARY_COLUMNS, (_summary_row(k, e) for k, e in enumerate(data["effects"], 1))) + [""]
    for k, effect in enumerate(data["effects"], 1):
        out += _effect_block(k, effect, data) + [""]
    out += ["### Verdict rule", ""]
    for key, text in data["rule"].items():
        if key not in LEGACY_VERDICTS:  # the rule of a superseded verdict
            out += prose(f"**{key}**: {text}", first="- ", rest="  ")
    out += ["", "## Held-out gap per variable (display units)", ""] + _gap_table(data)
    out += ["", "## Ladder", ""]
    out += narrow_table(("rung", "mean RMS / base RMS (scored variables)", "(12 variables)"),
                        ((f"base{''.join(' + ' + e for e in rung['effects'])}", f"{rung['normalised_gap']:.3f}",
                          f"{rung['normalised_gap_all']:.3f}" if "normalised_gap_all" in rung else "-") for rung in data["ladder"]))
    if data.get("where"):
        out += ["", "## Where: unexplained error after the best model", ""] + _where_lines(data)
    reg = data["regimes"]
    out += ["", "## Where: base model residual by regime", ""]
    out += prose("Normalised residual RMS (each variable divided by its training residual RMS) per quartile of the "
                 f"regime variable, low -> high; a concentration needs a top/bottom ratio of {CONCENTRATION_MIN_RATIO:g}x "
                 "either way.") + [""]
    out += narrow_table(("regime", "quartile edges", "RMS per quartile", "top/bottom"),
                        (_regime_row(name, r) for name, r in reg["regimes"].items()))
    bands = list(next(iter(reg["frequency"].values())))
    out += ["", "## Where: base model residual power by frequency band", ""]
    out += narrow_table(("variable", *bands), ((v, *(percent(x, 0) for x in power.values())) for v, power in reg["frequency"].items()))
    out += ["", "## Worst held-out windows", ""]
    out += narrow_table(("flight", "start [s]", "end [s]", "normalised gap"),
                        ((Path(w["flight"]).name, f"{w['t_start_s']:.1f}", f"{w['t_end_s']:.1f}", f"{w['normalised_gap']:.2f}")
                         for w in reg["worst_windows"]))
    if figures:
        out += ["", "## Figures", ""] + [f"![{f}]({f})" for f in figures]
    return "\n".join(out) + "\n"


def _data_lines(data: dict) -> list[str]:
    """The Data section's list: flights, windows, preprocessing, base model, skipped flights."""
    cfg, windows = data["config"], data["windows"]
    items = [f"training flights ({windows['train_count']} windows): " + ", ".join(Path(s).name for s in cfg["train_flights"]),
             f"held-out flights ({windows['test_count']} windows): " + ", ".join(Path(s).name for s in cfg["test_flights"])]
    empty = windows.get("flights_without_windows", {})
    if any(empty.values()):
        items.append("flights with no window (too short after the drops, or every window near the ground): "
                     + "; ".join(f"{k}: " + ", ".join(Path(s).name for s in v) for k, v in empty.items() if v))
    items += [f"windows {windows['window_s']:.1f} s, drop {cfg['drop_start']:g} s / {cfg['drop_end']:g} s, warm start "
              f"{cfg['warm_s']:g} s, measurement and prediction low-passed at {cfg['smooth_cutoff_hz']:g} Hz",
              "windows left out because the vehicle touched the ground (within 1 cm of the flight's lowest point, in "
              "the window or 0.5 s either side): " + ", ".join(f"{k} {v}" for k, v in windows.get("ground_contact_dropped", {}).items()),
              f"base model: {data['base']['note']}: "
              + ", ".join(f"{k} = {v:.4g}" for k, v in data["base"]["values"].items() if isinstance(v, float))]
    items += [f"skipped: {s}" for s in data.get("skipped") or []]
    return [line for item in items for line in prose(item, first="- ", rest="  ")]


def _summary_row(rank: int, effect: dict) -> list[str]:
    """One row of :data:`SUMMARY_COLUMNS`; an effect without evidence shows dashes."""
    ev = effect.get("evidence") or {}
    total = effect.get("total_error")
    change = f"{total['change']:+.3f}" if total and total.get("change") is not None else "-"
    if not ev:
        return [str(rank), effect["name"], verdict_of(effect), "-", "-", "-", change]
    return [str(rank), effect["name"], verdict_of(effect), percent(effect["shrink"]), percent(effect["train_shrink"]),
            f"{ev['windows_improved']}/{ev['windows']}", change]


def _effect_block(rank: int, effect: dict, data: dict) -> list[str]:
    """### rank. name: verdict, its reason, the evidence, shrink per variable, parameters with units and bounds."""
    out = [f"### {rank}. {effect['name']}: {verdict_of(effect)}", ""]
    if effect.get("summary"):
        out += prose(effect["summary"][0].upper() + effect["summary"][1:] + ".")
    out += prose(f"Reason: {reason_of(effect)}") + [""]
    ev = effect.get("evidence") or {}
    items = []
    if effect.get("variables"):
        candidates = effect.get("candidate_variables") or effect["variables"]
        items.append(f"scored on {', '.join(effect['variables'])} (candidates {', '.join(candidates)})")
    if ev:
        low, high = ev["shrink_ci90"]
        items.append(f"held-out shrink {percent(effect['shrink'])} (90% interval {percent(low)}..{percent(high)}), training "
                     f"{percent(effect['train_shrink'])}; {ev['windows_improved']}/{ev['windows']} held-out windows better")
        alone = effect.get("alone") or {}
        alone_text = f"{verdict_of(alone)} {percent(alone['shrink'])}" if effect.get("given") and alone else "-"
        items.append(f"signature correlation {ev['signature_correlation']:.2f}; on top of: {', '.join(effect.get('given') or []) or '-'}; "
                     f"alone: {alone_text}; confounded with: {', '.join(effect.get('confounded_with') or []) or '-'}")
    total = effect.get("total_error")
    if total:
        items.append(f"total error (mean held-out RMS over the scored variables / base): {total['before']:.3f} -> "
                     f"{total['after']:.3f} ({total['change']:+.3f})")
    folds = effect.get("fold_stability")
    if folds:
        state = {True: "stable", False: "unstable", None: "not assessed"}[folds.get("stable")]
        values = "; ".join(f"{k} " + ", ".join(f"{x:.3g}" for x in v) for k, v in (folds.get("values") or {}).items())
        said = folds.get("reason") and reason_of(folds) != reason_of(effect)  # not again when it is the verdict's reason
        items.append(f"fold stability ({folds.get('folds', '-')} folds): {state}"
                     + (f" -- {folds['reason']}" if said else "") + (f"; per fold: {values}" if values else ""))
    if effect.get("note") and effect.get("reason"):
        items.append(f"note: {effect['note']}")
    out += [line for item in items for line in prose(item, first="- ", rest="  ")]
    shrink_rows = _shrink_rows(effect, data)
    if shrink_rows:
        out += [""] + narrow_table(("variable", "RMS before", "RMS after", "held-out shrink", "training shrink"), shrink_rows)
    params = _parameter_rows(effect)
    if params:
        out += [""] + narrow_table(("parameter", "value", "unit", "bounds", "at bound"), params)
        plausible = [f"{p['name']}: plausible {_number(p['plausible'][0])}..{_number(p['plausible'][1])} {p.get('unit', '')} "
                     f"({p.get('plausible_source', 'no source')}): {'inside' if p.get('plausible_ok') else 'OUTSIDE'}"
                     for p in effect.get("parameters") or [] if p.get("plausible")]
        out += [""] * bool(plausible) + [line for item in plausible for line in prose(item, first="- ", rest="  ")]
    return out


def _shrink_rows(effect: dict, data: dict) -> list[list[str]]:
    """Per variable of ``shrink_by_variable`` (else the scored ones): RMS before/after (display units), shrinks."""
    by_variable = effect.get("shrink_by_variable") or {}
    held_out, train = by_variable.get("held_out") or {}, by_variable.get("train") or {}
    names = list(held_out) or ([v for v in effect.get("variables", []) if v in effect.get("after", {})] if effect.get("evidence") else [])
    rows = []
    for v in names:
        before = (effect.get("before") or {}).get(v, data["gap"].get(v, {}).get("rms"))
        after = (effect.get("after") or {}).get(v)
        rows.append([variable_label(v), "-" if before is None else display_number(v, before),
                     "-" if after is None else display_number(v, after),
                     percent(held_out[v]) if v in held_out else "-", percent(train[v]) if v in train else "-"])
    return rows


def _parameter_rows(effect: dict) -> list[list[str]]:
    """Rows (parameter, value ± sigma, unit, bounds, at bound) from ``parameters``, else from the older
    ``params`` / ``param_units``."""
    if effect.get("parameters"):
        return [[p["name"], _number(p["value"]) + ("" if p.get("sigma") is None else f" ± {_number(p['sigma'])}"),
                 p.get("unit") or "-", f"[{_number(p.get('lower'))}, {_number(p.get('upper'))}]",
                 "yes" if p.get("at_bound") else "no"] for p in effect["parameters"]]
    units = effect.get("param_units") or {}
    return [[k, _number(v), units.get(k, "-"), "-", "-"] for k, v in (effect.get("params") or {}).items()]


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def _gap_table(data: dict) -> list[str]:
    """Held-out RMS/TIC of the base model per variable, RMS after the best model (scored variables) and of the NARX floor."""
    after = {row["variable"]: row["rms"] for row in (data.get("where") or {}).get("variables", [])}
    floor = (data.get("learnable") or {}).get("gap")
    header = ["variable", "base RMS", "base TIC", *(["best RMS"] if after else []), *(["NARX RMS"] if floor else [])]
    rows = [[variable_label(v), display_number(v, data["gap"][v]["rms"]), tic_text(data["gap"][v]["tic"]),
             *([display_number(v, after[v]) if v in after else "-"] if after else []), *([display_number(v, floor[v]["rms"])] if floor else [])]
            for v in EVAL_VARIABLES]
    note = []
    if after:
        best = data.get("best_effects") or []
        note = prose("best RMS: the best model (" + (" + ".join(["base", *best])) + ") on the scored variables.") + [""]
    return note + narrow_table(header, rows)


def _where_lines(data: dict) -> list[str]:
    """The held-out error left after the best model: variables, frequency bands and regimes ranked."""
    where = data["where"]
    best = data.get("best_effects") or []
    model = " + ".join(["base", *best]) if best else "the base model (nothing found)"
    out = prose(f"Best model: {model}. Ranked on the scored variables ({', '.join(where['scored_variables'])}): the "
                "accelerations and angular accelerations the effects are scored on; the open-loop velocities and rates "
                "drift. Normalised = RMS / s_v (the base model's training residual RMS); share = of the summed "
                "normalised error.") + [""]
    out += narrow_table(("#", "variable", "RMS", "normalised", "share"),
                        ([str(k), variable_label(r["variable"]), display_number(r["variable"], r["rms"]), f"{r['normalised']:.2f}",
                          percent(r["share"], 0)] for k, r in enumerate(where["variables"], 1)))
    out += [""] + narrow_table(("band", "share of power", "largest contributors"),
                               ([b["band"], percent(b["share"], 0), ", ".join(f"{c['variable']} {percent(c['share'], 0)}" for c in b["variables"])]
                                for b in where["bands"]))
    out += [""] + narrow_table(("regime", "ratio", "larger at", "concentrated", "quartile edges"),
                               (_ranked_regime_row(r) for r in where["regimes"]))
    return out


def _ranked_regime_row(regime: dict) -> list[str]:
    if regime.get("ratio") is None:
        return [regime["regime"], "-", "-", "no", regime.get("note", "")]
    return [f"{regime['regime']} [{regime['unit']}]", f"{regime['ratio']:.2f}", regime["side"], "yes" if regime["concentrated"] else "no",
            ", ".join(f"{e:.3g}" for e in regime["quartile_edges"])]


def _regime_row(name: str, regime: dict) -> list[str]:
    """Residual per quartile of one regime variable; a regime that could not be cut shows its note."""
    if "edges" not in regime:
        return [name, "-", regime.get("note", ""), "-"]
    ratio = regime.get("ratio_top_to_bottom")
    return [f"{name} [{regime['unit']}]", ", ".join(f"{e:.3g}" for e in regime["edges"]),
            ", ".join(f"{x:.2f}" for x in regime["normalised_rms"]), "-" if ratio is None else f"{ratio:.2f}"]


# ----------------------------------------------------------------------------- figures


def residual_spectra(result: Diagnosis, names=SCORED_VARIABLES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Welch PSD of the held-out residual of ``names``, each divided by s_v, for the base and the best model:
    frequencies (F,) [Hz], base (F, k) and best (F, k) [1/Hz] (:func:`~quad_modelling.core.diagnosis.localisation.residual_psd`)."""
    batch = result.test_batch
    best = getattr(result, "best_test", None)
    best = result.base_test if best is None else best
    rate = 1.0 / batch.dt
    f, before = residual_psd(scaled_residual(batch, result.base_test, result.scales, names), rate)
    _, after = residual_psd(scaled_residual(batch, best, result.scales, names), rate)
    return f, before, after


def _residual_spectrum_figure(result: Diagnosis, best: list[str], directory: Path, plt) -> str:
    """residual_spectrum.png: one panel per SI unit of the scored variables, base dashed, best (base + the
    effects ``best``) solid, the frequency bands shaded."""
    f, before, after = residual_spectra(result)
    groups: dict[str, list[int]] = {}
    for i, v in enumerate(SCORED_VARIABLES):
        groups.setdefault(SI_UNIT[v], []).append(i)
    fig, axes = plt.subplots(len(groups), 1, figsize=(8, 3.0 * len(groups)), sharex=True)
    axes = np.atleast_1d(axes)
    top = min(float(f[-1]), 2.5 * result.test_batch.smooth_cutoff_hz)  # the scored signals are low-passed at the cutoff
    shown = f <= top
    for ax, (unit, idx) in zip(axes, groups.items()):
        for colour, i in zip(("tab:blue", "tab:red", "tab:green"), idx):
            ax.semilogy(f[shown], before[shown, i], "--", color=colour, lw=1.0, label=f"{SCORED_VARIABLES[i]} base")
            ax.semilogy(f[shown], after[shown, i], "-", color=colour, lw=1.3, label=f"{SCORED_VARIABLES[i]} best")
        peak = max(float(before[shown][:, idx].max()), float(after[shown][:, idx].max()), 1e-12)
        ax.set_ylim(peak * 1e-5, peak * 3.0)
        for k, ((lo, hi), label) in enumerate(zip(FREQUENCY_BANDS_HZ, band_labels())):
            ax.axvspan(lo, min(hi, top), color="0.88" if k % 2 == 0 else "0.96", zorder=0)
            ax.text(0.5 * (lo + min(hi, top)), 0.97, label, transform=ax.get_xaxis_transform(), ha="center", va="top", fontsize=7,
                    rotation=90 if min(hi, top) - lo < 0.1 * top else 0)
        ax.set_ylabel(f"PSD of residual / s_v [1/Hz]\n({unit} variables)", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=3, loc="lower left")
    axes[-1].set_xlim(0.0, top)
    axes[-1].set_xlabel("frequency [Hz]")
    after = f"base + {' + '.join(best)}" if best else "best = base, nothing found"
    fig.suptitle(f"Held-out residual spectrum: base model (dashed) and after the best model ({after}; solid)", fontsize=9)
    fig.tight_layout()
    fig.savefig(directory / "residual_spectrum.png", dpi=90)
    plt.close(fig)
    return "residual_spectrum.png"


def write_figures(result: Diagnosis, data: dict, directory: Path) -> list[str]:
    """gap_by_regime.png, effect_shrink.png, residual_spectrum.png (when the scales are known) and
    before_after_<effect>.png (the worst held-out window, base model with and without the two top effects)
    into ``directory``; returns the file names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    regimes = {k: r for k, r in data["regimes"]["regimes"].items() if "edges" in r}
    if regimes:
        fig, axes = plt.subplots(1, len(regimes), figsize=(2.6 * len(regimes), 3.2), sharey=True)
        axes = np.atleast_1d(axes)
        for ax, (name, r) in zip(axes, regimes.items()):
            centres = [0.5 * (a + b) for a, b in zip(r["edges"][:-1], r["edges"][1:])]
            ax.bar(range(len(centres)), r["normalised_rms"], color="tab:red", alpha=0.7)
            ax.set_xticks(range(len(centres)), [f"{c:.2g}" for c in centres], fontsize=7)
            ax.set_xlabel(f"{name} [{r['unit']}]", fontsize=8)
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("normalised residual RMS")
        fig.suptitle("Base-model residual by flight regime (quartiles, held-out windows)", fontsize=10)
        fig.tight_layout()
        fig.savefig(directory / "gap_by_regime.png", dpi=90)
        plt.close(fig)
        written.append("gap_by_regime.png")
    effects = data["effects"]
    fig, ax = plt.subplots(figsize=(7, 3.8))
    names = [e["name"] for e in effects]
    ax.barh(names[::-1], [e["shrink"] * 100 for e in effects][::-1], color=[VERDICT_COLOURS[verdict_of(e)] for e in effects][::-1],
            label="held-out")
    ax.scatter([e["train_shrink"] * 100 for e in effects][::-1], names[::-1], color="k", marker="|", s=120, label="training", zorder=3)
    ax.axvline(5, color="k", lw=0.6, ls=":")
    ax.set_xlabel("gap shrink on the effect's variables [%]\n(on top of the effects ranked above; green found, orange weak, "
                  "grey not supported)", fontsize=9)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(directory / "effect_shrink.png", dpi=90)
    plt.close(fig)
    written.append("effect_shrink.png")
    if result.scales is not None:
        written.append(_residual_spectrum_figure(result, data.get("best_effects", data.get("found", [])), directory, plt))
    # before/after over the worst held-out window for the top effects
    outcomes = [o for o in result.outcomes if o.correction is not None][:2]
    if outcomes:
        batch = result.test_batch
        worst = int(np.argmax(data["regimes"]["window_gap"]))
        t = np.arange(batch.samples) * batch.dt
        for o in outcomes:
            variables = list(o.variables)[:3]
            fig, axes = plt.subplots(len(variables), 1, figsize=(8, 2.3 * len(variables)), sharex=True)
            axes = np.atleast_1d(axes)
            for ax, v in zip(axes, variables):
                unit, factor = DISPLAY[v]
                col = INDEX[v]
                ax.plot(t, batch.measured[worst, :, col] * factor, "b-", lw=1.3, label="measured")
                ax.plot(t, result.base_test[worst, :, col] * factor, "r--", lw=1.0, label="base")
                ax.plot(t, (result.base_test[worst, :, col] + o.correction[worst, :, col]) * factor, "g-", lw=1.0, label=f"base + {o.effect.name}")
                ax.set_ylabel(f"{v} [{unit}]", fontsize=8)
                ax.grid(alpha=0.3)
                ax.axvline(t[batch.warm - 1], color="0.6", lw=0.8)
            axes[0].legend(fontsize=7, loc="upper right")
            axes[-1].set_xlabel("time in window [s]")
            fig.suptitle(f"{o.effect.name} ({LEGACY_VERDICTS.get(o.verdict, o.verdict)}, held-out shrink {o.shrink:.0%}): "
                         f"{Path(batch.sources[worst]).name} t = {batch.t0[worst]:.1f} s", fontsize=9)
            fig.tight_layout()
            name = f"before_after_{o.effect.name}.png"
            fig.savefig(directory / name, dpi=90)
            plt.close(fig)
            written.append(name)
    return written


def write_diagnosis(result: Diagnosis, data: dict, directory: Path, vehicle: str) -> list[str]:
    """diagnosis.json, report.md and figures into ``directory`` (created); returns the file names."""
    directory.mkdir(parents=True)
    figures = write_figures(result, data, directory)
    (directory / "diagnosis.json").write_text(json_text(data))
    (directory / "report.md").write_text(markdown_report(data, vehicle, figures))
    return ["diagnosis.json", "report.md", *figures]
