"""The perfect-model floor (issue #25 item 7): the identified physics model against ``truth`` on simulated flights.

For each trial seed S and each simulator effect set (``none``: effect-free; ``ground_effect,battery``), as a user
runs it:

1. ``quad-modelling simulate`` three 220 s flights of ``--vehicle`` (``linkquad``, or ``crazyflie21``), seeds S, S+1, S+2;
2. ``quad-modelling identify`` the physics model on the first two (``--vehicle`` the shipped file, thesis spans);
3. ``quad-modelling evaluate`` the third, held out, with that vehicle file and the models :data:`MODELS`; the
   multi-step table (IDSIA, every start of the evaluation span 150-190 s, horizons 1..50) gives each model's SimErr
   ratio to naive on velocity and angular velocity.

Reported per trial: those ratios, physics / truth (the issue's target: within 1.25x), and the measurement-noise
level the issue quotes (50 x naive's one-step MAE / naive's SimErr: a model that is exact but starts from and is
compared with noisy measurements scores about this). ``truth:0.5,0.5`` is the truth anchored with the physics
model's disturbance observer, ``physics:0,0`` the physics model without it and ``physics:0.5,0`` with its linear
part only: what the observer itself costs.
``physics@true`` (:func:`true_constant_physics`) is the physics model with the simulator's true constants: what its
structure reaches when identification is perfect.

Run: ``.venv/bin/python -m bench.bench_truth_floor [--vehicle crazyflie21] [--seeds 4711,31337] [--effects none ground_effect,battery]``
(seeds are trial seeds; the development seed was 5001: report others). Writes bench/results/truth_floor.json/.md.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import write_results  # noqa: E402
from quad_modelling.cli import main as cli  # noqa: E402
from quad_modelling.core.models.physics import Observer  # noqa: E402
from quad_modelling.io.reports.formatting import markdown_table  # noqa: E402

MODELS = ("physics", "truth", "naive", "truth:0.5,0.5", "physics:0,0", "physics:0.5,0")
"""Specs evaluated on the held-out flight by ``quad-modelling evaluate``."""
TRUE_MODELS = {"physics@true": Observer(0.0, 0.0), "physics@true:0.5,0": Observer(0.5, 0.0), "physics@true:0.5,0.5": Observer()}
"""The physics model with the simulator's true constants (:func:`true_constant_physics`), without and with its
default disturbance observer."""
GROUPS = ("velocity", "angular_velocity")
TARGET = 1.25
"""Issue #25: the identified physics model's held-out SimErr within 1.25x of truth's."""
DEVELOPMENT_SEEDS = (5001,)
"""Trial seeds the truth model was developed on (flights 5001-5003); the report's seeds are others."""


def _run(args: list[str]) -> None:
    """One CLI call in this process, its output kept off the report; RuntimeError with it on failure."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = cli(args)
    if code != 0:
        raise RuntimeError(f"quad-modelling {' '.join(args)} exited {code}: {out.getvalue()[-2000:]}")


def true_constant_physics(flight: Path, identified: Path) -> dict:
    """The multi-step table (evaluate's thesis spans) of the physics model with the simulator's true constants instead
    of the identified ones (:data:`TRUE_MODELS`): what its structure reaches. Mapped from the log's notes: the ESC map
    Ω_ss = k_u (u - u_0) at V_ref, the motor lag and input delay when on (else 0), a, d, the rotor drag (k_h, k_h, k_v)
    at the hub height when on (else 0), the airframe's inertias; ground effect and battery have no term in it."""
    from quad_modelling.core.evaluation.multistep import multistep_evaluation
    from quad_modelling.core.models.physics import Observer, PhysicsPredictor
    from quad_modelling.core.preprocess import resample_uniform
    from quad_modelling.core.sim.params import sim_params_from_notes
    from quad_modelling.core.vehicle import load_vehicle
    from quad_modelling.core.windows import EvaluationConfig
    from quad_modelling.io.loader import load_flight

    log = load_flight(str(flight))
    truth = sim_params_from_notes(log.meta.notes, str(flight))
    effects = set(log.meta.notes["effects"])
    vehicle = load_vehicle(str(identified))
    constants = truth.vehicle
    k_u = truth.esc.speed_gain
    drag = (truth.rotor_drag.horizontal, truth.rotor_drag.horizontal, truth.rotor_drag.vertical) if "rotor_drag" in effects else (0.0,) * 3
    models = []
    for name, observer in TRUE_MODELS.items():
        model = PhysicsPredictor(vehicle, observer, name=name)
        model.params = model.params.with_values(
            mass=constants.mass, inertia=tuple(float(x) for x in constants.inertia), prop_inertia=constants.value("prop_inertia"),
            speed_gain=k_u, speed_offset=-k_u * truth.esc.zero_speed_input,
            time_constant=truth.motor_time_constant if "motor_lag" in effects else 0.0,
            delay=truth.input_delay if "input_delay" in effects else 0.0,
            thrust_constant=constants.value("rotor_thrust_constant"), torque_constant=constants.value("rotor_torque_constant"),
            drag=drag, drag_arm=truth.geometry.rotor_plane_z if "rotor_drag" in effects else 0.0)
        models.append(model)
    return multistep_evaluation([resample_uniform(log)], models, vehicle, EvaluationConfig())


def trial(seed: int, effects: str, directory: Path, duration: float, terms: str = "", vehicle_name: str = "linkquad") -> dict:
    """Simulate, identify on two flights, evaluate the third (module docstring): the multi-step ratios."""
    times = {}
    flights = []
    started = time.perf_counter()
    for k in range(3):
        path = directory / f"s{seed + k}_{effects.replace(',', '+')}.mat"
        _run(["simulate", "-o", str(path), "--vehicle", vehicle_name, "--effects", effects, "--seed", str(seed + k),
              "--duration", str(duration), "--force"])
        flights.append(path)
    times["simulate_s"] = time.perf_counter() - started
    vehicle = directory / f"identified_{seed}_{effects.replace(',', '+')}.yaml"
    started = time.perf_counter()
    _run(["identify", str(flights[0]), str(flights[1]), "--vehicle", vehicle_name, "-o", str(vehicle), "--force",
          *(["--effects", terms] if terms else [])])
    times["identify_s"] = time.perf_counter() - started
    out = directory / f"eval_{seed}_{effects.replace(',', '+')}"
    started = time.perf_counter()
    _run(["evaluate", str(flights[2]), "--vehicle", str(vehicle), *[a for m in MODELS for a in ("--model", m)], "-o", str(out),
          "--force"])
    times["evaluate_s"] = time.perf_counter() - started
    horizons = json.loads((out / "results.json").read_text())["horizons"]
    started = time.perf_counter()
    true_constants = true_constant_physics(flights[2], vehicle)
    for name, entry in true_constants["models"].items():
        if name == "naive":  # the same starts as evaluate's table
            assert abs(entry["velocity"]["sim_err"] - horizons["models"]["naive"]["velocity"]["sim_err"]) < 1e-9
        else:
            horizons["models"][name] = entry
    times["true_constants_s"] = time.perf_counter() - started
    result = {"vehicle": vehicle_name, "seed": seed, "effects": effects, "flights": [seed, seed + 1, seed + 2], "starts": horizons["starts"],
              "times": times, "ratio": {}, "sim_err": {}, "noise_ratio": {}}
    for model, entry in horizons["models"].items():
        result["ratio"][model] = {g: entry[g]["ratio_sim_err"] for g in GROUPS}
        result["sim_err"][model] = {g: entry[g]["sim_err"] for g in GROUPS}
    naive = horizons["models"]["naive"]
    result["noise_ratio"] = {g: 50.0 * naive[g]["naive_mae"]["1"] / naive[g]["naive_sim_err"] for g in GROUPS}
    result["physics_over_truth"] = {g: result["sim_err"]["physics"][g] / result["sim_err"]["truth"][g] for g in GROUPS}
    result["within_target"] = {g: result["physics_over_truth"][g] <= TARGET for g in GROUPS}
    return result


def markdown(results: list[dict], duration: float, vehicle_name: str = "linkquad") -> str:
    lines = [f"# The perfect-model floor: identified physics vs truth on simulated {vehicle_name} flights", "",
             f"Per trial seed S: three {duration:g} s {vehicle_name} flights (seeds S, S+1, S+2) from `quad-modelling simulate`; "
             f"`identify --vehicle {vehicle_name}` on the first two; `evaluate` of the third (held out) with the identified "
             "vehicle: multi-step SimErr (h = 1..50, every start of the evaluation span 150-190 s) as a ratio to naive, "
             "velocity / angular velocity. `truth` = the simulator's own physics, effects and constants from the log's "
             "notes, anchored on the measured state without a disturbance observer; `truth:0.5,0.5` = the same with the "
             "physics model's observer; `physics:0,0` = the identified physics model without it, `physics:0.5,0` with its linear "
             "part only (no angular trim); `physics@true` = the physics "
             "model's structure with the simulator's true constants (ESC map, lag and delay when on, a, d, rotor drag when "
             "on, the airframe's inertias; no term for ground effect or battery), without and with its observer. Noise = 50 x naive's "
             "one-step MAE / naive's SimErr (what an exact model scored against noisy measurements gets, about). "
             f"physics / truth: the ratio of their SimErr, target <= {TARGET} (issue #25). Development seed "
             f"{', '.join(map(str, DEVELOPMENT_SEEDS))}; the others were not looked at before this run.", ""]
    for effects in dict.fromkeys(r["effects"] for r in results):
        fitted = next(r.get("identify_effects", "") for r in results if r["effects"] == effects)
        rows = []
        for r in (r for r in results if r["effects"] == effects):
            def pair(values):
                return " / ".join(f"{values[g]:.3f}" for g in GROUPS)
            rows.append([str(r["seed"]) + (" (dev)" if r["seed"] in DEVELOPMENT_SEEDS else ""),
                         pair(r["ratio"]["physics"]), pair(r["ratio"]["truth"]), pair(r["physics_over_truth"]),
                         " / ".join("yes" if r["within_target"][g] else "no" for g in GROUPS),
                         pair(r["noise_ratio"]), pair(r["ratio"]["truth:0.5,0.5"]), pair(r["ratio"]["physics:0,0"]),
                         pair(r["ratio"]["physics:0.5,0"]), pair(r["ratio"]["physics@true"]),
                         pair(r["ratio"]["physics@true:0.5,0"]), pair(r["ratio"]["physics@true:0.5,0.5"]),
                         f"{r['times']['identify_s']:.0f} / {r['times']['evaluate_s']:.0f}"])
        lines += [f"## Simulator effects: {effects}", "",
                  f"identify --effects: {fitted or '(none)'}; the disturbance observer as identify chose it from the data.", "",
                  *markdown_table(["trial seed", "physics", "truth", "physics / truth", f"<= {TARGET}x", "noise",
                                   "truth:0.5,0.5", "physics:0,0", "physics:0.5,0", "physics@true", "physics@true:0.5,0",
                                   "physics@true:0.5,0.5",
                                   "identify / evaluate s"], rows), ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", default="linkquad", choices=("linkquad", "crazyflie21"), help="simulated and identified vehicle")
    parser.add_argument("--seeds", default="4711,31337", help="trial seeds, comma-separated (default 4711,31337)")
    parser.add_argument("--effects", nargs="+", default=["none", "ground_effect,battery"], help="simulator effect sets")
    parser.add_argument("--duration", type=float, default=220.0, help="flight duration [s] (default 220, the thesis's)")
    parser.add_argument("--name", default="truth_floor", help="results name (bench/results/NAME.json/.md)")
    parser.add_argument("--identify-effects", nargs="+", default=None, metavar="LIST",
                        help="identify --effects per simulator effect set, in the order of --effects ('' for none); "
                             "default: none for every set")
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        terms = args.identify_effects or [""] * len(args.effects)
        for effects, fitted in zip(args.effects, terms):
            for seed in seeds:
                results.append(trial(seed, effects, Path(tmp), args.duration, fitted, args.vehicle))
                results[-1]["identify_effects"] = fitted
                print(f"seed {seed} effects {effects}: {json.dumps(results[-1]['ratio'])}", file=sys.stderr, flush=True)
    write_results(args.name, {"vehicle": args.vehicle, "duration_s": args.duration, "models": list(MODELS), "target": TARGET,
                              "trials": results}, markdown(results, args.duration, args.vehicle))
    return 0


if __name__ == "__main__":
    sys.exit(main())
