"""Does an effect term explain the physics fit's inflated roll/pitch inertias (effective_ixx/iyy, docs/models.md)?

The physics fit identifies the roll/pitch inertias as I = k_f / alpha (physics_fit.py); on the NanoBench Crazyflie
flights they come out several times the airframe's (Foerster 2015). This refits them on the bundled bag and on
NanoBench flights (each alone, ``short`` preset: training span 0-60 %) with each disturbance observer ``identify``
chooses among (physics_result.OBSERVERS), without the body's gyroscopic torque (k_b = 0), and with each optional term the fit
can switch on (gyroscopic k_b/k_p, ground_effect, battery; default observer), and reports effective / airframe
for roll and pitch. Writes bench/results/effective_inertia.{json,md}.

Run: .venv/bin/python bench/bench_effective_inertia.py [--flights N]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import write_results  # noqa: E402
from quad_modelling.core.identification.physics_fit import identify_physics  # noqa: E402
from quad_modelling.core.identification.physics_result import OBSERVERS  # noqa: E402
from quad_modelling.core.physics.effects import EffectTerm, TermValue  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.core.windows import EvaluationConfig  # noqa: E402
from quad_modelling.io.loader import load_flight  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
NANOBENCH = Path("/work/shared/data/nanobench")
FLIGHTS = ("B2_circle_medium_rep2", "B3_figure8_medium_rep2", "B5_helix_medium_rep1", "B2_circle_fast_rep2")
CONFIG = EvaluationConfig.preset("short")


def variants(vehicle):
    """(label, vehicle, observer or None, terms) of every fit compared."""
    out = [(f"observer {name}", vehicle, observer, ()) for name, observer in OBSERVERS.items()]
    held = {name: TermValue(0.0, "1", (0.0, 10.0), "bench: removed", "held") for name in ("body_scale", "rotor_scale")}
    no_gyro = replace(vehicle, effects={**vehicle.effects, "gyroscopic": EffectTerm("gyroscopic", True, held)})
    out.append(("no gyroscopic torque, k_b = k_p = 0 (default observer)", no_gyro, OBSERVERS["default"], ()))
    for term in ("gyroscopic", "ground_effect", "battery"):
        out.append((f"+{term} fitted (default observer)", vehicle, OBSERVERS["default"], (term,)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--flights", type=int, default=len(FLIGHTS), help="NanoBench flights besides the bag")
    args = parser.parse_args()
    vehicle = load_vehicle("crazyflie21")
    ixx, iyy = vehicle.value("ixx"), vehicle.value("iyy")
    sources = [("bundled bag B7_oval_medium_rep2", BAG)]
    sources += [(name, NANOBENCH / f"{name}.csv.gz") for name in FLIGHTS[: args.flights] if (NANOBENCH / f"{name}.csv.gz").exists()]
    rows = []
    for label, path in sources:
        log = load_flight(path, vehicle)
        for name, v, observer, terms in variants(vehicle):
            try:
                fit = identify_physics([log], v, CONFIG, observer, terms)
            except Exception as err:  # a term the flight cannot fit: recorded, not fatal
                rows.append({"flight": label, "variant": name, "error": str(err)[:120]})
                print(label, name, "error", err, flush=True)
                continue
            row = {"flight": label, "variant": name, "ixx_ratio": fit.values["effective_ixx"] / ixx,
                   "iyy_ratio": fit.values["effective_iyy"] / iyy,
                   "ixx_ratio_sigma": fit.sigma["effective_ixx"] / ixx, "iyy_ratio_sigma": fit.sigma["effective_iyy"] / iyy,
                   "roll_error_ratio": fit.diagnostics["error_ratio"]["roll"], "pitch_error_ratio": fit.diagnostics["error_ratio"]["pitch"],
                   "terms": fit.terms}
            rows.append(row)
            print(f"{label} | {name} | {row['ixx_ratio']:.2f} ± {row['ixx_ratio_sigma']:.2f} | {row['iyy_ratio']:.2f} ± "
                  f"{row['iyy_ratio_sigma']:.2f}", flush=True)
    lines = ["# Effective roll/pitch inertia of the physics fit / the airframe's (Foerster 2015)", "",
             "`bench/bench_effective_inertia.py`: the physics fit on each flight alone (`short` preset), ratio "
             "effective_ixx / ixx and effective_iyy / iyy (± 1-sigma), and the fit's roll/pitch multi-step error ratio.", "",
             "| flight | variant | ixx ratio | iyy ratio | roll err | pitch err |", "|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['flight']} | {r['variant']} | error: {r['error']} | | | |")
        else:
            lines.append(f"| {r['flight']} | {r['variant']} | {r['ixx_ratio']:.2f} ± {r['ixx_ratio_sigma']:.2f} | "
                         f"{r['iyy_ratio']:.2f} ± {r['iyy_ratio_sigma']:.2f} | {r['roll_error_ratio']:.3f} | {r['pitch_error_ratio']:.3f} |")
    write_results("effective_inertia", {"rows": rows}, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
