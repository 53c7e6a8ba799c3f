"""Identification of the greybox model's motor constants from flight data (training spans only).

What the linear model can see (:mod:`quad_modelling.core.models.greybox`): each
rotor's thrust deviation follows the trimmed command through one pole,

.. math::

    \\dot T_i = A_m T_i + K u_i, \\qquad K = 2 B_m \\sqrt{a m g / 4},

and the measured accelerations are linear in the :math:`T_i`:

.. math::

    \\ddot Z = -\\frac{1}{m}\\sum_i T_i,\\quad
    \\ddot\\phi = -\\frac{1}{I_{xx}}\\sum_i y_i T_i,\\quad
    \\ddot\\theta = \\frac{1}{I_{yy}}\\sum_i x_i T_i,\\quad
    \\ddot\\psi = \\frac{1}{I_{zz}}\\Big(\\frac{d}{a}\\sum_i s_i T_i
        + I_{prop}\\sum_i s_i \\big(\\frac{A_m T_i}{2 a \\Omega_0} + B_m u_i\\big)\\Big).

So :math:`A_m` and :math:`K` are identified together (nonlinear least squares,
:func:`scipy.optimize.least_squares`, on the smoothed trimmed Z, roll and
pitch accelerations of every training window, each normalised by its standard
deviation), then the yaw drag ratio :math:`d/a` and a scale :math:`k_R` of the rotor-reaction
(:math:`I_{prop}`) term by linear least squares on the yaw acceleration (an
inconsistent configured :math:`I_{prop}` or :math:`a` would otherwise bias
:math:`d/a`). :math:`a` itself cannot be separated from :math:`B_m` (only
:math:`B_m \\sqrt a` appears): it is held at its configured value and
:math:`B_m = K / (2\\sqrt{a m g/4})`, :math:`d = a \\cdot (d/a)`.

Uncertainties (1 sigma) come from the Jacobian at the optimum,
:math:`\\mathrm{cov} = s^2 (J^T J)^{-1}` with :math:`s^2` = residual variance;
residuals are autocorrelated (smoothed, 100 Hz), so they are optimistic -- the
window-to-window spread is reported next to them.

Battery voltage: the thrust gain per command :math:`K` is fitted per window
(with :math:`A_m` fixed) and regressed on the window's mean voltage, giving
:math:`K(V) = K_0 (1 + \\kappa (V - V_0))`.

Motor order and spin check: the angular accelerations are regressed on the
four modelled thrusts separately; each motor's coefficient signs must match
its configured position (roll: :math:`-y_i`, pitch: :math:`x_i`) and spin
(yaw: :math:`s_i`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy import optimize

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.identification.greybox_fit import MOTOR_TIME_CONSTANT_RANGE
from quad_modelling.core.models.greybox import GreyboxParameters
from quad_modelling.core.models.motors import discrete_motor, motor_thrusts
from quad_modelling.core.preprocess import (
    resample_uniform,
    smooth,
    trimmed_inputs,
    trimmed_variables,
    uniform_time_check,
)
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import GRAVITY, VehicleConfig
from quad_modelling.core.windows import EvaluationConfig, Window, plan_windows
from quad_modelling.errors import DataError

MOTOR_POLE_RANGE = (1.0 / MOTOR_TIME_CONSTANT_RANGE[1], 1.0 / MOTOR_TIME_CONSTANT_RANGE[0])
"""Search range of -A_m [1/s]: the motor time constants of the diagnosis base fit,
:data:`~quad_modelling.core.identification.greybox_fit.MOTOR_TIME_CONSTANT_RANGE` (2 ms ... 2 s; its
docstring says why 2 ms); a fit that ends on a bound says so (``fit['motor_pole_at_bound']``)."""

ACC_COLUMNS = [INDEX["acc_z"], INDEX["roll_acc"], INDEX["pitch_acc"], INDEX["yaw_acc"]]


@dataclass
class TrainingWindow:
    """One training window, preprocessed: trimmed inputs and smoothed trimmed accelerations."""

    source: str
    t0: float
    dt: float
    u: np.ndarray  # (N, 4) trimmed commands
    acc: np.ndarray  # (N, 4) acc_z, roll_acc, pitch_acc, yaw_acc (trimmed, smoothed, SI)
    vbat: float | None
    skip: int  # rows of filter start-up not scored


@dataclass
class IdentificationResult:
    values: dict[str, float]
    sigma: dict[str, float]
    input_gain: float
    input_gain_sigma: float
    window_gains: list[float]
    voltage: dict | None
    motor_check: dict
    spans: list[dict]
    files: list[str]
    fit: dict = field(default_factory=dict)
    spins: list[int] = field(default_factory=list)

    def summary(self) -> str:
        lines = [f"identified from {len(self.spans)} training windows of {len(self.files)} flight(s):"]
        for key, value in self.values.items():
            lines.append(f"  {key} = {value:.6g} ± {self.sigma.get(key, float('nan')):.2g}")
        lines.append(f"  thrust gain K = {self.input_gain:.6g} ± {self.input_gain_sigma:.2g} N/s per command unit")
        if self.voltage:
            lines.append(f"  voltage dependence: K(V) = K0 (1 + {self.voltage['kappa_per_volt']:.3g} (V - {self.voltage['v0']:.2f} V)) "
                         f"± {self.voltage['kappa_sigma']:.2g} /V")
        lines.append(f"  motor order/spin check: {'consistent' if self.motor_check['consistent'] else 'INCONSISTENT'} with the config")
        if self.motor_check.get("yaw_reversed"):
            lines.append("    every rotor's yaw sign is opposite to the config while roll/pitch agree: the spins are reversed; "
                         "the identified file uses the spins the data shows")
        for motor in self.motor_check["motors"]:
            lines.append(f"    {motor['name']}: roll {motor['roll']:+.3g} (expect {motor['expect'][0]:+d}), pitch {motor['pitch']:+.3g} "
                         f"(expect {motor['expect'][1]:+d}), yaw {motor['yaw']:+.3g} (expect {motor['expect'][2]:+d})")
        return "\n".join(lines)


def training_windows(flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig) -> list[TrainingWindow]:
    """Preprocessed windows of the training span (never the evaluation span)."""
    flights = [resample_uniform(log) for log in flights]
    plan = plan_windows(flights, config)
    windows: list[Window] = plan.get("train", [])
    if not windows:
        raise DataError(f"no training window of {config.window_s:g} s in span {config.train}; adjust --train/--drop or --window")
    out = []
    for w in windows:
        log = flights[w.flight].slice(w.start, w.stop)
        uniform_time_check(log)
        measured = smooth(trimmed_variables(log, config.trim, vehicle), log.sample_rate, config.smooth_cutoff_hz)
        out.append(
            TrainingWindow(log.meta.source, float(log.t[0] - flights[w.flight].t[0]), 1.0 / log.sample_rate, trimmed_inputs(log, config.trim),
                           measured[:, ACC_COLUMNS], None if log.vbat is None else float(log.vbat.mean()), int(round(config.warm_s * log.sample_rate)))
        )
    return out


def lagged_thrusts(u: np.ndarray, pole_a_m: float, gain: float, dt: float) -> np.ndarray:
    """(N, 4) thrust deviations of the motor A_m = ``pole_a_m``, K = ``gain`` (:mod:`quad_modelling.core.models.motors`)."""
    return motor_thrusts(u, *discrete_motor(pole_a_m, gain, dt))


def _predicted_acc(p: GreyboxParameters, thrusts: np.ndarray) -> np.ndarray:
    """(N, 3) acc_z, roll_acc, pitch_acc of the linear model from thrust deviations."""
    pos = np.array(p.motor_positions)
    return np.column_stack([-thrusts.sum(axis=1) / p.mass, -(thrusts @ pos[:, 1]) / p.ixx, (thrusts @ pos[:, 0]) / p.iyy])


def identify(flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig | None = None) -> IdentificationResult:
    """Identify A_m, B_m (with a held), d and the voltage dependence; check motor order/spins."""
    config = config or EvaluationConfig()
    windows = training_windows(flights, vehicle, config)
    p = GreyboxParameters.from_vehicle(vehicle)
    scale = np.std(np.concatenate([w.acc[w.skip:, :3] for w in windows]), axis=0)
    scale = np.where(scale > 0, scale, 1.0)

    def residuals(theta: np.ndarray) -> np.ndarray:
        a_m, gain = -np.exp(theta[0]), np.exp(theta[1])
        res = []
        for w in windows:
            pred = smooth(-lagged_thrusts(w.u, a_m, gain, w.dt).sum(axis=1) / p.mass, 1.0 / w.dt, config.smooth_cutoff_hz)
            res.append((w.acc[:, 0] - pred)[w.skip:])
        return np.concatenate(res)

    theta0 = np.array([np.log(-p.motor_a_m), np.log(p.input_gain)])
    best = None
    bounds = ([np.log(MOTOR_POLE_RANGE[0]), -np.inf], [np.log(MOTOR_POLE_RANGE[1]), np.inf])
    theta0[0] = np.clip(theta0[0], bounds[0][0] + 1e-6, bounds[1][0] - 1e-6)
    for start_gain in (0.0, np.log(3.0), -np.log(3.0)):  # a few starts: K can be off by a lot
        fit = optimize.least_squares(residuals, theta0 + np.array([0.0, start_gain]), method="trf", x_scale=1.0, bounds=bounds)
        if best is None or fit.cost < best.cost:
            best = fit
    theta = best.x
    n_res = best.fun.size
    s2 = 2.0 * best.cost / max(n_res - theta.size, 1)
    try:
        cov = np.linalg.inv(best.jac.T @ best.jac) * s2
    except np.linalg.LinAlgError:
        cov = np.full((2, 2), np.nan)
    a_m, gain = -np.exp(theta[0]), np.exp(theta[1])
    sigma_a_m, sigma_gain = abs(a_m) * np.sqrt(cov[0, 0]), gain * np.sqrt(cov[1, 1])
    root = 2.0 * np.sqrt(p.thrust_constant * p.mass * GRAVITY / 4.0)
    b_m, sigma_b_m = gain / root, sigma_gain / root

    thrusts_by_window = [smooth(lagged_thrusts(w.u, a_m, gain, w.dt), 1.0 / w.dt, config.smooth_cutoff_hz) for w in windows]
    motor_check = check_motor_layout(windows, thrusts_by_window, vehicle)
    if motor_check["yaw_reversed"]:
        vehicle = vehicle_with_spins(vehicle, -vehicle.yaw_signs)
        p = GreyboxParameters.from_vehicle(vehicle)
    attitude_gain = []
    for k in (1, 2):
        unit = np.concatenate([_predicted_acc(p, t)[w.skip:, k] for w, t in zip(windows, thrusts_by_window)])
        target = np.concatenate([w.acc[w.skip:, k] for w in windows])
        attitude_gain.append(float(unit @ target / (unit @ unit)) if unit @ unit > 0 else float("nan"))

    # yaw: tau_psi Izz = (d/a) sum s_i T_i + I_prop sum s_i (A_m T_i / (2 a Omega0) + B_m u_i)
    signs = np.array(p.yaw_signs)
    omega0 = p.hover_rotor_speed
    columns, targets = [], []
    reaction_columns = []
    for w, thrusts in zip(windows, thrusts_by_window):
        u_smooth = smooth(w.u, 1.0 / w.dt, config.smooth_cutoff_hz)
        reaction = p.prop_inertia * ((thrusts @ signs) * a_m / (2 * p.thrust_constant * omega0) + b_m * (u_smooth @ signs))
        columns.append((thrusts @ signs)[w.skip:])
        reaction_columns.append(reaction[w.skip:])
        targets.append((w.acc[:, 3] * p.izz)[w.skip:])
    # tau_psi = (d/a) sum s_i T_i + k_R * (rotor reaction term with the configured I_prop, a, B_m): k_R is
    # fitted too, since an inconsistent I_prop or a (thesis Table 3-1) would otherwise bias d/a.
    design = np.column_stack([np.concatenate(columns), np.concatenate(reaction_columns)])
    y_yaw = np.concatenate(targets)
    if np.linalg.matrix_rank(design) < 2:
        ratio = sigma_ratio = reaction_scale = float("nan")
    else:
        (ratio, reaction_scale), *_ = np.linalg.lstsq(design, y_yaw, rcond=None)
        res_yaw = y_yaw - design @ np.array([ratio, reaction_scale])
        cov_yaw = np.linalg.inv(design.T @ design) * (res_yaw @ res_yaw) / max(len(y_yaw) - 2, 1)
        ratio, reaction_scale, sigma_ratio = float(ratio), float(reaction_scale), float(np.sqrt(cov_yaw[0, 0]))
    drag, sigma_drag = ratio * p.thrust_constant, sigma_ratio * p.thrust_constant

    # per-window gain (A_m fixed) and its voltage dependence
    window_gains = []
    for w, thrusts in zip(windows, thrusts_by_window):
        unit = -(thrusts / gain).sum(axis=1)[w.skip:] / p.mass
        target = w.acc[w.skip:, 0]
        denom = float(np.sum(unit * unit))
        window_gains.append(float(np.sum(unit * target) / denom) if denom > 0 else float("nan"))
    voltage = None
    volts = np.array([w.vbat if w.vbat is not None else np.nan for w in windows])
    gains = np.array(window_gains)
    ok = np.isfinite(volts) & np.isfinite(gains)
    if ok.sum() >= 3 and np.ptp(volts[ok]) > 0.05:
        v0 = float(volts[ok].mean())
        design = np.column_stack([np.ones(ok.sum()), volts[ok] - v0])
        coef, *_ = np.linalg.lstsq(design, gains[ok], rcond=None)
        resid = gains[ok] - design @ coef
        cov_v = np.linalg.inv(design.T @ design) * (resid @ resid) / max(ok.sum() - 2, 1)
        voltage = {
            "v0": v0, "k0": float(coef[0]), "dk_dv": float(coef[1]), "kappa_per_volt": float(coef[1] / coef[0]),
            "kappa_sigma": float(np.sqrt(cov_v[1, 1]) / abs(coef[0])), "windows": int(ok.sum()),
            "voltage_range": [float(volts[ok].min()), float(volts[ok].max())],
        }

    files = sorted({w.source for w in windows})
    spans = [{"file": w.source, "start_s": w.t0, "end_s": w.t0 + len(w.u) * w.dt} for w in windows]
    values = {"motor_a_m": float(a_m), "motor_b_m": float(b_m), "drag_constant": float(drag)}
    sigma = {"motor_a_m": float(sigma_a_m), "motor_b_m": float(sigma_b_m), "drag_constant": float(sigma_drag)}
    spread = float(np.nanstd(gains) / np.sqrt(max(ok.sum(), 1))) if gains.size else float("nan")
    return IdentificationResult(
        values, sigma, float(gain), float(sigma_gain), window_gains, voltage, motor_check, spans, files,
        fit={"cost": float(best.cost), "residuals": int(n_res), "gain_window_spread_sigma": spread,
             "thrust_constant_held": p.thrust_constant,
             "motor_pole_at_bound": bool(np.isclose(-a_m, MOTOR_POLE_RANGE, rtol=1e-3).any()),
             "fitted_on": "acc_z (A_m, K); yaw_acc (d/a and the rotor-reaction scale k_R)",
             "rotor_reaction_scale": reaction_scale,
             "roll_pitch_gain_ratio": attitude_gain,
             "roll_pitch_gain_ratio_meaning": "least-squares scale of the model's roll/pitch acceleration that best fits the data "
                                              "(1 = consistent with the Z-identified gain, inertia and arm length)"},
        spins=[int(s) for s in vehicle.yaw_signs],
    )


def check_motor_layout(windows: Sequence[TrainingWindow], thrusts: Sequence[np.ndarray], vehicle: VehicleConfig) -> dict:
    """Regress roll/pitch/yaw acceleration on each motor's modelled thrust; compare signs with the config."""
    x = np.concatenate([t[w.skip:] for w, t in zip(windows, thrusts)])
    y = np.concatenate([w.acc[w.skip:, 1:4] for w in windows])
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)  # (4 motors, 3 axes)
    pos = vehicle.motor_positions
    motors, consistent = [], True
    for i, motor in enumerate(vehicle.motors):
        expect = (int(np.sign(-pos[i, 1])), int(np.sign(pos[i, 0])), int(motor.yaw_sign))
        got = coef[i]
        agrees = [e == 0 or np.sign(g) == e for e, g in zip(expect, got)]
        consistent &= all(agrees)
        motors.append({"name": motor.name, "roll": float(got[0]), "pitch": float(got[1]), "yaw": float(got[2]),
                       "expect": list(expect), "agrees": [bool(a) for a in agrees]})
    roll_pitch_ok = all(all(m["agrees"][:2]) for m in motors)
    yaw_reversed = roll_pitch_ok and not any(m["agrees"][2] for m in motors)
    return {"consistent": bool(consistent), "yaw_reversed": bool(yaw_reversed), "motors": motors,
            "method": "least squares of measured roll/pitch/yaw acceleration on the four modelled rotor thrusts"}


def vehicle_with_spins(vehicle: VehicleConfig, yaw_signs: np.ndarray) -> VehicleConfig:
    """A copy of ``vehicle`` whose rotors have the given yaw signs (+1 = ccw seen from above)."""
    from dataclasses import replace

    motors = tuple(replace(m, yaw_sign=int(s)) for m, s in zip(vehicle.motors, yaw_signs))
    return replace(vehicle, motors=motors)


def identified_vehicle_document(vehicle: VehicleConfig, result: IdentificationResult, span_text: str) -> dict:
    """A vehicle YAML document (loadable by load_vehicle) with the identified constants and their provenance."""
    names = ", ".join(Path(f).name for f in result.files)
    source = f"identified from {names} spans {span_text} ({len(result.spans)} training windows) by quad-modelling identify"
    constants = {}
    for key, c in vehicle.constants.items():
        entry = {"value": c.value, "unit": c.unit, "source": c.source, "status": c.status}
        if key in result.values and not np.isfinite(result.values[key]):  # the flights do not excite it
            entry["source"] = f"{c.source}; kept: not identifiable from {names} spans {span_text} (no excitation)"
        elif key in result.values:
            entry.update(value=result.values[key], source=source, sigma=result.sigma[key])
        elif key == "thrust_constant" and c.status == "identified":
            entry["source"] = f"{c.source}; held fixed by identify (only B_m sqrt(a) is identifiable from motion)"
        constants[key] = entry
    return {
        "name": vehicle.name,
        "description": f"{vehicle.description} -- constants identified from flight data",
        "geometry": vehicle.geometry,
        "motors": [{"name": m.name, "position": list(m.position), "spin": "ccw" if s > 0 else "cw"}
                   for m, s in zip(vehicle.motors, result.spins or vehicle.yaw_signs)],
        "inputs": {"min": vehicle.input_min, "max": vehicle.input_max, "unit": vehicle.input_unit},
        "constants": constants,
        "identification": {
            "files": result.files,
            "spans": result.spans,
            "thrust_gain_K": {"value": result.input_gain, "sigma": result.input_gain_sigma, "unit": "N/s per command unit"},
            "voltage_dependence": result.voltage,
            "motor_check": result.motor_check,
            "fit": result.fit,
        },
    }


def write_vehicle_yaml(document: dict, path: Path) -> None:
    """Write a vehicle document as YAML (the caller wraps this in atomic_output)."""
    path.write_text(yaml.safe_dump(document, sort_keys=False, allow_unicode=True))
