"""``make demo``: the main job on the bundled bag, end to end.

Steps run through the same CLI a user types; outputs go to ``demo_output/``
(replaced on every run: it is the demo's own directory).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from quad_modelling.cli import main as cli

REPO = Path(__file__).resolve().parents[1]
BUNDLED_BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
OUTPUT = REPO / "demo_output"


def step(title: str, argv: list[str]) -> None:
    print(f"\n== {title}\n$ quad-modelling {' '.join(argv)}", flush=True)
    code = cli(argv)
    if code != 0:
        raise SystemExit(f"demo step failed with exit code {code}: {title}")


def run() -> int:
    os.chdir(REPO)
    if OUTPUT.exists():
        shutil.rmtree(OUTPUT)
    OUTPUT.mkdir()
    rel = BUNDLED_BAG.relative_to(REPO)
    step("What the bundled bag holds (a real Crazyflie 2.1 NanoBench flight)", ["info", str(rel)])
    step("Convert it to a thesis-style MATLAB log", ["convert", str(rel), "-o", str((OUTPUT / "flight.mat").relative_to(REPO))])
    step("Replay it through the live ROS 2 graph (replay, predictor, evaluator over DDS)",
         ["run-bag", str(rel), "--models", "naive", "--train", "0:20", "--eval", "20:40",
          "-o", str((OUTPUT / "live").relative_to(REPO))])
    print(f"\ndemo outputs in {OUTPUT.relative_to(REPO)}/")
    return 0


if __name__ == "__main__":
    sys.exit(run())
