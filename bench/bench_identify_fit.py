"""Why the linear greybox identification on the bundled bag is weak: data, bounds or fit?

On the bundled NanoBench flight (B7 oval, a closed-loop Crazyflie flight) this measures
1. the identified constants with their HAC 1-sigma on four training spans (5 s windows): is the fit stable?
2. the coherence of roll acceleration with the roll command and of Z acceleration with the collective,
   by frequency band: where do the commands explain the motion at all?
3. a variant that high-passes the roll/pitch residuals at 0.5 Hz on both sides (not kept): constants and
   the held-out (25-40 s) relative RMS of acc_z, roll/pitch/yaw acceleration that the windowed evaluation scores.
Writes bench/results/identify_fit.{json,md}.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
from scipy import signal  # noqa: E402

from bench.common import write_results  # noqa: E402
from quad_modelling.core.identification import greybox_fit  # noqa: E402
from quad_modelling.core.identification.base_model import predict_batch  # noqa: E402
from quad_modelling.core.identification.identify import training_batch  # noqa: E402
from quad_modelling.core.preprocess import measured_variables  # noqa: E402
from quad_modelling.core.variables import INDEX  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.core.windows import EvaluationConfig  # noqa: E402
from quad_modelling.io.loader import load_flight  # noqa: E402

BAG = Path(__file__).resolve().parents[1] / "bags" / "nanobench_B7_oval_medium_rep2"
SPANS = ("10:25", "5:20", "20:35", "5:35")
HELD_OUT = "25:40"
COLUMNS = [INDEX[v] for v in greybox_fit.FITTED_VARIABLES]
ANGULAR = [INDEX[v] for v in ("roll_acc", "pitch_acc")]


def _config(span: str) -> EvaluationConfig:
    return EvaluationConfig(drop_start=0, drop_end=0, train=span, eval="25:35", window_s=5)


def _highpassed(predict):
    sos = signal.butter(2, 0.5, btype="high", fs=100.0, output="sos")

    def wrapped(*args, **kwargs):
        out = predict(*args, **kwargs)
        out[:, :, ANGULAR] = signal.sosfiltfilt(sos, out[:, :, ANGULAR], axis=1)
        return out

    return wrapped, sos


def fits(log, vehicle, variant: bool) -> list[dict]:
    held_out = training_batch([log], vehicle, _config(HELD_OUT))
    rows = []
    original = greybox_fit.predict_batch
    for span in SPANS:
        batch = training_batch([log], vehicle, _config(span))
        if variant:
            greybox_fit.predict_batch, sos = _highpassed(original)
            batch.measured = batch.measured.copy()
            batch.measured[:, :, ANGULAR] = signal.sosfiltfilt(sos, batch.measured[:, :, ANGULAR], axis=1)
        try:
            fit = greybox_fit.identify_base(batch, vehicle)
        finally:
            greybox_fit.predict_batch = original
        pred = predict_batch(fit.model, held_out, columns=COLUMNS)[:, held_out.warm :][:, :, COLUMNS]
        meas = held_out.measured[:, held_out.warm :][:, :, COLUMNS]
        rel = np.sqrt(np.mean((meas - pred) ** 2, axis=(0, 1))) / np.sqrt(np.mean(meas**2, axis=(0, 1)))
        v, s = fit.values, fit.sigma
        rows.append({"span": span, **{k: v[k] for k in ("motor_a_m", "motor_b_m", "drag_constant", "arm_scale", "rotor_reaction_scale")},
                     "sigma": s, "at_bound": fit.fit["at_bound"], "held": fit.fit["held"],
                     "held_out_relative_rms": dict(zip(greybox_fit.FITTED_VARIABLES, rel.round(3).tolist()))})
    return rows


def coherence(log) -> dict:
    rows = slice(500, 3500)  # 5-35 s
    u, y = log.u[rows], measured_variables(log)[rows]
    signals = {"acc_z vs collective": (u.sum(axis=1), y[:, INDEX["acc_z"]]),
               "roll_acc vs roll command": ((u[:, 2] + u[:, 3]) - (u[:, 0] + u[:, 1]), y[:, INDEX["roll_acc"]])}
    out = {}
    for name, (x, z) in signals.items():
        f, c = signal.coherence(x - x.mean(), z - z.mean(), fs=100.0, nperseg=256)
        out[name] = {band: float(np.mean(c[(f >= lo) & (f < hi)])) for band, (lo, hi) in
                     {"0-1.2 Hz": (0, 1.2), "2-10 Hz": (2, 10), "10-20 Hz": (10, 20)}.items()}
    return out


def main() -> None:
    vehicle = load_vehicle("crazyflie21")
    log = load_flight(BAG, vehicle)
    data = {"bag": BAG.name, "fits": fits(log, vehicle, False), "highpass_variant": fits(log, vehicle, True), "coherence": coherence(log)}
    lines = ["# identify on the bundled bag: data, bounds or fit?", "",
             "| fit | span | A_m [1/s] | B_m | d [N m s2] | arm scale | k_R | held-out rel RMS acc_z/roll/pitch/yaw |",
             "|---|---|---|---|---|---|---|---|"]
    for label, rows in (("kept", data["fits"]), ("0.5 Hz high-pass (not kept)", data["highpass_variant"])):
        for r in rows:
            s, b = r["sigma"], r["at_bound"]
            flag = {name: " (bound)" if b.get(key) else "" for name, key in (("arm", "arm_scale"), ("kr", "ln_rotor_reaction_scale"))}
            rel = "/".join(f"{x:.2f}" for x in r["held_out_relative_rms"].values())
            lines.append(f"| {label} | {r['span']} | {r['motor_a_m']:.1f} ± {s['motor_a_m']:.2g} | {r['motor_b_m']:.3f} ± {s['motor_b_m']:.2g} "
                         f"| {r['drag_constant']:.2e} | {r['arm_scale']:.2f}{flag['arm']} | {r['rotor_reaction_scale']:.3g}{flag['kr']} | {rel} |")
    lines += ["", "| coherence | 0-1.2 Hz | 2-10 Hz | 10-20 Hz |", "|---|---|---|---|"]
    lines += [f"| {name} | {c['0-1.2 Hz']:.2f} | {c['2-10 Hz']:.2f} | {c['10-20 Hz']:.2f} |" for name, c in data["coherence"].items()]
    write_results("identify_fit", data, "\n".join(lines))


if __name__ == "__main__":
    main()
