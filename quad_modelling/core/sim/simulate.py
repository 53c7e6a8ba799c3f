"""Truth simulator: LinkQuad-like flights with switchable physical effects (DESIGN 9).

A closed loop like the thesis's flights (Fig 1.10): a seeded pilot script
(:mod:`~quad_modelling.core.sim.pilot`) gives roll/pitch/yaw/height references;
a per-channel PID stabiliser (:mod:`~quad_modelling.core.sim.control`) mixes
them into four engine commands u_i in the vehicle's input unit; the commands
reach the ESCs (after ``input_delay`` when on), which drive each rotor towards

.. math::

    \\Omega_{c,i} = g_i\\, k_u \\max(u_i - u_0, 0)\\, V / V_{ref}

(g_i: ``motor_imbalance`` gains, else 1; V: battery voltage with ``battery``,
else V_ref); the nonlinear rigid body (:mod:`~quad_modelling.core.sim.dynamics`)
is integrated with RK4 at ``physics_rate`` (1 kHz, each control tick's steps in one compiled call,
:func:`integrate_tick`); sensors
(:mod:`~quad_modelling.core.sim.sensors`) give the log at ``log_rate`` (100 Hz).

Battery (``battery`` on), updated every control tick (explicit Euler; the pack
changes over minutes):

.. math::

    I = \\frac{\\sum_i d\\,\\Omega_i^3}{\\eta V} + I_{av}, \\quad
    \\dot{SoC} = -\\frac{I}{3600\\,C}, \\quad V = n_{cells} OCV(SoC) - I R

so the stabiliser must raise u over the flight to keep hovering (the input
trend of thesis Fig 2.2). Wind (``wind`` on): steady mean plus first-order
Gauss-Markov gusts, updated every control tick. The airframe disturbances
``com_offset`` and ``bent_arm`` act in the dynamics (and, for ``com_offset``, the
accelerometer); they draw no random numbers, so every stream is the same with
them on or off.

The stabiliser starts trimmed for the airframe (its integrators hold what a
steady hover at V_ref needs, as a pilot who flew it before would trim it; with
``bent_arm`` that includes the yaw torque, and a roll/pitch stick trim leans the
vehicle against the side force); the pilot cuts the throttle once the vehicle
touches down during the descent.

Randomness: one ``numpy.random.SeedSequence(seed)`` spawns independent streams
for the pilot script, the stabiliser's gyro noise, the wind and the sensors, so
the same seed flies the same manoeuvres whatever the effects, and the same
seed + effects + duration give identical logs.
"""

from __future__ import annotations

import math
import sys
from collections import deque
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from quad_modelling.core import frames
from quad_modelling.core.effect_names import (
    SIM_DEFAULT_EFFECTS,
    SIM_EFFECTS,
    SIMULATOR,
    normalise_effect_names,
)
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.sim import sensors as sim_sensors
from quad_modelling.core.sim.control import Stabiliser
from quad_modelling.core.sim.dynamics import N_STATE, QuadDynamics
from quad_modelling.core.sim.params import (
    OCV_CELL,
    OCV_SOC,
    TRUTH_NOTES_KEY,
    SimParams,
    sim_params_for,
)
from quad_modelling.core.sim.pilot import (
    PHASE_FLYING,
    PHASE_IDLE,
    PilotScript,
    make_pilot_script,
    stick_noise,
)
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError

SIM_VERSION = 2
"""Bumped when the simulator's physics or script generator change the logs it writes."""

__all__ = ["SimResult", "simulate", "run_simulation", "open_circuit_voltage", "wind_series"]


def open_circuit_voltage(soc: float, cells: int) -> float:
    """Pack open-circuit voltage [V] at state of charge ``soc`` (piecewise linear OCV table)."""
    soc = min(1.0, max(0.0, soc))
    for i in range(1, len(OCV_SOC)):
        if soc <= OCV_SOC[i]:
            w = (soc - OCV_SOC[i - 1]) / (OCV_SOC[i] - OCV_SOC[i - 1])
            return cells * (OCV_CELL[i - 1] + w * (OCV_CELL[i] - OCV_CELL[i - 1]))
    return cells * OCV_CELL[-1]


@dataclass
class SimResult:
    """A simulated flight: the sensor log and the truth behind it.

    ``truth`` holds arrays at the log times: ``pos_n``, ``vel_n``, ``euler``,
    ``rates_b`` [rad/s], ``specific_force_b`` [m/s²] (period averages, at the CoM),
    ``omega`` [rad/s], ``thrust`` (N, 4) [N] (with ground effect), ``vbat`` [V],
    ``wind_n`` [m/s], ``height`` (CG above ground) [m], ``phase`` (0 off, 1 idle, 2 flying);
    ``imu_noise_free_acc_b`` [m/s²] and ``imu_noise_free_gyro_b`` [rad/s]: the logged IMU
    without its white noise (period average + turn-on bias + bias walk, and the lever-arm
    terms of ``com_offset``), so ``acc_b - imu_noise_free_acc_b`` is the white noise alone;
    ``imu_lever_arm_acc_b`` [m/s²]: the period-averaged lever-arm terms (zeros without ``com_offset``).
    """

    log: FlightLog
    truth: dict
    script: PilotScript
    params: SimParams
    effects: tuple[str, ...]
    seed: int


def simulate(
    vehicle: str | VehicleConfig = "linkquad",
    effects=SIM_DEFAULT_EFFECTS,
    seed: int = 0,
    duration: float = 220.0,
    progress: bool = False,
    params: SimParams | None = None,
) -> FlightLog:
    """Fly one seeded flight and return its sensor log (see :func:`run_simulation`)."""
    return run_simulation(vehicle, effects, seed, duration, progress, params).log


def run_simulation(
    vehicle: str | VehicleConfig = "linkquad",
    effects=SIM_DEFAULT_EFFECTS,
    seed: int = 0,
    duration: float = 220.0,
    progress: bool = False,
    params: SimParams | None = None,
) -> SimResult:
    """Fly one flight of ``duration`` s with the given effects switched on.

    ``params`` overrides the vehicle's simulator parameters (from
    :func:`~quad_modelling.core.sim.params.sim_params_for`). ``progress`` shows
    a tqdm bar on stderr.
    """
    params = params or sim_params_for(vehicle)
    effects = normalise_effect_names(effects, SIMULATOR)
    seed = int(seed)
    if seed < 0:
        raise ConfigError(f"simulation seed must be a non-negative integer, got {seed}")
    duration = float(duration)
    control = params.control
    steps_per_tick = params.physics_rate / control.rate
    steps_per_log = params.physics_rate / params.log_rate
    if abs(steps_per_tick - round(steps_per_tick)) > 1e-9 or abs(steps_per_log - round(steps_per_log)) > 1e-9:
        raise ConfigError(f"physics rate {params.physics_rate} Hz must be a multiple of the control ({control.rate} Hz) and log ({params.log_rate} Hz) rates")
    steps_per_tick, steps_per_log = int(round(steps_per_tick)), int(round(steps_per_log))
    steps_per_mocap = params.physics_rate / params.sensors.mocap_rate
    if abs(steps_per_mocap - round(steps_per_mocap)) > 1e-9:
        raise ConfigError(f"physics rate {params.physics_rate} Hz must be a multiple of the mocap rate {params.sensors.mocap_rate} Hz")
    steps_per_mocap = int(round(steps_per_mocap))

    pilot_seed, control_seed, wind_seed, sensor_seed = np.random.SeedSequence(seed).spawn(4)
    pilot_rng = np.random.default_rng(pilot_seed)
    script = make_pilot_script(params, duration, pilot_rng)
    n_ticks = int(round(duration * control.rate))
    # whole log periods only: the last log sample needs its averaging window
    n_log = int(round(duration * params.log_rate))
    n_steps = n_ticks * steps_per_tick
    dt = 1.0 / params.physics_rate
    dt_tick = 1.0 / control.rate
    t_ticks = np.arange(n_ticks) * dt_tick
    phases = script.phases(t_ticks)
    refs = script.references(t_ticks) + stick_noise(n_ticks, control.rate, params.pilot.stick_noise, pilot_rng) * (phases == PHASE_FLYING)[:, None]
    refs_list = refs.tolist()
    fed_forward = (phases == PHASE_FLYING) * float(control.height_feedforward)
    height_rates, height_accelerations = ((x * fed_forward).tolist() for x in script.height_feedforward(t_ticks))
    gyro_noise = (np.random.default_rng(control_seed).standard_normal((n_ticks, 3)) * params.sensors.gyro_noise).tolist()
    wind = wind_series(params, effects, seed, duration)
    wind_list = wind.tolist()

    dynamics = QuadDynamics(params, effects)
    stabiliser = Stabiliser(params)
    stabiliser.set_trim(dynamics.hover_commands(params.battery.reference_voltage), dynamics.hover_tilt())
    lag = "motor_lag" in effects
    battery_on = "battery" in effects
    battery = params.battery
    delay_steps = int(round(params.input_delay * params.physics_rate)) if "input_delay" in effects else 0
    torque_constant = dynamics.torque_constant
    airborne_height = dynamics.rest_height + 0.03
    touchdown_window = script.land_start + 0.5 * script.descent_time

    state = dynamics.state_at_rest()
    record = np.empty((n_steps, N_STATE + 6))  # state, then k1's translational and angular accelerations
    commands = np.empty((n_ticks, 4))
    voltages = np.empty(n_ticks)
    soc = battery.initial_soc
    voltage = initial_voltage(params, battery_on)
    u_esc = [params.vehicle.input_min] * 4
    pending: deque = deque()
    omega_cmd = [0.0] * 4
    record_every = max(1, n_ticks // 200)
    bar = tqdm(total=n_ticks, unit="tick", desc="simulate", disable=not progress, file=sys.stderr, mininterval=0.5)

    def apply_commands(s, u):
        nonlocal u_esc
        u_esc = u
        return esc_targets(dynamics, s, u, voltage, lag)

    try:
        for k in range(n_ticks):
            s = state
            if phases[k] == PHASE_FLYING and t_ticks[k] >= touchdown_window and -s[2] < airborne_height:
                phases[k:] = np.minimum(phases[k:], PHASE_IDLE)  # the pilot cuts the throttle on touchdown
            phase = phases[k]
            if phase == PHASE_FLYING:
                noise = gyro_noise[k]
                gyro = (s[10] + noise[0], s[11] + noise[1], s[12] + noise[2])
                u = stabiliser.flying(s, refs_list[k], gyro, -s[2] > airborne_height, height_rates[k], height_accelerations[k])
            else:
                stabiliser.reset()
                u = [stabiliser.u_idle] * 4 if phase == PHASE_IDLE else [stabiliser.u_off] * 4
            commands[k] = u
            if battery_on:
                soc, voltage = battery_tick(battery, torque_constant, s[13:17], soc, voltage, dt_tick)
            voltages[k] = voltage
            first = k * steps_per_tick
            if delay_steps:
                pending.append((first + delay_steps, u))
            else:
                u_esc = u
            omega_cmd = apply_commands(s, u_esc)
            s = integrate_tick(dynamics, s, omega_cmd, wind_list[k], dt, first, steps_per_tick, pending, apply_commands, record)
            state = s
            if k % record_every == record_every - 1:
                bar.update(record_every)
                if not all(math.isfinite(v) for v in s):
                    raise ConfigError(f"simulation diverged at t={t_ticks[k]:.3f} s (non-finite state); check the simulator parameters")
    finally:
        bar.close()

    return _assemble(params, effects, seed, script, record, commands, voltages, wind, phases, n_log, steps_per_tick, steps_per_log, steps_per_mocap, dynamics)


def integrate_tick(dynamics: QuadDynamics, s: list, omega_cmd, wind, dt: float, first: int, steps: int, pending: deque,
                   apply_commands, record: np.ndarray | None = None) -> list:
    """The state after the physics steps ``first`` .. ``first + steps - 1`` of one control tick, RK4 of ``dt`` [s] each
    (:meth:`QuadDynamics.advance <quad_modelling.core.sim.dynamics.QuadDynamics.advance>`) from state ``s`` under the
    ESC targets ``omega_cmd`` [rad/s] and air velocity ``wind``; a delayed command due at a step inside the tick
    (``pending``: (step, commands) in order) switches the targets there through ``apply_commands(s, u) -> targets``.
    ``record`` (n_steps, 23): each step's state and k1 accelerations written at its row."""
    step, end = first, first + steps
    while step < end:
        if pending and pending[0][0] <= step:
            omega_cmd = apply_commands(s, pending.popleft()[1])
        stop = min(end, pending[0][0]) if pending and pending[0][0] > step else end
        rows = dynamics.advance(s, omega_cmd, wind, dt, stop - step)
        if record is not None:
            record[step:stop] = rows[:-1]
        s = rows[-1, :N_STATE].tolist()
        step = stop
    return s


def initial_voltage(params: SimParams, battery_on: bool) -> float:
    """Battery voltage [V] at the start of a flight: the full pack under the avionics' current (``battery`` on), else V_ref."""
    battery = params.battery
    if not battery_on:
        return battery.reference_voltage
    return open_circuit_voltage(battery.initial_soc, battery.cells) - battery.avionics_current * battery.internal_resistance


def battery_tick(battery, torque_constant: float, rotor_speeds, soc: float, voltage: float, dt_tick: float) -> tuple[float, float]:
    """(state of charge, voltage [V]) after one control tick of ``dt_tick`` [s] at rotor speeds ``rotor_speeds``
    [rad/s] (module docstring's battery: the rotors' power over the efficiency, plus the avionics)."""
    current = torque_constant * sum(o * o * o for o in rotor_speeds) / (battery.efficiency * voltage) + battery.avionics_current
    soc -= current * dt_tick / (3600.0 * battery.capacity_ah)
    return soc, open_circuit_voltage(soc, battery.cells) - current * battery.internal_resistance


def esc_targets(dynamics: QuadDynamics, s: list, u, voltage: float, lag: bool) -> list[float]:
    """New ESC targets [rad/s] for commands ``u`` at ``voltage``; without motor lag (``lag`` False) the rotors of state
    ``s`` jump there and the body takes the reaction impulse I_p Σ s_i ΔΩ_i / I_zz about z (``s`` changed in place)."""
    target = dynamics.omega_command(u, voltage)
    if not lag:
        jump = sum(sign * (new - old) for sign, new, old in zip(dynamics.yaw_signs, target, s[13:17]))
        s[12] += dynamics.prop_inertia / float(dynamics.inertia[2]) * jump
        s[13:17] = target
    return target


def wind_series(params: SimParams, effects, seed: int, duration: float) -> np.ndarray:
    """(n_ticks, 3) air velocity in N [m/s] at each control tick of a flight of ``duration`` s: mean +
    Gauss-Markov gusts drawn from the seed's wind stream (zeros without ``wind``); the truth model
    (:mod:`~quad_modelling.core.sim.truth_model`) draws the same series from a log's notes."""
    n_ticks = int(round(float(duration) * params.control.rate))
    wind_seed = np.random.SeedSequence(int(seed)).spawn(4)[2]
    return _wind(params, effects, n_ticks, 1.0 / params.control.rate, np.random.default_rng(wind_seed))


def _wind(params: SimParams, effects, n_ticks: int, dt_tick: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) air velocity in N [m/s]: mean + Gauss-Markov gusts (zeros without ``wind``)."""
    if "wind" not in effects:
        return np.zeros((n_ticks, 3))
    from scipy import signal

    w = params.wind
    alpha = math.exp(-dt_tick / w.gust_time_constant)
    white = rng.standard_normal((n_ticks, 3)) * math.sqrt(1.0 - alpha**2) * np.asarray(w.gust_sigma)
    start = rng.standard_normal(3) * np.asarray(w.gust_sigma)
    gusts, _ = signal.lfilter([1.0], [1.0, -alpha], white, axis=0, zi=(alpha * start)[None, :])
    return np.asarray(w.mean_ned) + gusts


def _assemble(params, effects, seed, script, record, commands, voltages, wind, phases, n_log, steps_per_tick, steps_per_log, steps_per_mocap, dynamics) -> SimResult:
    sensors = params.sensors
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(4)[3])
    log_dt = 1.0 / params.log_rate
    t_log = np.arange(n_log) * log_dt
    log_steps = np.arange(n_log) * steps_per_log
    quat = record[:, 6:10]
    com_on = "com_offset" in effects
    imu = sim_sensors.imu(
        quat, record[:, N_STATE:N_STATE + 3], record[:, 10:13], steps_per_log, log_dt, sensors, rng,
        angular_accel_b=record[:, N_STATE + 3:] if com_on else None, position_b=dynamics.imu_position if com_on else None,
    )
    mocap_steps = np.arange(0, len(record), steps_per_mocap)
    t_mocap = mocap_steps / params.physics_rate
    pos_n, vel_n, euler = sim_sensors.motion_capture(t_mocap, record[mocap_steps, 0:3], quat[mocap_steps], t_log, sensors, rng)
    tick_of_log = np.minimum((t_log * params.control.rate + 1e-6).astype(int), len(commands) - 1)
    u = np.clip(commands[tick_of_log], params.vehicle.input_min, params.vehicle.input_max)
    vbat = voltages[tick_of_log] + rng.standard_normal(n_log) * params.battery.voltage_noise
    omega = record[log_steps, 13:17]
    true_states = record[log_steps]
    truth = {
        "t": t_log,
        "pos_n": true_states[:, 0:3],
        "vel_n": true_states[:, 3:6],
        "euler": frames.unwrap_angles(frames.rotation_to_euler_ned(sim_sensors.quaternion_rotations(true_states[:, 6:10]))),
        "rates_b": imu.rates_b,
        "specific_force_b": imu.specific_force_b,
        "imu_noise_free_acc_b": imu.noise_free_acc_b,
        "imu_noise_free_gyro_b": imu.noise_free_gyro_b,
        "imu_lever_arm_acc_b": imu.lever_arm_acc_b,
        "omega": omega,
        "thrust": np.array([dynamics.rotor_thrusts(row) for row in true_states]),
        "vbat": voltages[tick_of_log],
        "wind_n": wind[tick_of_log],
        "height": -true_states[:, 2],
        "phase": phases[tick_of_log],
    }
    notes = _notes(params, effects, seed, script)
    log = FlightLog(
        t=t_log, u=u, acc_b=imu.acc_b, gyro_b=imu.gyro_b, pos_n=pos_n, vel_n=vel_n, euler=euler,
        vbat=vbat, omega=omega, meta=FlightMeta(vehicle=params.vehicle.name, source="simulated", notes=notes),
    )
    return SimResult(log=log, truth=truth, script=script, params=params, effects=effects, seed=seed)


def flown_constants(params: SimParams, effects) -> dict[str, float]:
    """The vehicle's constants as this flight flew them: the vehicle file's, but the rotor lag, the command delay and
    the rotor drag the simulator's (``motor_lag``, ``input_delay``, ``rotor_drag``; 0 when switched off: the Crazyflie
    simulator flies an 8 ms delay where its vehicle file holds 20 ms)."""
    flown = {key: c.value for key, c in params.vehicle.constants.items()}
    drag = params.rotor_drag if "rotor_drag" in effects else None
    flown.update(rotor_time_constant=params.motor_time_constant if "motor_lag" in effects else 0.0,
                 rotor_delay=params.input_delay if "input_delay" in effects else 0.0,
                 rotor_drag_xy=drag.horizontal if drag else 0.0, rotor_drag_z=drag.vertical if drag else 0.0)
    return flown


def _notes(params: SimParams, effects, seed, script: PilotScript) -> dict:
    """What a tool needs to check its answer: effects, their parameters, the seed, the truth constants."""
    vehicle = params.vehicle
    return {
        "generator": "quad_modelling.core.sim.simulate",
        "sim_version": SIM_VERSION,
        "seed": seed,
        "effects": list(effects),
        "effects_off": [e for e in SIM_EFFECTS if e not in effects],
        "effect_parameters": params.effect_parameters(effects),
        "truth_constants": flown_constants(params, effects),
        "adjustments": params.adjustments,
        "esc": {"zero_speed_input": params.esc.zero_speed_input, "speed_gain": params.esc.speed_gain, "input_unit": vehicle.input_unit, "reference_voltage": params.battery.reference_voltage},
        "rates_hz": {"physics": params.physics_rate, "control": params.control.rate, "mocap": params.sensors.mocap_rate, "log": params.log_rate},
        "sensors": {k: float(v) if not isinstance(v, int) else v for k, v in vars(params.sensors).items()},
        "pilot": script.to_notes(),
        TRUTH_NOTES_KEY: params.truth_model_notes(),
    }
