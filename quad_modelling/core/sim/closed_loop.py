"""The truth simulator flown by an outside controller, one control tick at a time (docs/mpc.md).

:func:`~quad_modelling.core.sim.simulate.run_simulation` flies the simulator's own pilot script and stabiliser;
:class:`TruthLoop` hands the engine commands to the caller instead: each :meth:`TruthLoop.tick` holds the given
commands for one control period (the stabiliser's, 1 / ``control.rate``), through the same command path (input
delay, ESC map with battery voltage and motor gains, motor lag or the rotor jump), battery drain and RK4 rigid
body as a simulated flight (:mod:`~quad_modelling.core.sim.simulate`, :mod:`~quad_modelling.core.sim.dynamics`).
The controller reads the true state (:meth:`TruthLoop.observation`: no sensor noise). No wind: its gusts are
drawn per flight (``wind`` is refused).

:func:`stabiliser_commands` is the simulator's own controller (its PID stabiliser with the pilot's position
hold) steered to a moving reference, the baseline an MPC is compared with.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from quad_modelling.core.effect_names import SIM_DEFAULT_EFFECTS, SIMULATOR, normalise_effect_names
from quad_modelling.core.sim.control import Stabiliser
from quad_modelling.core.sim.dynamics import QuadDynamics
from quad_modelling.core.sim.params import SimParams, sim_params_for
from quad_modelling.core.sim.simulate import battery_tick, esc_targets, initial_voltage, integrate_tick
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError

NO_WIND = (0.0, 0.0, 0.0)
"""Air velocity in N [m/s] of the closed loop (still air)."""


class TruthLoop:
    """The truth simulator in hover at CG height ``height`` [m], stepped by :meth:`tick` (module docstring)."""

    def __init__(self, vehicle: str | VehicleConfig = "linkquad", effects=SIM_DEFAULT_EFFECTS, height: float = 1.0,
                 params: SimParams | None = None):
        self.params = params or sim_params_for(vehicle)
        self.effects = normalise_effect_names(effects, SIMULATOR)
        if "wind" in self.effects:
            raise ConfigError("the closed-loop simulator runs in still air: leave out the wind effect")
        self.dynamics = QuadDynamics(self.params, self.effects)
        self.state = self.dynamics.hover_state(height)
        self.battery_on = "battery" in self.effects
        self.lag = "motor_lag" in self.effects
        self.soc = self.params.battery.initial_soc
        self.voltage = initial_voltage(self.params, self.battery_on)
        self.control_dt = 1.0 / self.params.control.rate
        self.steps_per_tick = int(round(self.params.physics_rate / self.params.control.rate))
        self.physics_dt = 1.0 / self.params.physics_rate
        self.delay_steps = int(round(self.params.input_delay * self.params.physics_rate)) if "input_delay" in self.effects else 0
        self.u_esc = list(self.dynamics.hover_commands(self.voltage))
        self.omega_cmd = self.dynamics.omega_command(self.u_esc, self.voltage)
        self.pending: deque = deque()
        self.step_index = 0

    def _apply(self, s: list, u) -> list[float]:
        """A delayed command ``u`` reaching the ESCs: their new targets (the rotors of ``s`` jump without lag)."""
        self.u_esc = u
        self.omega_cmd = esc_targets(self.dynamics, s, u, self.voltage, self.lag)
        return self.omega_cmd

    @property
    def t(self) -> float:
        """Time since the start [s]."""
        return self.step_index * self.physics_dt

    def tick(self, u) -> None:
        """Hold engine commands ``u`` (4,) [input unit, clipped to the vehicle's range] for one control period."""
        vehicle = self.params.vehicle
        u = [min(vehicle.input_max, max(vehicle.input_min, float(v))) for v in u]
        s = self.state
        if self.battery_on:
            self.soc, self.voltage = battery_tick(self.params.battery, self.dynamics.torque_constant, s[13:17], self.soc,
                                                  self.voltage, self.control_dt)
        first = self.step_index
        if self.delay_steps:
            self.pending.append((first + self.delay_steps, u))
        else:
            self.u_esc = u
        self.omega_cmd = esc_targets(self.dynamics, s, self.u_esc, self.voltage, self.lag)
        s = integrate_tick(self.dynamics, s, self.omega_cmd, NO_WIND, self.physics_dt, first, self.steps_per_tick,
                           self.pending, self._apply)
        self.state = s
        self.step_index = first + self.steps_per_tick
        if not np.all(np.isfinite(s)):
            raise ConfigError(f"closed-loop simulation diverged at t={self.t:.3f} s (non-finite state)")

    def observation(self) -> dict:
        """The true state: ``pos_n``, ``vel_n`` [m, m/s, NED], ``rot`` R_N<-B (3, 3), ``rates`` [rad/s, FRD], ``rotor``
        [rad/s] (command order), battery ``voltage`` [V]."""
        s = self.state
        return {"pos_n": np.array(s[0:3]), "vel_n": np.array(s[3:6]), "rot": QuadDynamics.rotation(s),
                "rates": np.array(s[10:13]), "rotor": np.array(s[13:17]), "voltage": float(self.voltage)}


def stabiliser_commands(stabiliser: Stabiliser, loop: TruthLoop, position_ref, velocity_ref, acceleration_ref, yaw_ref: float = 0.0):
    """The simulator's own controller tracking a moving reference: its pilot's position hold
    (:meth:`~quad_modelling.core.sim.control.Stabiliser.hold_position`) on the errors to the reference position
    ``position_ref`` and velocity ``velocity_ref`` [m, m/s, NED], with the reference's acceleration
    ``acceleration_ref`` [m/s², N] fed forward as roll/pitch references (φ = a_right/g, θ = -a_fwd/g, level yaw
    ``yaw_ref``) and its height as the altitude reference. Returns the engine commands (4,)."""
    s = list(loop.state)
    s[0:6] = [s[0] - position_ref[0], s[1] - position_ref[1], s[2], s[3] - velocity_ref[0], s[4] - velocity_ref[1], s[5] - velocity_ref[2]]
    cos_yaw, sin_yaw = np.cos(yaw_ref), np.sin(yaw_ref)
    forward = cos_yaw * acceleration_ref[0] + sin_yaw * acceleration_ref[1]
    right = -sin_yaw * acceleration_ref[0] + cos_yaw * acceleration_ref[1]
    refs = (right / GRAVITY, -forward / GRAVITY, yaw_ref, -position_ref[2])
    return stabiliser.flying(s, refs, loop.state[10:13], True)


def trimmed_stabiliser(loop: TruthLoop) -> Stabiliser:
    """The simulator's stabiliser for ``loop``, trimmed as a simulated flight's (:func:`~quad_modelling.core.sim.simulate.run_simulation`)."""
    stabiliser = Stabiliser(loop.params)
    stabiliser.set_trim(loop.dynamics.hover_commands(loop.params.battery.reference_voltage), loop.dynamics.hover_tilt())
    return stabiliser
