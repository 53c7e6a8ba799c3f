"""Diagnosis reports: report.md (plain-language verdict first), diagnosis.json and figures.

The tables show display units (:mod:`quad_modelling.io.reports.formatting`); diagnosis.json keeps
the SI units of :meth:`quad_modelling.core.diagnosis.diagnose.Diagnosis.to_json`. Figures use
matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from quad_modelling.core.diagnosis.diagnose import Diagnosis
from quad_modelling.core.variables import DISPLAY, EVAL_VARIABLES, INDEX
from quad_modelling.io.reports.formatting import (
    display_number,
    display_value,
    json_text,
    markdown_table,
    percent,
    tic_text,
    variable_label,
)

EFFECT_COLUMNS = ("effect", "verdict", "held-out shrink", "90% interval", "training shrink", "windows better", "signature corr.",
                  "confounded with", "on top of", "alone", "parameters")
"""Columns of the ranked effects table of report.md."""


def verdict_text(data: dict) -> str:
    """Plain-language verdict: where the gap lies, which effect, how far it shrinks."""
    effects = data["effects"]
    found = [e for e in effects if e["verdict"] == "found"]
    rejected = [e for e in effects if e["verdict"] == "rejected"]
    gap = data["gap"]
    base_rms = {v: gap[v]["rms"] for v in EVAL_VARIABLES}
    worst_tic = sorted(EVAL_VARIABLES, key=lambda v: gap[v]["tic"], reverse=True)[:3]
    worst_text = ", ".join(f"{v} (TIC {tic_text(gap[v]['tic'])})" for v in worst_tic)
    lines = [f"Where: the largest held-out gap (TIC) is in {worst_text}."]
    regimes = data["regimes"].get("regimes", {})
    ratios = {k: r["ratio_top_to_bottom"] for k, r in regimes.items() if r.get("ratio_top_to_bottom") and k != "time_in_window"}
    if ratios:
        k = max(ratios, key=ratios.get)
        lines.append(f"The residual concentrates at high {k.replace('_', ' ')}: {ratios[k]:.1f}x the normalised RMS of the lowest quartile.")
    if found:
        top = found[0]
        best_var = max(top["variables"], key=lambda v: 1 - top["after"][v] / base_rms[v] if base_rms[v] > 0 else 0)
        lines.append(
            f"Which: {top['name']} ({top['summary']}) shrinks the held-out gap on {', '.join(top['variables'])} by "
            f"{top['shrink']:.0%} (90% interval {top['evidence']['shrink_ci90'][0]:.0%}..{top['evidence']['shrink_ci90'][1]:.0%}, "
            f"{top['evidence']['windows_improved']}/{top['evidence']['windows']} windows better); {best_var} RMS "
            f"{display_value(best_var, base_rms[best_var])} -> {display_value(best_var, top['after'][best_var])}."
        )
        if len(found) > 1:
            lines.append("Also found, each on top of the effects ranked above it: "
                         + ", ".join(f"{e['name']} ({e['shrink']:.0%}; alone {e['alone']['shrink']:.0%})" for e in found[1:]) + ".")
        twins = [e for e in effects if e.get("given") and e["alone"]["verdict"] == "found" and e["verdict"] != "found"]
        if twins:
            lines.append("Found alone but adding nothing on top of the effects ranked above: "
                         + ", ".join(f"{e['name']} (alone {e['alone']['shrink']:.0%}, on top {e['shrink']:.0%})" for e in twins) + ".")
        if top["confounded_with"]:
            lines.append(f"Warning: on this data {top['name']} cannot be told apart from {', '.join(top['confounded_with'])}.")
        if len(data["ladder"]) > 1:
            last = data["ladder"][-1]
            lines.append(f"With all found effects ({' + '.join(last['effects'])}) the mean held-out RMS over the 12 variables is "
                         f"{last['normalised_gap']:.0%} of the base model's.")
    else:
        lines.append("Which: no catalogue effect shrinks the held-out gap consistently (none found).")
    if rejected:
        lines.append("Rejected (help on training flights, not on held-out ones): "
                     + ", ".join(f"{e['name']} (train {e['train_shrink']:.0%}, held-out {e['shrink']:.0%})" for e in rejected) + ".")
    if data.get("learnable") and not data["learnable"].get("gap"):
        lines.append(f"Learnable: {data['learnable']['note']}.")
    elif data.get("learnable"):
        floor = data["learnable"]["gap"]
        better = [v for v in EVAL_VARIABLES if floor[v]["rms"] < base_rms[v]]
        lines.append(f"Learnable: the NARX model beats the base model on {len(better)} of 12 variables"
                     + (f" ({', '.join(better)})" if better else "") + ".")
    return "\n".join(lines)




def markdown_report(data: dict, vehicle: str, figures: list[str]) -> str:
    """report.md from diagnosis.json's document ``data``: verdict, data used, effects ranked, held-out gap per
    variable, ladder, residual by regime and frequency band, worst windows, then the ``figures`` (file names)."""
    cfg = data["config"]
    out = [f"# Sim-to-real gap diagnosis ({vehicle})", "", "## Verdict", "", verdict_text(data), ""]
    out += ["## Data", "", f"- training flights ({data['windows']['train_count']} windows): " + ", ".join(Path(s).name for s in cfg["train_flights"]),
            f"- held-out flights ({data['windows']['test_count']} windows): " + ", ".join(Path(s).name for s in cfg["test_flights"]),
            f"- windows {data['windows']['window_s']:.1f} s, drop {cfg['drop_start']:g} s / {cfg['drop_end']:g} s, warm start {cfg['warm_s']:g} s, "
            f"measurement and prediction low-passed at {cfg['smooth_cutoff_hz']:g} Hz",
            "- windows left out because the vehicle touched the ground (within 1 cm of the flight's lowest point, in the window "
            "or 0.5 s either side): " + ", ".join(f"{k} {v}" for k, v in data["windows"].get("ground_contact_dropped", {}).items()),
            f"- base model: {data['base']['note']}: " + ", ".join(f"{k} = {v:.4g}" for k, v in data["base"]["values"].items() if isinstance(v, float)),
            ""]
    empty = data["windows"].get("flights_without_windows", {})
    if any(empty.values()):
        out[-1:-1] = ["- flights with no window (too short after the drops, or every window near the ground): "
                      + "; ".join(f"{k}: " + ", ".join(Path(s).name for s in v) for k, v in empty.items() if v)]
    if data.get("skipped"):
        out += ["Skipped flights:", ""] + [f"- {s}" for s in data["skipped"]] + [""]
    out += ["## Effects (ranked by conditional contribution)", "",
            "Rank 1 is the found effect of largest held-out shrink; every later rank is assessed with the effects above it held "
            "at their identified parameters (column 'on top of'), so its shrink is what it adds to them. 'alone' is the effect "
            "assessed on its own against the base model.", ""]
    out += markdown_table(EFFECT_COLUMNS, (_effect_row(e) for e in data["effects"]))
    out += ["", "Verdict rule: " + "; ".join(f"**{k}**: {v}" for k, v in data["rule"].items()), ""]
    out += ["## Held-out gap per variable (display units)", ""] + _gap_table(data)
    out += ["", "## Ladder", ""]
    out += markdown_table(("rung", "mean RMS / base RMS (12 variables)"),
                          ((f"base{''.join(' + ' + e for e in rung['effects'])}", f"{rung['normalised_gap']:.3f}") for rung in data["ladder"]))
    reg = data["regimes"]
    out += ["", "## Where: residual by regime", "",
            "Normalised residual RMS (each variable divided by its training residual RMS) per quartile of the regime variable.", ""]
    out += markdown_table(("regime", "quartile edges", "RMS per quartile (low -> high)", "top/bottom"),
                          (_regime_row(name, r) for name, r in reg["regimes"].items()))
    bands = list(next(iter(reg["frequency"].values())))
    out += ["", "## Where: residual power by frequency band", ""]
    out += markdown_table(("variable", *bands), ((v, *(percent(x, 0) for x in power.values())) for v, power in reg["frequency"].items()))
    out += ["", "## Worst held-out windows", ""]
    out += markdown_table(("flight", "start [s]", "end [s]", "normalised gap"),
                          ((Path(w["flight"]).name, f"{w['t_start_s']:.1f}", f"{w['t_end_s']:.1f}", f"{w['normalised_gap']:.2f}")
                           for w in reg["worst_windows"]))
    if figures:
        out += ["", "## Figures", ""] + [f"![{f}]({f})" for f in figures]
    return "\n".join(out) + "\n"


def _effect_row(effect: dict) -> list[str]:
    """One row of the effects table (:data:`EFFECT_COLUMNS`); an effect without evidence shows its note."""
    ev = effect["evidence"]
    if not ev:
        return [effect["name"], effect["verdict"], *["-"] * 8, effect.get("note", "")]
    alone = "-" if not effect.get("given") else f"{effect['alone']['verdict']} {percent(effect['alone']['shrink'])}"
    low, high = ev["shrink_ci90"]
    return [effect["name"], f"**{effect['verdict']}**", percent(effect["shrink"]), f"{percent(low)}..{percent(high)}",
            percent(effect["train_shrink"]), f"{ev['windows_improved']}/{ev['windows']}", f"{ev['signature_correlation']:.2f}",
            ", ".join(effect["confounded_with"]) or "-", ", ".join(effect.get("given") or []) or "-", alone,
            ", ".join(f"{k}={v:.3g}" for k, v in effect["params"].items())]


def _gap_table(data: dict) -> list[str]:
    """Held-out RMS/TIC of the base model per variable, RMS with each of the top 3 effects and of the NARX floor."""
    top = data["effects"][:3]
    floor = (data.get("learnable") or {}).get("gap")
    header = ["variable", "base RMS", "base TIC", *(f"+{e['name']}" for e in top), *(["NARX"] if floor else [])]
    rows = [[variable_label(v), display_number(v, data["gap"][v]["rms"]), tic_text(data["gap"][v]["tic"]),
             *(display_number(v, e["after"][v]) for e in top), *([display_number(v, floor[v]["rms"])] if floor else [])]
            for v in EVAL_VARIABLES]
    return markdown_table(header, rows)


def _regime_row(name: str, regime: dict) -> list[str]:
    """Residual per quartile of one regime variable; a regime that could not be cut shows its note."""
    if "edges" not in regime:
        return [name, "-", regime.get("note", ""), "-"]
    return [f"{name} [{regime['unit']}]", ", ".join(f"{e:.3g}" for e in regime["edges"]),
            ", ".join(f"{x:.2f}" for x in regime["normalised_rms"]), f"{regime['ratio_top_to_bottom']:.2f}"]


def write_figures(result: Diagnosis, data: dict, directory: Path) -> list[str]:
    """gap_by_regime.png, effect_shrink.png and before_after_<effect>.png (the worst held-out window, base model
    with and without the two top effects) into ``directory``; returns the file names."""
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
    colours = {"found": "tab:green", "rejected": "tab:orange", "insignificant": "0.6"}
    ax.barh(names[::-1], [e["shrink"] * 100 for e in effects][::-1], color=[colours[e["verdict"]] for e in effects][::-1], label="held-out")
    ax.scatter([e["train_shrink"] * 100 for e in effects][::-1], names[::-1], color="k", marker="|", s=120, label="training", zorder=3)
    ax.axvline(5, color="k", lw=0.6, ls=":")
    ax.set_xlabel("gap shrink on the effect's variables [%]\n(on top of the effects ranked above; green found, orange rejected, grey insignificant)",
                  fontsize=9)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(directory / "effect_shrink.png", dpi=90)
    plt.close(fig)
    written.append("effect_shrink.png")
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
            fig.suptitle(f"{o.effect.name} ({o.verdict}, held-out shrink {o.shrink:.0%}): {Path(batch.sources[worst]).name} "
                         f"t = {batch.t0[worst]:.1f} s", fontsize=9)
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
