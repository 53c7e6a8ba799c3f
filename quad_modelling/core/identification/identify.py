"""Identification of the greybox model's motor constants from flight data (training spans only), for ``quad-modelling identify``.

The constants come from the one identification of the linear model,
:func:`quad_modelling.core.identification.greybox_fit.identify_base` -- the fit the diagnosis uses for its
base model -- on the windows of the training span (:func:`training_batch`): the motor pole
:math:`A_m = -1/\\tau_m`, the thrust gain :math:`K = 2 B_m \\sqrt{a m g / 4}`, the yaw drag ratio
:math:`d/a`, a common arm scale and the rotor-reaction scale :math:`k_R`, jointly on the smoothed
acc_z, roll, pitch and yaw accelerations. :math:`a` itself cannot be separated from :math:`B_m` (only
:math:`B_m \\sqrt a` appears): it is held at its configured value and
:math:`B_m = K / (2\\sqrt{a m g/4})`, :math:`d = a \\cdot (d/a)`. Bounds, units and uncertainties
are those of :mod:`~quad_modelling.core.identification.greybox_fit`.

Around that fit, with the identified motor (:func:`quad_modelling.core.discretise.motor_thrusts`):

Battery voltage: the thrust gain per command :math:`K` is fitted per window
(with :math:`A_m` fixed) on the acc_z of the linear model,
:math:`\\ddot Z = -\\sum_i T_i / m`, and regressed on the window's mean voltage, giving
:math:`K(V) = K_0 (1 + \\kappa (V - V_0))`.

Motor order and spin check (:mod:`~quad_modelling.core.identification.motor_check`): the angular
accelerations are regressed on the four modelled thrusts; each sign is judged with its HAC standard
error (consistent / inconsistent naming the likely fix / undetermined). When the order agrees and only
spins differ, the constants are identified again with the spins the data shows, and the vehicle file
carries those spins.

Reporting (:mod:`~quad_modelling.core.identification.constants_report`): every identified constant
with unit, 1-sigma, bounds, at-bound flag and change from the vehicle file, in the summary and the
identified vehicle YAML; poorly determined ones flagged with what would help.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.physics.effects import effects_document, held_at_zero
from quad_modelling.core.identification.constants_report import ConstantEstimate, add_physics_constants, constant_lines, estimate_source
from quad_modelling.core.identification.greybox_fit import BaseFit, constant_estimates, identify_base
from quad_modelling.core.identification.least_squares import poorly_determined
from quad_modelling.core.identification.motor_check import check_lines, check_motor_layout
from quad_modelling.core.identification.physics_fit import identify_physics
from quad_modelling.core.identification.physics_result import PhysicsFit
from quad_modelling.core.identification.window_batch import WindowBatch, prepare_windows
from quad_modelling.core.discretise import discrete_motor, motor_thrusts
from quad_modelling.core.preprocess import smooth
from quad_modelling.core.variables import INDEX
from quad_modelling.core.physics.parameters import PHYSICS_KEYS
from quad_modelling.core.vehicle import AIRFRAME_OF, Constant, VehicleConfig
from quad_modelling.core.windows import EvaluationConfig, SpanSpec, check_window_rate
from quad_modelling.errors import ConfigError, DataError

IDENTIFIED_CONSTANTS = ("motor_a_m", "motor_b_m", "torque_constant")
"""The greybox constants ``identify`` writes into the vehicle file's ``greybox:`` section, as effective values of
the linear model (the others of the fit are reported in ``identification.fit``); the physical constants are the
physics fit's (:func:`~quad_modelling.core.identification.physics_fit.add_physics_constants`)."""


def windows_text(count: int) -> str:
    """"1 training window", "3 training windows"."""
    return f"{count} training window{'' if count == 1 else 's'}"


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
    physics: PhysicsFit | None = None
    physics_note: str = ""
    airframe: dict[str, float] = field(default_factory=dict)
    """The vehicle file's airframe inertias (ixx, iyy [kg m²]) the effective ones are compared with."""
    constants: list[ConstantEstimate] = field(default_factory=list)
    """Every identified constant (:class:`~quad_modelling.core.identification.constants_report.ConstantEstimate`)
    of every fit, in print order; a fit adds its own (e.g. the physics model's) the same way."""

    def summary(self) -> str:
        """The printed report (lines <= 100 characters)."""
        names = ", ".join(Path(f).name for f in self.files)
        lines = constant_lines(self.constants, f"identified on {names} ({windows_text(len(self.spans))}); "
                                               f"1-sigma from HAC standard errors:")
        if self.voltage:  # a fitted value as the constants: the one rule says when it is poorly determined
            kappa, sigma = self.voltage["kappa_per_volt"], self.voltage["kappa_sigma"]
            lines.append(f"  voltage dependence: K(V) = K0 (1 + {kappa:.3g} (V - {self.voltage['v0']:.2f} V)), sigma {sigma:.2g} 1/V")
            why = poorly_determined(kappa, sigma, "1/V")
            if why:
                lines += [f"  poorly determined: voltage dependence: {why};", "    would help: flights over a wider battery range"]
        lines += check_lines(self.motor_check)
        lines.extend(self.physics.summary() if self.physics is not None else [f"physics model constants {self.physics_note}"])
        lines.extend(self.effective_inertia_lines())
        return "\n".join(lines)

    def effective_inertia_lines(self) -> list[str]:
        """One line per effective roll/pitch inertia the physics fit identified, with its ratio to the airframe's
        (an effective value: docs/models.md, effective inertia)."""
        if self.physics is None:
            return []
        lines = []
        for key, airframe_key in AIRFRAME_OF.items():
            value, airframe = self.physics.values.get(key), self.airframe.get(airframe_key)
            if value is not None and airframe:
                lines.append(f"  {key} {value:.3g} kg m2 = {value / airframe:.2f} x the airframe's {airframe_key} {airframe:.3g} "
                             f"(effective value)")
        return lines


def training_batch(flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig) -> WindowBatch:
    """The windows of ``config``'s training span (never the evaluation span), preprocessed as the diagnosis's
    (:func:`~quad_modelling.core.identification.window_batch.prepare_windows`, ground-contact windows left out)."""
    config.validate()
    for log in flights:
        log.require(("acc_b", "gyro_b"), "identify (it fits the measured Z and angular accelerations)")
        check_window_rate(log)  # a flight too slow for any window: its rate is the problem, not the spans
    try:
        return prepare_windows(flights, vehicle, config, SpanSpec.parse("train", config.train))
    except DataError as err:
        raise DataError(f"no usable training window of {config.window_s:g} s in span {config.train}: {err}; "
                        f"adjust --train/--drop or --window") from err


def modelled_thrusts(batch: WindowBatch, fit: BaseFit) -> np.ndarray:
    """(W, N, 4) thrust deviations [N] of the identified motor, smoothed as the measurement."""
    p = fit.model.parameters
    thrusts = motor_thrusts(batch.u, *discrete_motor(p.motor_a_m, p.input_gain, batch.dt), axis=1)
    return smooth(thrusts.transpose(1, 0, 2), 1.0 / batch.dt, batch.smooth_cutoff_hz).transpose(1, 0, 2)


def identify(flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig | None = None,
             terms: Sequence[str] = ()) -> IdentificationResult:
    """Identify A_m, B_m (with a held), d and the voltage dependence; check motor order/spins."""
    config = config or EvaluationConfig()
    batch = training_batch(flights, vehicle, config)
    fit = identify_base(batch, vehicle)
    motor_check = check_motor_layout(batch, modelled_thrusts(batch, fit), vehicle)
    start = vehicle
    if motor_check["data_spins"] is not None:
        vehicle = vehicle_with_spins(vehicle, np.array(motor_check["data_spins"]))
        fit = identify_base(batch, vehicle)
    p = fit.model.parameters
    gain = p.input_gain
    window_gains = _window_gains(batch, modelled_thrusts(batch, fit) / gain, p.mass)
    voltage = _voltage_dependence(batch, window_gains)
    files = sorted(set(batch.sources))
    length_s = batch.samples * batch.dt
    spans = [{"file": source, "start_s": float(t0), "end_s": float(t0 + length_s)} for source, t0 in zip(batch.sources, batch.t0)]
    gains = np.array(window_gains)
    finite = np.isfinite(gains)
    spread = float(np.std(gains[finite]) / np.sqrt(finite.sum())) if finite.any() else float("nan")
    physics, physics_note = identify_physics_if_configured(flights, vehicle, config, terms)
    return IdentificationResult(
        {key: float(fit.values[key]) for key in IDENTIFIED_CONSTANTS}, {key: fit.sigma[key] for key in IDENTIFIED_CONSTANTS},
        float(gain), fit.sigma["thrust_gain_K"], window_gains, voltage, motor_check, spans, files,
        fit={**fit.fit, "gain_window_spread_sigma": spread, "thrust_constant_held": p.thrust_constant,
             "rotor_reaction_scale": fit.values["rotor_reaction_scale"], "arm_scale": fit.values["arm_scale"],
             "arm_scale_meaning": "common scale of the motor arm lengths that best fits roll/pitch acceleration "
                                  "(1 = consistent with the configured geometry and inertia)",
             "ground_contact_windows_dropped": int(batch.ground_contact_dropped)},
        spins=[int(s) for s in vehicle.yaw_signs], physics=physics, physics_note=physics_note,
        airframe={key: vehicle.value(key) for key in AIRFRAME_OF.values()}, constants=constant_estimates(fit, start),
    )


def _window_gains(batch: WindowBatch, thrusts_per_gain: np.ndarray, mass: float) -> list[float]:
    """Least-squares K of each window with A_m fixed: acc_z = K (-sum_i T_i / K) / m."""
    unit = -thrusts_per_gain[:, batch.warm :].sum(axis=2) / mass
    target = batch.measured[:, batch.warm :, INDEX["acc_z"]]
    denominator = np.sum(unit * unit, axis=1)
    safe = np.where(denominator > 0, denominator, 1.0)
    return [float(g) for g in np.where(denominator > 0, np.sum(unit * target, axis=1) / safe, np.nan)]


def _voltage_dependence(batch: WindowBatch, window_gains: list[float]) -> dict | None:
    """K(V) = K0 (1 + kappa (V - V0)) from the per-window gains and mean voltages; None without a voltage spread."""
    if batch.vbat is None:
        return None
    volts = batch.vbat.mean(axis=1)
    gains = np.array(window_gains)
    ok = np.isfinite(volts) & np.isfinite(gains)
    if ok.sum() < 3 or np.ptp(volts[ok]) <= 0.05:
        return None
    v0 = float(volts[ok].mean())
    design = np.column_stack([np.ones(ok.sum()), volts[ok] - v0])
    coef, *_ = np.linalg.lstsq(design, gains[ok], rcond=None)
    resid = gains[ok] - design @ coef
    cov_v = np.linalg.inv(design.T @ design) * (resid @ resid) / max(ok.sum() - 2, 1)
    return {
        "v0": v0, "k0": float(coef[0]), "dk_dv": float(coef[1]), "kappa_per_volt": float(coef[1] / coef[0]),
        "kappa_sigma": float(np.sqrt(cov_v[1, 1]) / abs(coef[0])), "windows": int(ok.sum()),
        "voltage_range": [float(volts[ok].min()), float(volts[ok].max())],
    }


def vehicle_with_spins(vehicle: VehicleConfig, yaw_signs: np.ndarray) -> VehicleConfig:
    """A copy of ``vehicle`` whose rotors have the given yaw signs (+1 = ccw seen from above)."""
    from dataclasses import replace

    motors = tuple(replace(m, yaw_sign=int(s)) for m, s in zip(vehicle.motors, yaw_signs))
    return replace(vehicle, motors=motors)


def identified_vehicle_document(vehicle: VehicleConfig, result: IdentificationResult, span_text: str) -> dict:
    """A vehicle YAML document (loadable by load_vehicle) with the identified constants and their provenance."""
    names = ", ".join(Path(f).name for f in result.files)
    source = f"identified on {names} spans {span_text} ({windows_text(len(result.spans))}) by quad-modelling identify"
    estimates = {e.name: e for e in result.constants}
    constants = {key: _entry(c) for key, c in vehicle.constants.items()}  # the physics fit's are added below
    greybox = {}
    for key, c in vehicle.greybox_constants().items():
        entry = _entry(c)
        if key in result.values and not np.isfinite(result.values[key]):  # the flights do not excite it
            entry["source"] = f"{c.source}; kept: not identifiable from {names} spans {span_text} (no excitation)"
        elif key in estimates:
            entry.update(source=estimate_source(estimates[key], "greybox fit " + source), **estimates[key].as_dict())
            entry["unit"] = c.unit
        elif key == "thrust_constant":  # the greybox's a, before the physics fit (which writes rotor_thrust_constant)
            before = (f"derived from the vehicle file's rotor_thrust_constant before identification ({c.value:.4g} {c.unit}; "
                      "the physics fit's is in constants.rotor_thrust_constant)") if c.source.startswith("derived:") else c.source
            entry["source"] = f"{before}; held fixed by identify (only B_m sqrt(a) is identifiable from motion)"
        entry["status"] = "effective"  # the linear model's own values, whatever the physical constants are
        greybox[key] = entry
    document = {
        "name": vehicle.name,
        "description": f"{vehicle.description} -- constants identified from flight data",
        "geometry": vehicle.geometry,
        "motors": [{"name": m.name, "position": list(m.position), "spin": "ccw" if s > 0 else "cw"}
                   for m, s in zip(vehicle.motors, result.spins or vehicle.yaw_signs)],
        "inputs": {"min": vehicle.input_min, "max": vehicle.input_max, "unit": vehicle.input_unit},
        "constants": constants,
        "greybox": greybox,
        "identification": {
            "files": result.files,
            "spans": result.spans,
            "thrust_gain_K": {"value": result.input_gain, "sigma": result.input_gain_sigma, "unit": "N/s per command unit"},
            "voltage_dependence": result.voltage,
            "constants": {e.name: e.as_dict() for e in result.constants},
            "motor_check": result.motor_check,
            "fit": result.fit,
        },
    }
    if vehicle.effects:
        document["effects"] = effects_document(vehicle.effects)  # the terms identify did not fit, as the file had them
    add_physics_constants(document, result.physics, result.physics_note, source)
    return document


def _entry(c: Constant) -> dict:
    """A constant as a vehicle-file entry (its sigma when it has one)."""
    entry = {"value": c.value, "unit": c.unit, "source": c.source, "status": c.status}
    if c.sigma is not None:
        entry["sigma"] = c.sigma
    return entry


def write_vehicle_yaml(document: dict, path: Path) -> None:
    """Write a vehicle document as YAML (the caller wraps this in atomic_output)."""
    path.write_text(yaml.safe_dump(document, sort_keys=False, allow_unicode=True))


def identify_physics_if_configured(flights: Sequence[FlightLog], vehicle: VehicleConfig,
                                   config: EvaluationConfig, terms: Sequence[str] = ()) -> tuple[PhysicsFit | None, str]:
    """What ``quad-modelling identify`` runs: (the physics fit, "") or (None, why not) when the vehicle file has no
    physics constants or the training span has no usable anchor (the greybox identification still runs). With
    ``terms`` asked for, either is an error (ConfigError, DataError): the user asked for the physics model."""
    missing = [key for key in vehicle.missing(PHYSICS_KEYS) if key not in held_at_zero(vehicle.effects)]
    if missing:
        if terms:
            raise ConfigError(f"{vehicle.path}: --effects {','.join(terms)} fits terms of the physics model, and the vehicle "
                              f"file has no physics constants ({', '.join(missing)})")
        return None, (f"not identified: the vehicle file has no physics constants ({', '.join(missing)}); add starting "
                      "values for them (docs/formats.md, physics constants) to fit the physics model")
    try:
        return identify_physics(flights, vehicle, config, terms=terms), ""
    except DataError as err:
        if terms:
            raise
        return None, f"not identified: {err}"
