"""Diagnosis validation reports: validation.md and validation.json of ``quad-modelling diagnose --validate``.

The document is :func:`quad_modelling.core.diagnosis.validation.validate`'s (shrinks as fractions:
0.4 = the held-out gap shrinks by 40 %); the Markdown shows them as percentages.
"""

from __future__ import annotations

from pathlib import Path

from quad_modelling.io.reports.formatting import json_text, markdown_table, percent


def validation_summary(result: dict) -> str:
    """One line: accuracy, runs, what the null case found, pairs accuracy."""
    return (f"accuracy {percent(result['accuracy'], 0)} over {len(result['runs'])} runs; "
            f"null case found {', '.join(result['null']['found']) or 'nothing'}; pairs {percent(result['pairs_accuracy'], 0)}")


def write_validation(result: dict, directory: Path) -> list[str]:
    """validation.json and validation.md into ``directory`` (created); returns the file names."""
    directory.mkdir(parents=True)
    (directory / "validation.json").write_text(json_text(result))
    (directory / "validation.md").write_text(validation_markdown(result))
    return ["validation.json", "validation.md"]


def validation_markdown(result: dict) -> str:
    """validation.md: accuracy, the shrink columns explained, shrink per effect, then every run, null run and pair."""
    out = [f"# Diagnosis validation on simulated {result['vehicle']} flights", "",
           f"Accuracy (right effect ranked first and found): **{percent(result['accuracy'], 0)}** over {len(result['runs'])} (effect, seed) runs; "
           f"null case found: {', '.join(result['null']['found']) or 'nothing'}; pairs both found in top 3: "
           f"{percent(result['pairs_accuracy'], 0)}.", "",
           "Shrink columns: **held-out shrink** = the literal target (the diagnosis's shrink of the effect's affected-variable gap, "
           "base model without the effect -> with it); **attributable** = 1 - G_off/G_on, the share of the base model's held-out "
           "gap (all windows) that the same test seed flown with every effect off does not have, i.e. the ceiling of the literal "
           "shrink; **removed** = (G_on - G_after)/(G_on - G_off), the share of that effect-attributable gap the fitted effect removes "
           "(can exceed 100 %: the effect-off twin flies the manoeuvres slightly differently); **sensor ceiling** = "
           "1 - G_sensor/G_on on the scored windows and variables, G_sensor the gap between the measurement and the simulator's "
           "true IMU signals (same preprocessing): what a model predicting the true signals exactly would reach, so the literal "
           "shrink cannot exceed it (in expectation) and a run whose ceiling is below the target cannot meet it.", ""]
    if result.get("shrink_by_effect"):
        out += markdown_table(("effect", "held-out shrink min / median / max", "sensor ceiling min / median / max",
                               "attributable min / median", "removed min / median"),
                              (_effect_spread_row(result, name) for name in result["shrink_by_effect"]))
        out.append("")
    out += markdown_table(
        ("effect", "seed", "top", "correct", "held-out shrink", "sensor ceiling", "scored on", "attributable", "removed", "verdict", "ranking"),
        ((r["effect"], r["seed"], r["top"], _yes_no(r["correct"]), percent(r["shrink"]), percent(r.get("sensor_ceiling")),
          ", ".join(r.get("variables", [])) or "-", percent(r.get("attributable_share")), percent(r.get("attributable_removed")),
          r["verdict"], _shrinks(r["top_shrinks"])) for r in result["runs"]))
    out += [""] + markdown_table(("null seed", "found", "top shrinks"),
                                 ((n["seed"], ", ".join(n["found"]) or "-", _shrinks(n["top_shrinks"])) for n in result["null"]["runs"]))
    if result["pairs"]:
        out += ["", "Pairs are ranked by conditional contribution: the second effect's shrink is what it adds on top of the first.", ""]
        out += markdown_table(("pair", "seed", "top 3", "found", "both in top 3", "shrinks"),
                              ((" + ".join(p["effects"]), p["seed"], ", ".join(p["top3"]), ", ".join(p["found"]) or "-",
                                _yes_no(p["both_found_in_top3"]), _shrinks(p["shrinks"])) for p in result["pairs"]))
    return "\n".join(out) + "\n"


def _effect_spread_row(result: dict, name: str) -> list[str]:
    """min / median / max of one effect's held-out shrink and sensor ceiling, min / median of its attributable shares."""
    shrink = result["shrink_by_effect"][name]
    ceiling = result.get("sensor_ceiling_by_effect", {}).get(name, {})
    share = result.get("attributable_share_by_effect", {}).get(name, {})
    removed = result.get("attributable_removed_by_effect", {}).get(name, {})
    return [name, " / ".join(percent(shrink[k]) for k in ("min", "median", "max")),
            " / ".join(percent(ceiling.get(k)) for k in ("min", "median", "max")),
            " / ".join(percent(share.get(k)) for k in ("min", "median")), " / ".join(percent(removed.get(k)) for k in ("min", "median"))]


def _shrinks(shrinks: dict) -> str:
    """``{"rotor_drag": 0.559, "battery": 0.002}`` -> ``rotor_drag 55.9%, battery 0.2%``."""
    return ", ".join(f"{name} {percent(value)}" for name, value in shrinks.items())


def _yes_no(flag: bool) -> str:
    return "yes" if flag else "no"
