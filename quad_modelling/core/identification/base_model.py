"""The diagnosis base model: the linear greybox with effect hooks, predicted over a window batch."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.discretise import zero_order_hold
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.models.greybox import (
    N_STATES,
    GreyboxParameters,
    continuous_matrices,
)
from quad_modelling.core.discretise import motor_thrusts
from quad_modelling.core.preprocess import (
    differentiate,
    smooth,
)
from quad_modelling.core.variables import INDEX, VARIABLES
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig

FORCING_STATES = np.array([3, 4, 5, 9, 10, 11])
"""States (velocities, rates) the extra accelerations e act on."""


# ----------------------------------------------------------------------------- augmented model


@dataclass
class Augmentation:
    """What a set of effects does to the linear model on a batch (module docstring)."""

    u: np.ndarray  # (W, N, 4) commands after the input maps
    forcing: np.ndarray  # (W, N, 6) extra accelerations e
    a_delta: np.ndarray  # (16, 16) added to the continuous A
    command_shift: np.ndarray | float = 0.0  # (W, 1, 4) subtracted from the mapped commands (their warm-start mean)


@dataclass(frozen=True)
class Effect:
    """One catalogue entry.

    ``input_map(theta, batch, base, u) -> u`` changes the commands (stage
    ``stage``: 0 delay, 1 static gains/drift, 2 nonlinearity, 3 lag);
    ``forcing(theta, batch, base, u) -> (W, N, 6)`` adds accelerations (``u`` =
    the mapped commands); ``a_delta(theta, base) -> (16, 16)`` changes A.
    ``needs``: regime signals required (``"vbat"``). ``variables``: the candidate variables the form can
    change; the effect is fitted on all of them and scored on those its fitted correction moves
    (:func:`quad_modelling.core.diagnosis.attribution.affected_variables`).

    The verdict rules (:mod:`quad_modelling.core.diagnosis.verdicts`) read three more: ``plausible(base)``
    -> one (low, high) physically plausible range per parameter for this vehicle, with its
    ``plausible_source``; ``null``: per parameter the value at which its term vanishes (None for a shape
    parameter, e.g. a height offset, that matters whenever the effect does); ``nuisance``: parameters fitted
    only where the training data shows them (the wind of an airspeed-driven effect), else held at ``initial``.
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
    plausible: Callable | None = None
    plausible_source: str = ""
    null: tuple[float | None, ...] = ()
    nuisance: tuple[str, ...] = ()
    derived: Callable | None = None  # (theta, sigma) -> {name: value}: quantities reported from the parameters

    def plausible_ranges(self, base: BaseModel) -> tuple[tuple[float, float], ...]:
        """(low, high) per parameter for the vehicle of ``base``; the search bounds when none is given."""
        if self.plausible is None:
            return tuple(zip(self.lower, self.upper))
        return tuple(self.plausible(base))

    def applicable(self, batch: WindowBatch) -> str | None:
        """None when the effect can be evaluated on ``batch``, else the reason why not."""
        if "vbat" in self.needs and batch.vbat is None:
            return "no battery voltage in the flights"
        return None


@dataclass
class BaseModel:
    """Continuous linear model pieces of :mod:`~quad_modelling.core.models.greybox` for one parameter set."""

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
        return 1.0 / self.parameters.thrust_slope


def base_from_vehicle(vehicle: VehicleConfig, reference_voltage: float | None = None) -> BaseModel:
    """The linear greybox of the vehicle's configured constants."""
    return BaseModel(GreyboxParameters.from_vehicle(vehicle), reference_voltage)


def _forcing_matrix() -> np.ndarray:
    f = np.zeros((N_STATES, 6))
    f[FORCING_STATES, np.arange(6)] = 1.0
    return f


def apply_effects(effects: Sequence[Effect], thetas: Sequence[np.ndarray], batch: WindowBatch, base: BaseModel) -> Augmentation:
    """Compose the effects' input maps (by stage), forcings and A changes on ``batch``.

    The mapped commands are trimmed again by their warm-start mean, as the forcings are: the linearisation
    point is the warm start, where the measured outputs (the output trim) answer the thrust the *mapped*
    commands gave, not the raw commands' mean. Without this, a lag (or delay) applied to commands that
    move during the warm start biases the whole window by the difference of the two means.
    """
    u = batch.u
    mapped = False
    shift = 0.0
    for stage in range(4):
        for effect, theta in zip(effects, thetas):
            if effect.input_map is not None and effect.stage == stage:
                u = effect.input_map(theta, batch, base, u)
                mapped = True
    if mapped:
        shift = u[:, : batch.warm].mean(axis=1, keepdims=True)
        u = u - shift
    forcing = np.zeros(batch.u.shape[:2] + (6,))
    a_delta = np.zeros((N_STATES, N_STATES))
    for effect, theta in zip(effects, thetas):
        if effect.forcing is not None:
            forcing = forcing + effect.forcing(theta, batch, base, u)
        if effect.a_delta is not None:
            a_delta = a_delta + effect.a_delta(theta, base)
    return Augmentation(u, forcing, a_delta, shift)


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

    Three things differ from the linear greybox's (``greybox_outputs=True`` keeps
    the greybox's, as :class:`~quad_modelling.core.models.greybox.GreyboxPredictor`):

    * **the motor's linearisation point** (:func:`_motor_linearisation_point`): the thrust state is the
      deviation from the warm-start mean thrust of the motor filter run over the command history, the
      point the measured offsets belong to; the greybox anchors on the filter over the warm rows only,
      from the steady state of the first command, with the commands minus their warm mean;

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
      :func:`angular_acceleration_offsets`): the least-squares slope of the raw
      gyro over the warm start instead of the mean of the differentiated gyro over 0.2 s, whose noise
      (the difference of two noisy rates over 0.2 s, ~0.02 rad/s²) stayed in the
      prediction as a constant error for the whole window.
    """
    aug = apply_effects(effects, thetas, batch, base) if effects else Augmentation(batch.u, np.zeros(batch.u.shape[:2] + (6,)), None)
    a = base.a if aug.a_delta is None else base.a + aug.a_delta
    b_ext = np.hstack([base.b, _forcing_matrix()])
    ad, bd_ext = zero_order_hold(a, b_ext, batch.dt)
    cd = base.c + base.d @ a
    dd_ext = base.d @ b_ext
    w, n = batch.u.shape[:2]
    anchor = batch.warm - 1
    pole, gain = ad[12, 12], bd_ext[12, 0]
    if greybox_outputs:  # the greybox predictor's anchor: the filter over the warm rows, commands minus their warm mean
        thrust0, command_trim = motor_thrusts(aug.u[:, : anchor + 1], pole, gain, axis=1)[:, anchor], np.zeros((w, 4))
    else:
        thrust0, command_trim = _motor_linearisation_point(aug.u, batch.u_history - aug.command_shift, pole, gain, batch.warm)
    inputs = np.concatenate([aug.u - command_trim[:, None, :], aug.forcing], axis=2)  # (W, N, 10)
    offsets = batch.offsets
    if not greybox_outputs and anchor >= 2:
        offsets = offsets.copy()
        offsets[:, ANGULAR_ACCELERATION_COLUMNS] = angular_acceleration_offsets(batch)
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
    if greybox_outputs:  # the greybox's pose moves with its trim point from the anchor on (greybox.trim_motion)
        elapsed = np.arange(n - anchor) * batch.dt
        out[:, anchor:, cols] += elapsed[None, :, None] * batch.trim_motion[:, None, cols]
    if anchor > 0:  # rows before the anchor are the measurement (not scored), as the greybox predictor
        out[:, :anchor, cols] = batch.warm_rows[:, :anchor][:, :, cols]
    if smoothed:
        cutoff = smooth_cutoff_hz if smooth_cutoff_hz is not None else batch.smooth_cutoff_hz
        measurement_filter(out, batch.dt, cols)
        out[:, :, cols] = smooth(out[:, :, cols].transpose(1, 0, 2), 1.0 / batch.dt, cutoff).transpose(1, 0, 2)
    return out


def _motor_linearisation_point(u: np.ndarray, history: np.ndarray, pole: float, gain: float, warm: int) -> tuple[np.ndarray, np.ndarray]:
    r"""(W, 4) thrust state at the anchor and (W, 4) command trim of the motors, both relative to the warm start.

    The outputs' linearisation point is the warm-start mean of the measurement (``batch.offsets``,
    ``batch.specific_force0``, :func:`angular_acceleration_offsets`): the accelerations the *mean thrust*
    over the warm rows gave, :math:`\bar T = \frac{1}{n_w}\sum_{k<n_w} T_k`, with :math:`T_k` the motor
    filter :math:`T_{k+1} = p T_k + g u_k` run over the commands before the window (``history``, (W, H, 4),
    :data:`~quad_modelling.core.identification.window_batch.COMMAND_HISTORY_S`, from the steady state of its
    first command) and then the window's (``u``, (W, N, 4)), on the same trim. The thrust state is the deviation from that point, :math:`x_T = T - \bar T`,
    and the commands are trimmed by the command that holds :math:`\bar T` in steady state,
    :math:`\bar u = \bar T (1 - p) / g`, so that :math:`x_{T,k+1} = p\, x_{T,k} + g (u_k - \bar u)`
    is exactly :math:`T_{k+1} - \bar T` (the constant trim of ``u`` drops out).

    Anchoring instead on :math:`T` of the commands minus their warm mean (the steady thrust of the mean
    command, not the mean thrust) offset every window by :math:`-\sum_i (\bar T_i - g \bar u_i/(1-p))/m`
    whenever the thrust moved during the warm start, and starting the filter in steady state at the window's
    first command instead of running it over the history left the start-up transient in :math:`\bar T`.
    On the linear model's own flights (collective 2 Hz, :math:`A_m = -25` 1/s,
    ``test/core/test_identification.py``) the true constants' acc_z error was 0.023 m/s² RMS (measured
    signal 0.070 m/s²) and the joint fit found :math:`A_m = -26.2` 1/s; it is now 2e-8 m/s²
    (``test/core/test_base_model.py``).
    """
    h = history.shape[1]
    thrusts = motor_thrusts(np.concatenate([history, u], axis=1), pole, gain, axis=1)[:, h:]
    thrust_trim = thrusts[:, :warm].mean(axis=1)
    return thrusts[:, warm - 1] - thrust_trim, thrust_trim * (1.0 - pole) / gain


def angular_acceleration_offsets(batch: WindowBatch) -> np.ndarray:
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
    acc = frames.kinematic_acceleration(f_b.reshape(-1, 3), batch.euler[:, anchor:].reshape(-1, 3), GRAVITY).reshape(w, m, 3)
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

