"""Evaluation reports: results.json, tables.md (thesis Tables 5-1/5-2) and figures (Figs 5.4-5.7).

Tables show display units (m/s, m/s², deg/s, deg/s²: :data:`quad_modelling.core.variables.DISPLAY`);
results.json keeps SI units. Figures use matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from quad_modelling.core.evaluation.multistep import GROUPS
from quad_modelling.core.evaluation.windowed import EvaluationResult, ExampleWindow
from quad_modelling.core.variables import DISPLAY, EVAL_VARIABLES, INDEX

ROW_LABELS = {
    "vel_x": "X velocity", "vel_y": "Y velocity", "vel_z": "Z velocity",
    "acc_x": "X acceleration", "acc_y": "Y acceleration", "acc_z": "Z acceleration",
    "roll_rate": "Roll rate", "pitch_rate": "Pitch rate", "yaw_rate": "Yaw rate",
    "roll_acc": "Roll acceleration", "pitch_acc": "Pitch acceleration", "yaw_acc": "Yaw acceleration",
}

FIGURES = {
    "fig_z.png": ("Z axis", "acc_z", "vel_z"),
    "fig_roll.png": ("Roll", "roll_acc", "roll_rate"),
    "fig_pitch.png": ("Pitch", "pitch_acc", "pitch_rate"),
    "fig_yaw.png": ("Yaw", "yaw_acc", "yaw_rate"),
}
"""One figure per axis like thesis Figs 5.4-5.7: input, acceleration, velocity/rate over one window."""


def markdown_tables(result: EvaluationResult, title: str = "Evaluation") -> str:
    """Tables 5-1/5-2 style: one table per metric; rows = variables, columns = model x span."""
    data = result.to_json()
    models = list(data["models"])
    spans = sorted({s for m in models for s in data["models"][m]}, key=lambda s: (s != "eval", s))
    lines = [f"# {title}", ""]
    flights = data["config"]["flights"]
    used = [f for f in flights if not f.get("skipped")]
    lines.append(f"{len(used)} flight(s) ({len(flights) - len(used)} skipped); spans train {result.config.train}, eval {result.config.eval} "
                 f"(drop {result.config.drop_start:g} s / {result.config.drop_end:g} s); {result.config.window_s:g} s windows, "
                 f"{result.config.warm_s:g} s warm start. Windows per span: "
                 + ", ".join(f"{s} {data['windows'][models[0]].get(s, 0)}" for s in spans) + ".")
    lines.append("")
    for metric, caption in (("tic", "TIC (0 = perfect, 1 = no match)"), ("rms", "RMS error (display units)")):
        lines.append(f"## {caption}")
        lines.append("")
        header = ["Variable", "Unit"] + [f"{m} ({s})" for s in spans for m in models]
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "---|" * len(header))
        for var in EVAL_VARIABLES:
            unit, factor = DISPLAY[var]
            cells = [ROW_LABELS[var], unit if metric == "rms" else "-"]
            for s in spans:
                for m in models:
                    entry = data["models"][m].get(s, {}).get(var)
                    if entry is None:
                        cells.append("n/a")
                    else:
                        value = entry[metric] * (factor if metric == "rms" else 1.0)
                        cells.append(f"{value:.2f}" if metric == "tic" else f"{value:.3g}")
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    horizons = data.get("horizons") or {}
    if horizons.get("models"):
        lines.append(f"## Multi-step prediction (IDSIA protocol, span {horizons['span']}, {horizons['starts']} start times)")
        lines.append("")
        lines.append("MAE at horizon h steps and SimErr = sum of MAE_h for h = 1..50; ratio = model / naive constant-state prediction. "
                     "Units: m, m/s, rad (geodesic angle), rad/s.")
        lines.append("")
        hs = horizons["horizons"]
        header = ["Model", "Group"] + [f"MAE h={h}" for h in hs] + ["SimErr", "SimErr ratio"]
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "---|" * len(header))
        for m, groups in horizons["models"].items():
            for g in GROUPS:
                e = groups[g]
                ratio = e["ratio_sim_err"]
                lines.append("| " + " | ".join([m, g] + [f"{e['mae'][str(h)]:.4g}" for h in hs]
                                               + [f"{e['sim_err']:.4g}", "-" if ratio is None else f"{ratio:.3g}"]) + " |")
        if horizons.get("not_multistep"):
            lines.append("")
            lines.append(f"Not in the multi-step table (no open-loop form): {', '.join(horizons['not_multistep'])}.")
        lines.append("")
    return "\n".join(lines)


def window_figure(example: ExampleWindow, title: str, acc_var: str, rate_var: str, path: Path) -> None:
    """Input, acceleration and velocity/rate, measured vs each model, over one window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(8, 7.5), sharex=True)
    t = example.t
    for i in range(example.inputs.shape[1]):
        axes[0].plot(t, example.inputs[:, i], lw=0.8, label=f"u{i + 1}")
    axes[0].set_ylabel("trimmed input")
    axes[0].legend(loc="upper right", ncol=4, fontsize=8)
    for ax, var in ((axes[1], acc_var), (axes[2], rate_var)):
        unit, factor = DISPLAY[var]
        col = INDEX[var]
        ax.plot(t, example.measured[:, col] * factor, "b-", lw=1.4, label="measured")
        styles = ["r--", "c-.", "m:", "g--", "k-."]
        for k, (name, predicted) in enumerate(example.predicted.items()):
            ax.plot(t, predicted[:, col] * factor, styles[k % len(styles)], lw=1.1, label=name)
        ax.axvline(t[example.warm_samples - 1], color="0.6", lw=0.8)
        ax.set_ylabel(f"{ROW_LABELS[var]} [{unit}]")
        scale = np.nanmax(np.abs(example.measured[:, col] * factor))
        if np.isfinite(scale) and scale > 0:
            ax.set_ylim(-3 * scale, 3 * scale)  # keep the measurement readable when a model diverges
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    axes[2].set_xlabel("time in window [s]")
    fig.suptitle(f"{title}: {Path(example.source).name}, {example.span} window", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_report(result: EvaluationResult, directory: Path, title: str = "Evaluation") -> list[str]:
    """Write results.json, tables.md and the figures into ``directory`` (created); returns the file names."""
    directory.mkdir(parents=True)
    (directory / "results.json").write_text(json.dumps(result.to_json(), indent=2))
    (directory / "tables.md").write_text(markdown_tables(result, title))
    written = ["results.json", "tables.md"]
    example = next((e for e in result.examples if e.span == "eval"), result.examples[0] if result.examples else None)
    if example is not None:
        for name, (axis, acc_var, rate_var) in FIGURES.items():
            window_figure(example, axis, acc_var, rate_var, directory / name)
            written.append(name)
    return written
