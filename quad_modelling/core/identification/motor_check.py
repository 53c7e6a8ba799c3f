"""The motor order and spin check of ``identify``: does each command column drive the rotor the vehicle
file says, spinning the way it says? Every sign is judged with its significance.

Per axis :math:`a` (roll, pitch, yaw acceleration, measured: smoothed, trimmed, rad/s²) a linear
regression on the four modelled rotor thrust deviations :math:`T_i` [N] (the identified motor,
smoothed as the measurement) with one intercept per window, over the training windows:

.. math::

    \\dot\\omega_{a}(w, t) = \\sum_i g_{i,a}\\, T_i(w, t) + c_{a,w} + e_{a}(w, t),

roll and pitch after a high-pass of both sides (:data:`HIGHPASS_HZ`: the closed loop owns the low band).

The configuration predicts :math:`g_{i,\\phi} = -y_i / I_{xx}`, :math:`g_{i,\\theta} = x_i / I_{yy}`
(rotor i at :math:`(x_i, y_i)` in body FRD) and :math:`g_{i,\\psi} = s_i\\, (k_m/k_f) / I_{zz}` (spin
:math:`s_i = +1` counter-clockwise from above). The standard error of each :math:`g_{i,a}` is the HAC
(Newey-West) one over windows (:mod:`~quad_modelling.core.identification.uncertainty`): the
residuals are autocorrelated, and counting every 100 Hz sample as independent made gains like
-746 rad/s² per N look decisive on 15 s of flight. The four thrusts move together (the collective
carries most of the command), so single gains are often poorly determined; that is what the
standard error says.

A sign is *wrong* only when :math:`|t| = |g / \\sigma_g| >` :data:`T_THRESHOLD` and opposite to the
configuration's; it *agrees* when significant and equal; otherwise it is *undetermined*. Verdict:

* ``inconsistent``: at least one wrong sign; the likely fix is the controllable layout that best
  explains the signs (:func:`likely_layout`): command columns permuted among the configured positions
  (each rotor keeps its spin when its column moves) and spins reversed;
* ``consistent``: no wrong sign, and every motor's position (roll or pitch) and spin (yaw) confirmed
  by a significant agreeing sign;
* ``undetermined``: no wrong sign, but some motor not confirmed (more differential excitation would
  help: roll/pitch/yaw manoeuvres).
"""

from __future__ import annotations

import itertools

import numpy as np

from scipy import signal

from quad_modelling.core.identification.uncertainty import bandwidth_samples, hac_covariance
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import VehicleConfig

T_THRESHOLD = 3.0
"""|t| above which a gain's sign counts (about 0.3 % two-sided for a normal estimate; the HAC standard
error is itself uncertain with few windows, so stricter than the usual 2)."""

HIGHPASS_HZ = (0.5, 0.5, 0.0)
"""Zero-phase high-pass [Hz] (2nd-order Butterworth) on both sides of the roll, pitch and yaw regressions.
In closed loop the attitude controller cancels slow disturbance torques (centre-of-gravity offset, rotor
mismatch, battery sag), so below ~1 Hz the differential commands follow the disturbance, not the measured
acceleration: on the bundled bag (t 5-35 s) the coherence of roll acceleration with the roll command is
0.15-0.36 below 1.2 Hz and 0.8-0.93 at 2-10 Hz. With the high-pass the roll/pitch |t| of the bundled bag
rose from 0.2-3.1 to 2.4-7.6. Yaw keeps its low band (weak yaw loop; the high-pass lowered its |t| from
4.4-8.8 to 2.9-10)."""

AXES = ("roll", "pitch", "yaw")
ANGULAR_ACCELERATIONS = [INDEX["roll_acc"], INDEX["pitch_acc"], INDEX["yaw_acc"]]


def expected_gains(vehicle: VehicleConfig, positions: np.ndarray | None = None, spins: np.ndarray | None = None) -> np.ndarray:
    """(4, 3) angular acceleration per rotor thrust [rad/s² per N] of the configuration (module docstring)."""
    pos = vehicle.motor_positions if positions is None else positions
    spins = vehicle.yaw_signs if spins is None else spins
    ixx, iyy, izz = vehicle.inertia
    yaw_arm = vehicle.value("rotor_torque_constant") / vehicle.value("rotor_thrust_constant")  # k_m/k_f [m]
    return np.column_stack([-pos[:, 1] / ixx, pos[:, 0] / iyy, spins * yaw_arm / izz])


def regress_gains(batch: WindowBatch, thrusts: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """(4, 3) gains g, (4, 3) HAC standard errors and details of the regression of the module docstring.

    ``thrusts``: (W, N, 4) modelled thrust deviations [N]; rows from ``batch.warm`` on are used.
    """
    x = thrusts[:, batch.warm :]
    y = batch.measured[:, batch.warm :][:, :, ANGULAR_ACCELERATIONS]
    lags = bandwidth_samples(batch.dt)
    coef, se = np.zeros((4, 3)), np.full((4, 3), np.nan)
    for a, cutoff in enumerate(HIGHPASS_HZ):
        xa, ya = x, y[:, :, a]
        if cutoff > 0:  # the same linear filter on both sides keeps the static relation
            sos = signal.butter(2, cutoff, btype="high", fs=1.0 / batch.dt, output="sos")
            if x.shape[1] <= 3 * (2 * len(sos) + 1):  # fewer rows than filtfilt's padding: this axis stays undetermined
                continue
            xa, ya = signal.sosfiltfilt(sos, xa, axis=1), signal.sosfiltfilt(sos, ya, axis=1)
        xa = xa - xa.mean(axis=1, keepdims=True)  # the per-window intercepts (Frisch-Waugh)
        ya = ya - ya.mean(axis=1, keepdims=True)
        coef[:, a], *_ = np.linalg.lstsq(xa.reshape(-1, 4), ya.ravel(), rcond=None)
        resid = ya - xa @ coef[:, a]
        try:
            cov = hac_covariance(xa[:, :, None, :], resid[:, :, None], lags)
        except np.linalg.LinAlgError:
            continue  # a motor never moved apart from the others: its gains stay undetermined
        se[:, a] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return coef, se, {"windows": int(x.shape[0]), "samples": int(x.shape[0] * x.shape[1]), "hac_lags": lags}


def sign_status(t: float, expect: float) -> str:
    """'agrees', 'wrong' or 'undetermined' for a gain's t statistic against the expected sign."""
    if expect == 0 or not np.isfinite(t) or abs(t) <= T_THRESHOLD:
        return "undetermined"
    return "agrees" if np.sign(t) == np.sign(expect) else "wrong"


def valid_spins(positions: np.ndarray, spins: np.ndarray) -> bool:
    """Whether rotors at ``positions`` (4, 2) with ``spins`` (4,) make a controllable quadrotor: two spin each
    way (the reaction torques cancel at hover) and the mixing matrix of collective, roll (-y), pitch (x) and
    yaw (s) rows has full rank (in the "x" layout, diagonal rotors share a spin; reversing two neighbours
    makes yaw a multiple of roll or pitch)."""
    mixing = np.vstack([np.ones(4), -positions[:, 1], positions[:, 0], spins])
    return int(np.sum(spins)) == 0 and np.linalg.matrix_rank(mixing) == 4


def likely_layout(t: np.ndarray, vehicle: VehicleConfig) -> dict:
    """The valid layout (:func:`valid_spins`) that best explains the gains' t statistics ``t`` (4, 3).

    Candidates: the 24 orders of the command columns over the configured positions, each with the 16 spin
    sets; a rotor keeps its spin when its column moves, so a changed spin is one the moved rotor does not
    have. Ranked by significant contradictions (|t| > :data:`T_THRESHOLD`, opposite sign), then by the
    support :math:`\\sum_{i,a} t_{i,a}\\,\\mathrm{sign}(g^{exp}_{i,a})` (the weak signs decide between
    layouts the strong ones cannot tell apart), then by the number of changes.
    """
    pos, spins = vehicle.motor_positions, vehicle.yaw_signs
    t = np.nan_to_num(t)
    significant = np.abs(t) > T_THRESHOLD
    best = None
    for order in itertools.permutations(range(4)):
        moved = sum(i != j for i, j in enumerate(order))
        for candidate in itertools.product((1.0, -1.0), repeat=4):
            candidate = np.array(candidate)
            if not valid_spins(pos[list(order)], candidate):
                continue
            expect = np.sign(expected_gains(vehicle, pos[list(order)], candidate))
            contradictions = int(np.sum(significant & (expect != 0) & (np.sign(t) != expect)))
            support = float(np.sum(t * expect))
            changes = moved + int(np.sum(candidate != spins[list(order)]))
            key = (contradictions, -support, changes)
            if best is None or key < best[0]:
                best = (key, order, candidate)
    (contradictions, _, _), order, data_spins = best
    names = [m.name for m in vehicle.motors]
    reversed_spins = [names[i] for i in range(4) if data_spins[i] != spins[order[i]]]
    moved = sum(i != j for i, j in enumerate(order))
    return {"order": [names[j] for j in order], "moved": moved, "spins": [int(s) for s in data_spins],
            "reversed_spins": reversed_spins, "unexplained": contradictions}


def _describe_order(order: list[str], names: list[str]) -> list[str]:
    """Human cycles of a column order: ['m1 <-> m2'] for a swap, ['m1 -> m2 -> m3 -> m1'] otherwise."""
    target = dict(zip(names, order))
    seen, cycles = set(), []
    for start in names:
        if start in seen or target[start] == start:
            continue
        cycle, name = [], start
        while name not in seen:
            seen.add(name)
            cycle.append(name)
            name = target[name]
        cycles.append(f"{cycle[0]} <-> {cycle[1]}" if len(cycle) == 2 else " -> ".join(cycle + [cycle[0]]))
    return cycles


def check_motor_layout(batch: WindowBatch, thrusts: np.ndarray, vehicle: VehicleConfig) -> dict:
    """Judge every motor's roll/pitch/yaw gain sign against the configuration (module docstring).

    Returns ``verdict`` ('consistent' / 'inconsistent' / 'undetermined'), ``consistent`` (verdict is
    'consistent'), ``motors`` (per motor: gain, standard error, t, expected gain and status per axis),
    ``fix`` (the likely layout and its description when inconsistent), ``data_spins`` (the spins the data
    shows when the order agrees and only spins differ, else None) and ``yaw_reversed`` (every spin
    reversed).
    """
    coef, se, details = regress_gains(batch, thrusts)
    t = coef / se
    expect = expected_gains(vehicle)
    motors, wrong, unconfirmed = [], [], []
    for i, motor in enumerate(vehicle.motors):
        status = [sign_status(t[i, a], expect[i, a]) for a in range(3)]
        wrong += [f"{motor.name} {axis}" for axis, s in zip(AXES, status) if s == "wrong"]
        if "agrees" not in status[:2] or status[2] != "agrees":
            unconfirmed.append(motor.name)
        motors.append({"name": motor.name,
                       **{axis: {"gain": float(coef[i, a]), "sigma": float(se[i, a]), "t": float(t[i, a]),
                                 "expect": float(expect[i, a]), "status": status[a]} for a, axis in enumerate(AXES)}})
    verdict = "inconsistent" if wrong else ("undetermined" if unconfirmed else "consistent")
    fix, data_spins = None, None
    if wrong:
        layout = likely_layout(t, vehicle)
        names = [m.name for m in vehicle.motors]
        actions = [f"swapped order: {c}" for c in _describe_order(layout["order"], names)]
        if len(layout["reversed_spins"]) == 4:
            actions.append("every spin reversed")
        elif layout["reversed_spins"]:
            actions.append("reversed spin: " + ", ".join(layout["reversed_spins"]))
        fix = {**layout, "actions": actions or ["no layout explains the signs: check the vehicle file's positions"]}
        if layout["moved"] == 0 and layout["reversed_spins"] and layout["unexplained"] == 0:
            data_spins = layout["spins"]
    return {
        "verdict": verdict, "consistent": verdict == "consistent", "wrong": wrong, "unconfirmed": unconfirmed,
        "fix": fix, "data_spins": data_spins, "yaw_reversed": bool(fix and len(fix["reversed_spins"]) == 4 and fix["moved"] == 0),
        "motors": motors, "t_threshold": T_THRESHOLD,
        "method": ("least squares of measured roll/pitch/yaw acceleration on the four modelled rotor thrusts, one "
                   "intercept per window; HAC (Newey-West) standard errors, windows as blocks, Bartlett bandwidth "
                   f"{details['hac_lags']} samples; a sign counts when |t| > {T_THRESHOLD:g}"),
        **details,
    }


def check_lines(check: dict) -> list[str]:
    """The printed motor order/spin check (lines <= 100 characters)."""
    head = {"consistent": "consistent with the config", "undetermined": "undetermined (no sign contradicts the config)",
            "inconsistent": "INCONSISTENT with the config"}[check["verdict"]]
    lines = [f"  motor order/spin check: {head} (a sign counts when |t| > {check['t_threshold']:g})"]
    for m in check["motors"]:
        cells = []
        for axis in AXES:
            g = m[axis]
            mark = {"agrees": "ok", "wrong": "WRONG", "undetermined": "?"}[g["status"]]
            cells.append(f"{axis} {g['gain']:+.3g} (t {g['t']:+.1f}, exp {g['expect']:+.3g}) {mark}")
        lines.append(f"    {m['name']}:")
        lines.append("      " + "; ".join(cells[:2]))
        lines.append("      " + cells[2])
    if check["verdict"] == "inconsistent":
        lines.append("    wrong signs: " + ", ".join(check["wrong"]))
        for action in check["fix"]["actions"]:
            lines.append(f"    likely fix: {action}")
        if check["fix"]["moved"]:
            lines.append("    the constants above were identified with the configured order: fix it and identify again")
        elif check["data_spins"] is not None:
            lines.append("    the identified file uses the spins the data shows")
    elif check["verdict"] == "undetermined":
        lines.append("    not confirmed: " + ", ".join(check["unconfirmed"])
                     + " (more roll/pitch/yaw excitation would help)")
    return lines
