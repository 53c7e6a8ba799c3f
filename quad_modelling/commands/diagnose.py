"""``quad-modelling diagnose``: sim-to-real gap diagnosis (DESIGN 8), and its known-answer validation."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from quad_modelling.atomic import atomic_output, check_output
from quad_modelling.core.diagnosis.catalogue import parse_effect_list
from quad_modelling.core.diagnosis.diagnose import (
    DIAGNOSIS_CONFIG,
    Diagnosis,
    diagnose,
    narx_floor,
)
from quad_modelling.core.variables import DISPLAY, EVAL_VARIABLES, INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import ConfigError, QuadModellingError
from quad_modelling.io.loader import load_flight

NAME = "diagnose"
HELP = "diagnose the sim-to-real gap: where the model diverges, which effect causes it, how far it shrinks"
DESCRIPTION = """\
Compare the linear greybox model with flights and find which unmodelled effect explains the
gap. The base model's constants are identified on the --train flights; every catalogue effect
(rotor_drag, battery, motor_lag, input_delay, ground_effect, gyroscopic, thrust_nonlinearity,
motor_imbalance, trim_drift) is added alone, its parameters identified on the --train flights
only, and the gap measured on the --test flights. An effect is "found" when it shrinks the
held-out gap on its variables by >= 5 % consistently over held-out windows, "rejected" when it
helps on training data only. Also: the gap by flight regime and frequency band, the worst
windows, a cumulative ladder of the found effects, and (--narx) the NARX model's error as the
learnable floor.

OUTDIR receives diagnosis.json (SI units), report.md (plain-language verdict first) and PNG
figures. --validate instead flies simulated known-answer flights (each effect switched on in
turn, the model without it; a null case; pairs) and writes validation.json + validation.md.

examples:
  quad-modelling diagnose --train slow1.csv.gz slow2.csv.gz --test fast1.csv.gz -o diag
  quad-modelling diagnose --train a.mat --test b.mat --vehicle linkquad --effects rotor_drag,battery -o diag
  quad-modelling diagnose --validate --vehicle linkquad --seeds 0,1,2 -o validation
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--train", nargs="+", metavar="FLIGHT", help="training flights (bags, .mat, NanoBench .csv.gz)")
    parser.add_argument("--test", nargs="+", metavar="FLIGHT", help="held-out flights")
    parser.add_argument("--vehicle", metavar="NAME|FILE", help="vehicle config name or YAML (default: the one the first flight names)")
    parser.add_argument("--effects", default="all", metavar="all|LIST", help="comma list of catalogue effects (default all)")
    parser.add_argument("--no-identify", action="store_true", help="use the vehicle's constants as the base model instead of identifying them on --train")
    parser.add_argument("--narx", action="store_true", help="also train a NARX model on --train as the learnable floor (slower)")
    parser.add_argument("--window", type=float, default=DIAGNOSIS_CONFIG.window_s, metavar="SECONDS", help="window length (default 5)")
    parser.add_argument("--drop", default=f"{DIAGNOSIS_CONFIG.drop_start:g}:{DIAGNOSIS_CONFIG.drop_end:g}", metavar="START:END",
                        help=f"seconds dropped at take-off:landing of every flight (default {DIAGNOSIS_CONFIG.drop_start:g}:{DIAGNOSIS_CONFIG.drop_end:g})")
    parser.add_argument("--smooth", type=float, default=DIAGNOSIS_CONFIG.smooth_cutoff_hz, metavar="HZ",
                        help=f"low-pass cutoff applied to measurement and prediction alike before scoring (default {DIAGNOSIS_CONFIG.smooth_cutoff_hz:g} Hz)")
    parser.add_argument("--skip-bad", action="store_true", help="report unreadable flights and continue with the rest")
    parser.add_argument("--validate", action="store_true", help="known-answer validation on simulated flights instead")
    parser.add_argument("--seeds", default="0,1,2", metavar="LIST", help="validation seeds (default 0,1,2)")
    parser.add_argument("--duration", type=float, default=90.0, metavar="SECONDS", help="validation flight length (default 90)")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="new output directory")
    parser.add_argument("--force", action="store_true", help="overwrite an existing OUTDIR")


def _config(args: argparse.Namespace) -> EvaluationConfig:
    try:
        start, end = (float(x) for x in args.drop.split(":"))
    except ValueError as err:
        raise ConfigError(f"--drop {args.drop!r}: expected START:END seconds, e.g. 3.5:4.5") from err
    if not args.smooth > 0:
        raise ConfigError(f"--smooth {args.smooth:g}: the low-pass cutoff must be a positive frequency in Hz")
    config = replace(DIAGNOSIS_CONFIG, drop_start=start, drop_end=end, window_s=args.window, smooth_cutoff_hz=args.smooth)
    config.validate()
    return config


def _load(paths, vehicle, skip_bad, skipped):
    flights = []
    for path in paths:
        try:
            flights.append(load_flight(path, vehicle=vehicle))
        except QuadModellingError as err:
            if not skip_bad:
                raise
            skipped.append(str(err))
            print(f"skipped: {err}", file=sys.stderr)
    return flights


def _progress():
    from tqdm import tqdm

    bar = tqdm(desc="diagnose", unit="step", file=sys.stderr, disable=not sys.stderr.isatty())

    def say(message: str) -> None:
        bar.set_postfix_str(message[:50])
        bar.update(1)

    return say, bar


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    check_output(output, args.force)
    config = _config(args)
    effects = parse_effect_list(args.effects)
    if args.validate:
        return _run_validation(args, config, effects, output)
    if not args.train or not args.test:
        raise ConfigError("diagnose needs --train FLIGHT... and --test FLIGHT... (or --validate)")
    skipped: list[str] = []
    given = load_vehicle(args.vehicle) if args.vehicle else None  # once for every flight
    train = _load(args.train, given, args.skip_bad, skipped)
    test = _load(args.test, given, args.skip_bad, skipped)
    if not train or not test:
        raise ConfigError("no readable flight left in --train or --test")
    vehicle = given or load_vehicle(train[0].meta.vehicle)
    say, bar = _progress()
    learnable = (lambda: narx_floor(train, test, vehicle, config)) if args.narx else None
    try:
        result = diagnose(train, test, vehicle, effects, config, identify=not args.no_identify, learnable=learnable, progress=say)
    finally:
        bar.close()
    data = result.to_json()
    data["skipped"] = skipped
    with atomic_output(output, args.force) as tmp:
        files = write_diagnosis(result, data, tmp, vehicle.name)
    print(verdict_text(data))
    print(f"-> {output}/ ({', '.join(files)})")
    return 0


def _run_validation(args, config, effects, output: Path) -> int:
    from quad_modelling.core.diagnosis.validation import VALIDATED_EFFECTS, validate

    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError as err:
        raise ConfigError(f"--seeds {args.seeds!r}: expected comma-separated integers") from err
    names = [e.name for e in effects]
    switched = [e for e in VALIDATED_EFFECTS if e in names] if args.effects != "all" else list(VALIDATED_EFFECTS)
    say, bar = _progress()
    try:
        result = validate(args.vehicle or "linkquad", switched, seeds, catalogue=effects, duration=args.duration, config=config, progress=say)
    finally:
        bar.close()
    with atomic_output(output, args.force) as tmp:
        tmp.mkdir(parents=True)
        (tmp / "validation.json").write_text(json.dumps(result, indent=2, default=_json_default))
        (tmp / "validation.md").write_text(validation_markdown(result))
    print(f"accuracy {result['accuracy']:.0%} over {len(result['runs'])} runs; null case found {result['null']['found'] or 'nothing'}; "
          f"pairs {result['pairs_accuracy'] if result['pairs_accuracy'] is None else format(result['pairs_accuracy'], '.0%')} -> {output}/")
    return 0


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


# ----------------------------------------------------------------------------- report


def _fmt(var: str, value: float) -> str:
    unit, factor = DISPLAY[var]
    return f"{value * factor:.3g} {unit}"


def verdict_text(data: dict) -> str:
    """Plain-language verdict: where the gap lies, which effect, how far it shrinks."""
    effects = data["effects"]
    found = [e for e in effects if e["verdict"] == "found"]
    rejected = [e for e in effects if e["verdict"] == "rejected"]
    gap = data["gap"]
    base_rms = {v: gap[v]["rms"] for v in EVAL_VARIABLES}
    worst_tic = sorted(EVAL_VARIABLES, key=lambda v: gap[v]["tic"], reverse=True)[:3]
    worst_text = ", ".join(f"{v} (TIC {gap[v]['tic']:.2f})" for v in worst_tic)
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
            f"{_fmt(best_var, base_rms[best_var])} -> {_fmt(best_var, top['after'][best_var])}."
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
            "assessed on its own against the base model.", "",
            "| effect | verdict | held-out shrink | 90% interval | training shrink | windows better | signature corr. | confounded with | on top of | alone | parameters |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for e in data["effects"]:
        ev = e["evidence"]
        params = ", ".join(f"{k}={v:.3g}" for k, v in e["params"].items())
        if not ev:
            out.append(f"| {e['name']} | {e['verdict']} | - | - | - | - | - | - | - | - | {e.get('note', '')} |")
            continue
        alone = "-" if not e.get("given") else f"{e['alone']['verdict']} {e['alone']['shrink']:.1%}"
        out.append(f"| {e['name']} | **{e['verdict']}** | {e['shrink']:.1%} | {ev['shrink_ci90'][0]:.1%}..{ev['shrink_ci90'][1]:.1%} | "
                   f"{e['train_shrink']:.1%} | {ev['windows_improved']}/{ev['windows']} | {ev['signature_correlation']:.2f} | "
                   f"{', '.join(e['confounded_with']) or '-'} | {', '.join(e.get('given') or []) or '-'} | {alone} | {params} |")
    out += ["", "Verdict rule: " + "; ".join(f"**{k}**: {v}" for k, v in data["rule"].items()), ""]
    out += ["## Held-out gap per variable (display units)", "",
            "| variable | base RMS | base TIC | " + " | ".join(f"+{e['name']}" for e in data["effects"][:3]) + (" | NARX |" if (data.get("learnable") or {}).get("gap") else " |"),
            "|---|---|---|" + "---|" * min(3, len(data["effects"])) + ("---|" if (data.get("learnable") or {}).get("gap") else "")]
    for v in EVAL_VARIABLES:
        unit, factor = DISPLAY[v]
        row = f"| {v} [{unit}] | {data['gap'][v]['rms'] * factor:.3g} | {data['gap'][v]['tic']:.2f} | "
        row += " | ".join(f"{e['after'][v] * factor:.3g}" for e in data["effects"][:3])
        if (data.get("learnable") or {}).get("gap"):
            row += f" | {data['learnable']['gap'][v]['rms'] * factor:.3g}"
        out.append(row + " |")
    out += ["", "## Ladder", "", "| rung | mean RMS / base RMS (12 variables) |", "|---|---|"]
    for rung in data["ladder"]:
        out.append(f"| base{''.join(' + ' + e for e in rung['effects'])} | {rung['normalised_gap']:.3f} |")
    reg = data["regimes"]
    out += ["", "## Where: residual by regime", "",
            "Normalised residual RMS (each variable divided by its training residual RMS) per quartile of the regime variable.", "",
            "| regime | quartile edges | RMS per quartile (low -> high) | top/bottom |", "|---|---|---|---|"]
    for name, r in reg["regimes"].items():
        if "edges" not in r:
            out.append(f"| {name} | - | {r.get('note', '')} | - |")
            continue
        out.append(f"| {name} [{r['unit']}] | {', '.join(f'{e:.3g}' for e in r['edges'])} | {', '.join(f'{x:.2f}' for x in r['normalised_rms'])} | "
                   f"{r['ratio_top_to_bottom']:.2f} |")
    out += ["", "## Where: residual power by frequency band", "", "| variable | " + " | ".join(next(iter(reg["frequency"].values())).keys()) + " |",
            "|---|" + "---|" * len(next(iter(reg["frequency"].values())))]
    for v, bands in reg["frequency"].items():
        out.append(f"| {v} | " + " | ".join(f"{x:.0%}" for x in bands.values()) + " |")
    out += ["", "## Worst held-out windows", "", "| flight | start [s] | end [s] | normalised gap |", "|---|---|---|---|"]
    for w in reg["worst_windows"]:
        out.append(f"| {Path(w['flight']).name} | {w['t_start_s']:.1f} | {w['t_end_s']:.1f} | {w['normalised_gap']:.2f} |")
    if figures:
        out += ["", "## Figures", ""] + [f"![{f}]({f})" for f in figures]
    return "\n".join(out) + "\n"


def write_figures(result: Diagnosis, data: dict, directory: Path) -> list[str]:
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
    """diagnosis.json, report.md and figures into ``directory`` (created)."""
    directory.mkdir(parents=True)
    figures = write_figures(result, data, directory)
    (directory / "diagnosis.json").write_text(json.dumps(data, indent=2, default=_json_default))
    (directory / "report.md").write_text(markdown_report(data, vehicle, figures))
    return ["diagnosis.json", "report.md", *figures]


def validation_markdown(result: dict) -> str:
    def pct(x):
        return "-" if x is None else f"{x:.1%}"

    out = [f"# Diagnosis validation on simulated {result['vehicle']} flights", "",
           f"Accuracy (right effect ranked first and found): **{result['accuracy']:.0%}** over {len(result['runs'])} (effect, seed) runs; "
           f"null case found: {', '.join(result['null']['found']) or 'nothing'}; pairs both found in top 3: "
           f"{'-' if result['pairs_accuracy'] is None else format(result['pairs_accuracy'], '.0%')}.", "",
           "Shrink columns: **held-out shrink** = the literal target (the diagnosis's shrink of the effect's affected-variable gap, "
           "base model without the effect -> with it); **attributable** = 1 - G_off/G_on, the share of the base model's held-out "
           "gap (all windows) that the same test seed flown with every effect off does not have, i.e. the ceiling of the literal "
           "shrink; **removed** = (G_on - G_after)/(G_on - G_off), the share of that effect-attributable gap the fitted effect removes "
           "(can exceed 100 %: the effect-off twin flies the manoeuvres slightly differently); **sensor ceiling** = "
           "1 - G_sensor/G_on on the scored windows and variables, G_sensor the gap between the measurement and the simulator's "
           "true IMU signals (same preprocessing): what a model predicting the true signals exactly would reach, so the literal "
           "shrink cannot exceed it (in expectation) and a run whose ceiling is below the target cannot meet it.", ""]
    if result.get("shrink_by_effect"):
        out += ["| effect | held-out shrink min / median / max | sensor ceiling min / median / max | attributable min / median | removed min / median |",
                "|---|---|---|---|---|"]
        for name, v in result["shrink_by_effect"].items():
            c = result.get("sensor_ceiling_by_effect", {}).get(name, {})
            a = result.get("attributable_share_by_effect", {}).get(name, {})
            r = result.get("attributable_removed_by_effect", {}).get(name, {})
            out.append(f"| {name} | {pct(v['min'])} / {pct(v['median'])} / {pct(v['max'])} | "
                       f"{pct(c.get('min'))} / {pct(c.get('median'))} / {pct(c.get('max'))} | {pct(a.get('min'))} / {pct(a.get('median'))} | "
                       f"{pct(r.get('min'))} / {pct(r.get('median'))} |")
        out.append("")
    out += ["| effect | seed | top | correct | held-out shrink | sensor ceiling | scored on | attributable | removed | verdict | ranking |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["runs"]:
        out.append(f"| {r['effect']} | {r['seed']} | {r['top']} | {'yes' if r['correct'] else 'no'} | {pct(r['shrink'])} | "
                   f"{pct(r.get('sensor_ceiling'))} | {', '.join(r.get('variables', [])) or '-'} | "
                   f"{pct(r.get('attributable_share'))} | {pct(r.get('attributable_removed'))} | {r['verdict']} | "
                   + ", ".join(f"{k} {v:.1%}" for k, v in r["top_shrinks"].items()) + " |")
    out += ["", "| null seed | found | top shrinks |", "|---|---|---|"]
    for n in result["null"]["runs"]:
        out.append(f"| {n['seed']} | {', '.join(n['found']) or '-'} | " + ", ".join(f"{k} {v:.1%}" for k, v in n["top_shrinks"].items()) + " |")
    if result["pairs"]:
        out += ["", "Pairs are ranked by conditional contribution: the second effect's shrink is what it adds on top of the first.", "",
                "| pair | seed | top 3 | found | both in top 3 | shrinks |", "|---|---|---|---|---|---|"]
        for p in result["pairs"]:
            out.append(f"| {' + '.join(p['effects'])} | {p['seed']} | {', '.join(p['top3'])} | {', '.join(p['found']) or '-'} | "
                       f"{'yes' if p['both_found_in_top3'] else 'no'} | " + ", ".join(f"{k} {v:.1%}" for k, v in p["shrinks"].items()) + " |")
    return "\n".join(out) + "\n"
