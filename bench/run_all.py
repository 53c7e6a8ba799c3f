"""Run every benchmark in turn (``make bench``); each writes bench/results/<name>.json and .md.

Benchmarks run one at a time: the machine has 2 cores and timings are medians of
repeated runs, so nothing else should run meanwhile.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS = ("bench_convert", "bench_bag_compression", "bench_sim", "bench_evaluate", "bench_narx", "bench_training_memory", "bench_training_time", "bench_models", "bench_nodes",
              "bench_fleet", "bench_diagnose", "bench_diagnose_floor", "bench_topic_maps", "bench_mpc")


def main() -> int:
    failed = []
    for name in BENCHMARKS:
        print(f"== {name}", flush=True)
        start = time.perf_counter()
        code = subprocess.call([sys.executable, "-m", f"bench.{name}"], cwd=REPO)
        print(f"== {name}: exit {code} after {time.perf_counter() - start:.0f} s", flush=True)
        if code != 0:
            failed.append(name)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
