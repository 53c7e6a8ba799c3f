"""``make demo``: the main job on the bundled bag, end to end.

Identify the vehicle's constants, and train the NARX model, the hybrid (physics base plus
residual nets) and the direct model (physics base, body rates from a regression per horizon) on 10-25 s
of the bundled NanoBench flight (after take-off); then replay the bag through the live ROS 2 graph
(replay; greybox, physics, NARX, hybrid and direct predictors; evaluator:
separate processes over DDS on loopback) and print the live RMS/TIC table for the training
(10-25 s) and held-out (25-35 s) 5 s windows and the multi-step table of every model. The
``physics`` model is built from the identified vehicle file. Steps run through the same CLI a
user types; outputs go to ``demo_output/`` (replaced on every run: it is the demo's own directory).
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
    bag = str(BUNDLED_BAG.relative_to(REPO))
    out = OUTPUT.relative_to(REPO)
    # Live windows start at the first motor input (t0) and are 5 s long; take-off ends about
    # 6 s and landing starts about 36 s after t0: train on 10-25 s, hold out 25-35 s.
    spans = ["--drop", "0:0", "--train", "10:25", "--window", "5"]
    step("What the bundled bag holds (a real Crazyflie 2.1 NanoBench flight)", ["info", bag])
    step("Identify the Crazyflie's motor constants on the training span (10-25 s)",
         ["identify", bag, "--vehicle", "crazyflie21", *spans, "--eval", "25:35", "-o", str(out / "crazyflie21_identified.yaml")])
    step("Train the NARX model (rollout training, early-stopped on the span's last 20 %) on the same training span",
         ["train", bag, "--vehicle", str(out / "crazyflie21_identified.yaml"), "--drop", "0:0", "--train", "10:25",
          "--quiet", "-o", str(out / "narx.npz")])
    step("Train the hybrid (physics base plus residual nets) on the same training span",
         ["train", bag, "--vehicle", str(out / "crazyflie21_identified.yaml"), "--drop", "0:0", "--train", "10:25",
          "--hybrid", "--quiet", "-o", str(out / "hybrid.npz")])
    step("Fit the direct model (physics base, body rates from a ridge regression per horizon) on the same training span",
         ["train", bag, "--vehicle", str(out / "crazyflie21_identified.yaml"), "--drop", "0:0", "--train", "10:25",
          "--direct", "--quiet", "-o", str(out / "direct.npz")])
    models = f"greybox,physics,narx:{out / 'narx.npz'},hybrid:{out / 'hybrid.npz'},direct:{out / 'direct.npz'}"
    step("Replay the bag through the live ROS 2 graph over DDS (replay; greybox, physics, NARX, hybrid and direct predictors; "
         "evaluator)",
         ["run-bag", bag, "--models", models, "--vehicle", str(out / "crazyflie21_identified.yaml"),
          "--window", "5", "--train", "10:25", "--eval", "25:35", "-o", str(out / "live")])
    print(f"\ndemo outputs in {OUTPUT.relative_to(REPO)}/")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m quad_modelling.demo``: no arguments (``--help`` says what it does, and touches nothing)."""
    import argparse

    argparse.ArgumentParser(prog="python -m quad_modelling.demo", description=__doc__.split("\n\n")[1].replace("\n", " "),
                            epilog=f"Writes {OUTPUT} (replaced on every run).").parse_args(argv)
    return run()


if __name__ == "__main__":
    sys.exit(main())
