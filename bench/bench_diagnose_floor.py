"""What the diagnosis's base model gets wrong on flights with *no* effect (G_off), split by source.

The known-answer validation's literal shrink is capped by the base model's own gap on effects-off
flights (docs/diagnosis.md, "Limits"). The simulator knows the truth, so that gap can be split per
scored variable (acc_x/y/z, roll/pitch/yaw acceleration; mean RMS over the held-out windows of the
validation's effects-off test flights, seeds 2000/2010/2020, base identified on the effects-off
training flights of the same validation seed):

* ``gap`` -- the measured gap the diagnosis scores (measurement vs prediction);
* ``sensor_floor`` -- the measurement vs the simulator's *true* IMU signals put through the same
  preprocessing (trim, Savitzky-Golay derivative, low-pass): IMU noise and drift, nothing a model
  could predict;
* ``structural`` -- the true signals vs the prediction from the logged anchor (model structure and
  the noise of the measured linearisation point);
* ``structural_true_anchor`` -- the true signals vs the prediction from a window whose IMU and
  motion-capture channels are the truth (model structure alone).

For the diagnosis's accelerations the prediction carries the measured warm-start body force, bias
included: against the true signal (``structural``) that bias turning with the attitude shows
(~0.025 m/s² in acc_x/acc_y), in the measured ``gap`` it cancels, which is why ``gap`` can be below
``sensor_floor`` there.

Rows: the greybox's own outputs (small-angle accelerations, warm-start means as offsets; before) and
the diagnosis's outputs (:func:`quad_modelling.core.identification.base_model.predict_batch`), each at the smoothing
cutoffs given. Truth is used here only to *measure*; the diagnosis never sees it.

Writes bench/results/diagnose_floor.json and .md. Run: .venv/bin/python -m bench.bench_diagnose_floor
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np

from bench.common import write_results
from quad_modelling.core.identification.base_model import predict_batch
from quad_modelling.core.identification.window_batch import prepare_windows
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG
from quad_modelling.core.diagnosis.validation import (
    VALIDATION_DURATION_S,
    test_seeds,
    train_seeds,
)
from quad_modelling.core.evaluation.metrics import rms
from quad_modelling.core.identification.greybox_fit import identify_base
from quad_modelling.core.sim.simulate import run_simulation
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle

VARIABLES = ("acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc", "yaw_acc")
SEEDS = (0, 1, 2)
CUTOFFS_HZ = (5.0, 3.0, 2.0)
PARTS = ("gap", "sensor_floor", "structural", "structural_true_anchor")


def _truth_log(run, motion_capture: bool = False):
    """The flight's log with the IMU (and optionally the motion capture) replaced by the simulator's truth."""
    log = replace(run.log, acc_b=run.truth["specific_force_b"], gyro_b=run.truth["rates_b"])
    if motion_capture:
        log = replace(log, euler=run.truth["euler"], pos_n=run.truth["pos_n"], vel_n=run.truth["vel_n"])
    return log


def main() -> int:
    vehicle = load_vehicle("linkquad")
    cols = np.array([INDEX[v] for v in VARIABLES])
    flights = {}
    for seed in SEEDS:
        for s in train_seeds(seed) + test_seeds(seed):
            print(f"simulating seed {s} (effects off)", file=sys.stderr)
            flights[s] = run_simulation("linkquad", effects=(), seed=s, duration=VALIDATION_DURATION_S)
    rows = []
    for greybox in (True, False):
        for cutoff in CUTOFFS_HZ if not greybox else (5.0,):
            config = replace(DIAGNOSIS_CONFIG, smooth_cutoff_hz=cutoff)
            per_seed = {k: [] for k in PARTS}
            for seed in SEEDS:
                train = prepare_windows([flights[s].log for s in train_seeds(seed)], vehicle, config)
                base = identify_base(train, vehicle).model
                runs = [flights[s] for s in test_seeds(seed)]
                test = prepare_windows([r.log for r in runs], vehicle, config)
                true_imu = prepare_windows([_truth_log(r) for r in runs], vehicle, config)
                true_all = prepare_windows([_truth_log(r, True) for r in runs], vehicle, config)
                predicted = predict_batch(base, test, greybox_outputs=greybox)
                predicted_true = predict_batch(base, true_all, greybox_outputs=greybox)

                def mean_window_rms(a: np.ndarray, b: np.ndarray) -> np.ndarray:
                    return rms(a[:, test.warm :][:, :, cols], b[:, test.warm :][:, :, cols], axis=1).mean(axis=0)

                parts = (mean_window_rms(test.measured, predicted), mean_window_rms(test.measured, true_imu.measured),
                         mean_window_rms(true_imu.measured, predicted), mean_window_rms(true_all.measured, predicted_true))
                for key, value in zip(PARTS, parts):
                    per_seed[key].append(value)
            rows.append({"outputs": "greybox" if greybox else "diagnosis", "cutoff_hz": cutoff,
                         **{k: {v: float(np.mean([x[i] for x in per_seed[k]])) for i, v in enumerate(VARIABLES)} for k in PARTS}})
    md = ["# Base model's gap on effects-off flights, by source", "",
          "Mean RMS over the held-out windows of the validation's effects-off test flights (seeds 2000/2010/2020), "
          "mean over the 3 validation seeds; m/s² for acc_*, rad/s² for *_acc. `bench/bench_diagnose_floor.py` "
          "(module docstring: what each column is).", ""]
    for row in rows:
        title = ("greybox outputs (small-angle accelerations, warm-start means as offsets)" if row["outputs"] == "greybox"
                 else "diagnosis outputs (force rotated by the measured attitude, gyro-slope offsets)")
        md += [f"## {title}, low-pass {row['cutoff_hz']:g} Hz", "", "| variable | " + " | ".join(PARTS) + " |",
               "|---|" + "---|" * len(PARTS)]
        md += [f"| {v} | " + " | ".join(f"{row[k][v]:.4f}" for k in PARTS) + " |" for v in VARIABLES]
        md.append("")
    write_results("diagnose_floor", {"variables": list(VARIABLES), "seeds": list(SEEDS), "rows": rows}, "\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
