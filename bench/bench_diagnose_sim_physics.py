"""Known answers on simulated flights for the PHYSICS-base diagnosis (issue #26 item 9; ``diagnose`` without ``--base``).

Protocol: *the vehicle switches off every catalogue effect it assesses*. The diagnosis runs on the ``linkquad``
vehicle with ``effects: {motor_lag: {enabled: false}, input_delay: {enabled: false}}`` and rotor drag not switched
on (:func:`switched_vehicle`), in every case, so all seven candidates of
:data:`~quad_modelling.core.diagnosis.physics_base.CANDIDATES` are assessed: rotor drag, motor lag, input delay,
ground effect, battery, gyroscopic, motor imbalance.

The truth simulator (:func:`quad_modelling.core.sim.simulate.run_simulation`) flies that vehicle with the effects
of each case (:func:`cases`): each candidate alone, null (no effect), the pairs of :data:`PAIRS`, all seven on, and
the out-of-catalogue disturbances wind, com_offset, bent_arm alone. With ``motor_lag`` off the simulator's rotors
jump to their ESC target at each command (``esc_targets``: no first-order lag, the body takes the rotors' reaction
impulse, which the physics model's :math:`I_p \\sum s_i \\dot\\Omega_i` has from the speed differences); with
``input_delay`` off the commands reach the ESCs at the control tick they are computed (``delay_steps`` 0). So with
the vehicle's lag and delay switched off the null flights hold nothing the base lacks, and the right answer of null
and of every disturbance is "nothing found"; of the others, exactly the effects switched on.

Per seed set (train A B, test C, :data:`SEED_SETS`; the same trajectories and noise for every case, so the cases
differ only by the effects) the diagnosis runs as ``quad-modelling diagnose --train A B --test C`` runs it
(``PHYSICS_CONFIG``, every candidate; the base identified on the effect-on flights, as a user must).

Reported per case: found, right, the held-out J base -> final and its shrink, the perfect-model ceiling (the
``truth`` model, :class:`~quad_modelling.core.sim.truth_model.TruthPredictor`: the simulator's own physics from
the log's notes, scored on the same starts: ceiling = 1 - J_truth / J_base) and shrink / ceiling, the velocity /
angular-velocity SimErr ratios to naive, the first-step shrink of every candidate with its main component, the wall
time, and the sparse-regression comparison (:mod:`bench.sindy_selection`, PySINDy STLSQ over the same candidate
columns; it has no linear column for the lag or the delay, nonlinear constants of the command path, so it cannot
select them). The protocol, the per-case scoring and the targets are ``quad-modelling diagnose --validate``'s
(:mod:`quad_modelling.core.diagnosis.physics_validation`); this bench runs them on explicit seed sets and adds SINDy.

Writes bench/results/<--name>.json and .md (default ``diagnose_sim_physics_switched``). Run:
``nice -n 10 .venv/bin/python -m bench.bench_diagnose_sim_physics [--seeds 6201,6202,6203 6301,6302,6303]``
(5101,5102,5103 is the development set).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_diagnose_real import _finite  # noqa: E402
from bench.common import write_results  # noqa: E402
from bench.sindy_selection import HEADLINE, agreement, sindy_for  # noqa: E402
from quad_modelling.commands.diagnose import PHYSICS_CONFIG  # noqa: E402
from quad_modelling.core.diagnosis.physics_base import CANDIDATES  # noqa: E402
from quad_modelling.core.diagnosis.physics_validation import ASSESSED_SWITCHES, assessing_vehicle, scored_case, targets  # noqa: E402
from quad_modelling.core.diagnosis.validation import DEFAULT_PAIRS  # noqa: E402
from quad_modelling.core.effect_names import DISTURBANCES  # noqa: E402
from quad_modelling.core.sim.simulate import simulate  # noqa: E402
from quad_modelling.core.vehicle import VehicleConfig  # noqa: E402

VEHICLE = "linkquad"
SEED_SETS = ((6201, 6202, 6203), (6301, 6302, 6303))
"""(train, train, test) seeds of each set; none the diagnosis was developed on (development: 5101, 5102, 5103)."""
DEVELOPMENT = (5101, 5102, 5103)
"""The seed set the bench and any fix were developed on."""
DURATION_S = 60.0
"""Flight length [s]: 50 s scored after the 5 s / 5 s take-off and landing drops (the NanoBench flights give 32 s)."""
PAIRS = DEFAULT_PAIRS
"""The two-effect cases (issue #26 item 9), ``diagnose --validate``'s."""
SWITCHES = ASSESSED_SWITCHES


def switched_vehicle() -> VehicleConfig:
    """The ``linkquad`` vehicle with the validation's switches (lag and delay off; rotor drag not on)."""
    return assessing_vehicle(VEHICLE)


def cases() -> list[tuple[str, str, tuple[str, ...]]]:
    """(kind, label, simulator effects): single, null, pair, all, disturbance."""
    return [*(("single", c, (c,)) for c in CANDIDATES), ("null", "null", ()),
            *(("pair", "+".join(p), p) for p in PAIRS), ("all", "all seven", tuple(CANDIDATES)),
            *(("disturbance", d, (d,)) for d in DISTURBANCES)]


def run_case(kind: str, label: str, effects: tuple[str, ...], seeds: tuple[int, int, int], vehicle: VehicleConfig,
             duration: float) -> dict:
    """One case as ``diagnose --validate`` scores it (:func:`scored_case`), on this bench's explicit seed set, with
    the sparse-regression comparison."""
    clock = time.perf_counter()
    train = [simulate(VEHICLE, effects=effects, seed=s, duration=duration) for s in seeds[:2]]
    test = [simulate(VEHICLE, effects=effects, seed=seeds[2], duration=duration)]
    simulated = time.perf_counter() - clock
    row, result = scored_case(kind, effects, train, test, vehicle, PHYSICS_CONFIG, CANDIDATES,
                              progress=lambda m: print(f"  [{label} {seeds}] {m}", file=sys.stderr, flush=True))
    sindy = sindy_for(train, vehicle, PHYSICS_CONFIG, result.base.fit, result.candidates)
    return {**row, "case": label, "seeds": list(seeds), "selection": result.steps, "ladder": result.ladder,
            "sindy": sindy, "sindy_right": sorted(sindy["headline"]) == sorted(row["expected"]), "simulate_s": simulated}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=DURATION_S)
    parser.add_argument("--seeds", nargs="+", default=[",".join(map(str, s)) for s in SEED_SETS],
                        help="seed sets TRAIN1,TRAIN2,TEST (default: the two unseen sets)")
    parser.add_argument("--cases", default="", help="comma list of case labels (default: all)")
    parser.add_argument("--name", default="diagnose_sim_physics_switched", help="results file name in bench/results")
    args = parser.parse_args(argv)
    seed_sets = [tuple(int(x) for x in s.split(",")) for s in args.seeds]
    if any(len(s) != 3 for s in seed_sets):
        parser.error("--seeds: each set is TRAIN1,TRAIN2,TEST")
    vehicle = switched_vehicle()
    began = time.perf_counter()
    rows = []
    wanted = [c for c in args.cases.split(",") if c]
    for seeds in seed_sets:
        for kind, label, effects in cases():
            if wanted and label not in wanted and kind not in wanted:
                continue
            row = run_case(kind, label, effects, seeds, vehicle, args.duration)
            rows.append(row)
            print(f"{label} {seeds}: found {row['found']} right={row['right']} shrink {row['shrink']:.1%} ceiling "
                  f"{row['ceiling']:.1%} sindy {row['sindy']['headline']} ({row['diagnose_s']:.0f} s)", file=sys.stderr, flush=True)
            write_results(args.name, _finite(data(rows, seed_sets, args.duration, began, False)),
                          markdown(rows, seed_sets, args.duration, time.perf_counter() - began))
    write_results(args.name, _finite(data(rows, seed_sets, args.duration, began, True)),
                  markdown(rows, seed_sets, args.duration, time.perf_counter() - began))
    return 0


def data(rows: list[dict], seed_sets, duration: float, began: float, complete: bool) -> dict:
    return {"vehicle": VEHICLE, "vehicle_effects": SWITCHES, "seed_sets": [list(s) for s in seed_sets],
            "duration_s": duration, "cases": rows, "targets": targets(rows), "wall_s": time.perf_counter() - began,
            "complete": complete}


def _main_text(part: dict | None) -> str:
    if not part:
        return ""
    flag = "" if part["resolved"] else " unres."
    return f" [{part['value']:.3g}{flag}]"


def markdown(rows: list[dict], seed_sets, duration: float, wall: float) -> str:
    sets = "; ".join(f"train {a}, {b}, test {c}" for a, b, c in seed_sets)
    lines = ["# Physics-base diagnosis on simulated known answers, every catalogue effect switched off and assessed", "",
             f"Truth simulator, vehicle `{VEHICLE}` with `effects: motor_lag/input_delay {{enabled: false}}` (rotor drag "
             f"not on): all seven candidates assessed in every case. {duration:g} s flights (5 s / 5 s dropped), seed "
             f"sets {sets}{'' if DEVELOPMENT not in seed_sets else ' (5101-5103: the development set)'}{' (not the development set 5101-5103)' if DEVELOPMENT not in seed_sets else ''}. `diagnose_physics` as `quad-modelling diagnose` runs it, "
             "base identified on the effect-on training flights. Right = exactly the switched catalogue effect(s) found "
             "(null and disturbances: nothing). Shrink = 1 - J final / J base on the held-out flight (every 2nd start, "
             "as the selection scores); ceiling = 1 - J truth / J base on the same starts (`truth` model: the "
             "simulator's own physics); first-step shrink per candidate, in brackets the "
             "main component's value as reported (the final fit when found, else its last trial; unres. = not resolved). SINDy: PySINDy STLSQ over the same candidate columns (threshold "
             f"{HEADLINE:g}; no column for lag or delay).", "", "## Against the targets (issue #26 item 9)", "",
             "| target | measured | met |", "|---|---|---|"]
    for t in targets(rows):
        lines.append(f"| {t['target']} | {t['measured']} | {'' if t['met'] is None else 'yes' if t['met'] else '**no**'} |")
    lines += ["", "## Cases", "",
              "| seeds | case | found | right | J base -> final (shrink) | J truth (ceiling) | shrink / ceiling | "
              "vel / AV ratio base -> final | first-step shrink per candidate [main component] | SINDy selects | SINDy right | diagnose s |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        rb, rf = r["ratio_base"], r["ratio_final"]
        first = ", ".join(f"{c} {v:.1%}{_main_text(r['main_component'].get(c))}"
                          for c, v in r["first_step_shrink"].items())
        of_ceiling = f"{r['shrink_of_ceiling']:.0%}" if r["shrink_of_ceiling"] is not None else "-"
        lines.append(f"| {r['seeds'][2]} | {r['case']} | {', '.join(r['found']) or 'nothing'} | {'yes' if r['right'] else '**no**'} | "
                     f"{r['J_base']:.4f} -> {r['J_final']:.4f} ({r['shrink']:.1%}) | {r['J_truth']:.4f} ({r['ceiling']:.1%}) | "
                     f"{of_ceiling} | {rb['velocity']:.3f} / {rb['angular_velocity']:.3f} -> {rf['velocity']:.3f} / "
                     f"{rf['angular_velocity']:.3f} | {first} | {', '.join(r['sindy']['headline']) or 'nothing'} | "
                     f"{'yes' if r['sindy_right'] else 'no'} | {r['diagnose_s']:.0f} |")
    right = sum(r["right"] for r in rows)
    sindy_right = sum(r["sindy_right"] for r in rows)
    lines += ["", f"Diagnosis right: **{right} of {len(rows)}**; SINDy (threshold {HEADLINE:g}) right: **{sindy_right} of "
              f"{len(rows)}**. Whole bench {wall / 60:.1f} min on a shared, loaded 2-core machine (nice 10).", "",
              "Per case, each effect's sentence (`effects[c].text`):", ""]
    for r in rows:
        lines.append(f"- {r['seeds'][2]} {r['case']}: " + "; ".join(t for t in r["texts"].values() if t))
    if rows:
        lines += ["", "SINDy at every threshold:", "", "| seeds | case | " + " | ".join(f"STLSQ {t}" for t in rows[0]["sindy"]["selected"]) + " |",
                  "|---|---|" + "---|" * len(rows[0]["sindy"]["selected"])]
        for r in rows:
            lines.append(f"| {r['seeds'][2]} | {r['case']} | " + " | ".join(", ".join(v) or "nothing" for v in r["sindy"]["selected"].values()) + " |")
        lines += ["", "Against the known answer: " + agreement([(r["expected"], r["sindy"]) for r in rows]).replace(
            "the diagnosis's effects", "the switched effects")]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
