"""The physics-base diagnosis's report.md and diagnosis.json (:mod:`quad_modelling.core.diagnosis.physics_base`).

report.md leads with the answer (what was found, how far the held-out error falls), then the user's terms (delay,
motor command gains), the selection, each effect's components, the constants with their at-bound flags and, with
``--inject``, the known-answer checks. Lines are at most :data:`~quad_modelling.io.reports.formatting.REPORT_WIDTH`
characters.
"""

from __future__ import annotations

from pathlib import Path

from quad_modelling.core.diagnosis.verdicts import FOUND_MIN_BOUND, signed_percent
from quad_modelling.io.reports.formatting import REPORT_WIDTH, json_text, markdown_table, prose


def verdict_lines(data: dict, width: int = REPORT_WIDTH) -> list[str]:
    """The console answer, lines of at most ``width`` characters: found effects with their components, the held-out
    ratios before and after, the delay and motor gains, the known-answer checks."""
    return [wrapped for line in _verdict(data) for wrapped in prose(line.strip(), width, "  " if line.startswith(" ") else "",
                                                                   "    " if line.startswith(" ") else "  ")]


def _verdict(data: dict) -> list[str]:
    base, final = data["held_out"]["base"], data["held_out"]["final"]
    found = data["found"]
    head = (f"found: {', '.join(found)}" if found else "nothing among the candidates explains the gap")
    injection = data.get("injection")
    lines = [f"diagnosis (physics base){' of the flights with --inject ' + injection['spec'] if injection else ''}: {head}"]
    if data.get("in_sample_flights"):
        lines.append(f"  IN-SAMPLE: {', '.join(data['in_sample_flights'])} in both --train and --test: the held-out scores "
                     "below are in-sample")
    for name in found:
        lines.append(f"  {data['effects'][name]['text']}")
    if found and data.get("folds_note"):
        lines.append("  (the training flights' halves were not fitted apart, a half too short to fit alone: components "
                     "resolved on sigma and bounds alone; report.md says why)")
    lines.append(f"  held-out SimErr / naive, velocity {base['ratio_to_naive']['velocity']:.3f} -> "
                 f"{final['ratio_to_naive']['velocity']:.3f}, angular velocity {base['ratio_to_naive']['angular_velocity']:.3f} -> "
                 f"{final['ratio_to_naive']['angular_velocity']:.3f} (J {base['J']:.3f} -> {final['J']:.3f})")
    s = data["summary"]
    gains = s["motor_command_gains"]
    lines.append(f"  command delay {delay_text(s['delay_s'], (data.get('constants') or {}).get('rotor_delay'))}; motor command gains "
                 + (" ".join(f"{g:.3f}" for g in gains["value"]) if gains["fitted"] else "not fitted (motor_imbalance not a candidate)"))
    at_bound = [name for name, c in (data.get("constants") or {}).items()
                if isinstance(c, dict) and c.get("at_bound") and name != "rotor_delay"]  # the delay's line says its own
    if at_bound:  # in the report's constants table only, a user read the summary's model as fully measured
        lines.append(f"  AT BOUND (the fit ran to a search bound: not measured, the model holds the bound): {', '.join(at_bound)}")
    base_at_bound = [name for name, c in (data.get("base_constants") or {}).items()
                     if isinstance(c, dict) and c.get("at_bound") and name != "rotor_delay" and name not in at_bound]
    if base_at_bound:  # a base on its bounds: part of a term's shrink may be mending it (review: both splits' inertias)
        lines.append(f"  the base model (candidates off) ended AT BOUND on {', '.join(base_at_bound)}"
                     + (": part of a found term's shrink may mend that base, not the flights' physics" if found else ""))
    order = data.get("motor_order") or {}
    logged_order = ((data.get("un_injected") or {}).get("motor_order") or {}).get("verdict")
    if order.get("verdict") == "inconsistent" and injection and logged_order != "inconsistent":
        swap = order.get("diagnosed_with_swap")
        why = ("the injected change" if injection["spec"].startswith("swap:") else
               f"NOT the injection's doing: --inject {injection['spec']} exchanges no motors")
        lines.append(f"  motor order/spin of the injected flights: {', '.join(order['actions'])} ({why}; the flights "
                     f"as logged: {logged_order or 'not checked'})"
                     + (f"; diagnosed with the logged commands of motors {swap[0]} and {swap[1]} exchanged" if swap else ""))
    elif injection and logged_order == "inconsistent":
        logged = data["un_injected"]["motor_order"]
        lines.append(f"  motor order/spin of the flights as logged: INCONSISTENT with the vehicle file (fix it before trusting "
                     f"the effects): {', '.join(logged.get('actions') or []) or 'swap ' + str(logged.get('swap'))}; the "
                     f"injected flights ({injection['spec']}): {order.get('verdict', 'not checked')}")
    elif order.get("verdict") == "inconsistent":
        swap = order.get("diagnosed_with_swap")
        lines.append("  motor order/spin: INCONSISTENT with the vehicle file (fix it before trusting the effects): "
                     + ", ".join(order["actions"])
                     + (f"; diagnosed with the logged commands of motors {swap[0]} and {swap[1]} exchanged" if swap else "")
                     + ("; the written vehicle lists them in that order" if swap and data.get("vehicle_written") else ""))
    if injection:
        logged = data["un_injected"]
        s0 = logged["summary"]
        lines.append(f"  the flights as logged (un-injected run): found {', '.join(logged['found']) or 'nothing'}; command delay "
                     f"{delay_text(s0['delay_s'], {}, sigma=False)}; held-out J {logged['held_out']['base']['J']:.3f} -> "
                     f"{logged['held_out']['final']['J']:.3f}" + ("; --write-vehicle wrote this run's model"
                                                                 if data.get("vehicle_written") else ""))
        lines.append(f"  --inject {injection['spec']}: {VERDICTS[injection['passed']]} ("
                     + "; ".join(f"{c['check']}: {HOLDS[c['holds']]}" for c in injection["checks"]) + ")")
        lines += [f"    {_check_note(c)}" for c in injection["checks"] if c["holds"] is None]
        gain = gain_injection_note(data)
        if gain:
            lines.append(f"    {gain}")
    return lines


GAIN_NOT_FOUND = ("the motor imbalance need not be found as an effect for it: a constant torque of one stronger motor is "
                  "mostly a trim the disturbance observer holds, so the imbalance term's shrink of the held-out error may "
                  "stay too small or too uncertain to be confirmed")
"""Why a gain injection passes with the motor imbalance not found (NanoBench, trained on B2/B3/B7 medium, tested on
B5 helix medium, ``gain:2:1.25``: the ratio measured right, the imbalance 'not supported' at +5.4 %)."""


def gain_injection_note(data: dict) -> str:
    """For ``--inject gain:M:K``: the injected gain measured (motor M's ratio against K, the check) and, when the motor
    imbalance is not found, why it need not be (:data:`GAIN_NOT_FOUND`); '' for other injections or none."""
    injection = data.get("injection") or {}
    check = next((c for c in injection.get("checks", []) if c["check"].endswith("relative gain changes by K")), None)
    if check is None:
        return ""
    motor = check["check"].split("'")[0]
    text = (f"--inject {injection['spec']}: the injected gain is measured in the imbalance's fitted gains, {motor}'s over "
            f"the others' changed by the factor {check['measured']:.3f} against K = {check['expected']:g} +- {check['tolerance']:.0%} "
            f"(the check: {HOLDS[check['holds']]})")
    imbalance = (data.get("effects") or {}).get("motor_imbalance") or {}
    if imbalance.get("verdict") not in (None, "found"):
        text += f"; {GAIN_NOT_FOUND}"
    return text


def delay_text(delay: dict, constant: dict | None, sigma: bool = True) -> str:
    """The command delay of ``summary.delay_s`` (``constant``: its entry in ``constants``, for held and at-bound): value
    +- sigma, or, held, why; on a search bound the bound said and no sigma (it read "0.0 +- 0.3 ms" on its lower bound)."""
    constant = constant or {}
    value = delay["value"] * 1e3
    if constant.get("held"):
        return f"{value:.1f} ms ({constant['held']})"
    if delay.get("at_bound") or constant.get("at_bound"):
        if value <= 0.0:
            return (f"{value:.1f} ms (AT BOUND: the search's lower bound 0: the commands act at or before their stamps, "
                    "or a lag of the command path took the delay)")
        return f"{value:.1f} ms (AT BOUND: the search's; not measured)"
    return f"{value:.1f} +- {delay['sigma'] * 1e3:.1f} ms" if sigma else f"{value:.1f} ms"


def report_markdown(data: dict) -> str:
    """report.md of a physics-base diagnosis document (:meth:`PhysicsDiagnosis.to_json` plus injection/vehicle)."""
    out = ["# Sim-to-real gap diagnosis (physics base)", ""]
    out += [f"    {line}" for line in verdict_lines(data, REPORT_WIDTH - 4)] + [""]
    out += prose("The base is the physics model identified on the training flights with the candidate effects off; "
                 "each candidate is a term of that model, fitted with all its constants on the training flights and "
                 "scored on the held-out flights with the multi-step protocol of the models table (SimErr over "
                 "h = 1..50 relative to naive, J = the mean of velocity and angular velocity).") + [""]
    logged = ("The un-injected run: what `evaluate --model physics --vehicle V.yaml` gives on the held-out flights as logged "
              "for the vehicle `--write-vehicle` writes, and that run's verdict.")
    tables = [("Held-out multi-step error (SimErr / naive)", None, data)]
    if data.get("injection"):
        tables = [("Held-out multi-step error, injected flights (SimErr / naive)", None, data),
                  ("Held-out multi-step error, flights as logged (SimErr / naive)", logged, data["un_injected"])]
    for title, note, run in tables:
        out += _multistep_lines(title, note, run)
    out += ["## Selection (joint refit of every chosen effect)", ""]
    rows = []
    for step in data["selection"]:
        for name, t in [*step["trials"].items(), *step.get("pairs", {}).items()]:
            why = _why_not_joined(t, step) if name in step["trials"] else _why_pair_not_joined(t, name, step)
            rows.append([" + ".join(step["on_top_of"]) or "base", name, f"{signed_percent(t['shrink'])}", f"{signed_percent(t['shrink_5pct'])}",
                         "joined" if step["joined"] and name == step["best"] else why])
    out += markdown_table(["on top of", "candidate", "shrink of J", "5 % bound", ""], rows) + [""]
    if data.get("ladder"):
        out += prose("Ladder (each rung refitted jointly), held-out J: " + " -> ".join(
            f"{' + '.join(r['effects']) or 'base'} {r['J']:.3f}" for r in data["ladder"])) + [""]
    if data["dropped_shrink"]:
        out += prose("Order-free: each chosen effect dropped from the final set and the rest refitted, the shrink of J it "
                     "brings back (1 - J with it / J without it): "
                     + ", ".join(f"{k} {signed_percent(v)}" for k, v in data["dropped_shrink"].items())
                     + " (an effect whose shrink has a 5 % bound under 1 % left the set).") + [""]
    out += ["## Effects", ""]
    for name, effect in data["effects"].items():
        injected = gain_injection_note(data) if name == "motor_imbalance" else ""  # the gain injected, beside its verdict
        out += prose(effect["text"] + (f" ({injected})" if injected else ""), first="- ", rest="  ")
    for name, why in data["in_base"].items():
        out += prose(f"{name.replace('_', ' ')}: {why}", first="- ", rest="  ")
    rows = [[name, p["component"], f"{p['value']:.4g}", "-" if p.get("held") else f"{p['sigma']:.2g}", p["unit"],
             f"[{p['bounds'][0]:.3g}, {p['bounds'][1]:.3g}]", _component_state(p)]
            for name, effect in data["effects"].items() for p in effect.get("components", [])]
    if rows:
        out += ["", "Every component as fitted (sigma nan: the fit cannot separate it; -: held, not fitted):", ""]
        out += markdown_table(["effect", "component", "value", "sigma", "unit", "bounds", ""], rows)
        if data.get("folds_note"):
            out += [""] + prose(f"Note: {data['folds_note']}.")
    out += ["", "## Constants of the final model" + (" (the injected flights' run; --write-vehicle writes the un-injected run's)"
                                                      if data.get("injection") else ""), ""]
    base = data.get("base_constants") or {}  # the base's (candidates off): a base on its bounds is what a term may mend
    rows = [[name, f"{c['value']:.4g}", "-" if c.get("held") else f"{c['sigma']:.2g}", c["unit"],
             f"[{c['bounds'][0]:.3g}, {c['bounds'][1]:.3g}]", c["held"].split(":")[0] if c.get("held") else "AT BOUND" if c["at_bound"] else "",
             (f"{base[name]['value']:.4g}" + (" AT BOUND" if base[name]["at_bound"] else "")) if name in base else ""]
            for name, c in data["constants"].items()]
    out += markdown_table(["constant", "value", "sigma", "unit", "bounds", "", "base model's"], rows) + [""]
    order = data.get("motor_order")
    if order:
        out += prose(f"Motor order check: {order['verdict']}" + (f"; likely fix: {', '.join(order['actions'])}" if order["actions"] else ""))
        out += [""]
    injection = data.get("injection")
    if injection:
        out += [f"## Known answer: --inject {injection['spec']}", ""]
        out += markdown_table(["check", "expected", "measured", "holds", "note"],
                              [[c["check"], _check_value(c, "expected"), _check_value(c, "measured"),
                                HOLDS[c["holds"]], _check_note(c)] for c in injection["checks"]]) + [""]
    return "\n".join(out) + "\n"


def _check_value(check: dict, which: str) -> str:
    """An injection check's ``expected`` or ``measured`` cell: a delay in ms (+- its tolerance), a ratio, motors named."""
    if f"{which}_s" in check:
        tolerance = f" +- {check['tolerance_s'] * 1000:g}" if which == "expected" else ""
        return f"{check[f'{which}_s'] * 1000:.1f} ms{tolerance}"
    if which in check and isinstance(check[which], float):
        return f"{check[which]:.3f}" + (f" +- {check['tolerance']:.0%}" if which == "expected" and "tolerance" in check else "")
    if which == "expected" and "newly_found" in check:
        allowed = ", ".join(check.get("expected_new") or ())
        return "nothing" + (f" ({allowed} may: the injected change)" if allowed else "")
    value = check.get("named", check.get("newly_found", "")) if which == "measured" else check.get(which, "")
    if which == "measured" and "newly_found" in check:  # the effects newly found
        return ", ".join(check["newly_found"]) or "nothing"
    return "no swap" if value is None else str(value)


def _component_state(part: dict) -> str:
    """A component's flag in the report's table: resolved, held, at its bound, or not resolved."""
    if part.get("held"):
        return "held"
    if part["at_bound"]:
        return "AT BOUND"
    return "resolved" if part["resolved"] else "not resolved"


def _multistep_lines(title: str, note: str | None, run: dict) -> list[str]:
    """The held-out SimErr / naive of naive, base and final of a run on its two sets of starts, with the count of
    each: the verdict's (``run["held_out"]``, the summary's ratios) and every start (``run["multistep"]``, what
    ``evaluate`` gives); the difference is the starts that touch the ground and the verdict's sampling."""
    table, held = run["multistep"], run["held_out"]
    if not table.get("models"):
        return []
    every, airborne = table["starts"], table["airborne_starts"]
    sets = (f"Off the ground: the verdict's starts (its ratios and J), every second start whose 50 steps stay off the "
            f"ground, {held['final']['starts']} here. Every start: what `evaluate --model physics` gives, {every} starts, ")
    sets += (f"{every - airborne} of them touching the ground (within 1 cm of the flight's lowest point): no model here "
             "has ground contact and naive's standing prediction is exact there, so the verdict leaves them out (no "
             "candidate can supply the contact)." if every > airborne else
             "none touching the ground: the two differ only by the verdict's sampling of every second start.")
    verdict = {"naive": {"velocity": 1.0, "angular_velocity": 1.0}, **{k: held[k]["ratio_to_naive"] for k in ("base", "final")}}
    groups = ("velocity", "angular_velocity")
    rows = [[name, *(f"{verdict[name][g]:.3f}" for g in groups), *(f"{m[g]['ratio_sim_err']:.3f}" for g in groups)]
            for name, m in table["models"].items() if "ratio_sim_err" in m.get("velocity", {})]
    header = ["model", "off the ground: velocity", "angular velocity", "every start: velocity", "angular velocity"]
    return [f"## {title}", ""] + (prose(note) + [""] if note else []) + prose(sets) + [""] + markdown_table(header, rows) + [""]


def _why_not_joined(trial: dict, step: dict) -> str:
    """The selection table's last cell for a trial that did not join: the rule it missed, or that it qualified and
    another candidate shrank J more (the cell was empty: battery +2.7 %, bound +2.1 %, beside rotor drag's 26 %)."""
    if trial.get("yaw_pattern_only"):
        return f"a yaw pattern only: its roll and pitch part's 5 % bound < {FOUND_MIN_BOUND:.0%}"
    if trial["shrink_5pct"] < FOUND_MIN_BOUND:
        return f"5 % bound < {FOUND_MIN_BOUND:.0%}"
    if trial.get("main_resolved") is False:
        return "main component not resolved"
    return f"qualified; {step['best']} shrinks J more" if step.get("joined") and step.get("best") else ""


def _why_pair_not_joined(pair: dict, name: str, step: dict) -> str:
    """The selection table's last cell for a pair that did not join (:func:`~quad_modelling.core.diagnosis.physics_base.
    pair_candidates`: a pair joins on twice the single bound with both main components resolved)."""
    if pair["shrink_5pct"] < 2 * FOUND_MIN_BOUND:
        return f"5 % bound < {2 * FOUND_MIN_BOUND:.0%} (a pair's)"
    if pair.get("main_resolved") is False:
        return "a main component not resolved"
    if "motor_imbalance" in name and not (step.get("imbalance_roll_pitch") or {}).get("supported", True):
        return f"a yaw pattern only: its roll and pitch part's 5 % bound < {FOUND_MIN_BOUND:.0%}"
    return "another pair shrinks J more" if step.get("joined") else ""


VERDICTS = {True: "PASSED", False: "FAILED", None: "NOT JUDGED"}
"""An injection's verdict (``passed``: every check holds, one does not, one could not be judged)."""
HOLDS = {True: "yes", False: "NO", None: "not judged"}


def _check_note(check: dict) -> str:
    """What a reader needs beside an injection check's numbers: a delay identified on its search bound, a rise not
    judged from an un-injected delay of 0 ms (its lower bound)."""
    if check.get("at_search_bound"):
        return "on the delay's search bound: not measured"
    if check["check"].endswith("relative gain changes by K"):
        return "from the imbalance's gains, found or not"
    if check.get("logged_swap"):
        motors = " and ".join(map(str, check["logged_swap"]))
        return (f"the flights as logged have motors {motors} exchanged: " + ("the injection undoes it" if check["holds"] is not None
                else "with the injected one that makes two exchanges, which the order check (naming one) cannot name"))
    if check.get("reference_at_zero"):
        return ("the un-injected delay is 0 ms, its search's lower bound: the flights' commands act at or before their "
                "stamps, or the command path's lag was fitted as rotor lag; the rise from that bound falls short of the "
                "injected delay by an unknown amount and is not judged; compare two injections (delay:20 and delay:40) instead")
    return ""


def write_physics_diagnosis(data: dict, directory: Path) -> list[str]:
    """Write diagnosis.json and report.md into ``directory`` (created); the file names."""
    directory.mkdir(parents=True)
    (directory / "diagnosis.json").write_text(json_text(data))
    (directory / "report.md").write_text(report_markdown(data))
    return ["diagnosis.json", "report.md"]
