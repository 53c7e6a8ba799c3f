"""Bag size and write/read time with zstd-compressed MCAP chunks against uncompressed ones.

The bundled 42 s NanoBench flight and a 220 s, 100 Hz thesis-like log, each written both ways with
``quad_modelling.io.bag_io.write_bag`` (``compress=True`` is what ``convert`` and ``simulate`` write)
and read back with ``read_bag``; the two bags' messages are compared byte for byte.
Writes bench/results/bag_compression.{json,md}.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_convert import thesis_like_log  # noqa: E402
from bench.common import median_seconds, write_results  # noqa: E402
from quad_modelling.io.bag_io import read_bag, read_recorded, write_bag  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def measure(name: str, log, work: Path) -> dict:
    row = {"flight": name, "seconds": float(log.t[-1] - log.t[0]), "samples": len(log)}
    bags = {}
    for compress in (False, True):
        key = "zstd" if compress else "plain"
        runs = iter(range(100))
        write_s, _ = median_seconds(lambda: write_bag(log, work / f"{name}_{key}_{next(runs)}", compress=compress), repeats=3)
        bags[key] = work / f"{name}_{key}_0"
        read_s, _ = median_seconds(lambda: read_bag(bags[key]), repeats=3)
        row[key] = {"bytes": sum(f.stat().st_size for f in bags[key].iterdir()), "write_s": write_s, "read_s": read_s}
    row["ratio"] = row["plain"]["bytes"] / row["zstd"]["bytes"]
    row["messages_identical"] = read_recorded(bags["zstd"]) == read_recorded(bags["plain"])
    return row


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        rows = [measure("bundled_B7_oval", read_bag(REPO / "bags" / "nanobench_B7_oval_medium_rep2"), work),
                measure("thesis_like_220s", thesis_like_log(), work)]
    md = ["# Bag compression: zstd MCAP chunks vs uncompressed", "",
          "| flight | duration [s] | plain [MB] | zstd [MB] | ratio | write plain / zstd [s] | read plain / zstd [s] | messages identical |",
          "|---|---|---|---|---|---|---|---|"]
    md += [f"| {r['flight']} | {r['seconds']:.1f} | {r['plain']['bytes'] / 1e6:.2f} | {r['zstd']['bytes'] / 1e6:.2f} | {r['ratio']:.1f}x | "
           f"{r['plain']['write_s']:.2f} / {r['zstd']['write_s']:.2f} | {r['plain']['read_s']:.2f} / {r['zstd']['read_s']:.2f} | "
           f"{r['messages_identical']} |" for r in rows]
    md += ["", "Medians of 3; times depend on the machine's load (see machine in the JSON)."]
    md[-1] += f" Load average while measuring: {os.getloadavg()[0]:.1f}."
    write_results("bag_compression", {"rows": rows, "load_average_1min": os.getloadavg()[0]}, "\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
