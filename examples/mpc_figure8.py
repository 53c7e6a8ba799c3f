"""An MPC built on the exported CasADi model flies the truth simulator along a figure-8 (docs/mpc.md).

    python examples/mpc_figure8.py --model effects_model --base base_model -o mpc_results

``--model`` and ``--base`` are directories written by ``quad-modelling export`` (docs/export.md): the identified
physics model with its effect terms, and the same vehicle identified without them. Each is flown by a nonlinear
MPC (CasADi Opti + IPOPT from the casadi wheel) on the exported one-step Function ``F_disturbed``, with and without
the disturbance observer's estimate ``d`` (the model's anchoring, computed here with the exported ``f_disturbed``);
next to them flies the simulator's own controller (PID stabiliser with its pilot's position hold, steered to the
same reference). The truth simulator (``quad_modelling.core.sim.closed_loop.TruthLoop``) runs its own physics at
1 kHz with every default effect on; the controllers read its true state (no sensor noise), except the rotor speeds,
which the MPC estimates with the model. Writes ``results.json`` and ``results.md`` (tracking error per controller).

The MPC, per tick of ``--dt`` seconds (commands held in between):

    min  sum_k  w_p |p_k - p_ref,k|^2 + w_v |v_k - v_ref,k|^2 + w_w |w_k|^2 + w_yaw R21_k^2
                + w_u |u_k - u_hover|^2 + w_du |u_k - u_k-1|^2
    s.t. x_0 = measured state, x_k+1 = F_disturbed(x_k, u_k, dt, d), input_min <= u_k <= input_max

with the command delay of the model (rotor_delay < dt): over the first delay of step 0 the rotors still answer the
previous command, so step 0 is two calls of F (delay, then dt - delay).
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import casadi
import numpy as np
import yaml

from quad_modelling.core.models.physics import Observer, observed_disturbance
from quad_modelling.core.sim.closed_loop import TruthLoop, stabiliser_commands, trimmed_stabiliser
from quad_modelling.core.variables import VARIABLES
from quad_modelling.cli import OneLineParser

TRUTH_VEHICLE = "linkquad"
"""The simulator's vehicle the example flies (its truth physics); the exports must be models of it."""

SETTLE_S = 1.0
"""The tracking error is scored from this time on [s] (the controller takes over in hover at the reference's start)."""

MPC_DT = 0.04
"""The MPC's step [s] (25 Hz; a model's rotor_delay must be shorter)."""


@dataclass(frozen=True)
class Figure8:
    """p_ref(t) = (a sin θ, b sin 2θ, -height) in NED [m], θ(t) = ω (t - ramp/2) after a ramp-in of ``ramp`` s
    (θ = ω t² / (2 ramp) before: the reference starts at rest, velocity and acceleration continuous)."""

    half_length: float = 1.5
    half_width: float = 0.75
    height: float = 1.0
    period: float = 10.0
    ramp: float = 2.0

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, velocity, acceleration) of the reference at ``t`` [s], N frame."""
        omega = 2.0 * np.pi / self.period
        if t < self.ramp:
            theta, theta_dot, theta_ddot = omega * t * t / (2.0 * self.ramp), omega * t / self.ramp, omega / self.ramp
        else:
            theta, theta_dot, theta_ddot = omega * (t - self.ramp / 2.0), omega, 0.0
        a, b = self.half_length, self.half_width
        pos = np.array([a * np.sin(theta), b * np.sin(2 * theta), -self.height])
        vel = np.array([a * np.cos(theta) * theta_dot, 2 * b * np.cos(2 * theta) * theta_dot, 0.0])
        acc = np.array([a * (np.cos(theta) * theta_ddot - np.sin(theta) * theta_dot**2),
                        2 * b * (np.cos(2 * theta) * theta_ddot - 2 * np.sin(2 * theta) * theta_dot**2), 0.0])
        return pos, vel, acc


class ExportedModel:
    """An export directory: its layout and the Functions the MPC and the observer call."""

    def __init__(self, directory: str | Path):
        directory = Path(directory)
        self.layout = yaml.safe_load((directory / "layout.yaml").read_text())
        self.step = casadi.Function.load(str(directory / "F_disturbed.casadi"))
        self.derivative = casadi.Function.load(str(directory / "f_disturbed.casadi"))
        names = [entry["name"] for entry in self.layout["input"]]
        if names[:4] != ["u_1", "u_2", "u_3", "u_4"] or "u_logged_1" in names:
            raise ValueError(f"{directory}: the example flies a physics model export (inputs u_1..u_4[, battery_voltage]), got {names}")
        self.battery = names[-1] == "battery_voltage"
        c = self.layout["constants"]
        self.delay, self.u_min, self.u_max = c["rotor_delay_s"], c["input_min"], c["input_max"]
        self.hover_rotor_speed = c["hover_rotor_speed_rad_s"]
        self.hover_rotor_speeds = np.asarray(c.get("hover_rotor_speeds_rad_s", [self.hover_rotor_speed] * 4), dtype=float)
        self.hover_commands = np.asarray(c.get("hover_commands", [c["hover_command"]] * 4), dtype=float)  # per motor
        self.terms, self.vehicle = self.layout["terms_on"], self.layout["vehicle"]

    def inputs(self, commands, voltage):
        """The Function's input u: the commands, then the battery voltage when the battery term is on."""
        return casadi.vertcat(commands, voltage) if self.battery else commands


def state_vector(observation: dict, rotor: np.ndarray) -> np.ndarray:
    """x (22) in the export's layout from a TruthLoop observation, with the model's rotor-speed estimate ``rotor``."""
    return np.concatenate([observation["pos_n"], observation["vel_n"], observation["rot"].ravel(), observation["rates"], rotor])


class DisturbanceObserver:
    """The physics model's observer (docs/export.md; ``quad_modelling.core.models.physics.observed_disturbance``, the
    package's one definition) on the controller's ticks, with the model's accelerations from the exported
    ``f_disturbed``: over the last ``linear_history_s``, d_v = measured mean acceleration - the model's mean dv/dt;
    over ``angular_history_s``, d_ω = -the model's mean dω/dt (angular trim) or measured - modelled."""

    def __init__(self, model: ExportedModel):
        o = model.layout["observer"]
        self.model = model
        self.observer = Observer(o["linear_history_s"], o["angular_history_s"], o["angular_trim"])
        self.history: deque = deque()

    def estimate(self, t: float, x: np.ndarray, u_answered: np.ndarray, voltage: float) -> np.ndarray:
        """d (6) at time ``t`` from the state ``x`` and the commands the rotors answer now."""
        xdot = np.asarray(self.model.derivative(x, self.model.inputs(u_answered, voltage), np.zeros(6))).ravel()
        measured = np.zeros(len(VARIABLES))  # the observer reads the velocity and the body rates of a measurement row
        measured[3:6], measured[12:15] = x[3:6], x[15:18]
        self.history.append((t, measured, np.concatenate([xdot[3:6], xdot[15:18]])))
        while t - self.history[0][0] > max(self.observer.linear_s, self.observer.angular_s) + 1.0:
            self.history.popleft()
        times, rows, modelled = (np.array(column) for column in zip(*self.history))
        d = observed_disturbance(times, rows, modelled, np.array([len(times) - 1]), self.observer)
        return np.concatenate([d.linear_n[0], d.angular_b[0]])


class ModelPredictiveController:
    """The MPC of the module docstring on ``model``, ``horizon`` steps of ``dt`` seconds. :data:`WEIGHTS`: chosen
    by hand on this figure-8 (position first, then calm rates and commands); the same for every model."""

    WEIGHTS = {"position": 20.0, "height": 40.0, "velocity": 2.0, "rates": 0.2, "yaw": 5.0, "input": 0.05, "input_change": 2.0}

    def __init__(self, model: ExportedModel, dt: float = MPC_DT, horizon: int = 15):
        if not 0.0 <= model.delay < dt:
            raise ValueError(f"the model's rotor_delay {model.delay} s must be shorter than the MPC step {dt} s")
        self.model, self.dt, self.horizon = model, dt, horizon
        w = self.WEIGHTS
        scale = np.concatenate([np.ones(18), np.full(4, model.hover_rotor_speed)])
        span = model.u_max - model.u_min
        self.hover = (model.hover_commands - model.u_min) / span  # (4,): each motor's, with its command gain
        opti = casadi.Opti()
        X, U = opti.variable(22, horizon + 1), opti.variable(4, horizon)
        x0, d, ref, u_prev, voltage = opti.parameter(22), opti.parameter(6), opti.parameter(6, horizon), opti.parameter(4), opti.parameter()

        def physical(normalised):
            """Commands [input unit] of commands scaled to 0..1 of the vehicle's range."""
            return model.u_min + span * normalised

        opti.subject_to(X[:, 0] == x0 / scale)
        cost = 0
        for k in range(horizon):
            x = X[:, k] * scale
            if k == 0 and model.delay > 0:
                x = model.step(x, model.inputs(physical(u_prev), voltage), model.delay, d)
                x_next = model.step(x, model.inputs(physical(U[:, 0]), voltage), dt - model.delay, d)
            else:
                x_next = model.step(x, model.inputs(physical(U[:, k]), voltage), dt, d)
            opti.subject_to(X[:, k + 1] == x_next / scale)
            position_error = X[0:3, k + 1] - ref[0:3, k]
            cost += w["position"] * casadi.sumsqr(position_error[0:2]) + w["height"] * position_error[2] ** 2
            cost += w["velocity"] * casadi.sumsqr(X[3:6, k + 1] - ref[3:6, k]) + w["rates"] * casadi.sumsqr(X[15:18, k + 1])
            cost += w["yaw"] * X[9, k + 1] ** 2 + w["input"] * casadi.sumsqr(U[:, k] - self.hover)
            cost += w["input_change"] * casadi.sumsqr(U[:, k] - (u_prev if k == 0 else U[:, k - 1]))
        opti.subject_to(opti.bounded(0.0, U, 1.0))
        opti.minimize(cost)
        opti.solver("ipopt", {"expand": True, "print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": 40,
                              "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_iter": 3,
                              "ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-3})
        self.solve = opti.to_function("mpc", [x0, d, ref, u_prev, voltage, X, U], [U, X],
                                      ["x0", "d", "ref", "u_prev", "voltage", "X_guess", "U_guess"], ["U", "X"])
        self.scale = scale
        self.X_guess, self.U_guess = None, np.tile(self.hover[:, None], (1, horizon))
        self.u_prev = self.hover.copy()

    def command(self, x: np.ndarray, d: np.ndarray, reference: np.ndarray, voltage: float) -> np.ndarray:
        """The commands (4,) [input unit] to send now, from the state ``x``, disturbance ``d`` and the reference
        (6, horizon) (position and velocity at the end of each step)."""
        if self.X_guess is None:
            self.X_guess = np.tile((x / self.scale)[:, None], (1, self.horizon + 1))
        U, X = self.solve(x, d, reference, self.u_prev, voltage, self.X_guess, self.U_guess)
        U, X = np.asarray(U), np.asarray(X)
        self.U_guess = np.hstack([U[:, 1:], U[:, -1:]])  # warm start: the plan shifted by one step
        self.X_guess = np.hstack([X[:, 1:], X[:, -1:]])
        self.u_prev = U[:, 0]
        return self.model.u_min + (self.model.u_max - self.model.u_min) * U[:, 0]


def tracking(errors: list) -> dict:
    """RMS and largest distance to the reference [m], and the RMS of its horizontal and height parts, of the
    position errors (K, 3) [m, NED]."""
    errors = np.asarray(errors)
    distance = np.linalg.norm(errors, axis=1)
    return {"rms_m": float(np.sqrt(np.mean(distance**2))), "max_m": float(distance.max()),
            "horizontal_rms_m": float(np.sqrt(np.mean(np.sum(errors[:, :2] ** 2, axis=1)))),
            "height_rms_m": float(np.sqrt(np.mean(errors[:, 2] ** 2)))}


def fly_mpc(model: ExportedModel, reference: Figure8, duration: float, use_observer: bool, dt: float = MPC_DT,
            horizon: int = 15, settle: float = SETTLE_S, vehicle: str = TRUTH_VEHICLE) -> dict:
    """Fly the truth simulator with the MPC on ``model`` for ``duration`` s; tracking error after ``settle`` s."""
    loop = TruthLoop(vehicle, height=reference.height)
    mpc = ModelPredictiveController(model, dt, horizon)
    ticks_per_step = int(round(dt / loop.control_dt))
    observer = DisturbanceObserver(model)
    rotor = model.hover_rotor_speeds.copy()  # the model's estimate (nothing measures them): its hover, where it takes over
    u_sent = model.hover_commands.copy()
    u_answered = u_sent.copy()
    errors, solve_s = [], []
    for k in range(int(round(duration / dt))):
        t = k * dt
        observation = loop.observation()
        x = state_vector(observation, rotor)
        if t >= settle:
            errors.append(observation["pos_n"] - reference.at(t)[0])
        d = observer.estimate(t, x, u_answered, observation["voltage"]) if use_observer else np.zeros(6)
        ref = np.array([np.concatenate(reference.at(t + (j + 1) * dt)[:2]) for j in range(horizon)]).T
        started = time.perf_counter()
        u_new = mpc.command(x, d, ref, observation["voltage"])
        solve_s.append(time.perf_counter() - started)
        voltage = observation["voltage"]
        x_mid = model.step(x, model.inputs(u_sent, voltage), model.delay, d) if model.delay > 0 else x
        rotor = np.asarray(model.step(x_mid, model.inputs(u_new, voltage), dt - model.delay, d)).ravel()[18:22]  # the model's rotor estimate
        u_answered, u_sent = u_sent, u_new
        for _ in range(ticks_per_step):
            loop.tick(u_new)
    return {**tracking(errors), "solve_ms_median": 1e3 * float(np.median(solve_s)), "solve_ms_max": 1e3 * float(np.max(solve_s))}


def fly_stabiliser(reference: Figure8, duration: float, dt: float = 0.04, settle: float = SETTLE_S,
                   vehicle: str = TRUTH_VEHICLE) -> dict:
    """Fly the truth simulator with its own stabiliser steered to the reference; error sampled every ``dt``."""
    loop = TruthLoop(vehicle, height=reference.height)
    stabiliser = trimmed_stabiliser(loop)
    every = int(round(dt / loop.control_dt))
    errors = []
    for k in range(int(round(duration / loop.control_dt))):
        t = k * loop.control_dt
        position, velocity, acceleration = reference.at(t)
        if k % every == 0 and t >= settle:
            errors.append(loop.observation()["pos_n"] - position)
        loop.tick(stabiliser_commands(stabiliser, loop, position, velocity, acceleration))
    return tracking(errors)


def markdown(results: dict, reference: Figure8, duration: float) -> str:
    lines = [f"# MPC on the exported model: figure-8 ({2 * reference.half_length:g} m x {2 * reference.half_width:g} m at "
             f"{reference.height:g} m, {reference.period:g} s per lap, {duration:g} s flown, error from {1.0:g} s)", "",
             "| controller | model terms | observer | RMS error mm | horizontal RMS mm | height RMS mm | max error mm | median solve ms |",
             "|---|---|---|---|---|---|---|---|"]
    for name, r in results["runs"].items():
        solve = f"{r['solve_ms_median']:.0f}" if "solve_ms_median" in r else "-"
        lines.append(f"| {name} | {r.get('terms', '-')} | {r.get('observer', '-')} | {1e3 * r['rms_m']:.1f} | "
                     f"{1e3 * r['horizontal_rms_m']:.1f} | {1e3 * r['height_rms_m']:.1f} | {1e3 * r['max_m']:.1f} | {solve} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = OneLineParser(prog="mpc_figure8.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="export directory of the model with its effect terms")
    parser.add_argument("--base", help="export directory of the base model (no terms)")
    parser.add_argument("--duration", type=float, default=12.0, help="seconds flown (default 12: the ramp-in and one lap)")
    parser.add_argument("--height", type=float, default=1.0, help="figure-8 height [m] (default 1)")
    parser.add_argument("-o", "--output", required=True, help="directory to write results.json and results.md into")
    parser.add_argument("--force", action="store_true", help="overwrite the results an earlier run wrote there")
    args = parser.parse_args(argv)
    if not args.duration > SETTLE_S + MPC_DT:
        parser.error(f"--duration {args.duration:g} s: the tracking error is scored from {SETTLE_S:g} s on; fly longer")
    if not args.height > 0.0:
        parser.error(f"--height {args.height:g} m: the figure-8 flies above the ground (height > 0)")
    directories = [d for d in (args.model, args.base) if d is not None]
    for directory in directories:  # one line, not a traceback
        if not (Path(directory) / "layout.yaml").is_file():
            parser.error(f"{directory}: not an export directory (no layout.yaml); write one with "
                         "`quad-modelling export VEHICLE.yaml --format casadi -o DIR`")
    try:
        models = {label: ExportedModel(d) for label, d in (("exported model", args.model), ("base model", args.base)) if d is not None}
    except ValueError as err:  # a hybrid's export: one line, exit 2 as every other bad --model
        parser.error(str(err))
    for directory, model in zip(directories, models.values()):
        if model.vehicle != TRUTH_VEHICLE:
            parser.error(f"{directory}: a model of vehicle {model.vehicle}; this example flies the simulator's {TRUTH_VEHICLE} "
                         f"(export a model identified on `quad-modelling simulate --vehicle {TRUTH_VEHICLE}` flights)")
        if not 0.0 <= model.delay < MPC_DT:  # before anything flies (it failed after the stabiliser's flight, exit 1)
            parser.error(f"{directory}: the model's rotor_delay {model.delay:g} s must be shorter than the MPC step {MPC_DT:g} s")
    output = Path(args.output)
    if output.exists() and not output.is_dir():
        parser.error(f"-o {output}: exists and is not a directory")
    existing = next(p for p in [output, *output.absolute().parents] if p.exists())  # where the results' directory goes
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        parser.error(f"-o {output}: {existing} is {'not a directory' if not existing.is_dir() else 'not writable'}; "
                     "the results cannot be written there")
    for directory in map(Path, directories):  # an input is never an output
        inside = output.resolve() == directory.resolve() or directory.resolve() in output.resolve().parents
        if inside or output.resolve() in directory.resolve().parents:
            parser.error(f"-o {output}: the output {'lies in' if inside else 'holds'} the export {directory} it reads; "
                         "write the results elsewhere")
    if not args.force and any((output / name).exists() for name in ("results.json", "results.md")):
        parser.error(f"-o {output}: holds the results of an earlier run; pass --force to overwrite them")
    reference = Figure8(height=args.height)
    runs = {"simulator's stabiliser + position hold": fly_stabiliser(reference, args.duration)}
    started = time.perf_counter()
    for label, model in models.items():
        for use_observer in (True, False):
            name = f"MPC, {label}, observer {'on' if use_observer else 'off'}"
            runs[name] = {**fly_mpc(model, reference, args.duration, use_observer), "terms": ", ".join(model.terms) or "none",
                          "observer": "on" if use_observer else "off"}
            print(f"{name}: RMS {runs[name]['rms_m']:.3f} m, max {runs[name]['max_m']:.3f} m", file=sys.stderr)
    results = {"reference": vars(reference), "duration_s": args.duration, "mpc_wall_s": time.perf_counter() - started, "runs": runs}
    output.mkdir(parents=True, exist_ok=True)  # only now: a run that fails leaves nothing behind
    for name, text in (("results.json", json.dumps(results, indent=2)), ("results.md", markdown(results, reference, args.duration))):
        partial = output / f".{name}.partial"
        partial.write_text(text)
        os.replace(partial, output / name)  # atomic: an earlier run's file is whole or replaced
    print(markdown(results, reference, args.duration))
    return 0


if __name__ == "__main__":
    sys.exit(main())
