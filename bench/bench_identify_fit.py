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


READING = """Reading (closed-loop flight, 100 Hz): the **data** limit the fit, the bounds only show it.
Roll acceleration follows the roll command at 2-10 Hz and not below 1.2 Hz, where the attitude
controller cancels slow disturbance torques; the open-loop output-error fit over 5 s windows is dominated
by that slow band, the modelled and measured roll/pitch accelerations barely correlate, and least squares
shrinks the torque gain (arm scale x thrust gain) to the arm scale's lower bound 0.3 on every span. The
collective explains acc_z below 1.2 Hz only, so A_m/B_m come from a few slow thrust changes: A_m moves
from -18 to -31 1/s between spans and its HAC sigma is larger than the value (the earlier sigma 25 on -31
counted every 4th 100 Hz sample as independent; 63 with HAC). The fit itself converges (80 or 400
evaluations give the same optimum). High-passing roll/pitch at 0.5 Hz gives a stable A_m (-17..-21,
sigma 3-4) and a consistent torque gain (~0.45 of the configured), but predicts the held-out roll/pitch
acceleration 6-8x worse in the windowed evaluation (the linear greybox has no controller, so the slow
band matters there): not kept; the thesis greybox is fitted as before. k_R sat on its lower bound 1e-3
because its term is 0.07 % of the yaw acceleration (flat cost): it is now held at 1 and says so."""


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
        rows.append({"span": span, **{k: v[k] for k in ("motor_a_m", "motor_b_m", "torque_constant", "arm_scale", "rotor_reaction_scale")},
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
            flag = {name: " (bound)" if b.get(key) else "" for name, key in (("arm", "arm_scale"), ("kr", "rotor_reaction_scale"))}
            rel = "/".join(f"{x:.2f}" for x in r["held_out_relative_rms"].values())
            lines.append(f"| {label} | {r['span']} | {r['motor_a_m']:.1f} ± {s['motor_a_m']:.2g} | {r['motor_b_m']:.3f} ± {s['motor_b_m']:.2g} "
                         f"| {r['torque_constant']:.2e} | {r['arm_scale']:.2f}{flag['arm']} | {r['rotor_reaction_scale']:.3g}{flag['kr']} | {rel} |")
    lines += ["", "| coherence | 0-1.2 Hz | 2-10 Hz | 10-20 Hz |", "|---|---|---|---|"]
    lines += [f"| {name} | {c['0-1.2 Hz']:.2f} | {c['2-10 Hz']:.2f} | {c['10-20 Hz']:.2f} |" for name, c in data["coherence"].items()]
    lines += ["", READING]
    write_results("identify_fit", data, "\n".join(lines))


if __name__ == "__main__":
    main()
