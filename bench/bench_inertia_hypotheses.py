"""Why does the physics fit need 3.5-7x the airframe's roll/pitch inertia on the NanoBench flights (issue #28 item 1)?

Each hypothesis measured on the flights of bench_effective_inertia.py (B2_circle_medium_rep2, B3_figure8_medium_rep2,
B5_helix_medium_rep1, B2_circle_fast_rep2: the flights this was developed on) and on simulated Crazyflie flights:

* (a) errors in variables: the 100 Hz motor log as noisy point samples of the stabiliser's output. Measured by the
  commands' sample-to-sample roughness and the frequency response from the model's roll/pitch acceleration (the
  commands through the vehicle file's physics at the airframe inertia) to the measured one (gyro differentiated):
  per band 1/|H1| (cross / input spectrum, biased *up* by input noise) and 1/|H2| (output / cross spectrum, biased
  *down* by it) bracket the true gain ratio; their agreement and the coherence say whether noise is the cause. On
  the simulator (its own physics, 250 Hz stabiliser, commands point-sampled at 100 Hz) the stabiliser's gyro noise is
  raised 1x/10x/30x (its D term puts it into the commands) and the fit's effective inertia / the simulator's reported.
* (b) rotor dynamics: the fit with the rotor time constant held at 10/30/100 ms; a rate-damping moment (c ω) as a
  second regressor of the band-passed (0.3-15 Hz) acceleration regression; the command map: the logged commands
  taken as the Crazyflie firmware's thrust requests mapped through its battery compensation
  (bench/compensated_data.py), fitted as they are otherwise; the four motors' gains (``motor_imbalance``) fitted.
* (c) the observer: every fit with the default observer (angular trim) and the ``measured`` one.

Writes bench/results/inertia_hypotheses.{json,md}. Run: .venv/bin/python -m bench.bench_inertia_hypotheses
(``--write-compensated DIR`` instead writes the NanoBench copy with the compensation map, for
``bench.bench_models --data DIR``: the held-out scores of the map, bench/results/models_inertia_compensated.md).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import signal

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import write_results  # noqa: E402
from bench.compensated_data import compensated_copy, equivalent_duty  # noqa: E402
from quad_modelling.core.identification.physics_fit import identify_physics  # noqa: E402
from quad_modelling.core.identification.physics_result import OBSERVERS  # noqa: E402
from quad_modelling.core.physics.parameters import PhysicsParameters  # noqa: E402
from quad_modelling.core.physics.rigid_body import rotor_wrench  # noqa: E402
from quad_modelling.core.physics.rotors import delayed_commands, interval_rotor_speeds, rotor_speeds  # noqa: E402
from quad_modelling.core.sim.params import sim_params_for  # noqa: E402
from quad_modelling.core.sim.simulate import run_simulation  # noqa: E402
from quad_modelling.core.vehicle import load_vehicle  # noqa: E402
from quad_modelling.core.windows import EvaluationConfig  # noqa: E402
from quad_modelling.io.loader import load_flight  # noqa: E402

NANOBENCH = Path("/work/shared/data/nanobench")
FLIGHTS = ("B2_circle_medium_rep2", "B3_figure8_medium_rep2", "B5_helix_medium_rep1", "B2_circle_fast_rep2")
CONFIG = EvaluationConfig.preset("short")
BANDS_HZ = ((0.5, 2.0), (2.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 50.0))
MIDDLE = (0.15, 0.85)
"""Share of each flight analysed spectrally: the flying middle (take-off and landing out)."""
WELCH_SEGMENT = 256
"""Welch segment [samples]: 2.56 s at 100 Hz, 0.39 Hz resolution."""
REGRESSION_BAND_HZ = (0.3, 15.0)
SIM_SEED, SIM_DURATION_S = 7001, 60.0
SIM_GYRO_NOISE_FACTORS = (1.0, 10.0, 30.0)
HELD_TIME_CONSTANTS_S = (0.01, 0.03, 0.1)


def modelled_acceleration(log, vehicle, time_constant: float, delay: float) -> np.ndarray:
    """(N, 3) angular acceleration [rad/s², B] the commands give through the vehicle file's physics at its airframe
    inertia (rotor wrench only: no drag, no gyroscopic term)."""
    p = PhysicsParameters.from_vehicle(vehicle).with_values(time_constant=time_constant, delay=delay)
    commands = delayed_commands(p, log.u, log.t)
    mean = interval_rotor_speeds(p, rotor_speeds(p, commands, log.t), commands, log.t)
    _, torque = rotor_wrench(p, mean, np.zeros_like(mean), np.zeros((len(log.t), 3)))
    return torque / np.asarray(p.inertia)


def command_statistics(log) -> dict:
    """Roughness of the logged commands over the flying middle: std of each motor's deviation from the four's mean
    [input unit], std of its sample-to-sample change, their ratio, and the median command."""
    a, b = (int(f * len(log.t)) for f in MIDDLE)
    deviation = log.u[a:b] - log.u[a:b].mean(axis=1, keepdims=True)
    spread, step = float(np.std(deviation)), float(np.std(np.diff(deviation, axis=0)))
    return {"deviation_std": spread, "step_std": step, "step_to_deviation": step / spread, "median_command": float(np.median(log.u[a:b]))}


def band_response(log, vehicle, time_constant: float, delay: float) -> dict:
    """Per axis (roll, pitch) and band of :data:`BANDS_HZ`: 1/|H1|, 1/|H2| (module docstring) and the mean coherence
    from the modelled to the measured angular acceleration; 1/|H| is the effective / airframe inertia at that band."""
    a, b = (int(f * len(log.t)) for f in MIDDLE)
    rate = 1.0 / float(np.median(np.diff(log.t)))
    model = modelled_acceleration(log, vehicle, time_constant, delay)[a:b]
    measured = np.gradient(log.gyro_b, log.t, axis=0)[a:b]
    out = {}
    for axis, name in ((0, "roll"), (1, "pitch")):
        x, y = model[:, axis] - model[:, axis].mean(), measured[:, axis] - measured[:, axis].mean()
        f, sxy = signal.csd(x, y, rate, nperseg=WELCH_SEGMENT)
        _, sxx = signal.welch(x, rate, nperseg=WELCH_SEGMENT)
        _, syy = signal.welch(y, rate, nperseg=WELCH_SEGMENT)
        coherence = np.abs(sxy) ** 2 / (sxx * syy)
        rows = []
        for low, high in BANDS_HZ:
            m = (f >= low) & (f < high)
            cross = abs(sxy[m].sum())
            rows.append({"band_hz": [low, high], "inv_h1": float(sxx[m].sum() / cross), "inv_h2": float(cross / syy[m].sum()),
                         "coherence": float(coherence[m].mean()), "model_power": float(sxx[m].sum() * (f[1] - f[0]))})
        out[name] = rows
    return out


def damping_regression(log, vehicle, time_constant: float, delay: float) -> dict:
    """Band-passed (:data:`REGRESSION_BAND_HZ`) least squares of the measured roll/pitch acceleration on the modelled
    one (gain α: effective inertia ratio 1/α) and with the body rate as a second regressor (a damping moment -c ω:
    c/I_eff = -coefficient/α [1/s]); R² of each."""
    a, b = (int(f * len(log.t)) for f in MIDDLE)
    rate = 1.0 / float(np.median(np.diff(log.t)))
    sos = signal.butter(2, REGRESSION_BAND_HZ, "bandpass", fs=rate, output="sos")
    model = modelled_acceleration(log, vehicle, time_constant, delay)[a:b]
    measured = np.gradient(log.gyro_b, log.t, axis=0)[a:b]
    out = {}
    for axis, name in ((0, "roll"), (1, "pitch")):
        y = signal.sosfiltfilt(sos, measured[:, axis])
        x = signal.sosfiltfilt(sos, model[:, axis])
        w = signal.sosfiltfilt(sos, log.gyro_b[a:b, axis])
        alone, *_ = np.linalg.lstsq(x[:, None], y, rcond=None)
        both, *_ = np.linalg.lstsq(np.stack([x, w], 1), y, rcond=None)
        r2 = lambda X, th: float(1.0 - np.var(y - X @ th) / np.var(y))  # noqa: E731
        out[name] = {"inertia_ratio": float(1.0 / alone[0]), "r2": r2(x[:, None], alone),
                     "inertia_ratio_with_damping": float(1.0 / both[0]), "damping_per_s": float(-both[1] / both[0]),
                     "r2_with_damping": r2(np.stack([x, w], 1), both)}
    return out


def fit_row(log, vehicle, observer_name: str, dynamics=None, terms: tuple[str, ...] = ()) -> dict:
    """The physics fit on one flight (``short`` preset): effective / airframe roll and pitch inertia, the fitted rotor
    time constant and delay, each channel's error ratio (the fit's own multi-step SSR / the observer alone's)."""
    fit = identify_physics([log], vehicle, CONFIG, OBSERVERS[observer_name], terms, dynamics=dynamics)
    return {"ixx_ratio": fit.values["effective_ixx"] / vehicle.value("ixx"), "iyy_ratio": fit.values["effective_iyy"] / vehicle.value("iyy"),
            "time_constant_s": fit.values["rotor_time_constant"], "delay_s": fit.values["rotor_delay"],
            "thrust_constant": fit.values["rotor_thrust_constant"], "error_ratio": dict(fit.diagnostics["error_ratio"])}


def real_flight(name: str, vehicle) -> dict:
    """Every measurement of one NanoBench flight (module docstring)."""
    log = load_flight(NANOBENCH / f"{name}.csv.gz", vehicle)
    compensated = replace(log, u=equivalent_duty(log.u))
    base = fit_row(log, vehicle, "default")
    tau, delay = base["time_constant_s"], base["delay_s"]
    fits = {"logged, default observer": base, "logged, measured observer": fit_row(log, vehicle, "measured"),
            "compensated map, default observer": fit_row(compensated, vehicle, "default"),
            "compensated map, measured observer": fit_row(compensated, vehicle, "measured")}
    fits["logged, +motor_imbalance fitted"] = fit_row(log, vehicle, "default", terms=("motor_imbalance",))
    fits["compensated map, +motor_imbalance fitted"] = fit_row(compensated, vehicle, "default", terms=("motor_imbalance",))
    for held in HELD_TIME_CONSTANTS_S:
        fits[f"logged, tau held {held * 1e3:g} ms"] = fit_row(log, vehicle, "default", dynamics=(held, delay, 0.0))
    comp_fit = fits["compensated map, default observer"]
    return {"flight": name, "commands": command_statistics(log), "fits": fits,
            "bands": band_response(log, vehicle, tau, delay),
            "bands_compensated": band_response(compensated, vehicle, comp_fit["time_constant_s"], comp_fit["delay_s"]),
            "damping": damping_regression(log, vehicle, tau, delay)}


def simulated_flight(factor: float) -> dict:
    """A simulated Crazyflie flight with the stabiliser's gyro noise ``factor`` x the default: command roughness,
    band response and the fit's effective inertia against the simulator's own (its vehicle: the true constants)."""
    params = sim_params_for("crazyflie21")
    params = replace(params, sensors=replace(params.sensors, gyro_noise=params.sensors.gyro_noise * factor))
    result = run_simulation("crazyflie21", seed=SIM_SEED, duration=SIM_DURATION_S, params=params)
    vehicle = params.vehicle
    fits = {name: fit_row(result.log, vehicle, name) for name in ("default", "measured")}
    tau, delay = vehicle.value("rotor_time_constant"), params.input_delay
    return {"gyro_noise_factor": factor, "gyro_noise_rad_s": params.sensors.gyro_noise, "commands": command_statistics(result.log),
            "fits": fits, "bands": band_response(result.log, vehicle, tau, delay)}


def markdown(real: list[dict], sim: list[dict]) -> str:
    lines = ["# Why the physics fit needs several times the airframe's roll/pitch inertia (issue #28 item 1)", "",
             "`bench/bench_inertia_hypotheses.py` (method in its docstring). Inertia ratio = effective / airframe "
             "(Foerster 2015; simulator: its own). err = the fit's roll/pitch multi-step error / the observer alone's.", "",
             "## Fits per flight", "", "| flight | variant | ixx ratio | iyy ratio | tau [ms] | delay [ms] | roll err | pitch err | vel err |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in real:
        for label, f in r["fits"].items():
            e = f["error_ratio"]
            lines.append(f"| {r['flight']} | {label} | {f['ixx_ratio']:.2f} | {f['iyy_ratio']:.2f} | {f['time_constant_s'] * 1e3:.1f} | "
                         f"{f['delay_s'] * 1e3:.0f} | {e['roll']:.3f} | {e['pitch']:.3f} | {e['velocity']:.3f} |")
    for s in sim:
        for label, f in s["fits"].items():
            e = f["error_ratio"]
            lines.append(f"| sim seed {SIM_SEED}, gyro noise x{s['gyro_noise_factor']:g} | {label} observer | {f['ixx_ratio']:.2f} | "
                         f"{f['iyy_ratio']:.2f} | {f['time_constant_s'] * 1e3:.1f} | {f['delay_s'] * 1e3:.0f} | {e['roll']:.3f} | {e['pitch']:.3f} | {e['velocity']:.3f} |")
    lines += ["", "## Logged commands (flying middle)", "", "| flight | median u | deviation std | step std | step / deviation |", "|---|---|---|---|---|"]
    for label, c in [(r["flight"], r["commands"]) for r in real] + [(f"sim x{s['gyro_noise_factor']:g}", s["commands"]) for s in sim]:
        lines.append(f"| {label} | {c['median_command']:.0f} | {c['deviation_std']:.0f} | {c['step_std']:.0f} | {c['step_to_deviation']:.3f} |")
    lines += ["", "## Frequency response, modelled -> measured roll acceleration", "",
              "1/|H1| / 1/|H2| / coherence per band: effective inertia ratio at that frequency (H1 and H2 bracket it when "
              "the input is noisy; they agree when it is not).", "",
              "| flight | commands | " + " | ".join(f"{lo:g}-{hi:g} Hz" for lo, hi in BANDS_HZ) + " |", "|---|---|" + "---|" * len(BANDS_HZ)]
    cell = lambda b: f"{b['inv_h1']:.2f} / {b['inv_h2']:.2f} / {b['coherence']:.2f}"  # noqa: E731
    for r in real:
        lines.append(f"| {r['flight']} | logged | " + " | ".join(cell(b) for b in r["bands"]["roll"]) + " |")
        lines.append(f"| {r['flight']} | compensated map | " + " | ".join(cell(b) for b in r["bands_compensated"]["roll"]) + " |")
    for s in sim:
        lines.append(f"| sim x{s['gyro_noise_factor']:g} | logged | " + " | ".join(cell(b) for b in s["bands"]["roll"]) + " |")
    lines += ["", "## Rate damping (band-passed regression, 0.3-15 Hz, logged commands)", "",
              "| flight | axis | inertia ratio | R² | with damping: inertia ratio | c / I_eff [1/s] | R² |", "|---|---|---|---|---|---|---|"]
    for r in real:
        for axis, d in r["damping"].items():
            lines.append(f"| {r['flight']} | {axis} | {d['inertia_ratio']:.2f} | {d['r2']:.3f} | {d['inertia_ratio_with_damping']:.2f} | "
                         f"{d['damping_per_s']:.1f} | {d['r2_with_damping']:.3f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--write-compensated", type=Path, help="write the NanoBench copy with the compensation map here and stop")
    args = parser.parse_args()
    if args.write_compensated:
        written = compensated_copy(NANOBENCH, args.write_compensated)
        print(f"{len(written)} flights in {args.write_compensated}; next: bench.bench_models --data {args.write_compensated}")
        return
    vehicle = load_vehicle("crazyflie21")
    real = []
    for name in FLIGHTS:
        if (NANOBENCH / f"{name}.csv.gz").exists():
            real.append(real_flight(name, vehicle))
            print("done", name, flush=True)
    sim = []
    for factor in SIM_GYRO_NOISE_FACTORS:
        sim.append(simulated_flight(factor))
        print("done sim", factor, flush=True)
    write_results("inertia_hypotheses", {"flights": real, "simulated": sim, "sim_seed": SIM_SEED}, markdown(real, sim))


if __name__ == "__main__":
    main()
