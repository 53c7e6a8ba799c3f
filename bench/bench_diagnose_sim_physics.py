"""Known answers on simulated flights for the PHYSICS-base diagnosis (issue #26; ``diagnose`` without ``--base``).

The truth simulator (:func:`quad_modelling.core.sim.simulate.run_simulation`) flies the ``linkquad`` vehicle with
each candidate of the physics base alone (rotor drag, ground effect, battery, gyroscopic, motor imbalance), no
effect (null) and one pair (:data:`PAIR`): two training flights and one held-out test flight per case, seeds
:data:`TRAIN_SEEDS` and :data:`TEST_SEED` (the same trajectories and noise for every case, so the cases differ only
by the effects; none of the seeds 0-2 the diagnosis was developed on), :data:`DURATION_S` s each. The diagnosis runs
as ``quad-modelling diagnose --train A B --test C`` runs it (``PHYSICS_CONFIG``, every candidate; the base identified
on the same effect-on flights, as a user must).

Right: the effect(s) switched on found and nothing else; null: nothing found. Reported per case: found, right, the
held-out J base -> final and its shrink, the velocity / angular-velocity SimErr ratios to naive, the wall time, and
the sparse-regression comparison (:mod:`bench.sindy_selection`, PySINDy STLSQ over the same candidate columns).

Writes bench/results/diagnose_sim_physics.json and .md. Run:
``nice -n 10 .venv/bin/python -m bench.bench_diagnose_sim_physics [--duration 60]``
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
from quad_modelling.core.diagnosis.physics_base import CANDIDATES, diagnose_physics  # noqa: E402
from quad_modelling.core.sim.simulate import simulate  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402

VEHICLE = "linkquad"
TRAIN_SEEDS = (5101, 5102)
TEST_SEED = 5103
DURATION_S = 60.0
"""Flight length [s]: 50 s scored after the 5 s / 5 s take-off and landing drops (the NanoBench flights give 32 s)."""
PAIR = ("rotor_drag", "motor_imbalance")


def cases() -> list[tuple[str, tuple[str, ...]]]:
    return [*((c, (c,)) for c in CANDIDATES), ("null", ()), ("pair", PAIR)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=DURATION_S)
    parser.add_argument("--cases", default="", help="comma list of case labels (default: all)")
    args = parser.parse_args(argv)
    vehicle = load_vehicle(VEHICLE)
    began = time.perf_counter()
    rows = []
    wanted = [c for c in args.cases.split(",") if c]
    for label, effects in cases():
        name = "+".join(effects) or "null"
        if wanted and name not in wanted and label not in wanted:
            continue
        clock = time.perf_counter()
        train = [simulate(vehicle, effects=effects, seed=s, duration=args.duration) for s in TRAIN_SEEDS]
        test = [simulate(vehicle, effects=effects, seed=TEST_SEED, duration=args.duration)]
        simulated = time.perf_counter() - clock
        result = diagnose_physics(train, test, vehicle, PHYSICS_CONFIG, CANDIDATES,
                                  progress=lambda m, n=name: print(f"  [{n}] {m}", file=sys.stderr, flush=True))
        seconds = time.perf_counter() - clock - simulated
        found = result.found
        right = sorted(found) == sorted(effects)
        sindy = sindy_for(train, vehicle, PHYSICS_CONFIG, result.base.fit, result.candidates)
        trials = {c: t["shrink"] for s in result.steps[:1] for c, t in s["trials"].items()}
        rows.append({"case": name, "effects": list(effects), "found": found, "right": right,
                     "J_base": result.base.score.j, "J_final": result.final.score.j,
                     "shrink": 1 - result.final.score.j / result.base.score.j,
                     "ratio_base": result.base.score.ratios(), "ratio_final": result.final.score.ratios(),
                     "first_step_shrink": trials, "selection": result.steps, "dropped_shrink": result.dropped,
                     "texts": {c: e.get("text") for c, e in result.effects.items()},
                     "delay_s": result.summary["delay_s"], "motor_command_gains": result.summary["motor_command_gains"],
                     "sindy": sindy, "sindy_right": sorted(sindy["headline"]) == sorted(effects),
                     "simulate_s": simulated, "diagnose_s": seconds})
        print(f"{name}: found {found} right={right} sindy {sindy['headline']} ({seconds:.0f} s)", file=sys.stderr, flush=True)
        write_results("diagnose_sim_physics", _finite(data(rows, args.duration, began, False)),
                      markdown(rows, args.duration, time.perf_counter() - began))
    write_results("diagnose_sim_physics", _finite(data(rows, args.duration, began, True)),
                  markdown(rows, args.duration, time.perf_counter() - began))
    return 0


def data(rows: list[dict], duration: float, began: float, complete: bool) -> dict:
    return {"vehicle": VEHICLE, "train_seeds": list(TRAIN_SEEDS), "test_seed": TEST_SEED, "duration_s": duration,
            "cases": rows, "wall_s": time.perf_counter() - began, "complete": complete}


def markdown(rows: list[dict], duration: float, wall: float) -> str:
    right = sum(r["right"] for r in rows)
    sindy_right = sum(r["sindy_right"] for r in rows)
    lines = ["# Physics-base diagnosis on simulated known answers", "",
             f"Truth simulator, vehicle `{VEHICLE}`, {duration:g} s flights (5 s / 5 s dropped), training seeds "
             f"{', '.join(map(str, TRAIN_SEEDS))}, test seed {TEST_SEED} (the same for every case; not the development "
             "seeds 0-2). `diagnose_physics` with every candidate, base identified on the effect-on training flights. "
             "Right = exactly the switched effect(s) found (null: nothing). Shrink = 1 - J final / J base on the "
             f"held-out flight. SINDy: PySINDy STLSQ over the same candidate columns (threshold {HEADLINE:g}).", "",
             "| case | found | right | J base -> final (shrink) | vel / AV ratio base -> final | first-step shrink per candidate | SINDy selects | SINDy right | diagnose s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        rb, rf = r["ratio_base"], r["ratio_final"]
        first = ", ".join(f"{c} {v:.1%}" for c, v in r["first_step_shrink"].items())
        lines.append(f"| {r['case']} | {', '.join(r['found']) or 'nothing'} | {'yes' if r['right'] else '**no**'} | "
                     f"{r['J_base']:.4f} -> {r['J_final']:.4f} ({r['shrink']:.1%}) | {rb['velocity']:.3f} / "
                     f"{rb['angular_velocity']:.3f} -> {rf['velocity']:.3f} / {rf['angular_velocity']:.3f} | {first} | "
                     f"{', '.join(r['sindy']['headline']) or 'nothing'} | {'yes' if r['sindy_right'] else 'no'} | {r['diagnose_s']:.0f} |")
    lines += ["", f"Diagnosis right: **{right} of {len(rows)}**; SINDy (threshold {HEADLINE:g}) right: **{sindy_right} of "
              f"{len(rows)}**. Whole bench {wall / 60:.1f} min on a shared, loaded 2-core machine.", "",
              "SINDy at every threshold:", "", "| case | " + " | ".join(f"STLSQ {t}" for t in rows[0]["sindy"]["selected"]) + " |",
              "|---|" + "---|" * len(rows[0]["sindy"]["selected"])]
    for r in rows:
        lines.append(f"| {r['case']} | " + " | ".join(", ".join(v) or "nothing" for v in r["sindy"]["selected"].values()) + " |")
    lines += ["", "Against the known answer: " + agreement([(r["effects"], r["sindy"]) for r in rows]).replace(
        "the diagnosis's effects", "the switched effects")]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
