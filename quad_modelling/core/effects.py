"""Effect catalogue: identifiable nonlinear extensions of the linear greybox model (DESIGN 6.2).

Every effect is a small, documented change of the linear model of
:mod:`quad_modelling.core.greybox` with a few parameters identified from
training windows only. The forms are deliberately simpler than the truth
simulator's physics (:mod:`quad_modelling.core.sim_dynamics`): the diagnosis
asks "which missing term would close the gap", not "what is the exact physics".

The augmented model of one window (trimmed convention, state x of
:mod:`~quad_modelling.core.greybox`) is

.. math::

    \\dot x = (A + \\Delta A)\\, x + B\\, \\tilde u + F\\, e, \\qquad
    Y = C x + D \\dot x

* :math:`\\tilde u` = the trimmed engine commands after the effects' *input maps*
  (delay, gains, nonlinearity, drift, lag -- applied in that order);
* :math:`e = (\\ddot X, \\ddot Y, \\ddot Z, \\ddot\\phi, \\ddot\\theta, \\ddot\\psi)_{extra}`,
  extra accelerations [m/s², rad/s²] the effects add, driven by the window's
  measured *regime signals* (velocity, height, battery voltage, body rates) and
  minus their value at the trim interval (the trimmed convention: the trim is
  an equilibrium); F puts them on the velocity and rate states;
* :math:`\\Delta A`: effects linear in the state (centre-of-gravity offset).

Two outputs differ from :math:`Y = C x + D \\dot x` (:func:`predict_batch`): acc_x/y/z are the
modelled body force rotated by the *measured* attitude (plus g and :math:`e_{XYZ}`), and the offsets
of the angular accelerations are the gyro slope over the warm start.

Regime signals are measured, not predicted: an open-loop prediction drifts over
a window, and a drag force computed from a drifting predicted velocity would
"help" by damping that drift whether or not drag exists. Driving an effect by
the measured signal asks the sharper question -- does the residual follow the
effect's signature? -- and a null flight fits it to zero.

Symbols: :math:`u_i` trimmed command of rotor i, :math:`\\bar u_i` its trim
value (absolute command), :math:`u_{span}` = input max - input min of the
vehicle, :math:`t` time from the window start [s], :math:`v` measured trimmed
velocity in N [m/s], :math:`v_B = R_z(\\psi)^T v` its body-axes form, :math:`h`
measured height above the flight's lowest point [m], :math:`V` battery
voltage [V] (low-passed), :math:`V_{ref}` the mean voltage of the data the base
model was identified on, :math:`p, q, r` measured body rates [rad/s],
:math:`T_i` modelled thrust deviations [N], :math:`s_i` yaw signs.

=====================  ===================================================================  =====================
effect                 form                                                                 parameters
=====================  ===================================================================  =====================
rotor_drag             :math:`e_{XY} = -c_h v_{XY},\\ e_Z = -c_v v_Z,\\ e_\\phi = c_m v_{B,y},\\
                       e_\\theta = -c_m v_{B,x}` (rotor drag at the hub, its moment arm)      c_h, c_v [1/s], c_m [rad/s² per m/s]
battery                :math:`\\tilde u_i = u_i (1 + \\kappa (V_0 - V_{ref})) + \\sigma\\,u_{span} (V - V_0)`,
                       V_0 = trim voltage (gain ∝ V, sag coupling)                           κ [1/V], σ [1/V]
motor_lag              :math:`\\tau \\dot{\\tilde u}_i = u_i - \\tilde u_i` (extra first-order lag)   τ [s]
input_delay            :math:`\\tilde u_i(t) = u_i(t - \\delta)` (linear interpolation)            δ [s]
ground_effect          :math:`e_Z = -g\\,(G(h) - G(h_0)),\\ G(h) = c_{ge} / (h + h_{off})^2`
                       (Cheeseman-Bennett's :math:`(R/4h)^2` term)                          c_ge [m²], h_off [m]
gyroscopic             :math:`e_\\phi = k_b \\frac{I_{yy}-I_{zz}}{I_{xx}} q r + k_p \\frac{I_p}{I_{xx}} H q`,
                       :math:`e_\\theta = k_b \\frac{I_{zz}-I_{xx}}{I_{yy}} p r - k_p \\frac{I_p}{I_{yy}} H p`,
                       :math:`e_\\psi = k_b \\frac{I_{xx}-I_{yy}}{I_{zz}} p q`,
                       :math:`H = \\sum_i s_i T_i / (2 a \\Omega_0)`                          k_b, k_p [1]
thrust_nonlinearity    :math:`\\tilde u_i = u_i + \\beta\\, u_i^2 / u_{span}` (T = aΩ², Ω ∝ u)      β [1]
motor_imbalance        :math:`\\tilde u_i = (1 + \\epsilon_i) u_i,\\ \\epsilon_4 = -\\sum_{i<4}\\epsilon_i`;
                       :math:`\\Delta\\ddot\\phi = c_y \\sum T_i / I_{xx},\\
                       \\Delta\\ddot\\theta = -c_x \\sum T_i / I_{yy}` (CG offset c)              ε1..ε3 [1], c_x, c_y [m]
trim_drift             :math:`\\tilde u_i = u_i - r_i\\, u_{span}\\, (t - t_{trim})`              r1..r4 [1/s]
=====================  ===================================================================  =====================

:func:`prepare_windows` cuts and preprocesses windows once into a
:class:`WindowBatch` (all windows of equal length); :func:`predict_batch`
runs the augmented model on every window at once (one time loop over an
(W, 16) state array); :func:`fit_effects` identifies the parameters of a set
of effects by :func:`scipy.optimize.least_squares`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import linalg, optimize, signal

from quad_modelling.core import frames
from quad_modelling.core.evaluation import EvaluationConfig, SpanSpec, span_windows, warm_samples_for
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.greybox import MEASURED_STATE_COLUMNS, N_STATES, GreyboxParameters, continuous_matrices
from quad_modelling.core.preprocess import (
    differentiate,
    measured_variables,
    resample_uniform,
    smooth,
    trim_values,
    uniform_time_check,
)
from quad_modelling.core.variables import INDEX, VARIABLES
from quad_modelling.core.vehicle import GRAVITY, VehicleConfig
from quad_modelling.errors import ConfigError, DataError

REGIME_CUTOFF_HZ = 1.0
"""Low-pass of the height that drives ground effect [Hz] (it changes slowly; removes motion-capture noise).
Battery voltage keeps the evaluation bandwidth: its sag follows the throttle."""

COMMAND_HISTORY_S = 0.5
"""Commands kept from before each window [s] for the input maps with memory (lag, delay): a lag started in
steady state at the window's first command is wrong by exp(-t/tau) of the difference to the true rotor
state, and with the motors' 105 ms lag (LinkQuad) that error is still 15 % at the end of a 0.2 s warm start.
0.5 s is 5 time constants of that lag and beyond the catalogue's 0.2 s delay bound."""

GROUND_CONTACT_M = 0.01
"""A window whose height comes within 1 cm of the flight's lowest point -- where the vehicle
stood before take-off -- touches the ground and is left out: no model here has ground contact, and the
contact forces read as a height-dependent thrust. On a simulated effects-off flight whose low pass
touched down (test seed 2001), ground effect fitted the two contact windows and was 'found' with a
40 % shrink. The simulator's feet compress ~1 mm at rest (15 Hz gear); its ground-effect low passes
stay >= 1.1 cm above it.

The test uses the motion-capture height through a 5-sample running median (:data:`CONTACT_MEDIAN_SAMPLES`:
robust to a single bad sample, no smearing), not the 1 Hz regime signal, over the window and
:data:`CONTACT_GUARD_S` either side of it. With the zero-phase 1 Hz low-pass inside the window alone, on
150 s validation flights the window in which the vehicle touched down and the throttle was cut to idle
(an acc_z step of ~g in its last samples, the feet still 2 cm above their resting height) stayed in, and
pulled the base model's identification to a 70 ms motor time constant and the arm scale to its bound."""

CONTACT_MEDIAN_SAMPLES = 5
CONTACT_GUARD_S = 0.5
"""[s] either side of a window in which ground contact also excludes it (touchdown and lift-off transients,
the throttle cut when the feet meet the ground)."""

FIT_STRIDE = 4
"""Residual rows used when fitting: every 4th sample (25 Hz at 100 Hz, above the 5 Hz smoothing cutoff)."""

THRUST_DRIVEN = ("acc_z", "roll_acc", "pitch_acc", "yaw_acc")
"""The variables the rotor thrusts drive without integration: every effect on the command path acts on
them directly. Velocities, rates and attitude-driven horizontal accelerations integrate them, and over an
open-loop window their error is dominated by drift from the initial state; effects are fitted and scored on
the direct variables (the report shows every variable before/after)."""

TORQUE_DRIVEN = ("roll_acc", "pitch_acc", "yaw_acc")
"""The variables the *differential* thrusts drive. Motor imbalance changes only those: its gains sum to
zero (eps_4 = -(eps_1 + eps_2 + eps_3)), so the collective thrust, and acc_z, is unchanged to first order,
and its CG offset changes the roll and pitch rows of A only."""

COLLECTIVE = ("acc_z",)
"""The variable a change of the *collective* thrust drives. The battery's sag term adds the same command to
all four rotors (no torque: it moves acc_z only) and its gain term scales the commands by a few per cent,
which on the small differential commands behind roll/pitch/yaw is lost in their gap; scored on the four
thrust-driven variables its acc_z signature (a quarter to a half of the acc_z gap held out) was diluted to
4-5 % and the effect was never found in validation."""

FORCING_STATES = np.array([3, 4, 5, 9, 10, 11])
"""States (velocities, rates) the extra accelerations e act on."""


# ----------------------------------------------------------------------------- windows


@dataclass
class WindowBatch:
    """Equal-length windows of several flights, preprocessed once (SI units, N = NED, B = FRD).

    Arrays are (W, N, ...) for W windows of N samples. ``measured`` is the
    smoothed trimmed best measurement (the evaluation reference),
    ``anchor_states`` the 12 measured states (pos, vel, angles, rates) at the
    last warm sample, from the trimmed measurement low-passed over the warm
    samples only (as :class:`~quad_modelling.core.greybox.GreyboxPredictor`).
    """

    sources: list[str]
    t0: np.ndarray  # (W,) window start [s from the flight's first sample]
    dt: float
    warm: int
    u: np.ndarray  # (W, N, 4) trimmed commands
    u_history: np.ndarray  # (W, H, 4) trimmed commands of the H samples before each window (COMMAND_HISTORY_S)
    u_trim: np.ndarray  # (W, 4) trim values (absolute commands)
    u_span: float
    measured: np.ndarray  # (W, N, 18)
    anchor_states: np.ndarray  # (W, 12)
    velocity: np.ndarray  # (W, N, 3) smoothed trimmed velocity in N
    velocity_abs: np.ndarray  # (W, N, 3) absolute velocity in N
    velocity_smooth: np.ndarray  # (W, N, 3) absolute velocity in N, smoothed as ``measured``
    euler: np.ndarray  # (W, N, 3) absolute attitude (yaw unwrapped)
    rates: np.ndarray  # (W, N, 3) absolute gyro rates, smoothed
    height: np.ndarray  # (W, N) above the flight's lowest point, low-passed
    vbat: np.ndarray | None  # (W, N) low-passed, or None when a flight has no voltage
    input_min: float

    def __len__(self) -> int:
        return len(self.sources)

    @property
    def samples(self) -> int:
        return self.u.shape[1]

    offsets: np.ndarray = None  # (W, 18) linearisation point (warm-start mean) minus the window trim
    warm_rows: np.ndarray = None  # (W, warm, 18) unsmoothed measurement of the warm start minus the window trim
    trim_samples: int = 100  # rows of the trim interval
    ground_contact_dropped: int = 0  # windows left out because the vehicle touched the ground (GROUND_CONTACT_M)
    smooth_cutoff_hz: float = 5.0  # the evaluation low-pass ``measured`` went through [Hz]
    specific_force0: np.ndarray = None  # (W, 3) measured body specific force, mean over the warm start [m/s², B]
    acc_trim: np.ndarray = None  # (W, 3) window trim of acc_x/y/z (absolute, N) [m/s²]
    angacc_trim: np.ndarray = None  # (W, 3) window trim of roll/pitch/yaw acceleration [rad/s²]

    def subset(self, index: np.ndarray) -> WindowBatch:
        """The windows at ``index`` (same preprocessing)."""
        index = np.asarray(index, dtype=int)
        picked = {}
        for name in ("t0", "u", "u_history", "u_trim", "measured", "anchor_states", "velocity", "velocity_abs", "velocity_smooth", "euler", "rates", "height", "warm_rows", "offsets",
                     "specific_force0", "acc_trim", "angacc_trim"):
            picked[name] = getattr(self, name)[index]
        picked["vbat"] = None if self.vbat is None else self.vbat[index]
        return replace(self, sources=[self.sources[i] for i in index], **picked)


def flying_span(text: str = "0%:100%") -> SpanSpec:
    """The span of each flight the diagnosis uses (relative to its flying part by default)."""
    return SpanSpec.parse("diagnosis", text)


def prepare_windows(
    flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig, span: SpanSpec | None = None
) -> WindowBatch:
    """Cut each flight's ``span`` (after the take-off/landing drops of ``config``) into windows and preprocess them;
    windows that touch the ground (:data:`GROUND_CONTACT_M`) are left out and counted.

    DataError when no window fits.
    """
    span = span or flying_span()
    windows: list[FlightLog] = []
    starts: list[float] = []
    grounds: list[float] = []
    histories: list[np.ndarray] = []  # absolute commands before each window, rows [start - H, start)
    contact_height: list[float] = []  # lowest height above ground in and around each window [m]
    for log in flights:
        log = resample_uniform(log)
        uniform_time_check(log)
        ground = float(np.max(log.pos_n[:, 2]))  # NED: the lowest point of the flight
        h = int(round(COMMAND_HISTORY_S * log.sample_rate))
        guard = int(round(CONTACT_GUARD_S * log.sample_rate))
        height_above_ground = signal.medfilt(ground - log.pos_n[:, 2], CONTACT_MEDIAN_SAMPLES)
        for w in span_windows(log, span, config):
            windows.append(log.slice(w.start, w.stop))
            contact_height.append(float(np.min(height_above_ground[max(w.start - guard, 0) : w.stop + guard])))
            starts.append(float(log.t[w.start] - log.t[0]))
            grounds.append(ground)
            before = log.u[max(w.start - h, 0) : w.start]
            pad = np.repeat(log.u[w.start : w.start + 1], h - len(before), axis=0)  # flight starts: repeat the first command
            histories.append(np.concatenate([pad, before]))
    if not windows:
        durations = ", ".join(f"{log.duration:.1f} s" for log in flights)
        raise DataError(
            f"no {config.window_s:g} s window fits span {span.text()} after dropping {config.drop_start:g} s/"
            f"{config.drop_end:g} s (flight durations {durations}); shorten --window or the drops"
        )
    lengths = {len(w) for w in windows}
    n = min(lengths)
    rates = np.array([w.sample_rate for w in windows])
    if rates.max() > 1.01 * rates.min():
        raise DataError(f"flights have different sample rates ({rates.min():.2f}..{rates.max():.2f} Hz); resample them to one rate first")
    rate = float(np.median(rates))
    dt = 1.0 / rate
    warm = warm_samples_for(windows[0].slice(0, n), config.warm_s)
    trim_rows = config.trim.trim_samples(windows[0].slice(0, n))
    has_vbat = all(w.vbat is not None for w in windows)
    u, u_trim, measured, anchors, offsets, vel, vel_abs, vel_smooth, euler, rates_b, height, vbat, warm_rows = ([] for _ in range(13))
    u_history, force0, acc_trims, angacc_trims = [], [], [], []
    history_rows = min(len(h) for h in histories)
    for w, ground, history in zip(windows, grounds, histories):
        w = w.slice(0, n)
        raw = measured_variables(w)
        window_trim = trim_values(raw, trim_rows)
        measured.append(smooth(raw - window_trim, rate, config.smooth_cutoff_hz))
        # linearisation point: the warm start (as GreyboxPredictor._anchor)
        warm_log = w.slice(0, warm)
        warm_measured = measured_variables(warm_log)
        output_trim = warm_measured.mean(axis=0)
        input_trim = warm_log.u.mean(axis=0)
        anchors.append(smooth(warm_measured - output_trim, rate)[-1, MEASURED_STATE_COLUMNS])
        offsets.append(output_trim - window_trim)
        force0.append(warm_log.acc_b.mean(axis=0))
        acc_trims.append(window_trim[6:9])
        angacc_trims.append(window_trim[15:18])
        warm_rows.append(warm_measured - window_trim)
        u.append(w.u - input_trim)
        u_history.append(history[len(history) - history_rows :] - input_trim)
        u_trim.append(input_trim)
        vel.append(smooth(raw[:, 3:6] - output_trim[3:6], rate, config.smooth_cutoff_hz))
        vel_abs.append(raw[:, 3:6])
        vel_smooth.append(smooth(raw[:, 3:6], rate, config.smooth_cutoff_hz))
        euler.append(raw[:, 9:12])
        rates_b.append(smooth(raw[:, 12:15], rate, config.smooth_cutoff_hz))
        height.append(smooth(ground - w.pos_n[:, 2], rate, REGIME_CUTOFF_HZ))
        if has_vbat:
            vbat.append(smooth(w.vbat, rate, config.smooth_cutoff_hz))  # sag follows the throttle: keep its bandwidth
    batch = WindowBatch(
        sources=[w.meta.source for w in windows], t0=np.array(starts), dt=dt, warm=warm,
        u=np.array(u), u_history=np.array(u_history).reshape(len(u), history_rows, 4), u_trim=np.array(u_trim), u_span=float(vehicle.input_max - vehicle.input_min),
        measured=np.array(measured), anchor_states=np.array(anchors), offsets=np.array(offsets), velocity=np.array(vel), velocity_abs=np.array(vel_abs),
        velocity_smooth=np.array(vel_smooth),
        euler=np.array(euler), rates=np.array(rates_b), height=np.array(height), vbat=np.array(vbat) if has_vbat else None,
        input_min=float(vehicle.input_min), warm_rows=np.array(warm_rows), trim_samples=trim_rows,
        smooth_cutoff_hz=float(config.smooth_cutoff_hz),
        specific_force0=np.array(force0), acc_trim=np.array(acc_trims), angacc_trim=np.array(angacc_trims),
    )
    airborne = np.array(contact_height) >= GROUND_CONTACT_M
    if not airborne.any():
        raise DataError(f"every {config.window_s:g} s window touches the ground (height within {GROUND_CONTACT_M * 100:g} cm of the "
                        f"flight's lowest point); nothing to diagnose")
    if airborne.all():
        return batch
    return replace(batch.subset(np.where(airborne)[0]), ground_contact_dropped=int(np.sum(~airborne)))


# ----------------------------------------------------------------------------- augmented model


@dataclass
class Augmentation:
    """What a set of effects does to the linear model on a batch (module docstring)."""

    u: np.ndarray  # (W, N, 4) commands after the input maps
    forcing: np.ndarray  # (W, N, 6) extra accelerations e
    a_delta: np.ndarray  # (16, 16) added to the continuous A


@dataclass(frozen=True)
class Effect:
    """One catalogue entry.

    ``input_map(theta, batch, base, u) -> u`` changes the commands (stage
    ``stage``: 0 delay, 1 static gains/drift, 2 nonlinearity, 3 lag);
    ``forcing(theta, batch, base, u) -> (W, N, 6)`` adds accelerations (``u`` =
    the mapped commands); ``a_delta(theta, base) -> (16, 16)`` changes A.
    ``needs``: regime signals required (``"vbat"``). ``variables``: the candidate variables the form can
    change; the effect is fitted on all of them and scored on those its fitted correction moves
    (:func:`quad_modelling.core.diagnosis.affected_variables`).
    """

    name: str
    summary: str
    parameters: tuple[str, ...]
    units: tuple[str, ...]
    initial: tuple[float, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    variables: tuple[str, ...]
    stage: int = 1
    input_map: Callable | None = None
    forcing: Callable | None = None
    a_delta: Callable | None = None
    needs: tuple[str, ...] = ()

    def applicable(self, batch: WindowBatch) -> str | None:
        """None when the effect can be evaluated on ``batch``, else the reason why not."""
        if "vbat" in self.needs and batch.vbat is None:
            return "no battery voltage in the flights"
        return None


@dataclass
class BaseModel:
    """Continuous linear model pieces of :mod:`~quad_modelling.core.greybox` for one parameter set."""

    parameters: GreyboxParameters
    reference_voltage: float | None = None  # V_ref: mean battery voltage of the data the base was identified on [V]
    a: np.ndarray = field(init=False)
    b: np.ndarray = field(init=False)
    c: np.ndarray = field(init=False)
    d: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.a, self.b, self.c, self.d = continuous_matrices(self.parameters)

    @property
    def thrust_to_speed(self) -> float:
        """dΩ/dT at hover = 1 / (2 a Ω0) [rad/s per N]."""
        p = self.parameters
        return 1.0 / (2.0 * p.thrust_constant * p.hover_rotor_speed)


def _forcing_matrix() -> np.ndarray:
    f = np.zeros((N_STATES, 6))
    f[FORCING_STATES, np.arange(6)] = 1.0
    return f


_DISCRETE_CACHE: dict = {}
_DISCRETE_CACHE_SIZE = 64


def _discretise(a: np.ndarray, b_ext: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order hold of (A, [B F]) via one matrix exponential (memoised: a fit calls it with the
    same matrices for every effect that leaves A alone)."""
    key = (a.tobytes(), b_ext.tobytes(), float(dt))
    hit = _DISCRETE_CACHE.get(key)
    if hit is not None:
        return hit
    if len(_DISCRETE_CACHE) >= _DISCRETE_CACHE_SIZE:
        _DISCRETE_CACHE.pop(next(iter(_DISCRETE_CACHE)))
    _DISCRETE_CACHE[key] = result = _expm_hold(a, b_ext, dt)
    return result


def _expm_hold(a: np.ndarray, b_ext: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    n, m = a.shape[0], b_ext.shape[1]
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a * dt
    block[:n, n:] = b_ext * dt
    e = linalg.expm(block)
    return e[:n, :n], e[:n, n:]


def apply_effects(effects: Sequence[Effect], thetas: Sequence[np.ndarray], batch: WindowBatch, base: BaseModel) -> Augmentation:
    """Compose the effects' input maps (by stage), forcings and A changes on ``batch``.

    The mapped commands are trimmed again by their warm-start mean, as the forcings are: the linearisation
    point is the warm start, where the measured outputs (the output trim) answer the thrust the *mapped*
    commands gave, not the raw commands' mean. Without this, a lag (or delay) applied to commands that
    move during the warm start biases the whole window by the difference of the two means.
    """
    u = batch.u
    mapped = False
    for stage in range(4):
        for effect, theta in zip(effects, thetas):
            if effect.input_map is not None and effect.stage == stage:
                u = effect.input_map(theta, batch, base, u)
                mapped = True
    if mapped:
        u = u - u[:, : batch.warm].mean(axis=1, keepdims=True)
    forcing = np.zeros(batch.u.shape[:2] + (6,))
    a_delta = np.zeros((N_STATES, N_STATES))
    for effect, theta in zip(effects, thetas):
        if effect.forcing is not None:
            forcing = forcing + effect.forcing(theta, batch, base, u)
        if effect.a_delta is not None:
            a_delta = a_delta + effect.a_delta(theta, base)
    return Augmentation(u, forcing, a_delta)


def _motor_thrusts(u: np.ndarray, pole: float, gain: float) -> np.ndarray:
    steady = gain / (1.0 - pole) * u[:, 0, :]
    zi = steady[:, None, :]
    y, _ = signal.lfilter([0.0, gain], [1.0, -pole], u, axis=1, zi=zi)
    return y


def predict_batch(
    base: BaseModel, batch: WindowBatch, effects: Sequence[Effect] = (), thetas: Sequence[np.ndarray] = (), smoothed: bool = True,
    smooth_cutoff_hz: float | None = None, columns: Sequence[int] | None = None, greybox_outputs: bool = False,
) -> np.ndarray:
    r"""(W, N, 18) trimmed predictions of the (augmented) model for every window of ``batch``.

    Rows before the anchor (last warm sample) are the measurement, as the
    greybox predictor does; ``smoothed`` passes the prediction through what the
    measurement went through, so the result compares directly with
    ``batch.measured``: the angular accelerations, measured as Savitzky-Golay
    derivatives of the gyro rates (:func:`~quad_modelling.core.preprocess.differentiate`,
    a 0.11 s window that low-passes them), are integrated (trapezoid) and
    differentiated by the same filter (:func:`measurement_filter`), then every
    column gets the evaluation's low-pass (cutoff ``smooth_cutoff_hz``, default
    the batch's). ``columns`` limits the output to those VARIABLES columns
    (others are zero) to save time.

    Two outputs differ from the linear greybox's (``greybox_outputs=True`` keeps
    the greybox's, as :class:`~quad_modelling.core.greybox.GreyboxPredictor`):

    * **accelerations acc_x/y/z** (:func:`_projected_accelerations`): the
      modelled body specific force -- the measured warm-start level plus the
      thrust-state deviation :math:`-\sum_i T_i/m` on body z -- rotated into N by the
      *measured* attitude of each sample, plus g and the effects' forcings in N.
      The greybox's :math:`\ddot X = -g\theta` integrates its angular
      accelerations twice, and over a 5 s open-loop window that drift made the
      acc_x/acc_y error ~8 m/s² RMS on effects-off flights (0.02 m/s² of it noise);
      its :math:`\ddot Z = -\sum T_i/m` drops the tilt (small-angle
      linearisation). With the attitude measured, as the effects' regime signals
      are, accelerations are driven by the forces without integration;
    * **offsets of roll/pitch/yaw acceleration** (the linearisation point,
      :func:`_angular_acceleration_offsets`): the least-squares slope of the raw
      gyro over the warm start instead of the mean of the differentiated gyro over 0.2 s, whose noise
      (the difference of two noisy rates over 0.2 s, ~0.02 rad/s²) stayed in the
      prediction as a constant error for the whole window.
    """
    aug = apply_effects(effects, thetas, batch, base) if effects else Augmentation(batch.u, np.zeros(batch.u.shape[:2] + (6,)), None)
    a = base.a if aug.a_delta is None else base.a + aug.a_delta
    b_ext = np.hstack([base.b, _forcing_matrix()])
    ad, bd_ext = _discretise(a, b_ext, batch.dt)
    cd = base.c + base.d @ a
    dd_ext = base.d @ b_ext
    w, n = batch.u.shape[:2]
    anchor = batch.warm - 1
    inputs = np.concatenate([aug.u, aug.forcing], axis=2)  # (W, N, 10)
    pole, gain = ad[12, 12], bd_ext[12, 0]
    thrust0 = _motor_thrusts(aug.u[:, : anchor + 1], pole, gain)[:, anchor]
    offsets = batch.offsets
    if not greybox_outputs and anchor >= 2:
        offsets = offsets.copy()
        offsets[:, ANGULAR_ACCELERATION_COLUMNS] = _angular_acceleration_offsets(batch)
    x = np.concatenate([batch.anchor_states, thrust0], axis=1)
    forced = inputs @ bd_ext.T  # (W, N, 16)
    states = np.zeros((w, n, N_STATES))
    ad_t = ad.T.copy()
    for k in range(anchor, n):
        states[:, k] = x
        x = x @ ad_t + forced[:, k]
    cols = np.arange(len(VARIABLES)) if columns is None else np.asarray(columns, dtype=int)
    out = np.zeros((w, n, len(VARIABLES)))
    out[:, anchor:, cols] = states[:, anchor:] @ cd[cols].T + inputs[:, anchor:] @ dd_ext[cols].T + offsets[:, None, cols]
    acc_cols = [c for c in ACCELERATION_COLUMNS if c in set(cols.tolist())]
    if not greybox_outputs and acc_cols:
        acc_n = _projected_accelerations(batch, base, states[:, anchor:, 12:16], aug.forcing[:, anchor:, 0:3], anchor)
        out[:, anchor:, acc_cols] = acc_n[:, :, [c - ACCELERATION_COLUMNS[0] for c in acc_cols]]
    if anchor > 0:  # rows before the anchor are the measurement (not scored), as the greybox predictor
        out[:, :anchor, cols] = batch.warm_rows[:, :anchor][:, :, cols]
    if smoothed:
        cutoff = smooth_cutoff_hz if smooth_cutoff_hz is not None else batch.smooth_cutoff_hz
        measurement_filter(out, batch.dt, cols)
        out[:, :, cols] = smooth(out[:, :, cols].transpose(1, 0, 2), 1.0 / batch.dt, cutoff).transpose(1, 0, 2)
    return out


def _angular_acceleration_offsets(batch: WindowBatch) -> np.ndarray:
    r"""(W, 3) linearisation point of roll/pitch/yaw acceleration, window-trimmed [rad/s²]: the least-squares
    slope of the raw gyro rates over the warm start.

    The greybox takes the mean of the differentiated gyro over the 0.2 s warm start, which is nearly the
    difference of the first and last rates over 0.2 s: with the simulator's 0.003 rad/s gyro noise
    ~0.02 rad/s², a constant error for the whole window as large as the base model's whole effects-off gap.
    The slope over the 20 samples has ~0.012 rad/s² (0.003 / sqrt(sum (t - t_mean)^2)). On effects-off
    validation flights (3 seeds) the base model's roll/pitch/yaw acceleration gap fell from
    0.025/0.032/0.026 to 0.024/0.028/0.020 rad/s² (bench/results/diagnose_floor.md, 5 Hz). Tried and not kept: the slope net of the model's own
    rate response over the warm start (0.022/0.025/0.019 rad/s²), because fitted with the base model's
    response it absorbed part of an input delay (fitted 16-17 ms of the simulator's 20 ms), and motor lag
    then outranked input delay on one validation seed.
    """
    y = batch.warm_rows[:, :, RATE_COLUMNS]
    t = (np.arange(batch.warm) - (batch.warm - 1) / 2.0) * batch.dt
    return np.einsum("k,wkj->wj", t, y - y.mean(axis=1, keepdims=True)) / (t @ t) - batch.angacc_trim


def _projected_accelerations(batch: WindowBatch, base: BaseModel, thrusts: np.ndarray, forcing_n: np.ndarray, anchor: int) -> np.ndarray:
    r"""(W, M, 3) trimmed acc_x/y/z [m/s², N] from the anchor on: :math:`R(\eta_m)\, f_B + g e_z + e_{XYZ} - \text{trim}`.

    :math:`f_B = f_{B,0} + (0, 0, -\sum_i T_i / m)`: :math:`f_{B,0}` the measured
    body specific force averaged over the warm start (accelerometer bias
    included, so it cancels), :math:`T_i` the thrust states (``thrusts``, (W, M, 4));
    :math:`R(\eta_m)` the measured attitude of each sample (the one the
    accelerometer is rotated with, :func:`~quad_modelling.core.preprocess.nav_acceleration`),
    so the residual is the body-frame force residual rotated into N;
    :math:`e_{XYZ}` the effects' extra accelerations in N (``forcing_n``).
    """
    w, m = thrusts.shape[:2]
    mass = base.parameters.mass
    f_b = np.repeat(batch.specific_force0[:, None, :], m, axis=1)
    f_b[:, :, 2] -= thrusts.sum(axis=2) / mass
    rot = frames.euler_ned_to_matrix(batch.euler[:, anchor:].reshape(-1, 3)).reshape(w, m, 3, 3)
    acc = np.einsum("wkij,wkj->wki", rot, f_b)
    acc[:, :, 2] += GRAVITY
    return acc + forcing_n - batch.acc_trim[:, None, :]


ANGULAR_ACCELERATION_COLUMNS = np.array([INDEX[v] for v in ("roll_acc", "pitch_acc", "yaw_acc")])
ACCELERATION_COLUMNS = np.array([INDEX[v] for v in ("acc_x", "acc_y", "acc_z")])
RATE_COLUMNS = np.array([INDEX[v] for v in ("roll_rate", "pitch_rate", "yaw_rate")])


def measurement_filter(predicted: np.ndarray, dt: float, columns: np.ndarray) -> None:
    """In place: predicted angular accelerations (W, N, 18) as the measurement sees them.

    The measured angular acceleration is the Savitzky-Golay derivative of the
    gyro rates; the model's is the exact derivative of its rates. The same
    operator is applied to the model: its angular acceleration is integrated
    (cumulative trapezoid; the constant drops out of the derivative) and
    differentiated by :func:`~quad_modelling.core.preprocess.differentiate`.
    """
    picked = [c for c in ANGULAR_ACCELERATION_COLUMNS if c in set(np.asarray(columns).tolist())]
    if not picked:
        return
    acc = predicted[:, :, picked]
    rate = np.concatenate([np.zeros_like(acc[:, :1]), np.cumsum(0.5 * (acc[:, 1:] + acc[:, :-1]) * dt, axis=1)], axis=1)
    predicted[:, :, picked] = differentiate(rate.transpose(1, 0, 2), dt).transpose(1, 0, 2)


def window_rms(batch: WindowBatch, predicted: np.ndarray, columns: Sequence[int] | None = None) -> np.ndarray:
    """(W, k) RMS error per window over the scored rows (after the warm start)."""
    cols = np.arange(len(VARIABLES)) if columns is None else np.asarray(columns, dtype=int)
    err = batch.measured[:, batch.warm :, cols] - predicted[:, batch.warm :, cols]
    return np.sqrt(np.mean(err**2, axis=1))


def window_tic(batch: WindowBatch, predicted: np.ndarray, columns: Sequence[int] | None = None) -> np.ndarray:
    """(W, k) Theil inequality coefficient per window over the scored rows."""
    cols = np.arange(len(VARIABLES)) if columns is None else np.asarray(columns, dtype=int)
    m = batch.measured[:, batch.warm :, cols]
    p = predicted[:, batch.warm :, cols]
    num = np.sqrt(np.mean((m - p) ** 2, axis=1))
    den = np.sqrt(np.mean(m**2, axis=1)) + np.sqrt(np.mean(p**2, axis=1))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


# ----------------------------------------------------------------------------- the catalogue


def _trim_mean(values: np.ndarray, rows: int) -> np.ndarray:
    """Mean over the first ``rows`` samples (the warm start, the model's linearisation point) along axis 1, kept."""
    return values[:, :rows].mean(axis=1, keepdims=True)


def _drag_forcing(theta, batch: WindowBatch, base: BaseModel, u):
    """Drag of the absolute measured velocity, rotated into body axes sample by sample, minus its warm-start
    value. (Rotating the *trimmed* velocity v - v_0 by the current yaw is wrong in a turn flown at speed:
    the body-axes velocity changes as the heading turns even when the velocity in N does not.)"""
    c_h, c_v, c_m = theta
    v = batch.velocity_smooth
    yaw = batch.euler[:, :, 2]
    cos, sin = np.cos(yaw), np.sin(yaw)
    v_bx = cos * v[:, :, 0] + sin * v[:, :, 1]
    v_by = -sin * v[:, :, 0] + cos * v[:, :, 1]
    e = np.zeros(v.shape[:2] + (6,))
    e[:, :, 0] = -c_h * v[:, :, 0]
    e[:, :, 1] = -c_h * v[:, :, 1]
    e[:, :, 2] = -c_v * v[:, :, 2]
    e[:, :, 3] = c_m * v_by
    e[:, :, 4] = -c_m * v_bx
    return e - _trim_mean(e, batch.warm)


def _battery_map(theta, batch: WindowBatch, base: BaseModel, u):
    kappa, sigma = theta
    v = batch.vbat
    v0 = _trim_mean(v, batch.warm)  # (W, 1)
    v_ref = base.reference_voltage if base.reference_voltage is not None else float(v.mean())
    gain = 1.0 + kappa * (v0 - v_ref)
    return u * gain[:, :, None] + (sigma * batch.u_span * (v - v0))[:, :, None]


def _lag_map(theta, batch: WindowBatch, base: BaseModel, u):
    r""":math:`\tilde u_k = p \tilde u_{k-1} + (1 - p) u_k`, :math:`p = e^{-\Delta t/\tau}`: the lag without an
    added sample of delay (τ -> 0 gives the identity), run over the commands before the window
    (``u_history``, in steady state at its first sample) so that the window starts from the lagged state."""
    tau = float(theta[0])
    pole = float(np.exp(-batch.dt / max(tau, 1e-6)))
    history = batch.u_history
    zi = pole * (history[:, :1, :] if history.shape[1] else u[:, :1, :])
    if history.shape[1]:
        _, zi = signal.lfilter([1.0 - pole], [1.0, -pole], history, axis=1, zi=zi)
    y, _ = signal.lfilter([1.0 - pole], [1.0, -pole], u, axis=1, zi=zi)
    return y


def _delay_map(theta, batch: WindowBatch, base: BaseModel, u):
    """u(t - delay), linear interpolation; the samples before the window come from ``u_history`` (the first
    command repeated beyond it)."""
    shift = max(float(theta[0]), 0.0) / batch.dt
    whole = int(np.floor(shift))
    frac = shift - whole
    n = u.shape[1]
    history = batch.u_history[:, max(batch.u_history.shape[1] - (whole + 1), 0) :]
    first = history[:, :1] if history.shape[1] else u[:, :1]
    padded = np.concatenate([np.repeat(first, whole + 1 - history.shape[1], axis=1), history, u], axis=1)
    later = padded[:, 1 : n + 1]  # u[k - whole]
    earlier = padded[:, 0:n]  # u[k - whole - 1]
    return (1.0 - frac) * later + frac * earlier


def _ground_forcing(theta, batch: WindowBatch, base: BaseModel, u):
    c_ge, h_off = theta
    g = c_ge / (np.maximum(batch.height, 0.0) + h_off) ** 2
    e = np.zeros(batch.height.shape + (6,))
    e[:, :, 2] = -GRAVITY * (g - _trim_mean(g, batch.warm))
    return e


def _gyro_forcing(theta, batch: WindowBatch, base: BaseModel, u):
    k_body, k_prop = theta
    p_ = base.parameters
    ixx, iyy, izz = p_.ixx, p_.iyy, p_.izz
    rp, rq, rr = batch.rates[:, :, 0], batch.rates[:, :, 1], batch.rates[:, :, 2]
    ad_pole = np.exp(p_.motor_a_m * batch.dt)
    gain = p_.input_gain * (ad_pole - 1.0) / p_.motor_a_m
    thrusts = _motor_thrusts(u, ad_pole, gain)
    momentum = (thrusts @ np.asarray(p_.yaw_signs)) * base.thrust_to_speed  # H / I_p = sum s_i dOmega_i
    e = np.zeros(rp.shape + (6,))
    e[:, :, 3] = k_body * (iyy - izz) / ixx * rq * rr + k_prop * p_.prop_inertia / ixx * momentum * rq
    e[:, :, 4] = k_body * (izz - ixx) / iyy * rp * rr - k_prop * p_.prop_inertia / iyy * momentum * rp
    e[:, :, 5] = k_body * (ixx - iyy) / izz * rp * rq
    return e - _trim_mean(e, batch.warm)


def _nonlinearity_map(theta, batch: WindowBatch, base: BaseModel, u):
    return u + theta[0] * u**2 / batch.u_span


def _imbalance_map(theta, batch: WindowBatch, base: BaseModel, u):
    eps = np.array([theta[0], theta[1], theta[2], -(theta[0] + theta[1] + theta[2])])
    return u * (1.0 + eps)


def _imbalance_a_delta(theta, base: BaseModel):
    cg_x, cg_y = theta[3], theta[4]
    p_ = base.parameters
    delta = np.zeros((N_STATES, N_STATES))
    delta[9, 12:16] = cg_y / p_.ixx
    delta[10, 12:16] = -cg_x / p_.iyy
    return delta


def _drift_map(theta, batch: WindowBatch, base: BaseModel, u):
    t = (np.arange(u.shape[1]) - (batch.warm - 1) / 2.0) * batch.dt
    return u - np.asarray(theta)[None, None, :] * batch.u_span * t[None, :, None]


CATALOGUE: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("rotor_drag", "rotor/body drag: force against the velocity, and its moment about the CG",
               ("c_h", "c_v", "c_m"), ("1/s", "1/s", "rad/s2 per m/s"), (0.0, 0.0, 0.0), (0.0, 0.0, -20.0), (5.0, 5.0, 20.0),
               ("acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc"), forcing=_drag_forcing),
        Effect("battery", "battery voltage: thrust gain proportional to voltage, and voltage sag",
               ("kappa", "sigma"), ("1/V", "1/V"), (0.0, 0.0), (-2.0, -2.0), (2.0, 2.0), COLLECTIVE,
               stage=1, input_map=_battery_map, needs=("vbat",)),
        Effect("motor_lag", "motor lag: an extra first-order lag between command and thrust",
               ("tau",), ("s",), (0.02,), (1e-4,), (0.5,), THRUST_DRIVEN, stage=3, input_map=_lag_map),
        Effect("input_delay", "input delay: commands reach the rotors late",
               ("delay",), ("s",), (0.01,), (0.0,), (0.2,), THRUST_DRIVEN, stage=0, input_map=_delay_map),
        Effect("ground_effect", "ground effect: thrust gain near the ground",
               ("c_ge", "h_off"), ("m2", "m"), (1e-3, 0.2), (0.0, 0.005), (0.5, 2.0), ("acc_z",), forcing=_ground_forcing),
        Effect("gyroscopic", "body and propeller gyroscopic torques",
               ("k_body", "k_prop"), ("1", "1"), (0.0, 0.0), (-5.0, -1e3), (5.0, 1e3),
               ("roll_acc", "pitch_acc", "yaw_acc"), forcing=_gyro_forcing),
        Effect("thrust_nonlinearity", "thrust nonlinearity: T = a Omega^2 instead of the hover linearisation",
               ("beta",), ("1",), (0.0,), (-5.0,), (5.0,), THRUST_DRIVEN, stage=2, input_map=_nonlinearity_map),
        Effect("motor_imbalance", "per-motor gain imbalance and centre-of-gravity offset",
               ("eps_1", "eps_2", "eps_3", "cg_x", "cg_y"), ("1", "1", "1", "m", "m"), (0.0,) * 5,
               (-0.3, -0.3, -0.3, -0.05, -0.05), (0.3, 0.3, 0.3, 0.05, 0.05), TORQUE_DRIVEN,
               stage=1, input_map=_imbalance_map, a_delta=_imbalance_a_delta),
        Effect("trim_drift", "input trim drift within a window (e.g. battery drain)",
               ("r_1", "r_2", "r_3", "r_4"), ("1/s",) * 4, (0.0,) * 4, (-0.01,) * 4, (0.01,) * 4, THRUST_DRIVEN,
               stage=1, input_map=_drift_map),
    )
}
"""The effect catalogue, by name (module docstring table)."""

EFFECT_NAMES: tuple[str, ...] = tuple(CATALOGUE)


def parse_effect_list(text: str | None) -> list[Effect]:
    """``all``/None -> the whole catalogue, else a comma list of names (ConfigError naming unknown ones)."""
    if text is None or text.strip() in ("", "all"):
        return list(CATALOGUE.values())
    names = [part.strip() for part in text.split(",") if part.strip()]
    unknown = [n for n in names if n not in CATALOGUE]
    if unknown:
        raise ConfigError(f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECT_NAMES)} (or all)")
    return [CATALOGUE[n] for n in dict.fromkeys(names)]


# ----------------------------------------------------------------------------- fitting


@dataclass
class FitResult:
    """Identified parameters of a set of effects (training windows only)."""

    effects: list[Effect]
    thetas: list[np.ndarray]
    cost: float
    evaluations: int
    success: bool
    message: str

    def params(self) -> dict[str, dict[str, float]]:
        return {e.name: {k: float(v) for k, v in zip(e.parameters, th)} for e, th in zip(self.effects, self.thetas)}


def variable_scales(batch: WindowBatch, predicted: np.ndarray) -> np.ndarray:
    """(18,) scale of each variable's residual: its RMS over the batch's scored rows (>0)."""
    err = batch.measured[:, batch.warm :] - predicted[:, batch.warm :]
    scale = np.sqrt(np.mean(err**2, axis=(0, 1)))
    floor = 1e-9 + 1e-6 * np.sqrt(np.mean(batch.measured[:, batch.warm :] ** 2, axis=(0, 1)))
    return np.maximum(scale, floor)


def fit_effects(
    base: BaseModel, batch: WindowBatch, effects: Sequence[Effect], scales: np.ndarray, variables: Sequence[str] | None = None,
    fixed: Sequence[tuple[Effect, np.ndarray]] = (), smooth_cutoff_hz: float | None = None, starts: int = 1,
) -> FitResult:
    """Identify the parameters of ``effects`` on ``batch`` (with ``fixed`` effects held at their values).

    Minimises :math:`\\sum_{w,k,v} ((y_m - y_p)_{w,k,v} / s_v)^2` over the
    scored rows (every :data:`FIT_STRIDE`-th) of the effects' affected
    variables (or ``variables``), :math:`s_v` = ``scales`` (the base model's
    training residual RMS, so each variable weighs by its share of the gap),
    with :func:`scipy.optimize.least_squares` (trust-region reflective, bounds
    from the catalogue, parameters scaled by their bound widths).
    """
    effects = list(effects)
    if not effects:
        raise ConfigError("fit_effects: no effect to fit")
    names = variables or sorted({v for e in effects for v in e.variables}, key=VARIABLES.index)
    cols = np.array([INDEX[v] for v in names])
    sizes = [len(e.parameters) for e in effects]
    lower = np.concatenate([e.lower for e in effects]).astype(float)
    upper = np.concatenate([e.upper for e in effects]).astype(float)
    x0 = np.clip(np.concatenate([e.initial for e in effects]).astype(float), lower, upper)
    width = upper - lower
    all_effects = [f[0] for f in fixed] + effects
    rows = slice(batch.warm, None, FIT_STRIDE)
    target = batch.measured[:, rows][:, :, cols]

    def split(z: np.ndarray) -> list[np.ndarray]:
        theta = lower + z * width
        return np.split(theta, np.cumsum(sizes)[:-1])

    def residuals(z: np.ndarray) -> np.ndarray:
        thetas = [f[1] for f in fixed] + split(z)
        pred = predict_batch(base, batch, all_effects, thetas, columns=cols, smooth_cutoff_hz=smooth_cutoff_hz)
        r = (target - pred[:, rows][:, :, cols]) / scales[cols]
        r = np.nan_to_num(r, nan=1e6, posinf=1e6, neginf=-1e6)
        return r.ravel()

    z0 = (x0 - lower) / width
    candidates = [z0]
    rng = np.random.default_rng(0)
    for _ in range(max(starts, 1) - 1):
        candidates.append(np.clip(z0 + rng.normal(0.0, 0.15, size=z0.shape), 0.0, 1.0))
    best = None
    evaluations = 0
    for z in candidates:
        fit = optimize.least_squares(residuals, z, bounds=(0.0, 1.0), method="trf", diff_step=1e-3, xtol=1e-6, ftol=1e-6, max_nfev=60)
        evaluations += fit.nfev
        if best is None or fit.cost < best.cost:
            best = fit
    return FitResult(effects, split(best.x), float(best.cost), evaluations, bool(best.success), str(best.message))
