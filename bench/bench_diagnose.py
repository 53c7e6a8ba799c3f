"""Diagnosis benchmark: time to diagnose 10 NanoBench flights with the whole catalogue, and the known-answer
validation run as a user runs it (base identified on the effect-on flights) over its default cases (7 effects
alone, null, pairs, all effects at once, 3 out-of-catalogue disturbances) on the default seeds 0, 1, 2 with
two Dask workers (time and every target of issue #17), then the same cases on seeds the diagnosis was never
developed on (``--unseen``, default 4711 and 31337).

Writes bench/results/diagnose_greybox.json and .md (until session 17 diagnose.json / .md, whose greybox section
is this bench's last run; diagnose.md now leads with the physics base's ``--validate`` table). Run:
.venv/bin/python -m bench.bench_diagnose [--unseen 4711,31337] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys
import time

from bench.common import SHARED_DATA, write_results
from quad_modelling.core.diagnosis.diagnose import diagnose
from quad_modelling.core.diagnosis.validation import validate
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.loader import load_flight
from quad_modelling.io.reports.validation import validation_markdown, validation_summary

TRAIN = ["B2_circle_slow_rep2", "B2_circle_medium_rep2", "B3_figure8_slow_rep2", "B3_figure8_medium_rep2",
         "B5_helix_slow_rep1", "B5_helix_medium_rep1", "B7_oval_slow_rep2"]
TEST = ["B2_circle_fast_rep2", "B3_figure8_fast_rep2", "B5_helix_fast_rep1"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--unseen", default="4711,31337", help="seeds never used in development ('' to skip)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--skip-nanobench", action="store_true")
    args = parser.parse_args(argv)
    data: dict = {}
    nanobench = SHARED_DATA / "nanobench"
    if nanobench.is_dir() and not args.skip_nanobench:
        vehicle = load_vehicle("crazyflie21")
        start = time.perf_counter()
        train = [load_flight(nanobench / f"{n}.csv.gz") for n in TRAIN]
        test = [load_flight(nanobench / f"{n}.csv.gz") for n in TEST]
        loaded = time.perf_counter() - start
        result = diagnose(train, test, vehicle)
        total = time.perf_counter() - start
        data["nanobench_10_flights"] = {"flights": len(train) + len(test), "load_s": loaded, "total_s": total,
                                        "stages_s": result.timings, "found": result.found, "target_s": 120.0,
                                        "verdicts": {o.effect.name: [o.verdict, o.reason] for o in result.outcomes}}
        print(f"10 NanoBench flights, whole catalogue: {total:.1f} s (found {result.found})", file=sys.stderr)
    md = ["# Diagnosis benchmark", ""]
    nb = data.get("nanobench_10_flights")
    if nb:
        md.append(f"- diagnose 10 NanoBench flights (7 train, 3 test), whole catalogue: **{nb['total_s']:.1f} s** (target < 120 s), "
                  f"of which loading {nb['load_s']:.1f} s; found: {', '.join(nb['found']) or 'nothing'}")
    for key, seeds in (("validation", args.seeds), ("validation_unseen", args.unseen)):
        if not seeds:
            continue
        seed_list = tuple(int(s) for s in seeds.split(","))
        start = time.perf_counter()
        result = validate("linkquad", seeds=seed_list, jobs=args.jobs, progress=lambda m, k=key: print(f"{k}: {m}", file=sys.stderr))
        data[key] = result
        data[f"{key}_s"] = time.perf_counter() - start
        md.append(f"- {key.replace('_', ' ')} (seeds {seeds}, {args.jobs} workers, simulation included): "
                  f"**{data[f'{key}_s']:.0f} s**; {validation_summary(result)}")
    md.append("")
    for key in ("validation", "validation_unseen"):
        if key in data:
            md += [f"## {key.replace('_', ' ')}", "", validation_markdown(data[key])]
    write_results("diagnose_greybox", data, "\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
