"""Diagnosis benchmark: time to diagnose 10 NanoBench flights with the whole catalogue, and the
known-answer validation over the catalogue and 3 seeds (time and accuracy numbers).

Writes bench/results/diagnose.json and diagnose.md. Run: .venv/bin/python -m bench.bench_diagnose
"""

from __future__ import annotations

import sys
import time

from bench.common import SHARED_DATA, write_results
from quad_modelling.core.diagnosis.diagnose import diagnose
from quad_modelling.core.diagnosis.validation import validate
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.loader import load_flight
from quad_modelling.io.reports.validation import validation_markdown

TRAIN = ["B2_circle_slow_rep2", "B2_circle_medium_rep2", "B3_figure8_slow_rep2", "B3_figure8_medium_rep2",
         "B5_helix_slow_rep1", "B5_helix_medium_rep1", "B7_oval_slow_rep2"]
TEST = ["B2_circle_fast_rep2", "B3_figure8_fast_rep2", "B5_helix_fast_rep1"]


def main() -> int:
    data: dict = {}
    nanobench = SHARED_DATA / "nanobench"
    if nanobench.is_dir():
        vehicle = load_vehicle("crazyflie21")
        start = time.perf_counter()
        train = [load_flight(nanobench / f"{n}.csv.gz") for n in TRAIN]
        test = [load_flight(nanobench / f"{n}.csv.gz") for n in TEST]
        loaded = time.perf_counter() - start
        result = diagnose(train, test, vehicle)
        total = time.perf_counter() - start
        data["nanobench_10_flights"] = {"flights": len(train) + len(test), "load_s": loaded, "total_s": total,
                                        "stages_s": result.timings, "found": result.found, "target_s": 120.0}
        print(f"10 NanoBench flights, whole catalogue: {total:.1f} s (found {result.found})", file=sys.stderr)
    start = time.perf_counter()
    validation = validate("linkquad", seeds=(0, 1, 2), progress=lambda m: print(m, file=sys.stderr))
    data["validation"] = {k: v for k, v in validation.items()}
    data["validation_s"] = time.perf_counter() - start
    data["validation_target_s"] = 600.0
    nb = data.get("nanobench_10_flights")
    md = ["# Diagnosis benchmark", ""]
    if nb:
        md.append(f"- diagnose 10 NanoBench flights (7 train, 3 test), whole catalogue: **{nb['total_s']:.1f} s** (target < 120 s), "
                  f"of which loading {nb['load_s']:.1f} s; found: {', '.join(nb['found']) or 'nothing'}")
    md.append(f"- validation (7 effects x 3 seeds + null + 3 pairs x 3 seeds, 90 s simulated flights, simulation included): "
              f"**{data['validation_s']:.0f} s** (target < 600 s)")
    md.append(f"- accuracy: **{validation['accuracy']:.0%}**; null case found: {', '.join(validation['null']['found']) or 'nothing'}; "
              f"pairs both found in top 3: {validation['pairs_accuracy']:.0%}")
    md += ["", validation_markdown(validation)]
    write_results("diagnose", data, "\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
