"""Truth-simulator speed: ``quad-modelling simulate`` of a 220 s LinkQuad flight.

Target (issue 3): under 30 s on this 2-core machine. Measures the CLI end to end
in a fresh process (import, simulate, sensors, .mat write), and the simulation
alone per effect set (µs per 1 kHz RK4 step, including the 250 Hz stabiliser).
Writes bench/results/sim.{json,md}.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import median_seconds, write_results  # noqa: E402
from quad_modelling.core.effect_names import SIM_DEFAULT_EFFECTS, SIM_EFFECTS  # noqa: E402
from quad_modelling.core.sim.simulate import run_simulation  # noqa: E402

DURATION = 220.0
TARGET_S = 30.0
REPO = Path(__file__).resolve().parents[1]


def main_bench() -> None:
    work = Path(tempfile.mkdtemp(prefix="bench_sim_"))
    executable = Path(sys.executable).parent / "quad-modelling"
    command = [str(executable), "simulate", "-o", str(work / "flight.mat"), "--force"]
    try:
        def cli():
            subprocess.run(command, check=True, cwd=REPO, capture_output=True)

        cli_s, cli_runs = median_seconds(cli, repeats=3)
        size = (work / "flight.mat").stat().st_size
    finally:
        shutil.rmtree(work, ignore_errors=True)

    per_effects = {}
    for label, effects in (("none", ()), ("default", SIM_DEFAULT_EFFECTS), ("all", SIM_EFFECTS)):
        for vehicle in ("linkquad", "crazyflie21"):
            start = time.perf_counter()
            run_simulation(vehicle, effects, seed=0, duration=DURATION)
            seconds = time.perf_counter() - start
            per_effects[f"{vehicle}/{label}"] = {"seconds": seconds, "us_per_physics_step": seconds / (DURATION * 1000.0) * 1e6}

    results = {
        "cli_220s_linkquad_default": {"median_s": cli_s, "runs_s": cli_runs, "target_s": TARGET_S, "mat_bytes": size, "meets_target": cli_s < TARGET_S},
        "simulation_only_220s": per_effects,
        "rates_hz": {"physics": 1000, "control": 250, "mocap": 250, "log": 100},
    }
    lines = [
        "# Truth simulator benchmark",
        "",
        f"`quad-modelling simulate -o flight.mat` (LinkQuad, default effects, {DURATION:.0f} s flight, "
        "1 kHz RK4, 250 Hz stabiliser, 100 Hz log), fresh process, median of 3:",
        "",
        "| run | median s | target |",
        "|---|---|---|",
        f"| CLI end to end (import + simulate + sensors + .mat) | {cli_s:.1f} | < {TARGET_S:.0f} s |",
        "",
        "Simulation alone (`run_simulation`), one run each:",
        "",
        "| vehicle / effects | s | µs per physics step |",
        "|---|---|---|",
    ]
    for key, row in per_effects.items():
        lines.append(f"| {key} | {row['seconds']:.1f} | {row['us_per_physics_step']:.1f} |")
    lines += ["", "Machine shared with other work; times vary by ±30 %."]
    write_results("sim", results, "\n".join(lines))


if __name__ == "__main__":
    main_bench()
