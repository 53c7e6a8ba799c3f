"""Conversion speed: thesis .mat log (220 s, 100 Hz) -> MCAP bag, and real NanoBench flights.

Target (issue 2): under 5 s for a 220 s, 100 Hz log. Writes bench/results/convert.{json,md}.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import SHARED_DATA, median_seconds, write_results  # noqa: E402
from quad_modelling.cli import main  # noqa: E402
from quad_modelling.core.flight_log import FlightLog, FlightMeta  # noqa: E402
from quad_modelling.io.matlog import write_matlog  # noqa: E402


def thesis_like_log(seconds: float = 220.0, rate: float = 100.0) -> FlightLog:
    rng = np.random.default_rng(0)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    wave = np.sin(2 * np.pi * 0.2 * t)[:, None]
    return FlightLog(
        t=t, u=1.5e-3 + 5e-5 * rng.standard_normal((n, 4)),
        acc_b=np.column_stack([0.2 * wave[:, 0], -0.1 * wave[:, 0], -9.81 + 0.05 * rng.standard_normal(n)]),
        gyro_b=0.1 * rng.standard_normal((n, 3)), pos_n=np.hstack([wave, wave, -1 + 0 * wave]),
        vel_n=np.hstack([wave, -wave, 0 * wave]), euler=np.hstack([0.05 * wave, -0.05 * wave, 0.3 * wave]),
        vbat=np.linspace(12.5, 11.1, n), meta=FlightMeta("linkquad", "bench", {}),
    )


def main_bench() -> None:
    work = Path(tempfile.mkdtemp(prefix="bench_convert_"))
    try:
        log = thesis_like_log()
        mat = write_matlog(log, work / "flight220.mat")

        def convert_mat():
            assert main(["convert", str(mat), "-o", str(work / "bag"), "--force"]) == 0

        seconds, runs = median_seconds(convert_mat, repeats=5)
        rows = len(log)
        results = {"thesis_mat_220s": {"rows": rows, "median_s": seconds, "runs_s": runs, "rows_per_s": rows / seconds, "target_s": 5.0}}
        lines = [
            "# Conversion benchmark",
            "",
            "| input | rows | median s | rows/s | target |",
            "|---|---|---|---|---|",
            f"| thesis .mat, 220 s at 100 Hz (4 topics) | {rows} | {seconds:.2f} | {rows / seconds:,.0f} | < 5 s |",
        ]
        flight = SHARED_DATA / "nanobench" / "B7_oval_medium_rep2.csv.gz"
        if flight.exists():
            def convert_csv():
                assert main(["convert", str(flight), "-o", str(work / "nb"), "--force"]) == 0

            nb_seconds, nb_runs = median_seconds(convert_csv, repeats=5)
            results["nanobench_B7_oval_medium_rep2"] = {"rows": 4227, "median_s": nb_seconds, "runs_s": nb_runs, "rows_per_s": 4227 / nb_seconds}
            lines.append(f"| NanoBench B7_oval_medium_rep2.csv.gz (5 topics) | 4227 | {nb_seconds:.2f} | {4227 / nb_seconds:,.0f} | |")
        lines += ["", "Median of 5 runs, read + validate + write (atomic rename), on this machine (2 cores)."]
        write_results("convert", results, "\n".join(lines))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main_bench()
