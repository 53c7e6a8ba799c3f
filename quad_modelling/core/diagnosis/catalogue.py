"""Effect catalogue: identifiable nonlinear extensions of the linear greybox model (DESIGN 6.2).

Every effect is a small, documented change of the linear model of
:mod:`quad_modelling.core.models.greybox` with a few parameters identified from
training windows only. The forms are deliberately simpler than the truth
simulator's physics (:mod:`quad_modelling.core.sim.dynamics`): the diagnosis
asks "which missing term would close the gap", not "what is the exact physics".

The augmented model of one window (trimmed convention, state x of
:mod:`~quad_modelling.core.models.greybox`) is

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
                       e_\\theta = -c_m v_{B,x}` (rotor drag at the hub, its moment arm), v the c_h, c_v [1/s], c_m [rad/s² per m/s],
                       airspeed v - w, w the wind (nuisance m = c_m w, :func:`_drag_forcing`) m_x, m_y [rad/s²]
battery                :math:`\\tilde u_i = u_i (1 + \\kappa (V_0 - V_{ref})) + \\sigma\\,u_{span} (V - V_0)`,
                       V_0 = trim voltage (gain ∝ V, sag coupling)                           κ [1/V], σ [1/V]
motor_lag              :math:`\\tau \\dot{v}_i = u_i - v_i,\\ \\tilde u_i = g v_i` (extra first-order lag, τ [s], g [1]
                       base command gain re-fitted with it)
input_delay            :math:`\\tilde u_i(t) = g\\, u_i(t - \\delta)` (linear interpolation; g the   δ [s], g [1]
                       base command gain re-fitted with it)
ground_effect          :math:`e_Z = -g\\,(G(h) - G(h_0)),\\ G(h) = c_{ge} / (h + h_{off})^2`,   g_ref [1], h_off [m]
                       :math:`c_{ge} = g_{ref} (h_{ref} + h_{off})^2` (the physics model's form, aero.py)
gyroscopic             :math:`e_\\phi = k_b \\frac{I_{yy}-I_{zz}}{I_{xx}} q r + k_p \\frac{I_p}{I_{xx}} H q`,
                       :math:`e_\\theta = k_b \\frac{I_{zz}-I_{xx}}{I_{yy}} p r - k_p \\frac{I_p}{I_{yy}} H p`,
                       :math:`e_\\psi = k_b \\frac{I_{xx}-I_{yy}}{I_{zz}} p q`,
                       :math:`H = \\sum_i s_i T_i / (2 a \\Omega_0)`                          k_b, k_p [1]
thrust_nonlinearity    :math:`\\tilde u_i = u_i + \\beta\\, u_i^2 / u_{span}` (T = aΩ², Ω ∝ u)      β [1]
motor_imbalance        :math:`\\tilde u_i = (1 + \\epsilon_i) u_i,\\ \\epsilon = P^T e`, P the roll, pitch, e_roll, e_pitch, e_yaw [1],
                       yaw gain patterns (:func:`imbalance_patterns`);                       c_x, c_y [m]
                       :math:`\\Delta\\ddot\\phi = c_y \\sum T_i / I_{xx},\\
                       \\Delta\\ddot\\theta = -c_x \\sum T_i / I_{yy}` (CG offset c)
trim_drift             :math:`\\tilde u_i = u_i - r_i\\, u_{span}\\, (t - t_{trim})`              r1..r4 [1/s]
=====================  ===================================================================  =====================

:func:`~quad_modelling.core.identification.window_batch.prepare_windows` cuts and preprocesses windows once
into a :class:`~quad_modelling.core.identification.window_batch.WindowBatch` (all windows of equal length);
:func:`~quad_modelling.core.identification.base_model.predict_batch` runs the augmented model on every window at
once (one time loop over an (W, 16) state array); :func:`~quad_modelling.core.diagnosis.fitting.fit_effects`
identifies the parameters of a set of effects (:func:`~quad_modelling.core.identification.least_squares.fit_least_squares`).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from quad_modelling.core.effect_names import DIAGNOSIS, parse_effect_names
from quad_modelling.core.identification.base_model import BaseModel, Effect
from quad_modelling.core.identification.window_batch import WindowBatch, _trim_mean
from quad_modelling.core.models.greybox import (
    N_STATES,
)
from quad_modelling.core.discretise import discrete_motor, motor_thrusts
from quad_modelling.core.physics.rigid_body import GRAVITY

THRUST_DRIVEN = ("acc_z", "roll_acc", "pitch_acc", "yaw_acc")
"""The variables the rotor thrusts drive without integration: every effect on the command path acts on
them directly. Velocities, rates and attitude-driven horizontal accelerations integrate them, and over an
open-loop window their error is dominated by drift from the initial state; effects are fitted and scored on
the direct variables (the report shows every variable before/after)."""


TORQUE_DRIVEN = ("roll_acc", "pitch_acc", "yaw_acc")
"""The variables the *differential* thrusts drive. Motor imbalance changes only those: its gains sum to
zero (:func:`imbalance_patterns`), so the collective thrust, and acc_z, is unchanged to first order,
and its CG offset changes the roll and pitch rows of A only."""


# Battery: fitted on the four thrust-driven variables (THRUST_DRIVEN), scored where its correction is material
# (acc_z on every simulated flight: its sag term adds the same command to all four rotors). Fitted on acc_z alone,
# as before, its gain term kappa, which also scales the differential commands behind roll/pitch/yaw, was free to
# take the wrong sign (-0.33 1/V on the seed-0 battery flight, base identified the user's way): acc_z improved by
# 24 % and the total held-out error rose 1.000 -> 1.039. Fitted on all four, kappa = +0.08 1/V, 27 %.



def _drag_forcing(theta, batch: WindowBatch, base: BaseModel, u):
    """Drag of the measured airspeed :math:`v_{air} = v - w` (``w`` = (w_x, w_y, 0) the wind in N), rotated into
    body axes sample by sample, minus its warm-start value. (Rotating the *trimmed* velocity v - v_0 by the current
    yaw is wrong in a turn flown at speed: the body-axes velocity changes as the heading turns even when the
    velocity in N does not.)

    In the trimmed convention a steady wind drops out of the force terms (:math:`-c_h (v - w)` minus its
    warm-start value is :math:`-c_h (v - v_0)`); it shows only in the moment terms, through the heading, as
    :math:`c_m R_z(\\psi)^T w`. The wind is therefore fitted as that product, the *wind moment*
    :math:`m = c_m w` (m_x, m_y [rad/s²], nuisance parameters): the prediction is linear in it, where (c_m, w)
    was bilinear and the least squares stopped in a wrong valley (c_m of the wrong sign with w on its bound,
    on data made with c_m = -1.5, w = (1.5, -1)). The wind estimate is :math:`w = m / c_m`
    (:func:`drag_wind_estimate`)."""
    c_h, c_v, c_m, m_x, m_y = theta
    v = batch.velocity_smooth
    yaw = batch.euler[:, :, 2]
    cos, sin = np.cos(yaw), np.sin(yaw)
    v_bx = cos * v[:, :, 0] + sin * v[:, :, 1]
    v_by = -sin * v[:, :, 0] + cos * v[:, :, 1]
    e = np.zeros(v.shape[:2] + (6,))
    e[:, :, 0] = -c_h * v[:, :, 0]
    e[:, :, 1] = -c_h * v[:, :, 1]
    e[:, :, 2] = -c_v * v[:, :, 2]
    m_by = -sin * m_x + cos * m_y  # R_z(psi)^T m
    m_bx = cos * m_x + sin * m_y
    e[:, :, 3] = c_m * v_by - m_by
    e[:, :, 4] = -(c_m * v_bx - m_bx)
    return e - _trim_mean(e, batch.warm)


def drag_wind_estimate(theta, sigma=None) -> dict:
    """The wind behind a rotor-drag fit, :math:`w = m / c_m` [m/s] in N (with its 1-sigma from the fit's, the
    product rule, when ``sigma`` is given); None entries when c_m is zero. ``diagnosis.json`` reports it per effect
    under ``derived``."""
    c_m, m_x, m_y = float(theta[2]), float(theta[3]), float(theta[4])
    if c_m == 0.0:
        return {"w_x": None, "w_y": None}
    out = {"w_x": m_x / c_m, "w_y": m_y / c_m}
    if sigma is not None:
        s_c, s_x, s_y = float(sigma[2]), float(sigma[3]), float(sigma[4])
        out["sigma_w_x"] = abs(out["w_x"]) * float(np.hypot(s_x / m_x if m_x else 0.0, s_c / c_m)) if m_x else s_x / abs(c_m)
        out["sigma_w_y"] = abs(out["w_y"]) * float(np.hypot(s_y / m_y if m_y else 0.0, s_c / c_m)) if m_y else s_y / abs(c_m)
        out = {k: (v if v is None or np.isfinite(v) else None) for k, v in out.items()}  # a held wind has no sigma
    return out


def _battery_map(theta, batch: WindowBatch, base: BaseModel, u):
    kappa, sigma = theta
    v = batch.vbat
    v0 = _trim_mean(v, batch.warm)  # (W, 1)
    v_ref = base.reference_voltage if base.reference_voltage is not None else float(v.mean())
    gain = 1.0 + kappa * (v0 - v_ref)
    return u * gain[:, :, None] + (sigma * batch.u_span * (v - v0))[:, :, None]


def _lag_map(theta, batch: WindowBatch, base: BaseModel, u):
    r""":math:`\tilde u_k = g\,(p \tilde u_{k-1} + (1 - p) u_k)`, :math:`p = e^{-\Delta t/\tau}`: the lag without an
    added sample of delay (τ -> 0, g = 1 gives the identity), run over the commands before the window
    (``u_history``, in steady state at its first sample) so that the window starts from the lagged state.

    g re-fits the base's command gain with the lag: a base identified on flights whose motors lag, without a
    lag of its own, shrinks its steady gain and arm scale to match the lag's attenuation of the manoeuvres, and
    a lag on top of that base then only attenuates further (seed 31337: the true 105 ms lag fitted to 0.1 ms,
    and an 82 ms input delay took its place). A lag attenuates every motor alike, so one gain restores every
    channel."""
    tau, gain = float(theta[0]), float(theta[1])
    pole = float(np.exp(-batch.dt / max(tau, 1e-6)))
    history = batch.u_history
    zi = pole * (history[:, :1, :] if history.shape[1] else u[:, :1, :])
    if history.shape[1]:
        _, zi = signal.lfilter([1.0 - pole], [1.0, -pole], history, axis=1, zi=zi)
    y, _ = signal.lfilter([1.0 - pole], [1.0, -pole], u, axis=1, zi=zi)
    return gain * y


def _delay_map(theta, batch: WindowBatch, base: BaseModel, u):
    """g u(t - delay), linear interpolation; the samples before the window come from ``u_history`` (the first
    command repeated beyond it). g re-fits the base's command gain with the delay, as for the motor lag
    (:func:`_lag_map`): the twins get the same freedom, so neither wins on a gain alone."""
    gain = float(theta[1])
    shift = max(float(theta[0]), 0.0) / batch.dt
    whole = int(np.floor(shift))
    frac = shift - whole
    n = u.shape[1]
    history = batch.u_history[:, max(batch.u_history.shape[1] - (whole + 1), 0) :]
    first = history[:, :1] if history.shape[1] else u[:, :1]
    padded = np.concatenate([np.repeat(first, whole + 1 - history.shape[1], axis=1), history, u], axis=1)
    later = padded[:, 1 : n + 1]  # u[k - whole]
    earlier = padded[:, 0:n]  # u[k - whole - 1]
    return gain * ((1.0 - frac) * later + frac * earlier)


GROUND_REFERENCE_HEIGHT_M = 0.3
"""Height above the lowest point at which ground effect's gain g_ref is stated [m]: inside the low passes flown
near the ground (0.2-0.45 m on the simulated LinkQuad). Parametrised by c_ge = g_ref (h_ref + h_off)^2 instead of
c_ge, the two estimates stop trading against each other: on the simulated ground-effect flights (seeds 0, 1) the
fit on each training flight alone moved c_ge by -70 % / +74 % and h_off from 0.005 to 0.24 m, while the gain at
0.3 m moved by -25 % / +30 %."""


def _ground_forcing(theta, batch: WindowBatch, base: BaseModel, u):
    """:math:`e_Z = -g (G(h) - G(h_0))`, :math:`G(h) = g_{ref} ((h_{ref} + h_{off}) / (h + h_{off}))^2`: the physics
    model's :math:`c_{ge}/(h + h_{off})^2` (:func:`~quad_modelling.core.physics.aero.ground_effect_factor`) with :math:`c_{ge} = g_{ref} (h_{ref} + h_{off})^2` (:data:`GROUND_REFERENCE_HEIGHT_M`)."""
    g_ref, h_off = theta
    g = g_ref * ((GROUND_REFERENCE_HEIGHT_M + h_off) / (np.maximum(batch.height, 0.0) + h_off)) ** 2
    e = np.zeros(batch.height.shape + (6,))
    e[:, :, 2] = -GRAVITY * (g - _trim_mean(g, batch.warm))
    return e


def _gyro_forcing(theta, batch: WindowBatch, base: BaseModel, u):
    k_body, k_prop = theta
    p_ = base.parameters
    ixx, iyy, izz = p_.ixx, p_.iyy, p_.izz
    rp, rq, rr = batch.rates[:, :, 0], batch.rates[:, :, 1], batch.rates[:, :, 2]
    thrusts = motor_thrusts(u, *discrete_motor(p_.motor_a_m, p_.input_gain, batch.dt), axis=1)
    momentum = (thrusts @ np.asarray(p_.yaw_signs)) * base.thrust_to_speed  # H / I_p = sum s_i dOmega_i
    e = np.zeros(rp.shape + (6,))
    e[:, :, 3] = k_body * (iyy - izz) / ixx * rq * rr + k_prop * p_.prop_inertia / ixx * momentum * rq
    e[:, :, 4] = k_body * (izz - ixx) / iyy * rp * rr - k_prop * p_.prop_inertia / iyy * momentum * rp
    e[:, :, 5] = k_body * (ixx - iyy) / izz * rp * rq
    return e - _trim_mean(e, batch.warm)


def _nonlinearity_map(theta, batch: WindowBatch, base: BaseModel, u):
    return u + theta[0] * u**2 / batch.u_span


def imbalance_patterns(base: BaseModel) -> np.ndarray:
    """(3, 4) per-motor gain patterns of a roll, a pitch and a yaw imbalance: the rows of the torque map
    (-y_i, x_i, s_i), each scaled to a largest entry of 1 and made to sum to zero over the motors.

    The gain spread eps = P^T (e_roll, e_pitch, e_yaw) spans the three torque axes a motor imbalance can
    show on (the common mode, a collective gain, is the base's steady gain). Per motor, eps_i of a "+" frame
    traded against one another: the yaw combination moves only the small rotor-drag torque (d/a ~ 1-2 cm), so
    on 90 s of simulated flight one motor's gain flipped sign between the halves of the flight while the roll
    and pitch differences held. Per axis, the poorly excited direction is one parameter, e_yaw."""
    p_ = base.parameters
    pos = np.asarray(p_.motor_positions, dtype=float)
    rows = np.vstack([-pos[:, 1], pos[:, 0], np.asarray(p_.yaw_signs, dtype=float)])
    rows = rows - rows.mean(axis=1, keepdims=True)
    return rows / np.abs(rows).max(axis=1, keepdims=True)


def _imbalance_map(theta, batch: WindowBatch, base: BaseModel, u):
    eps = np.asarray(theta[:3]) @ imbalance_patterns(base)
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


def _drag_plausible(base: BaseModel):
    """c_h, c_v: drag per mass 0.01-2 1/s; c_m: that drag at a hub up to 0.1 m above the CG over the smaller
    roll/pitch inertia; the wind moment that c_m in a wind up to 5 m/s (module constants' sources)."""
    p_ = base.parameters
    c_m = DRAG_PER_MASS_MAX * p_.mass * HUB_HEIGHT_MAX / min(p_.ixx, p_.iyy)
    return ((0.01, DRAG_PER_MASS_MAX), (0.0, DRAG_PER_MASS_MAX), (-c_m, c_m), (-c_m * WIND_MAX, c_m * WIND_MAX),
            (-c_m * WIND_MAX, c_m * WIND_MAX))


def _battery_plausible(base: BaseModel):
    """kappa, sigma in [0, 3/V_ref] (module constants)."""
    v_ref = base.reference_voltage or 1.0
    return ((0.0, BATTERY_GAIN_PER_VOLT_MAX / v_ref), (0.0, BATTERY_GAIN_PER_VOLT_MAX / v_ref))


def _imbalance_plausible(base: BaseModel):
    """e_roll, e_pitch, e_yaw within +-15 %; the CG within a quarter of the mean arm of the centre (module constants)."""
    arm = float(np.mean(np.hypot(*np.asarray(base.parameters.motor_positions).T)))
    cg = CG_OFFSET_MAX_ARM_FRACTION * arm
    return ((-MOTOR_GAIN_SPREAD_MAX, MOTOR_GAIN_SPREAD_MAX),) * 3 + ((-cg, cg),) * 2


DRAG_PER_MASS_MAX = 2.0
"""Largest plausible rotor drag per mass [1/s]. Measured: 0.3-0.4 1/s on a Crazyflie (Foerster 2015, ETH
Zurich, "System identification of the Crazyflie 2.0 nano quadrocopter"), 0.3-0.6 1/s on 0.5-1 kg
quadrotors (Faessler, Franchi & Scaramuzza 2018, IEEE RA-L 3(2), "Differential flatness of quadrotor
dynamics subject to rotor drag"); 2 1/s is five times the largest."""

HUB_HEIGHT_MAX = 0.1
"""Largest plausible height of the rotor hubs above the CG [m] (guess: 4 cm on the simulated LinkQuad, about
1 cm on a Crazyflie; a hub 10 cm above the CG is a tall frame)."""

WIND_MAX = 5.0
"""Largest plausible steady wind of a flight the diagnosis serves [m/s] (Beaufort 3, a gentle breeze;
indoor draughts are well below 1 m/s)."""

BATTERY_GAIN_PER_VOLT_MAX = 3.0
"""Largest plausible battery gain and sag coupling times the reference voltage [1]. A DC motor's speed at
fixed duty scales with the supply voltage (back-EMF limited), so the command gain changes by ~1/V per
volt; 3/V allows thrust up to the square of the voltage and an ESC's nonlinearity (guess). Both are
positive: a lower voltage gives less thrust for the same command."""

MOTOR_GAIN_SPREAD_MAX = 0.15
"""Largest plausible per-motor gain spread [1] (guess: motors and ESCs of one batch differ by a few per
cent; the simulator's LinkQuad uses 2.5 %)."""

CG_OFFSET_MAX_ARM_FRACTION = 0.25
"""Largest plausible CG offset as a fraction of the mean arm (guess: a quarter of the arm off centre leaves
a quarter of the roll/pitch authority to hold it)."""


CATALOGUE: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("rotor_drag", "rotor/body drag: force against the airspeed, and its moment about the CG",
               ("c_h", "c_v", "c_m", "m_x", "m_y"), ("1/s", "1/s", "rad/s2 per m/s", "rad/s2", "rad/s2"), (0.0,) * 5,
               (0.0, 0.0, -20.0, -100.0, -100.0), (5.0, 5.0, 20.0, 100.0, 100.0),
               ("acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc"), forcing=_drag_forcing,
               plausible=_drag_plausible, null=(0.0, 0.0, 0.0, 0.0, 0.0), nuisance=("m_x", "m_y"), derived=drag_wind_estimate,
               plausible_source="drag per mass 0.01-2 1/s (Foerster 2015; Faessler et al. 2018), hub <= 0.1 m above "
                                "the CG, wind <= 5 m/s (DRAG_PER_MASS_MAX, HUB_HEIGHT_MAX, WIND_MAX)"),
        Effect("battery", "battery voltage: thrust gain proportional to voltage, and voltage sag",
               ("kappa", "sigma"), ("1/V", "1/V"), (0.0, 0.0), (-2.0, -2.0), (2.0, 2.0), THRUST_DRIVEN,
               stage=1, input_map=_battery_map, needs=("vbat",),
               plausible=_battery_plausible, null=(0.0, 0.0),
               plausible_source="0-3/V_ref each: a DC motor's speed scales with its supply voltage; a lower voltage "
                                "gives less thrust (BATTERY_GAIN_PER_VOLT_MAX)"),
        Effect("motor_lag", "motor lag: an extra first-order lag between command and thrust",
               ("tau", "k_lag"), ("s", "1"), (0.02, 1.0), (1e-4, 0.3), (0.5, 3.0), THRUST_DRIVEN, stage=3, input_map=_lag_map,
               plausible=lambda base: ((0.005, 0.3), (0.3, 3.0)), null=(1e-4, None),
               plausible_source="brushless motor and propeller time constants of 20-150 ms (LinkQuad Table 3-1: "
                                "105 ms; Crazyflie coreless motors ~50 ms, its vehicle file); 5-300 ms allowed; "
                                "the gain is the base's command gain re-fitted with the lag (within its 0.3-3 range)"),
        Effect("input_delay", "input delay: commands reach the rotors late",
               ("delay", "k_delay"), ("s", "1"), (0.01, 1.0), (0.0, 0.3), (0.2, 3.0), THRUST_DRIVEN, stage=0, input_map=_delay_map,
               plausible=lambda base: ((0.002, 0.1), (0.3, 3.0)), null=(0.0, None),
               plausible_source="ESC update and bus latency of a few to 50 ms (guess: a 50 Hz ESC loop is 20 ms); "
                                "100 ms is a slow radio link"),
        Effect("ground_effect", "ground effect: thrust gain near the ground",
               ("g_ref", "h_off"), ("1", "m"), (0.01, 0.2), (0.0, 0.005), (0.5, 2.0), ("acc_z",), forcing=_ground_forcing,
               plausible=lambda base: ((2e-5, 0.2), (0.01, 0.4)), null=(0.0, 0.0),
               plausible_source="Cheeseman & Bennett 1955: c_ge = R^2/16 with a rotor radius R of 1.3 cm to 0.57 m, "
                                "h_off the rotor height above the feet, 1-40 cm (Crazyflie ~1.5 cm, LinkQuad ~16 cm): "
                                "g_ref = c_ge / (0.3 m + h_off)^2 within 2e-5..0.2"),
        Effect("gyroscopic", "body and propeller gyroscopic torques",
               ("k_body", "k_prop"), ("1", "1"), (0.0, 0.0), (-5.0, -1e3), (5.0, 1e3),
               ("roll_acc", "pitch_acc", "yaw_acc"), forcing=_gyro_forcing,
               plausible=lambda base: ((0.5, 1.5), (0.0, 3.0)), null=(0.0, 0.0),
               plausible_source="Euler's equations give k_body = 1 (+-50 % for inertia errors, guess); k_prop = 1 "
                                "with the configured propeller inertia, itself a guess on both vehicles (0-3)"),
        Effect("thrust_nonlinearity", "thrust nonlinearity: T = a Omega^2 instead of the hover linearisation",
               ("beta",), ("1",), (0.0,), (-5.0,), (5.0,), THRUST_DRIVEN, stage=2, input_map=_nonlinearity_map,
               plausible=lambda base: ((0.0, 3.0),), null=(0.0,),
               plausible_source="T = a Omega^2 with Omega linear in the command is convex: beta = u_span / "
                                "(2 (u_hover - u_0)), about 1 for a hover at mid-range (0-3 allowed)"),
        Effect("motor_imbalance", "per-motor gain imbalance and centre-of-gravity offset",
               ("e_roll", "e_pitch", "e_yaw", "cg_x", "cg_y"), ("1", "1", "1", "m", "m"), (0.0,) * 5,
               (-0.3, -0.3, -0.3, -0.05, -0.05), (0.3, 0.3, 0.3, 0.05, 0.05), TORQUE_DRIVEN,
               stage=1, input_map=_imbalance_map, a_delta=_imbalance_a_delta, plausible=_imbalance_plausible,
               plausible_source="gain spreads within +-15 % (motors of one batch differ by a few %), the CG within a "
                                "quarter of the arm of the centre (MOTOR_GAIN_SPREAD_MAX, CG_OFFSET_MAX_ARM_FRACTION)",
               null=(0.0,) * 5),
        Effect("trim_drift", "input trim drift within a window (e.g. battery drain)",
               ("r_1", "r_2", "r_3", "r_4"), ("1/s",) * 4, (0.0,) * 4, (-0.01,) * 4, (0.01,) * 4, THRUST_DRIVEN,
               stage=1, input_map=_drift_map, plausible=lambda base: ((-2e-3, 2e-3),) * 4, null=(0.0,) * 4,
               plausible_source="battery drain moves the trim by a few % of the input range over a 200 s flight "
                                "(thesis Fig 2.2, ~1e-4 1/s); 20x that allowed (guess)"),
    )
}
"""The effect catalogue, by name, in the order of :data:`quad_modelling.core.effect_names.CATALOGUE_EFFECTS`
(module docstring table; test/core/test_effects.py holds the two together)."""


def parse_effect_list(text: str | None) -> list[Effect]:
    """The catalogue entries an ``--effects`` text names (:func:`~quad_modelling.core.effect_names.parse_effect_names`
    with :data:`~quad_modelling.core.effect_names.DIAGNOSIS`: default and ``all`` the whole catalogue), in catalogue order."""
    return [CATALOGUE[name] for name in parse_effect_names(text, DIAGNOSIS)]
