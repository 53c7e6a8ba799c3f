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

import numpy as np
from scipy import signal

from quad_modelling.core.effect_names import DIAGNOSIS, parse_effect_names
from quad_modelling.core.identification.base_model import BaseModel, Effect
from quad_modelling.core.identification.window_batch import WindowBatch, _trim_mean
from quad_modelling.core.models.greybox import (
    N_STATES,
)
from quad_modelling.core.models.motors import discrete_motor, motor_thrusts
from quad_modelling.core.vehicle import GRAVITY

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
    thrusts = motor_thrusts(u, *discrete_motor(p_.motor_a_m, p_.input_gain, batch.dt), axis=1)
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
"""The effect catalogue, by name, in the order of :data:`quad_modelling.core.effect_names.CATALOGUE_EFFECTS`
(module docstring table; test/core/test_effects.py holds the two together)."""


def parse_effect_list(text: str | None) -> list[Effect]:
    """The catalogue entries an ``--effects`` text names (:func:`~quad_modelling.core.effect_names.parse_effect_names`
    with :data:`~quad_modelling.core.effect_names.DIAGNOSIS`: default and ``all`` the whole catalogue), in catalogue order."""
    return [CATALOGUE[name] for name in parse_effect_names(text, DIAGNOSIS)]
