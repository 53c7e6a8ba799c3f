"""Helpers for the benchmarks: timing with medians, results as JSON + Markdown."""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

# Benchmarks that start DDS keep it on this machine.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MPLBACKEND", "Agg")


def median_seconds(function, repeats: int = 5) -> tuple[float, list[float]]:
    """Median wall time of ``function()`` over ``repeats`` runs, and all the runs."""
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        runs.append(time.perf_counter() - start)
    return statistics.median(runs), runs


CALIBRATION_ROUNDS = 20
"""Rounds of :func:`calibration_ms`'s workload: ~0.14 ms in a fast phase of session 40's machine, 0.26 ms in a slow one."""


def calibration_ms() -> float:
    """Wall time [ms] of a fixed workload made like a predictor's answer to an input: small numpy products, ufuncs and
    concatenations (8 x 8), then a Python loop. Run between the inputs of a timed stream, it slows down and speeds up
    with the shared machine (up to 2x between runs on session 38's machine) as the handler does, so the handler's
    median over the calibration's compares runs minutes apart and on other machines: in session 40's six runs of the
    physics forecast, handler medians 0.61-1.04 ms, calibration 0.14-0.26 ms, their ratio 3.99-4.36."""
    import numpy as np

    started = time.perf_counter()
    x = _CALIBRATION_MATRIX
    for _ in range(CALIBRATION_ROUNDS):
        x = np.tanh(x @ _CALIBRATION_MATRIX) + np.concatenate([x[:4], x[4:]])
    total = 0.0
    for i in range(300):
        total += i * 0.5
    return (time.perf_counter() - started) * 1e3


def _calibration_matrix():
    import numpy as np

    return np.random.default_rng(0).normal(size=(8, 8)) / 8.0


_CALIBRATION_MATRIX = _calibration_matrix()


def machine() -> dict:
    return {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count()}


def write_results(name: str, data: dict, markdown: str) -> Path:
    """bench/results/<name>.json and <name>.md."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    data = {"benchmark": name, "machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M"), **data}
    (RESULTS / f"{name}.json").write_text(json.dumps(data, indent=2) + "\n")
    (RESULTS / f"{name}.md").write_text(markdown.rstrip() + "\n")
    print(markdown)
    return RESULTS / f"{name}.json"
