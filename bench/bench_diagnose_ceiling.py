"""Is the 50 % held-out shrink out of reach because of the diagnosis, or because of the sensors?

The known-answer validation (bench/bench_diagnose.py) reports per run the *sensor ceiling*
(:func:`quad_modelling.core.diagnosis.validation.sensor_ceiling`): the shrink a model predicting the
simulator's true IMU signals exactly would reach, because the IMU's noise and drift stay in the measured
gap whatever the model. This benchmark flies the same validation (same seeds, scripts and effect
strengths) twice for the effects whose literal shrink stays below 50 %:

* ``as designed`` -- the simulator's sensor model (accelerometer 0.05 m/s², gyro 0.003 rad/s per 100 Hz
  sample, plus bias and drift; sim_params.py);
* ``perfect IMU`` -- the same flights with the IMU's noise, bias and drift set to zero (the closed loop
  flies the same script; its stabiliser no longer sees gyro noise, so the flights differ slightly).

If the diagnosis reaches the target with a perfect IMU, the shortfall as designed is the sensors', not
the method's. The truth is used to *build* the flights only; the diagnosis never sees it.

Writes bench/results/diagnose_ceiling.json and .md. Run: .venv/bin/python -m bench.bench_diagnose_ceiling
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

from bench.common import write_results
from quad_modelling.core.diagnosis.validation import validate
from quad_modelling.core.sim.params import sim_params_for

EFFECTS = ("battery", "input_delay", "ground_effect")
SEEDS = (0, 1, 2)
TARGET = 0.5


def perfect_imu(params):
    """``params`` with an IMU without noise, bias or drift."""
    sensors = replace(params.sensors, acc_noise=0.0, acc_bias=0.0, acc_drift=0.0, gyro_noise=0.0, gyro_bias=0.0, gyro_drift=0.0)
    return replace(params, sensors=sensors)


def main() -> int:
    params = sim_params_for("linkquad")
    variants = {"as designed": params, "perfect IMU": perfect_imu(params)}
    data: dict = {"effects": list(EFFECTS), "seeds": list(SEEDS), "target": TARGET, "variants": {}}
    for name, variant in variants.items():
        start = time.perf_counter()
        result = validate("linkquad", effects=EFFECTS, seeds=SEEDS, pairs=(), sim_params=variant,
                          progress=lambda m, n=name: print(f"{n}: {m}", file=sys.stderr))
        data["variants"][name] = {
            "seconds": time.perf_counter() - start,
            "accuracy": result["accuracy"],
            "null_found": result["null"]["found"],
            "runs": [{k: r.get(k) for k in ("effect", "seed", "top", "correct", "shrink", "sensor_ceiling", "attributable_share",
                                            "attributable_removed", "variables", "params")} for r in result["runs"]],
        }
    md = ["# Literal shrink against the sensor ceiling, as designed and with a perfect IMU", "",
          "Known-answer validation (`quad_modelling.core.diagnosis.validation.validate`, linkquad, 90 s flights, seeds "
          f"{', '.join(map(str, SEEDS))}) for the effects whose literal held-out shrink stays below {TARGET:.0%}. "
          "**sensor ceiling**: the shrink a model predicting the true IMU signals exactly would reach (1 - G_sensor/G_on). "
          "**perfect IMU**: the same flights with the IMU's noise, bias and drift set to zero. `bench/bench_diagnose_ceiling.py`.", ""]
    md += ["| effect | seed | shrink as designed | ceiling as designed | shrink, perfect IMU | ceiling, perfect IMU | right and found (designed / perfect) |",
           "|---|---|---|---|---|---|---|"]
    designed, perfect = (data["variants"][k]["runs"] for k in ("as designed", "perfect IMU"))
    for a, b in zip(designed, perfect):
        md.append(f"| {a['effect']} | {a['seed']} | {a['shrink']:.1%} | {a['sensor_ceiling']:.1%} | {b['shrink']:.1%} | "
                  f"{b['sensor_ceiling']:.1%} | {'yes' if a['correct'] else 'no'} / {'yes' if b['correct'] else 'no'} |")
    md.append("")
    for name, v in data["variants"].items():
        md.append(f"- {name}: accuracy {v['accuracy']:.0%}, null case found: {', '.join(v['null_found']) or 'nothing'}, {v['seconds']:.0f} s")
    write_results("diagnose_ceiling", data, "\n".join(md) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
