"""`quad-modelling identify` on the bundled bag: CPU time of this checkout against a baseline checkout (#25 item 8).

Runs ``identify bags/nanobench_B7_oval_medium_rep2 --vehicle crazyflie21 --preset short`` as a user does (a whole
process) ``--repeats`` times for each checkout, alternating them so a load change hits both alike, and reports the
median CPU time (user + system of the process: less noisy than wall time on this shared 2-core machine) and wall
time, and the ratio this / baseline. The baseline is a checkout of another commit (``git worktree add DIR REV``),
run with this checkout's venv and ``PYTHONPATH=DIR``. Writes bench/results/identify_time.{json,md}.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import write_results  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"


def run_identify(checkout: Path, output: Path) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of one identify process run from ``checkout``'s package."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    command = [sys.executable, "-m", "quad_modelling.cli", "identify", str(BAG), "--vehicle", "crazyflie21", "--preset", "short",
               "-o", str(output), "--force"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(command, env=env, cwd=checkout, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of the baseline commit (git worktree add DIR REV)")
    parser.add_argument("--label", default="", help="what the baseline is (e.g. its commit)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    runs: dict[str, list[tuple[float, float]]] = {"this": [], "baseline": []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            for name, checkout in (("baseline", args.baseline.resolve()), ("this", REPO)):
                runs[name].append(run_identify(checkout, Path(tmp) / f"{name}{i}.yaml"))
    medians = {name: {"cpu_s": statistics.median(c for c, _ in r), "wall_s": statistics.median(w for _, w in r)} for name, r in runs.items()}
    ratio = medians["this"]["cpu_s"] / medians["baseline"]["cpu_s"]
    load = os.getloadavg()[0]
    markdown = f"""# identify on the bundled bag: this checkout vs {args.label or args.baseline}

`identify {BAG.relative_to(REPO)} --vehicle crazyflie21 --preset short`, {args.repeats} runs each, alternated; medians.
Load average at the end: {load:.1f} (2 cores).

| checkout | CPU [s] | wall [s] |
|---|---|---|
| baseline ({args.label or args.baseline}) | {medians['baseline']['cpu_s']:.2f} | {medians['baseline']['wall_s']:.2f} |
| this | {medians['this']['cpu_s']:.2f} | {medians['this']['wall_s']:.2f} |

CPU ratio this / baseline: **{ratio:.2f}** (target <= 1.20).
"""
    write_results("identify_time", {"runs": runs, "medians": medians, "cpu_ratio": ratio, "baseline": args.label,
                                    "load_average": load}, markdown)


if __name__ == "__main__":
    main()
