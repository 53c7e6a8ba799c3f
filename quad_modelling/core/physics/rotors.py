r"""The rotors: command-to-speed map, command delay, rotor lag, thrust and yaw torque, hover speed (one definition).

Symbols (the code's :class:`~quad_modelling.core.physics.parameters.PhysicsParameters` fields): engine command
:math:`u_i` [input unit] of rotor i (command order), speed map :math:`k_u` [rad/s per input unit] and
:math:`\Omega_{off}` [rad/s], rotor time constant :math:`\tau_m` [s], command delay :math:`\delta` [s], thrust and
yaw-torque constants :math:`k_f` [N s²/rad²] and :math:`k_m` [N m s²/rad²], rotor speed :math:`\Omega_i` [rad/s].

* command map (:func:`steady_rotor_speed`, inverse :func:`command_for_rotor_speed`):
  :math:`\Omega_{ss,i} = \max(k_u u_i + \Omega_{off}, 0)`;
* command delay (:func:`delayed_commands`): the rotors answer the logged commands interpolated at
  :math:`t_k - \delta`, :math:`\tilde u_k = (1 - f) u_j + f u_{j+1}`, j the last row with :math:`t_j \le t_k - \delta`,
  :math:`f = (t_k - \delta - t_j) / (t_{j+1} - t_j)`: for a command held between samples (zero-order hold) this is
  its mean over the model's step, so a delay between two samples is resolved (causal: j + 1 <= k for δ > 0);
* rotor lag (:func:`rotor_step`, exact for a command held over :math:`\Delta t`):
  :math:`\Omega_{k+1} = \Omega_{ss} + (\Omega_k - \Omega_{ss}) e^{-\Delta t/\tau_m}`, its derivative
  :math:`\dot\Omega = (\Omega_{ss} - \Omega)/\tau_m` (:func:`rotor_acceleration`), a whole series at once
  (:func:`rotor_speeds`);
* the step's mean (:func:`interval_rotor_speed`): :math:`\bar\Omega` with :math:`\bar\Omega^2` the mean of
  :math:`\Omega^2` over a step under the held command, what thrust and torque are integrated with;
* thrust and yaw torque of each rotor (:func:`rotor_thrusts`, :func:`rotor_yaw_torques`):
  :math:`T_i = k_f \Omega_i^2`, :math:`Q_i = k_m \Omega_i^2`; inverse :func:`rotor_speed_for_thrust`;
* hover (:func:`hover_rotor_speed`): :math:`\Omega_H = \sqrt{m g / (4 k_f)}`; the thrust slope there
  (:func:`thrust_slope`) :math:`\partial T/\partial\Omega = 2 k_f \Omega_H` is what the thesis's linear greybox
  calls :math:`K / B_m = 2 \sqrt{a m g / 4}` (Eq 3-7);
* the rotor lag as the greybox's linear motor (:func:`linear_motor`): :math:`\dot\Omega = A_m \Omega + B_m u + \Omega_{off}/\tau_m`
  with :math:`A_m = -1/\tau_m`, :math:`B_m = k_u/\tau_m` (thesis Eq 3-5, A-0-1; the offset drops out of the
  deviations about hover);
* battery-voltage scaling (:func:`battery_speed_factor`, the model's form): the rotor speed a command reaches
  grows with the battery voltage V, :math:`\Omega_{ss} \to \Omega_{ss} (1 + \kappa (V - V_{ref}))`.

Every function takes numpy arrays or torch tensors (:mod:`quad_modelling.core.physics.arrays`) and any record
``p`` with the fields it names (:class:`PhysicsParameters` or the torch twin's).
"""

from __future__ import annotations

import numpy as np

from quad_modelling.core.physics import arrays

STAMP_TOLERANCE_S = 1e-7
"""Stamps closer than this [s] count as equal when looking up the delayed command (float rounding of t - δ)."""


def delayed_commands(p, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 4) commands the rotors answer at each row: the logged ``u`` (N, 4) interpolated at t_k - δ (module
    docstring; row 0 before the first), ``t`` (N,) [s]. Causal: ũ_k uses rows <= k."""
    u = np.asarray(u, dtype=float)
    if p.delay <= 0.0:
        return u
    t = np.asarray(t, dtype=float)
    target = t - p.delay
    rows = np.searchsorted(t, target + STAMP_TOLERANCE_S, side="right") - 1  # <= N - 1
    j = np.maximum(rows, 0)  # np.minimum / np.maximum: np.clip's numbers at a tenth of its cost here
    nxt = np.minimum(j + 1, len(t) - 1)
    t_j = t[j]
    span = t[nxt] - t_j
    f = np.divide(target - t_j, span, out=np.zeros(len(t)), where=(rows >= 0) & (span > 0))  # else 0: row 0 / equal stamps
    f[f * span <= STAMP_TOLERANCE_S] = 0.0
    f = np.minimum(np.maximum(f, 0.0), 1.0)[:, None]
    return (1.0 - f) * u[j] + f * u[nxt]


def delayed_command_at(p, times, commands, t_s: float):
    """The command the rotors answer at ``t_s`` from a short history (``times`` ascending [s], ``commands`` the
    logged ones): interpolated at t_s - δ between the last logged at or before it and the next (the first one
    before any) -- :func:`delayed_commands` of one row, for a live stream."""
    target = t_s - p.delay
    for i in range(len(times) - 1, -1, -1):
        if times[i] <= target + STAMP_TOLERANCE_S:
            if i + 1 < len(times) and p.delay > 0.0:
                f = (target - times[i]) / (times[i + 1] - times[i])
                if f * (times[i + 1] - times[i]) > STAMP_TOLERANCE_S:
                    f = min(f, 1.0)
                    return (1.0 - f) * commands[i] + f * commands[i + 1]
            return commands[i]
    return commands[0]


def effective_commands(p, u, voltage=None):
    r"""The commands the rotor map sees (..., 4): the (delayed) logged commands ``u`` through the optional terms of the
    command path (:mod:`~quad_modelling.core.physics.effects`), in order

    * motor imbalance, :math:`u_i \to g_i u_i`;
    * battery, :math:`\Omega_{ss} \to f \Omega_{ss}` with :math:`f = 1 + \kappa (V - V_{ref})`
      (:func:`battery_speed_factor`), written on the command as :math:`u \to f u + (f - 1) \Omega_{off} / k_u`
      (then :math:`k_u u + \Omega_{off} \to f (k_u u + \Omega_{off})`), ``voltage`` [V] broadcast against ``u``'s
      leading axes (one per row, or the anchor's held over a horizon).

    Without terms on, ``u`` itself. DataError-free: a battery term without a voltage is the caller's to refuse."""
    if p.motor_gains is not None:
        u = u * np.asarray(p.motor_gains, dtype=float)
    if p.battery is not None:
        kappa, reference = p.battery
        factor = battery_speed_factor(arrays.as_array(voltage), reference, kappa)[..., None]
        u = factor * u + (factor - 1.0) * (p.speed_offset / p.speed_gain)
    return u


def steady_rotor_speed(p, u):
    """Ω_ss = max(k_u u + Ω_off, 0) [rad/s] of commands ``u`` (..., 4)."""
    u = arrays.as_array(u)
    return arrays.clamp_min(p.speed_gain * u + p.speed_offset, 0.0)


def command_for_rotor_speed(speed, speed_gain: float, speed_offset: float):
    """u = (Ω - Ω_off) / k_u [input unit]: the command whose steady rotor speed is ``speed`` (Ω >= 0), the inverse
    of :func:`steady_rotor_speed` for the map k_u = ``speed_gain``, Ω_off = ``speed_offset``."""
    return (speed - speed_offset) / speed_gain


def rotor_step(p, rotor, u, dt):
    """Ω_{k+1} from Ω_k = ``rotor`` under command ``u`` held for ``dt`` [s] (scalar or one per batch member):
    the exact first-order lag (τ_m = 0: at once)."""
    target = steady_rotor_speed(p, u)
    if p.time_constant <= 0.0:
        return target
    decay = arrays.exp(-arrays.as_array(dt) / p.time_constant)
    if decay.ndim and decay.ndim < target.ndim:
        decay = decay.reshape(tuple(decay.shape) + (1,) * (target.ndim - decay.ndim))
    return target + (rotor - target) * decay


def interval_rotor_speed(p, rotor, u, dt):
    r"""The rotor speed :math:`\bar\Omega` whose square is the mean of :math:`\Omega(t)^2` over a step of ``dt`` [s]
    (scalar or one per batch member) that starts at :math:`\Omega_0` = ``rotor`` under command ``u`` held: with the
    exact lag :math:`\Omega(t) = \Omega_{ss} + D e^{-t/\tau_m}`, :math:`D = \Omega_0 - \Omega_{ss}`, :math:`x = \Delta t/\tau_m`,

    .. math:: \bar\Omega^2 = \Omega_{ss}^2 + 2 \Omega_{ss} D \frac{1 - e^{-x}}{x} + D^2 \frac{1 - e^{-2x}}{2x}

    so :math:`k_f \bar\Omega^2` is the step's mean thrust and :math:`k_m \bar\Omega^2` its mean yaw torque, exactly
    (τ_m = 0: :math:`\Omega_{ss}`, the command acts from the step's start). What :func:`~quad_modelling.core.physics.rigid_body.step`
    integrates with: the start-of-step speed instead lags the commands by up to one sample (on simulated flights
    1.5x truth's angular-velocity error with the true constants, 1.0x with this)."""
    target = steady_rotor_speed(p, u)
    if p.time_constant <= 0.0:
        return target
    x = arrays.as_array(dt) / p.time_constant
    if x.ndim and x.ndim < target.ndim:
        x = x.reshape(tuple(x.shape) + (1,) * (target.ndim - x.ndim))
    small = arrays.less(x, 1e-9)  # a step of dt = 0 (an MPC splitting a step at the delay): the limits, Ω̄ = Ω_0
    safe = arrays.where(small, x * 0.0 + 1.0, x)
    first = arrays.where(small, 1.0 - 0.5 * x, (1.0 - arrays.exp(-safe)) / safe)
    second = arrays.where(small, 1.0 - x, (1.0 - arrays.exp(-2.0 * safe)) / (2.0 * safe))
    d = rotor - target
    return arrays.sqrt(arrays.clamp_min(target * target + 2.0 * first * target * d + second * d * d, 0.0))


def interval_rotor_speeds(p, rotor: np.ndarray, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, ..., 4) :func:`interval_rotor_speed` of each row's step to the next (``rotor`` from :func:`rotor_speeds`
    of the same commands ``u`` stamped ``t``): the rotor speeds the model integrates row k's interval with; the last
    row, without an interval, keeps its own speed. Causal: row k uses u_k, which acts from t_k."""
    out = np.array(rotor, dtype=float, copy=True)
    if len(out) > 1:
        dt = np.diff(np.asarray(t, dtype=float), axis=0)
        out[:-1] = interval_rotor_speed(p, out[:-1], np.asarray(u, dtype=float)[:-1], dt)
    return out


def rotor_acceleration(p, rotor, u):
    """dΩ/dt = (Ω_ss(u) - Ω)/τ_m [rad/s²] (0 without lag)."""
    if p.time_constant <= 0.0:
        return arrays.zeros_like(rotor)
    return (steady_rotor_speed(p, u) - rotor) / p.time_constant


def rotor_speeds(p, u: np.ndarray, t: np.ndarray, initial: np.ndarray | None = None) -> np.ndarray:
    """(N, ..., 4) rotor speeds Ω_k at each row of commands ``u`` (N, ..., 4) stamped ``t`` (N, ...) [s]: the
    exact lag (:func:`rotor_step`) over each interval, for a whole series at once (numpy).

    Row k depends on u_0..u_{k-1} only (causal); Ω_0 = ``initial`` or the steady speed of u_0 (the motor
    settled before the data starts). Time runs along axis 0; other leading axes are independent series.
    """
    u = np.asarray(u, dtype=float)
    target = steady_rotor_speed(p, u)
    out = np.empty_like(target)
    out[0] = target[0] if initial is None else initial
    if p.time_constant <= 0.0:
        out[1:] = target[:-1]
        return out
    decay = np.exp(-np.diff(np.asarray(t, dtype=float), axis=0) / p.time_constant)
    decay = decay.reshape(decay.shape + (1,) * (target.ndim - decay.ndim)) * np.ones_like(target[:-1])
    gain, offset = first_order_scan(decay, (1.0 - decay) * target[:-1])
    out[1:] = gain * out[0] + offset
    return out


def first_order_scan(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, Q) with x_{k+1} = P_k x_0 + Q_k for the recurrence x_{k+1} = a_k x_k + b_k along axis 0.

    A Hillis-Steele prefix scan of the affine maps f_k(x) = a_k x + b_k (composition
    (P, Q)_k ∘ (P, Q)_{k-s} = (P_k P_{k-s}, P_k Q_{k-s} + Q_k)): log2(N) vectorised passes instead of N
    Python steps, exact up to rounding, stable for |a_k| <= 1 (products only shrink).
    """
    p, q = np.array(a, dtype=float), np.array(b, dtype=float)
    shift = 1
    while shift < len(p):
        q[shift:] = p[shift:] * q[:-shift] + q[shift:]
        p[shift:] = p[shift:] * p[:-shift]
        shift *= 2
    return p, q


def rotor_thrusts(thrust_constant: float, rotor):
    """T_i = k_f Ω_i² [N] of rotor speeds ``rotor`` (..., 4) [rad/s]."""
    return thrust_constant * (rotor * rotor)


def rotor_yaw_torques(torque_constant: float, rotor):
    """Q_i = k_m Ω_i² [N m]: each rotor's drag torque about its shaft; on the body it acts as s_i Q_i about FRD z
    (:func:`~quad_modelling.core.physics.rigid_body.rotor_wrench`)."""
    return torque_constant * (rotor * rotor)


def rotor_speed_for_thrust(thrust_constant: float, thrust):
    """Ω = √(T / k_f) [rad/s] (T >= 0): the inverse of :func:`rotor_thrusts`."""
    return arrays.sqrt(thrust / thrust_constant)


def hover_rotor_speed(mass: float, thrust_constant: float, gravity: float) -> float:
    """Ω_H = √(m g / (4 k_f)) [rad/s]: each rotor's speed when four equal thrusts carry the weight."""
    return float(np.sqrt(mass * gravity / (4.0 * thrust_constant)))


def thrust_slope(thrust_constant: float, speed: float) -> float:
    """∂T/∂Ω = 2 k_f Ω [N s/rad]: the thrust change per rotor-speed change at ``speed`` (the linearisation)."""
    return 2.0 * thrust_constant * speed


def linear_motor(time_constant: float, speed_gain: float) -> tuple[float, float]:
    """(A_m [1/s], B_m [rad/s² per input unit]) of the rotor lag τ_m Ω̇ = k_u u + Ω_off - Ω written as the thesis's linear
    motor Ω̇ = A_m Ω + B_m u (+ a constant): A_m = -1/τ_m, B_m = k_u/τ_m. ``time_constant`` τ_m > 0 [s], ``speed_gain``
    k_u [rad/s per input unit]."""
    return -1.0 / time_constant, speed_gain / time_constant


def battery_speed_factor(voltage, reference_voltage: float, kappa: float):
    """1 + κ (V - V_ref): the model's battery-voltage scaling of the steady rotor speed (κ [1/V])."""
    return 1.0 + kappa * (voltage - reference_voltage)
