"""The thesis's linear greybox model (chapter 3, DESIGN 6.1), restored equations.

State (16), deviations from hover:

.. math::

    x = [X, Y, Z,\\ \\dot X, \\dot Y, \\dot Z,\\ \\phi, \\theta, \\psi,\\
         \\dot\\phi, \\dot\\theta, \\dot\\psi,\\ T_1, T_2, T_3, T_4]

in N (NED) and Euler ZYX; :math:`T_i` is rotor i's thrust minus the hover
thrust :math:`T_H = m g / 4`; input :math:`u_i` is the trimmed engine command.

Motor/thrust (Eq 3-3 ... 3-7), with :math:`\\Omega_0 = \\sqrt{m g / (4 a)}`:

.. math::

    \\dot T_i = A_m T_i + K u_i, \\qquad K = 2 B_m \\sqrt{a m g / 4} = 2 a \\Omega_0 B_m

Translation, small angles (Eq 3-10):
:math:`\\ddot X = -g\\theta,\\ \\ddot Y = g\\phi,\\ \\ddot Z = -\\sum_i T_i / m`.

Torques from the motor positions :math:`(x_i, y_i)` in body FRD (a thrust
:math:`T_i` along :math:`-z_B` at :math:`(x_i, y_i, 0)` gives
:math:`r \\times F = (-y_i T_i,\\ x_i T_i,\\ 0)`); for the "+" frame this is
Eq 3-11/3-12, :math:`\\tau_\\phi = l (T_4 - T_2)`, :math:`\\tau_\\theta = l (T_1 - T_3)`:

.. math::

    \\tau_\\phi = -\\sum_i y_i T_i, \\qquad \\tau_\\theta = \\sum_i x_i T_i

Yaw (Eq 3-13 ... 3-16), :math:`s_i` = the config's ``yaw_sign`` (+1 = rotor
spins counter-clockwise seen from above; the thesis's :math:`(-1)^i` for the
LinkQuad, whose rotors 2 and 4 are ``ccw``):

.. math::

    \\tau_\\psi = \\frac{d}{a} \\sum_i s_i T_i + I_{prop} \\sum_i s_i \\dot\\Omega_i,
    \\qquad \\dot\\Omega_i = \\frac{A_m T_i}{2 a \\Omega_0} + B_m u_i

Angular (Eq 3-17): :math:`\\ddot\\phi = \\tau_\\phi / I_{xx}`,
:math:`\\ddot\\theta = \\tau_\\theta / I_{yy}`, :math:`\\ddot\\psi = \\tau_\\psi / I_{zz}`.

Outputs (Eq 3-21): :math:`Y = C x + D \\dot x = (C + D A) x + D B u`, the 18
variables of :data:`quad_modelling.core.variables.VARIABLES` (positions,
velocities, accelerations, angles, rates, angular accelerations).

Discretisation: explicit Euler as the thesis (Eq 3-19/20),
:math:`A_d = I + A\\,\\Delta t,\\ B_d = B\\,\\Delta t`, or exact zero-order hold
(:func:`quad_modelling.core.discretise.zero_order_hold`). Outputs at sample k use the continuous
derivative at :math:`(x_k, u_k)`, so :math:`C_d = C + D A`, :math:`D_d = D B`.

About Table 3-1 (LinkQuad): its constants are not mutually consistent (see
``config/vehicles/linkquad.yaml``); the model uses them as given: only the
products :math:`K`, :math:`d/a`, :math:`A_m/(2 a \\Omega_0)` and
:math:`I_{prop} B_m` enter it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from quad_modelling.core.discretise import zero_order_hold
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.discretise import motor_thrusts
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.preprocess import (
    TrimConfig,
    sample_period,
    smooth,
    state_measurement,
    trailing_means,
    trim_prediction,
    uniform_time_check,
)
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.physics.rigid_body import allocation_matrix
from quad_modelling.core.physics.rotors import hover_rotor_speed, thrust_slope
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError, DataError

STATES: tuple[str, ...] = (
    "X", "Y", "Z", "dX", "dY", "dZ", "phi", "theta", "psi", "dphi", "dtheta", "dpsi", "T1", "T2", "T3", "T4",
)
"""State names in order (positions, velocities, angles, rates, thrust deviations)."""

N_STATES = len(STATES)
DISCRETISATIONS = ("zoh", "euler")

MEASURED_STATE_COLUMNS = np.array([0, 1, 2, 3, 4, 5, 9, 10, 11, 12, 13, 14])
"""VARIABLES columns that give states 0..11 (pos, vel, angles, rates)."""


@dataclass(frozen=True)
class GreyboxParameters:
    """The constants the linear model uses, taken from a VehicleConfig (SI units)."""

    mass: float
    ixx: float
    iyy: float
    izz: float
    prop_inertia: float
    motor_a_m: float
    motor_b_m: float
    thrust_constant: float
    torque_constant: float
    motor_positions: tuple[tuple[float, float], ...]
    yaw_signs: tuple[float, ...]

    @classmethod
    def from_vehicle(cls, vehicle: VehicleConfig) -> GreyboxParameters:
        """The airframe's mass and inertias with the greybox constants A_m, B_m, a, d of
        :meth:`~quad_modelling.core.vehicle.VehicleConfig.greybox_constants`: the file's ``greybox`` section (thesis
        Table 3-1 for the LinkQuad reproduction), else derived from the physical rotor constants."""
        greybox = {key: c.value for key, c in vehicle.greybox_constants().items()}
        return cls(
            mass=vehicle.mass,
            ixx=vehicle.value("ixx"),
            iyy=vehicle.value("iyy"),
            izz=vehicle.value("izz"),
            prop_inertia=vehicle.value("prop_inertia"),
            motor_a_m=greybox["motor_a_m"],
            motor_b_m=greybox["motor_b_m"],
            thrust_constant=greybox["thrust_constant"],
            torque_constant=greybox["torque_constant"],
            motor_positions=tuple(map(tuple, vehicle.motor_positions.tolist())),
            yaw_signs=tuple(vehicle.yaw_signs.tolist()),
        )

    @property
    def hover_rotor_speed(self) -> float:
        """Ω0 = sqrt(m g / (4 a)) [rad/s] (:func:`~quad_modelling.core.physics.rotors.hover_rotor_speed`)."""
        return hover_rotor_speed(self.mass, self.thrust_constant, GRAVITY)

    @property
    def thrust_slope(self) -> float:
        """∂T/∂Ω at hover, 2 a Ω0 = 2 sqrt(a m g / 4) [N s/rad] (:func:`~quad_modelling.core.physics.rotors.thrust_slope`)."""
        return thrust_slope(self.thrust_constant, self.hover_rotor_speed)

    @property
    def input_gain(self) -> float:
        """K = 2 B_m sqrt(a m g / 4) = B_m ∂T/∂Ω: thrust-rate per unit trimmed command [N/s per unit]."""
        return float(self.motor_b_m * self.thrust_slope)

    def torque_matrix(self) -> np.ndarray:
        """(3, 4) map from rotor thrust deviations to (τφ, τθ, thrust part of τψ) [N m per N]: the torque rows of the
        one allocation (:func:`~quad_modelling.core.physics.rigid_body.allocation_matrix`)."""
        return allocation_matrix(self.motor_positions, self.yaw_signs, self.torque_constant / self.thrust_constant)[1:]


def continuous_matrices(p: GreyboxParameters) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continuous (A, B, C, D) with ẋ = A x + B u and Y = C x + D ẋ (module docstring)."""
    a = np.zeros((N_STATES, N_STATES))
    b = np.zeros((N_STATES, 4))
    a[0:3, 3:6] = np.eye(3)
    a[6:9, 9:12] = np.eye(3)
    a[3, 7] = -GRAVITY
    a[4, 6] = GRAVITY
    a[5, 12:16] = -1.0 / p.mass
    torque = p.torque_matrix()
    signs = np.array(p.yaw_signs)
    omega_per_thrust = p.motor_a_m / p.thrust_slope
    inertia = np.array([p.ixx, p.iyy, p.izz])
    a[9:12, 12:16] = torque / inertia[:, None]
    a[11, 12:16] += p.prop_inertia * signs * omega_per_thrust / p.izz
    b[11, :] = p.prop_inertia * signs * p.motor_b_m / p.izz
    a[12:16, 12:16] = p.motor_a_m * np.eye(4)
    b[12:16, :] = p.input_gain * np.eye(4)
    c = np.zeros((len(VARIABLES), N_STATES))
    d = np.zeros((len(VARIABLES), N_STATES))
    c[0:6, 0:6] = np.eye(6)  # positions, velocities
    d[6:9, 3:6] = np.eye(3)  # accelerations = d/dt velocities
    c[9:15, 6:12] = np.eye(6)  # angles, rates
    d[15:18, 9:12] = np.eye(3)  # angular accelerations = d/dt rates
    return a, b, c, d


@dataclass(frozen=True)
class DiscreteGreybox:
    """x[k+1] = Ad x[k] + Bd u[k];  y[k] = Cd x[k] + Dd u[k]  (sample period ``dt``)."""

    ad: np.ndarray
    bd: np.ndarray
    cd: np.ndarray
    dd: np.ndarray
    dt: float
    method: str

    def step(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Streaming form: (next state, the 18 outputs at this sample) for state ``x`` and trimmed input ``u``."""
        return self.ad @ x + self.bd @ u, self.cd @ x + self.dd @ u

    def simulate(self, x0: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (N, 16) and outputs (N, 18) for trimmed inputs ``u`` (N, 4) from ``x0``.

        Row k is the state at sample k (row 0 = ``x0``), the same numbers as
        calling :meth:`step` N times.
        """
        u = np.asarray(u, dtype=float)
        forced = u @ self.bd.T
        states = np.empty((len(u), N_STATES))
        x = np.asarray(x0, dtype=float)
        ad = self.ad
        for k in range(len(u)):
            states[k] = x
            x = ad @ x + forced[k]
        return states, states @ self.cd.T + u @ self.dd.T

    def motor_thrusts(self, u: np.ndarray) -> np.ndarray:
        """(N, 4) rotor thrust deviations driven by trimmed ``u`` alone, starting in steady state of u[0].

        The motor subsystem is decoupled from the rest (Eq 3-7), so this is the
        model's causal estimate of T_i at every sample.
        """
        return motor_thrusts(u, self.ad[12, 12], self.bd[12, 0])


PERIOD_DIGITS = 6
"""A sample period is rounded to 1 µs before discretising: a log's period is the median of its µs-jittered
steps, which differs in the last digits between a whole flight and the 2 s a live receding-horizon
predictor holds (bundled flight: 9.99999 ms vs 10.00002 ms); both must be the same model. Over a 10 s
window at 100 Hz the rounding moves the last sample's model time by at most 0.5 ms."""


class GreyboxModel:
    """The linear model of one vehicle; discretised matrices cached per sample period (rounded to
    :data:`PERIOD_DIGITS` decimals of a second)."""

    def __init__(self, vehicle: VehicleConfig | GreyboxParameters):
        self.parameters = vehicle if isinstance(vehicle, GreyboxParameters) else GreyboxParameters.from_vehicle(vehicle)
        self.a, self.b, self.c, self.d = continuous_matrices(self.parameters)

    def discretise(self, dt: float, method: str = "zoh") -> DiscreteGreybox:
        """Discrete model at sample period ``dt`` [s]: ``zoh`` (exact) or ``euler`` (thesis Eq 3-19/20)."""
        return _discretise(self.parameters, round(float(dt), PERIOD_DIGITS), method)


@lru_cache(maxsize=4096)
def _discretise(p: GreyboxParameters, dt: float, method: str) -> DiscreteGreybox:
    if method not in DISCRETISATIONS:
        raise ConfigError(f"greybox discretisation must be one of {', '.join(DISCRETISATIONS)}, got {method!r}")
    if not dt > 0:
        raise DataError(f"greybox: sample period must be positive, got {dt}")
    a, b, c, d = continuous_matrices(p)
    if method == "euler":
        ad, bd = np.eye(N_STATES) + a * dt, b * dt
    else:
        ad, bd = zero_order_hold(a, b, dt)
    for m in (ad, bd):
        m.setflags(write=False)
    return DiscreteGreybox(ad, bd, c + d @ a, d @ b, dt, method)


def anchor_state(measured_row: np.ndarray, thrusts: np.ndarray) -> np.ndarray:
    """State (16) from one row of the 18 variables (pos, vel, angles, rates) and thrust deviations (4)."""
    x = np.empty(N_STATES)
    x[:12] = np.asarray(measured_row)[..., MEASURED_STATE_COLUMNS]
    x[12:] = thrusts
    return x


def trim_motion(output_trim: np.ndarray) -> np.ndarray:
    """(18,) rate of change of the trim point: the trimmed velocity moves the position, the trimmed body rates the
    angles (:math:`\\dot p = \\bar v`, :math:`\\dot\\eta = \\bar\\omega`); zero for every other variable.

    The greybox predicts deviations from the warm rows' mean; its absolute pose
    :math:`y_{trim} + C x + \\tau\\,\\dot y_{trim}` (τ from the anchor) moves with the published velocity
    instead of standing at the warm rows' mean position until the next window re-anchors it. Positions
    and angles are not in the thesis tables (:data:`~quad_modelling.core.variables.EVAL_VARIABLES`).
    """
    motion = np.zeros(len(VARIABLES))
    motion[0:3] = output_trim[3:6]
    motion[9:12] = output_trim[12:15]
    return motion


THESIS_LABEL = "thesis reproduction"
"""What tables and docs call the greybox: the thesis's linear model (chapter 3) reproduced."""

THESIS_DESCRIPTION = (
    "greybox = thesis reproduction: the linear model of Sonntag 2011 chapter 3 (hover linearisation, "
    "first-order motors); windowed rows follow the thesis protocol (0.2 s warm start, trims per window); "
    "multi-step rows trim on the 1 s before each start (causal)"
)
"""One sentence for a report's model notes."""


STEP_TOLERANCE = 0.002
"""A live step within this fraction of the window's period dt is taken as dt: a uniform log's µs jitter (the
bundled flight: 0.06 %), so the offline numbers hold; any other step is discretised at its real length
(:meth:`GreyboxStream.push_at`). Taking a 5 % longer step as dt would leave the pose behind by 0.5 ms of
motion per step.
"""

STEP_QUANTUM_S = 1e-5
"""Real step lengths are rounded to this [s] before discretising (bounds the discretisation cache; the
time error is at most 5 µs per step, not accumulated: each step starts at the previous sample's stamp)."""


class GreyboxStream:
    """Live form of one greybox window after its warm start (:mod:`quad_modelling.core.models.streaming`).

    Holds the state x[k] and the trims; ``push(u_k)`` returns the absolute
    prediction ``y_trim + Cd x[k] + Dd (u_k - u_trim)`` and advances
    ``x[k+1] = Ad x[k] + Bd (u_k - u_trim)`` by the window's period dt.

    ``push_at(u_k, t_k)`` steps from the previous sample (state :math:`x_{k-1}`, input
    :math:`u_{k-1}` held over the step) to :math:`t_k`: with the window's matrices when
    :math:`|\\Delta t - dt| \\le` :data:`STEP_TOLERANCE` dt (then it equals ``push``), else with the
    model discretised at the real step :math:`\\Delta t = t_k - t_{k-1}` (rounded to
    :data:`STEP_QUANTUM_S`): :math:`x_k = A_d(\\Delta t) x_{k-1} + B_d(\\Delta t) u_{k-1}`. A jittered
    command timer (±2 ms at 100 Hz, a dropped command) is integrated over the time that really
    passed instead of refused.
    """

    def __init__(self, model: DiscreteGreybox, state: np.ndarray, input_trim: np.ndarray, output_trim: np.ndarray,
                 continuous: GreyboxModel | None = None, anchor: tuple[float, np.ndarray, np.ndarray] | None = None):
        self.model = model
        self.state = state
        self.input_trim = input_trim
        self.output_trim = output_trim
        self.motion = trim_motion(output_trim)
        self.elapsed = 0.0  # model time since the anchor [s]: the sum of the steps taken
        self.continuous = continuous
        # (time [s], state, trimmed input) of the last sample: what a step of another length starts from
        self.t_s, self.previous_state, self.previous_input = anchor if anchor is not None else (None, None, None)

    def push(self, command: np.ndarray) -> np.ndarray:
        u = np.asarray(command, dtype=float) - self.input_trim
        x = self.state
        self.state, outputs = self.model.step(x, u)
        self.previous_state, self.previous_input = x, u
        self.elapsed += self.model.dt
        if self.t_s is not None:
            self.t_s += self.model.dt
        return self.output_trim + outputs + self.elapsed * self.motion

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        if self.t_s is None or self.continuous is None:
            return self.push(command)
        dt = t_s - self.t_s
        if not dt > 0:
            raise DataError(f"greybox stream: sample time {t_s:.6f} s is not after the previous {self.t_s:.6f} s")
        model = self.model
        if abs(dt - model.dt) > STEP_TOLERANCE * model.dt:
            real = self.continuous.discretise(max(STEP_QUANTUM_S, round(dt / STEP_QUANTUM_S) * STEP_QUANTUM_S), model.method)
            self.state = real.ad @ self.previous_state + real.bd @ self.previous_input
            self.elapsed += real.dt - model.dt  # push adds the nominal step
        outputs = self.push(command)
        self.t_s = t_s
        return outputs


class GreyboxPredictor:
    """:class:`~quad_modelling.core.models.base.Predictor` and live streaming predictor for the linear greybox model.

    Causal, so that a live node and the offline evaluation give the same numbers
    (DESIGN 2): everything the model is given comes from the window's warm-start
    rows (the thesis's first 0.2 s) and the commands up to each sample.

    * Trims: input trim u_trim = mean of the warm commands; output trim
      y_trim = mean of the warm best measurements. (The thesis trimmed the inputs
      over the window's first second, which a live predictor cannot see yet;
      the evaluator still trims the outputs over the first second.)
    * Anchor: on the last warm sample, positions, velocities, angles and rates
      from the warm measurement minus y_trim, low-passed over the warm rows only;
      thrust deviations from the motor model driven by the warm commands.
    * Then open loop: ``x[k+1] = Ad x[k] + Bd (u_k - u_trim)``,
      ``y_k = y_trim + Cd x[k] + Dd (u_k - u_trim)``.

    :meth:`start_window`/``push`` are the live form; :meth:`predict_window`
    computes the same numbers vectorised and returns them trimmed
    (:func:`~quad_modelling.core.preprocess.trim_prediction`). This window mode is
    the **thesis reproduction** (:data:`THESIS_LABEL`): the thesis's model and
    windowed protocol, kept as they are. The multi-step form
    (:meth:`predict_horizons`) anchors each start on its own past rows.
    """

    label = THESIS_LABEL
    """Short tag a report shows next to the name: this model is the thesis's, reproduced."""

    description = THESIS_DESCRIPTION

    def __init__(self, vehicle: VehicleConfig, discretisation: str = "zoh", trim: TrimConfig | None = None):
        if discretisation not in DISCRETISATIONS:
            raise ConfigError(f"greybox discretisation must be one of {', '.join(DISCRETISATIONS)}, got {discretisation!r}")
        self.vehicle = vehicle
        self.model = GreyboxModel(vehicle)
        self.discretisation = discretisation
        self.trim = trim or TrimConfig()
        self.name = "greybox" if discretisation == "zoh" else f"greybox:{discretisation}"

    def discrete(self, log: FlightLog) -> DiscreteGreybox:
        uniform_time_check(log)
        return self.model.discretise(sample_period(log), self.discretisation)

    def _anchor(self, warm: FlightLog) -> tuple[DiscreteGreybox, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(model, warm predictions (W, 18), state after the anchor sample, input trim, output trim)."""
        return self._anchor_sample(warm)[:5]

    def _anchor_sample(self, warm: FlightLog, check_uniform: bool = True) -> tuple:
        """:meth:`_anchor` and (state at the anchor sample, its trimmed input); ``check_uniform`` False for the live
        form (dt = the warm rows' median step, whatever their jitter)."""
        if len(warm) < 2:
            raise DataError(f"{warm.meta.source}: the greybox needs at least 2 warm-start samples, got {len(warm)}")
        model = self.discrete(warm) if check_uniform else self.model.discretise(sample_period(warm), self.discretisation)
        measured = state_measurement(warm, self.vehicle)
        input_trim = warm.u.mean(axis=0)
        output_trim = measured.mean(axis=0)
        u = warm.u - input_trim
        deviation = smooth(measured - output_trim, warm.sample_rate)
        thrusts = model.motor_thrusts(u)[-1]
        x_anchor = anchor_state(deviation[-1], thrusts)
        state, anchor_outputs = model.step(x_anchor, u[-1])
        predictions = measured.copy()
        predictions[-1] = output_trim + anchor_outputs
        return model, predictions, state, input_trim, output_trim, (x_anchor, u[-1])

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, GreyboxStream]:
        """Warm rows -> (their absolute predictions (W, 18), stream for the following samples).

        The live form takes real timers: the warm rows' steps are not checked for uniformity
        (dt = their median step) and the stream's ``push_at`` integrates each real step."""
        model, predictions, state, input_trim, output_trim, (x_anchor, u_anchor) = self._anchor_sample(warm, check_uniform=False)
        return predictions, GreyboxStream(model, state, input_trim, output_trim, self.model,
                                          (float(warm.t[-1]), x_anchor, u_anchor))

    def predict_absolute(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) absolute prediction; equal to the streaming form (vectorised where every step is dt).

        A window whose real steps differ from dt by more than :data:`STEP_TOLERANCE` dt (jitter, a
        dropped row) is predicted by the streaming form itself, which discretises each step at its
        real length, so the offline evaluation equals what a live node publishes on the same rows."""
        if not 2 <= warm_samples < len(window):
            raise DataError(f"{window.meta.source}: warm start of {warm_samples} samples does not fit a window of {len(window)}")
        model, warm_predictions, state, input_trim, output_trim = self._anchor(window.slice(0, warm_samples))
        steps = np.diff(window.t[warm_samples - 1:])
        if np.any(np.abs(steps - model.dt) > STEP_TOLERANCE * model.dt):
            return predict_window_by_stream(self, window, warm_samples)
        _, outputs = model.simulate(state, window.u[warm_samples:] - input_trim)
        elapsed = np.zeros(len(outputs))
        for k in range(len(outputs)):  # the stream's running sum of steps, bit for bit
            elapsed[k] = (elapsed[k - 1] if k else 0.0) + model.dt
        return np.concatenate([warm_predictions, output_trim + outputs + elapsed[:, None] * trim_motion(output_trim)])

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) prediction in the evaluation's trimmed convention."""
        return trim_prediction(window, self.predict_absolute(window, warm_samples), self.trim)

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """Open-loop predictions from each start s (absolute, IDSIA multi-step protocol), causal.

        Everything the model is given at start s comes from rows <= s (the
        causality rule, docs/architecture.md), vectorised over starts. With
        :math:`P_s` = the last ``trim.trim_s`` seconds of rows up to and
        including s (the thesis's 1 s trim interval, ending at the anchor
        instead of starting at the window start; fewer rows near row 0):

        * input trim :math:`\\bar u_s` = mean of the commands over :math:`P_s`;
          roll/pitch offset :math:`(\\bar\\phi_s, \\bar\\theta_s)` = mean of the
          measured roll/pitch over :math:`P_s` (the hover attitude); no detrend;
        * start state: measured positions, velocities, yaw, rates of row s as
          they are (:func:`~quad_modelling.core.preprocess.state_measurement`,
          causal), roll/pitch minus their offset; thrust deviations
          :math:`T_s = M(u)_s - G \\bar u_s`, the motor filter :math:`M`
          (:func:`~quad_modelling.core.discretise.motor_thrusts`) run over the
          raw commands up to s, :math:`G = g / (1 - p)` its steady-state gain
          (linear, so this is the filter of :math:`u - \\bar u_s`);
        * then :math:`x_{h+1} = A_d x_h + B_d (u_{s+h} - \\bar u_s)`,
          :math:`y_{s+h} = C_d x_h + D_d (u_{s+h} - \\bar u_s)` plus the roll/pitch offset.

        The windowed mode (:meth:`predict_window`) is the thesis reproduction and is not changed by this.
        """
        model = self.discrete(segment)
        starts = np.asarray(starts, dtype=int)
        if starts.size and (starts.min() < 0 or starts.max() + horizon >= len(segment)):
            raise DataError(f"{segment.meta.source}: multi-step starts + horizon {horizon} leave the segment")
        rows = self.trim.trim_samples(segment)
        measured = state_measurement(segment, self.vehicle, causal=True)
        input_trim = trailing_means(segment.u, starts, rows)  # (S, 4)
        attitude_trim = trailing_means(measured[:, 9:11], starts, rows)  # (S, 2): roll, pitch
        pole, gain = model.ad[12, 12], model.bd[12, 0]
        reference = segment.u[0]  # any constant: M(u - c) = M(u) - G c
        thrusts = model.motor_thrusts(segment.u - reference)[starts] - (input_trim - reference) * (gain / (1.0 - pole))
        x = np.concatenate([measured[starts][:, MEASURED_STATE_COLUMNS], thrusts], axis=1)
        x[:, 6:8] -= attitude_trim
        rows = starts[:, None] + np.arange(horizon + 1)[None, :]
        return linear_horizons(model, x, segment.u[rows] - input_trim[:, None, :], attitude_trim)


def linear_horizons(model: DiscreteGreybox, x: np.ndarray, u: np.ndarray, attitude_trim: np.ndarray) -> np.ndarray:
    """(S, H + 1, 18) open-loop outputs of the multi-step form (:meth:`GreyboxPredictor.predict_horizons`; the
    carried-state forecast, :mod:`quad_modelling.core.live.forecast`, calls it too): from anchor states ``x``
    (S, 16) under trimmed inputs ``u`` (S, H + 1, 4), :math:`y_h = C_d x_h + D_d u_h`,
    :math:`x_{h+1} = A_d x_h + B_d u_h`, with the roll/pitch offset ``attitude_trim`` (S, 2) [rad] added back."""
    out = np.empty((len(x), u.shape[1], len(VARIABLES)))
    ad_t, bd_t, cd_t, dd_t = model.ad.T, model.bd.T, model.cd.T, model.dd.T
    for h in range(u.shape[1]):
        u_h = u[:, h]
        out[:, h] = x @ cd_t + u_h @ dd_t
        x = x @ ad_t + u_h @ bd_t
    out[:, :, 9:11] += attitude_trim[:, None, :]
    return out


def lifted_horizons(model: DiscreteGreybox, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`linear_horizons` of one anchor as two matrix products (the carried forecast's form): with
    :math:`x_{h+1} = A_d x_h + B_d u_h` unrolled,

    .. math:: y_h = C_d A_d^h x_0 + \\sum_{j<h} C_d A_d^{h-1-j} B_d u_j + D_d u_h = G_x[h] x_0 + G_u[h] \\mathrm{vec}(u),

    returned as ``G_x`` (H + 1, 18, 16) and ``G_u`` (H + 1, 18, 4 (H + 1)), u's rows 0..H stacked (blocks j > h zero).
    The same outputs to rounding (the products summed in another order), without the 2 (H + 1) small products of
    the recursion per anchor."""
    powers = [np.eye(N_STATES)]
    for _ in range(horizon):
        powers.append(model.ad @ powers[-1])
    g_x = np.array([model.cd @ a for a in powers])
    responses = [model.cd @ a @ model.bd for a in powers[:horizon]]  # C A^k B, k = 0 .. H - 1
    g_u = np.zeros((horizon + 1, len(VARIABLES), horizon + 1, model.bd.shape[1]))
    for h in range(horizon + 1):
        for j in range(h):
            g_u[h, :, j] = responses[h - 1 - j]
        g_u[h, :, h] = model.dd
    return g_x, g_u.reshape(horizon + 1, len(VARIABLES), -1)
