"""Diagnosis validation reports: validation.md and validation.json of ``quad-modelling diagnose --validate``.

The document is :func:`quad_modelling.core.diagnosis.validation.validate`'s (shrinks as fractions:
0.4 = the held-out gap shrinks by 40 %); the Markdown shows them as percentages, the targets first, every
line at most :data:`~quad_modelling.io.reports.formatting.REPORT_WIDTH` characters.
"""

from __future__ import annotations

from pathlib import Path

from quad_modelling.io.reports.formatting import json_text, narrow_table, percent, prose


def validation_summary(result: dict) -> str:
    """One line: single-effect accuracy, null, pairs, all effects, disturbances."""
    if result.get("base") == "physics":
        return "; ".join(f"{t['target']}: {t['measured']}" for t in result["targets"])
    t = result["targets"]
    all_found = ", ".join(f"{f}/{n}" for f, n in zip(t["all_effects"]["found"], t["all_effects"]["of"])) or "-"
    return (f"single {percent(result['accuracy'], 0)} of {len(result['runs'])}; null {t['null_clean']['right']}/"
            f"{t['null_clean']['runs']} clean; pairs {percent(result['pairs_accuracy'], 0)}; all on: {all_found} found; "
            f"disturbances {t['disturbances_unexplained']['right']}/{t['disturbances_unexplained']['runs']} unexplained")


def write_validation(result: dict, directory: Path) -> list[str]:
    """validation.json and validation.md into ``directory`` (created); returns the file names."""
    directory.mkdir(parents=True)
    (directory / "validation.json").write_text(json_text(result))
    physics = result.get("base") == "physics"
    (directory / "validation.md").write_text(physics_validation_markdown(result) if physics else validation_markdown(result))
    return ["validation.json", "validation.md"]


def validation_markdown(result: dict) -> str:
    """validation.md: the targets, the shrink against the ceiling per effect, then every case."""
    t = result["targets"]
    out = [f"# Diagnosis validation on simulated {result['vehicle']} flights", ""]
    out += prose(f"Seeds {', '.join(map(str, result['seeds']))}, {result['duration_s']:g} s flights; base model "
                 f"{result['flights']['base']}; {result['seconds']:.0f} s.")
    out += ["", "## Targets", ""]
    ceiling = t["shrink_of_ceiling"]
    rows = [
        ("single effects right (first and found)", ">= 90 %", f"{percent(t['single_right']['value'], 0)} of {t['single_right']['runs']}"),
        ("... or a signature first (battery: trim drift)", "", f"{percent(t['single_right'].get('by_signature'), 0)}"),
        ("... lag/delay twin first, said inseparable", "", f"{t['single_right'].get('inseparable_twin_first', 0)} runs"),
        ("shrink >= 80 % of a ceiling >= 20 %", "all runs", f"{ceiling['met']} of {ceiling['runs']} (min {percent(ceiling['min'], 0)})"),
        ("shrink above its ceiling + 2 points", "none", f"{t['shrink_not_above_ceiling']['above']} of {t['shrink_not_above_ceiling']['runs']} "
         f"(max excess {percent(t['shrink_not_above_ceiling']['max_excess'])})"),
        ("pairs: both found in the top 3", ">= 90 %", f"{percent(t['pairs_both_top3']['value'], 0)} of {t['pairs_both_top3']['runs']}"),
        ("null case: nothing found", "all", f"{t['null_clean']['right']} of {t['null_clean']['runs']}"),
        ("disturbances: nothing found", "all", f"{t['disturbances_unexplained']['right']} of {t['disturbances_unexplained']['runs']}"),
        ("all effects on: found", t["all_effects"]["target"],
         ", ".join(f"{f} of {n}" for f, n in zip(t["all_effects"]["found"], t["all_effects"]["of"])) or "-"),
        ("time", "< 600 s on 2 cores", f"{t['seconds']['value']:.0f} s (jobs {t['seconds']['jobs'] or 1})"),
    ]
    out += narrow_table(("target", "wanted", "measured"), rows)
    out += ["", "## Single effects: shrink against the sensor ceiling", ""]
    out += prose("Shrink: the held-out shrink of the effect's affected-variable gap. Sensor ceiling: the shrink a "
                 "perfect model anchored as the diagnosis anchors would reach on the same windows and variables "
                 "(the simulator's noise-free IMU: every sensor error but the white noise); of ceiling = shrink / ceiling.")
    out.append("")
    out += narrow_table(("effect", "shrink min/med/max", "ceiling min/med/max", "of ceiling min/med"),
                        (_spread_row(result, name) for name in result.get("shrink_by_effect", {})))
    out.append("")
    out += narrow_table(("effect", "seed", "top", "right", "shrink", "ceiling", "verdict"),
                        ((r["effect"], r["seed"], r["top"], _yes_no(r["right"]), percent(r["shrink"]),
                          percent(r["sensor_ceiling"]), r["verdict"]) for r in result["runs"]))
    wrong = [r for r in result["runs"] if not r["right"]]
    if wrong:
        out += ["", "Why the wrong single runs went wrong:", ""]
        for r in wrong:
            out += prose(f"{r['effect']} seed {r['seed']}: ranked {', '.join(r['ranking'])}; {r['effect']} {r['verdict']}: "
                         f"{r['reason']}", first="- ", rest="  ")
    out += ["", "## Null case, disturbances, pairs, all effects", ""]
    out += narrow_table(("case", "seed", "found", "right", "where (share of the gap left)"),
                        ((r["effects"][0] if r["effects"] else "null", r["seed"], ", ".join(r["found"]) or "-",
                          _yes_no(r["right"]), _where(r.get("where", {})))
                         for r in result["null"]["runs"] + result["disturbances"]))
    if result["pairs"]:
        out.append("")
        out += narrow_table(("pair", "seed", "top 3", "found", "right"),
                            ((" + ".join(p["effects"]), p["seed"], ", ".join(p["top3"]), ", ".join(p["found"]) or "-",
                              _yes_no(p["right"])) for p in result["pairs"]))
    for r in result["all"]:
        out.append("")
        out += prose(f"All effects on, seed {r['seed']}: {len(r['found_of_on'])} of {len(r['effects'])} found "
                     f"({', '.join(r['found_of_on']) or 'none'}); missed: "
                     f"{', '.join(e for e in r['effects'] if e not in r['found_of_on']) or 'none'}; "
                     f"found but not on: {', '.join(r['false']) or 'none'}.")
    return "\n".join(out) + "\n"


def _spread_row(result: dict, name: str) -> list[str]:
    shrink = result["shrink_by_effect"][name]
    ceiling = result.get("sensor_ceiling_by_effect", {}).get(name, {})
    fraction = result.get("ceiling_fraction_by_effect", {}).get(name, {})
    return [name, "/".join(percent(shrink[k], 0) for k in ("min", "median", "max")),
            "/".join(percent(ceiling.get(k), 0) for k in ("min", "median", "max")),
            "/".join(percent(fraction.get(k), 0) for k in ("min", "median"))]


def _where(where: dict) -> str:
    parts = [f"{v} {percent(s, 0)}" for v, s in where.get("variables", [])[:2]]
    parts += [f"{b} {percent(s, 0)}" for b, s in where.get("bands", [])[:1]]
    return ", ".join(parts) or "-"


def _yes_no(flag: bool) -> str:
    return "yes" if flag else "no"


def physics_validation_markdown(result: dict) -> str:
    """validation.md of the physics base (:func:`~quad_modelling.core.diagnosis.physics_validation.validate_physics`):
    the targets, then every case with its shrink against the perfect-model ceiling and each effect's sentence."""
    out = [f"# Physics-base diagnosis validation on simulated {result['vehicle']} flights", ""]
    out += prose(f"Seeds {', '.join(map(str, result['seeds']))}, {result['duration_s']:g} s flights; the vehicle switches "
                 f"motor lag and input delay off, so every candidate is assessed ({', '.join(result['candidates'])}); "
                 f"base model {result['flights']['base']}; {result['seconds']:.0f} s. Right: exactly the simulator's "
                 "switched candidates found (null and disturbances: nothing). Shrink = 1 - J final / J base on the "
                 "held-out flight's starts whose horizon does not touch the ground; ceiling = 1 - J truth / J base on "
                 "the same starts (the simulator's own physics).")
    out += ["", "## Targets", ""]
    out += narrow_table(("target", "measured", "met"),
                        ((t["target"], t["measured"], "" if t["met"] is None else _yes_no(t["met"])) for t in result["targets"]))
    out += ["", "## Cases", ""]
    out += narrow_table(("seed", "case", "found", "right", "J base -> final", "shrink", "ceiling"),
                        ((r["seed"], r["case"], ", ".join(r["found"]) or "-", _yes_no(r["right"]),
                          f"{r['J_base']:.3f} -> {r['J_final']:.3f}", percent(r["shrink"]), percent(r["ceiling"]))
                         for r in result["cases"]))
    wrong = [r for r in result["cases"] if not r["right"]]
    if wrong:
        out += ["", "The cases not right, each effect's sentence:", ""]
        for r in wrong:
            out += prose(f"seed {r['seed']} {r['case']}: " + "; ".join(t for t in r["texts"].values() if t), first="- ", rest="  ")
    return "\n".join(out) + "\n"
