"""Evaluation reports: results.json, tables.md (thesis Tables 5-1/5-2) and figures (Figs 5.4-5.7).

Tables show display units (m/s, m/s², deg/s, deg/s²: :data:`quad_modelling.core.variables.DISPLAY`);
results.json keeps SI units. Figures use matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np

from quad_modelling.core.evaluation.metrics import SIM_ERR_HORIZON
from quad_modelling.core.evaluation.multistep import GROUPS
from quad_modelling.core.evaluation.windowed import EvaluationResult, ExampleWindow
from quad_modelling.core.preprocess import GROUND_CONTACT_M
from quad_modelling.core.variables import DISPLAY, EVAL_VARIABLES, INDEX
from quad_modelling.io.reports.formatting import (
    display_number,
    display_unit,
    json_text,
    markdown_table,
    tic_text,
)

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


MODEL_NOTES = {
    "greybox": "linear greybox, the thesis reproduction (Sonntag 2011 ch. 3: its model and windowed protocol)",
    "naive": "the last measured state held (IDSIA baseline: the ratios' reference)",
    "dummy": "predicts zero deviation from the trim (thesis Fig 5.2 baseline, TIC 1)",
    "narx": "NARX nets (thesis ch. 4), closed loop from the measured warm start",
    "physics": "nonlinear rigid-body physics model (motor map, motor lag, rotor drag)",
    "hybrid": "physics base plus residual nets",
    "direct": "physics base with the body rates of a ridge regression per horizon (0.5 s)",
    "truth": "the truth simulator's own physics and constants from the log's notes (the perfect-model floor)",
}
"""What a table row is, by model kind (the text before ``:`` in a spec, e.g. ``greybox:euler`` -> greybox)."""


def model_note(name: str) -> str | None:
    """The note of a model name (``greybox:euler`` is a greybox; a name run-bag was given as NAME=SPEC has none)."""
    return MODEL_NOTES.get(name.partition(":")[0])


def model_notes(names, specs: dict[str, str] | None = None) -> list[str]:
    """``Models: greybox = linear greybox, the thesis reproduction (...); naive = ...`` (one line), or nothing.

    ``specs``: the spec of each model given a name (``--model NAME=SPEC``, :func:`quad_modelling.core.models.registry.named_spec`),
    listed as ``NAME (SPEC) = note`` with the note of its spec's kind (a name alone has none)."""
    specs = specs or {}
    notes = [f"{name} ({specs[name]}) = {model_note(specs[name])}" if name in specs else f"{name} = {model_note(name)}"
             for name in names if model_note(specs.get(name, name))]
    return ["Models: " + "; ".join(notes) + ".", ""] if notes else []


def markdown_tables(result: EvaluationResult, title: str = "Evaluation", specs: dict[str, str] | None = None) -> str:
    """Tables 5-1/5-2 style (:func:`tables_text`) of an evaluation result."""
    return tables_text(result.to_json(), title, specs)


MARKED_REASONS_SHOWN = 3
"""Distinct reasons of marked live windows tables.md lists (the rest are counted; results.json has every one)."""


def marked_lines(marked: list[dict]) -> list[str]:
    """tables.md's line on the live windows that were closed without a score (results.json ``live.marked``): how many,
    per model, and why (the most frequent reasons first)."""
    if not marked:
        return []
    per_model = Counter(r["model"] for r in marked)
    reasons = Counter(r["reason"] for r in marked).most_common()
    shown = "; ".join(f"{reason} (x{n})" for reason, n in reasons[:MARKED_REASONS_SHOWN])
    more = f"; {len(reasons) - MARKED_REASONS_SHOWN} other reason(s)" if len(reasons) > MARKED_REASONS_SHOWN else ""
    return ["", f"Marked, not scored: {len(marked)} window result(s) ({', '.join(f'{m} {n}' for m, n in per_model.items())}), "
                f"not in the tables below: {shown}{more} (each in results.json live.marked)."]


def received_text(counts: dict[str, int]) -> str:
    """A live node's exit-summary part ``received motor_input 4227, mocap_odom 4227, imu 4227``: the messages each of
    its subscriptions delivered (read back by :func:`summary_counts`)."""
    return "received " + (", ".join(f"{stream} {n}" for stream, n in counts.items()) or "nothing")


def summary_counts(log: str) -> tuple[int | None, dict[str, int] | None]:
    """(predictions published, messages received per stream) of the last exit summary in a node's ``log`` (a
    predictor's ``published N predictions ...; received motor_input N, ...; faults: ...``); None for what it lacks."""
    published = re.findall(r"\]: published (\d+) predictions ", log)
    received = re.findall(r"; received ((?:\S+ \d+(?:, )?)+|nothing); ", log)
    counts = None if not received else [item.rsplit(" ", 1) for item in received[-1].split(", ") if item != "nothing"]
    return int(published[-1]) if published else None, None if counts is None else {s: int(n) for s, n in counts}


def sample_accounting(played: dict[str, int], evaluator: dict[str, int] | None, predictor_logs: dict[str, str]) -> dict:
    """results.json ``live.samples`` of a run-bag: per stream what was sent (``sent``: the replay's ``played`` samples
    of each measurement stream; each predictor's predictions on ``<model>/odom`` and ``<model>/accel``, from its
    ``predictor_logs``' summary) and what each node started here received (``received``: the ``evaluator``'s
    ``live.received``, each predictor's summary), with one line per stream where they differ (``loss``,
    :func:`sample_loss_lines`). A node's stream it does not subscribe to (the evaluator's battery) is not compared."""
    sent = {stream: {"count": n, "by": "replay"} for stream, n in played.items()}
    received = {} if evaluator is None else {"evaluator": evaluator}
    for node, log in predictor_logs.items():
        published, received[node] = summary_counts(log)
        if published is not None:
            sent.update({f"{node.removesuffix('_predictor')}/{kind}": {"count": published, "by": node} for kind in ("odom", "accel")})
    return {"sent": sent, "received": received, "loss": sample_loss_lines(sent, received)}


def sample_loss_lines(sent: dict, received: dict) -> list[str]:
    """One line per stream some node received another number of samples of than were sent, e.g. ``imu: 4227 replayed,
    received 4101 by evaluator (126 lost), 4227 by naive_predictor`` (:func:`sample_accounting`); none when every node
    received every sample, as a rate-0 replay guarantees."""
    lines = []
    for stream, source in sent.items():
        n = source["count"]
        got = {node: counts[stream] for node, counts in received.items() if counts and stream in counts}
        if all(count == n for count in got.values()):
            continue
        how = "replayed" if source["by"] == "replay" else f"published by {source['by']}"
        parts = [f"{count} by {node}" + (f" ({n - count} lost)" if count < n else f" ({count - n} more)" if count > n else "")
                 for node, count in got.items()]
        lines.append(f"{stream}: {n} {how}, received {', '.join(parts)}")
    return lines


def sample_loss_section(samples: dict | None) -> list[str]:
    """tables.md's lines on the samples the live nodes did not receive (results.json ``live.samples``); none without."""
    loss = (samples or {}).get("loss") or []
    return ["", "Samples lost between sender and node (the live scores rest on incomplete input; results.json live.samples):",
            "", *(f"- {line}" for line in loss)] if loss else []


def tables_text(data: dict, title: str = "Evaluation", specs: dict[str, str] | None = None) -> str:
    """tables.md from a results.json document: one table per metric (rows = variables, columns = model x span),
    then the multi-step table (:func:`multistep_lines`) when the document has one. ``specs``: the spec of each named
    model (:func:`model_notes`); by default the document's ``statistics.model_specs``."""
    models = list(data["models"])
    if specs is None:
        specs = (data.get("statistics") or {}).get("model_specs")
    config = data["config"]
    spans = sorted({s for m in models for s in data["models"][m]}, key=lambda s: (s != "eval", s))
    lines = [f"# {title}", ""]
    flights = config["flights"]
    used = [f for f in flights if not f.get("skipped")]
    live = (data.get("live") or {}).get("spans")  # run-bag / the evaluator node: named seconds spans, no drops
    if live:
        named = ", ".join(f"{s['name']} {s['start_s']:g}:{'inf' if s.get('end_s') is None else format(s['end_s'], 'g')}"
                          for s in live)
        where = f"spans {named} (seconds from the first motor input)"
    else:
        where = (f"spans train {config['train']}, eval {config['eval']} "
                 f"(drop {config['drop_start']:g} s / {config['drop_end']:g} s)")
    counts = ", ".join(f"{s} {data['windows'][models[0]].get(s, 0)}" for s in spans) or "none scored"
    lines.append(f"{len(used)} flight(s) ({len(flights) - len(used)} skipped); {where}; {config['window_s']:g} s windows, "
                 f"{config['warm_s']:g} s warm start. Windows per span: {counts}.")
    lines += marked_lines((data.get("live") or {}).get("marked") or [])
    lines += sample_loss_section((data.get("live") or {}).get("samples"))
    lines.append("")
    lines += model_notes(models, specs)
    columns = [(m, s) for s in spans for m in models]
    for metric, caption in (("tic", "TIC (0 = perfect, 1 = no match)"), ("rms", "RMS error (display units)")):
        lines += [f"## {caption}", ""]
        rows = []
        for var in EVAL_VARIABLES:
            cells = [ROW_LABELS[var], display_unit(var) if metric == "rms" else "-"]
            for m, s in columns:
                entry = data["models"][m].get(s, {}).get(var)
                if entry is None:
                    cells.append("n/a")
                elif "needs" in entry:
                    cells.append(needs_text(entry))
                else:
                    cells.append(tic_text(entry["tic"]) if metric == "tic" else display_number(var, entry["rms"]))
            rows.append(cells)
        lines += markdown_table(["Variable", "Unit", *(column_title(m, s) for m, s in columns)], rows)
        lines.append("")
    lines += multistep_lines(data.get("horizons") or {})
    return "\n".join(lines)


def multistep_lines(horizons: dict, align: bool = False) -> list[str]:
    """The multi-step section of a results.json ``horizons`` document (empty when it has no model): every model's
    MAE at each horizon, SimErr and its ratio to naive per group, how each model predicted, and the models left
    out with the reason."""
    if not horizons.get("models"):
        return [f"Multi-step table: {horizons['note']}.", ""] if horizons.get("note") else []
    lines = [f"## Multi-step prediction (IDSIA protocol, span {horizons['span']}, {horizons['starts']} start times)", "",
             f"MAE at horizon h steps and SimErr = sum of MAE_h for h = 1..{SIM_ERR_HORIZON}; ratio = model / naive constant-state prediction. "
             "Units: m, m/s, rad (geodesic angle), rad/s.", ""]
    if horizons.get("ground_starts"):
        lines[-1:-1] = [f"{horizons['ground_starts']} of the {horizons['starts']} starts' horizons touch the ground (within "
                        f"{GROUND_CONTACT_M * 100:g} cm of where the flight stood): scored as the rest, though no model here has "
                        "ground contact (the diagnosis leaves them out)."]
    longest = horizons.get("sim_err_horizon", SIM_ERR_HORIZON)
    if longest > SIM_ERR_HORIZON:  # every start needs the longest horizon's rows ahead: fewer starts than the default's
        lines[-1:-1] = [f"Every start has {longest} rows ahead (the longest horizon asked for), so the starts are fewer than "
                        f"with horizons up to {SIM_ERR_HORIZON} and SimErr is not comparable with a default run's."]
    hs = horizons["horizons"]
    rows = []
    for m, groups in horizons["models"].items():
        for g in GROUPS:
            e = groups[g]
            if "needs" in e:
                rows.append([m, g, *(needs_text(e) for _ in hs), needs_text(e), "-"])
                continue
            ratio = e["ratio_sim_err"]
            rows.append([m, g, *(f"{e['mae'][str(h)]:.4g}" for h in hs), f"{e['sim_err']:.4g}", "-" if ratio is None else f"{ratio:.3g}"])
    lines += markdown_table(["Model", "Group", *(f"MAE h={h}" for h in hs), "SimErr", "SimErr ratio"], rows, align=align, label_columns=2)
    forms = horizons.get("forms", {})
    streamed = [m for m, form in forms.items() if form == "streaming"]
    if streamed:
        lines += ["", f"Predicted by their live form from each start s (start_window on the warm rows ending at s, then one push "
                      f"per command; causal by construction): {', '.join(streamed)}."]
    left_out = horizons.get("not_multistep") or {}
    if isinstance(left_out, list):  # results.json written before the reasons were recorded
        left_out = {m: "no open-loop form" for m in left_out}
    for m, why in left_out.items():
        lines += ["", f"Not in the multi-step table: {m} ({why})."]
    lines.append("")
    return lines


def needs_text(entry: dict) -> str:
    """The cell of a variable the flights cannot measure: ``needs gyro`` (results.json ``"needs"``)."""
    return f"needs {entry['needs']}"


def score_text(entry: dict, key: str) -> str:
    """TIC of a results.json entry as text, or ``needs <sensor>`` for an unmeasured variable."""
    return needs_text(entry) if "needs" in entry else tic_text(entry[key])


def column_title(model: str, span: str) -> str:
    """A score column of the evaluation tables: ``greybox (eval)``."""
    return f"{model} ({span})"


def windows_text(data: dict) -> str:
    """``windows eval 2, train 4``: windows scored per span (the dummy model is scored on every one), from results.json."""
    return "windows " + ", ".join(f"{s} {n}" for s, n in data["windows"]["dummy"].items())


def headline_scores(data: dict, model_names: list[str]) -> list[str]:
    """One line per model of results.json: TIC of acc_z, roll_rate and vel_z on the eval span; else on the first span
    that holds windows, named in the line (the train span's scores read as held-out ones when unlabelled)."""
    lines = []
    for name in model_names:
        spans = data["models"][name]
        span = "eval" if spans.get("eval") else next(iter(spans), None)
        scores = spans.get(span) if span else None
        if scores:
            label = "" if span == "eval" else f" (span {span}: no eval window)"
            lines.append(f"  {name}{label}: TIC acc_z {score_text(scores['acc_z'], 'tic')}, roll_rate "
                         f"{score_text(scores['roll_rate'], 'tic')}, vel_z {score_text(scores['vel_z'], 'tic')}")
    return lines


def live_summary_table(results: dict, model_names: list[str]) -> str:
    """The run-bag summary of a live results.json: TIC / RMS (display units) per variable, one column per model and span.

    The dummy baseline (predicts zero, TIC = 1) rides along on the held-out span when it is not one of ``model_names``:
    its RMS is the scale of the variable. Aligned Markdown, so it reads in a terminal and pastes into a report."""
    marked = results.get("live", {}).get("marked", [])
    columns = [(m, span) for m in model_names for span in results["models"].get(m, {})]
    dummy_spans = list(results["models"].get("dummy", {}))
    if dummy_spans and "dummy" not in model_names:
        columns.append(("dummy", "eval" if "eval" in dummy_spans else dummy_spans[-1]))
    if not columns:
        return "no window was scored" + (f"; marked: {marked[0]['reason']}" if marked else "")
    def cell(entry: dict, var: str) -> str:
        return needs_text(entry) if "needs" in entry else f"{tic_text(entry['tic'])} / {display_number(var, entry['rms'])}"

    rows = [[var, display_unit(var), *(cell(results['models'][m][s][var], var) for m, s in columns)] for var in EVAL_VARIABLES]
    lines = ["TIC / RMS per variable (mean over windows; RMS in display units)", ""]
    lines += markdown_table(["variable", "unit", *(column_title(m, s) for m, s in columns)], rows, align=True, label_columns=2)
    windows = ", ".join(f"{m} {s}: {results['windows'][m][s]}" for m, s in columns)
    lines += ["", f"windows scored: {windows}; marked: {len(marked)}"]
    notes = model_notes(dict.fromkeys(m for m, _ in columns))
    return "\n".join(lines + ([""] + notes[:1] if notes else []))


MODEL_COLOURS = ("tab:red", "tab:cyan", "tab:purple", "tab:green", "black", "tab:orange", "tab:brown")
"""Colours of the models' lines (the measurement is blue, solid)."""
MODEL_LINES = ("--", "-.", ":")


def model_style(k: int) -> tuple[str, str]:
    """(colour, line style) of the k-th model of a figure: every model of up to 21 its own (a five-style cycle drew
    greybox and direct alike in a figure of seven)."""
    return MODEL_COLOURS[k % len(MODEL_COLOURS)], MODEL_LINES[(k // len(MODEL_COLOURS)) % len(MODEL_LINES)]


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
        for k, (name, predicted) in enumerate(example.predicted.items()):
            color, line = model_style(k)
            ax.plot(t, predicted[:, col] * factor, color=color, linestyle=line, lw=1.1, label=name)
        ax.axvline(t[example.warm_samples - 1], color="0.6", lw=0.8)
        ax.set_ylabel(f"{ROW_LABELS[var]} [{unit}]")
        if not np.isfinite(example.measured[:, col]).any():  # the flight lacks the sensor (results.json "needs")
            ax.set_title(f"{ROW_LABELS[var]}: not measured by this flight's sensors", fontsize=9)
            continue
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


def write_report(result: EvaluationResult, directory: Path, title: str = "Evaluation", document: dict | None = None,
                 specs: dict[str, str] | None = None) -> list[str]:
    """Write results.json, tables.md and the figures into ``directory`` (created); returns the file names.

    results.json holds ``document`` when given (the evaluator node's: the result plus every live window), else
    ``result.to_json()``. ``specs``: the spec of each named model, for tables.md's ``Models:`` line (:func:`model_notes`)."""
    directory.mkdir(parents=True)
    (directory / "results.json").write_text(json_text(result.to_json() if document is None else document))
    (directory / "tables.md").write_text(markdown_tables(result, title, specs) if document is None
                                         else tables_text(document, title, specs))
    written = ["results.json", "tables.md"]
    example = next((e for e in result.examples if e.span == "eval"), result.examples[0] if result.examples else None)
    if example is not None:
        for name, (axis, acc_var, rate_var) in FIGURES.items():
            window_figure(example, axis, acc_var, rate_var, directory / name)
            written.append(name)
    return written
