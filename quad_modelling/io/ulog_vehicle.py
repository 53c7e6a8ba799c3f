"""A vehicle config started from a PX4 log's parameters (``quad-modelling convert FLIGHT.ulg --vehicle-from-log``).

From the log: rotor count (4, else refused), motor positions ``CA_ROTORn_PX/PY`` (body FRD [m]) symmetrised to
one arm length (a vehicle config holds one), spins from the sign of ``CA_ROTORn_KM`` (positive =
counter-clockwise seen from above), the input range of the motor topic (``actuator_motors``: 0..1 normalised;
``actuator_outputs``: the disarmed pulse .. the PWM maximum of the parameters). Mass, inertia and motor
constants are not in a log: copied from ``px4_iris.yaml`` / ``px4_iris_pwm.yaml`` and marked as guesses.
Every refusal is one DataError line naming the file. Reading the log: :mod:`quad_modelling.io.ulog`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from quad_modelling.core.vehicle import CONSTANT_KEYS, ON_AXIS, VehicleConfig, load_vehicle
from quad_modelling.errors import ConfigError, DataError
from quad_modelling.io.ulog import (
    DEFAULT_VEHICLES,
    MOTOR_UNITS,
    ROTORS,
    Topics,
    four_rotors,
    motor_channels,
    open_ulog,
    pwm_range,
    topics_of,
)

PWM_DISARMED_DEFAULT_US = 900.0
"""PX4's default disarmed PWM pulse [us] (``PWM_MAIN_DISARM``/``PWM_MAIN_DISn`` default; the value the
sample logs' outputs hold while disarmed), used when the log does not carry the parameter."""


AXIS_TOLERANCE_DEG = 10.0
"""Largest tilt [deg] of a rotor's thrust axis ``CA_ROTORn_AX/AY/AZ`` from straight up (0, 0, -1) FRD
read as a vertical rotor; a vehicle config holds vertical rotors only."""



@dataclass
class LogVehicle:
    """A vehicle document started from a log (:func:`vehicle_from_ulog`): ``document`` in the form
    :meth:`VehicleConfig.from_dict` reads, ``comments`` saying where each part came from (the YAML
    header), ``warnings`` for the parts guessed for want of parameters."""

    document: dict
    comments: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def rotor_frame(params: dict, where: str) -> tuple[np.ndarray, list[str]] | None:
    """((4, 2) positions CA_ROTOR0..3_PX/PY [m, FRD], spins 'cw'/'ccw' from the sign of CA_ROTORn_KM), or
    None when the log has no CA_ROTORn parameters; DataError for a rotor not vertical or of no spin."""
    keys = [f"CA_ROTOR{n}_{c}" for n in range(ROTORS) for c in ("PX", "PY", "KM")]
    if any(k not in params for k in keys):
        return None
    positions, spins = [], []
    for n in range(ROTORS):
        px, py, km = (float(params[f"CA_ROTOR{n}_{c}"]) for c in ("PX", "PY", "KM"))
        if not np.all(np.isfinite([px, py, km])):
            raise DataError(f"{where}: parameters CA_ROTOR{n}_PX/PY/KM are not finite: {px:g}, {py:g}, {km:g}")
        axis = np.array([float(params.get(f"CA_ROTOR{n}_A{c}", d)) for c, d in (("X", 0.0), ("Y", 0.0), ("Z", -1.0))])
        norm = float(np.linalg.norm(axis))
        tilt = float(np.degrees(np.arccos(np.clip(-axis[2] / norm, -1.0, 1.0)))) if norm > 0 else 180.0
        if not tilt <= AXIS_TOLERANCE_DEG:
            raise DataError(f"{where}: rotor CA_ROTOR{n} thrust axis (AX, AY, AZ) = {axis.round(3).tolist()} is {tilt:.0f} deg "
                            f"from straight up (0, 0, -1); a vehicle config holds vertical rotors only")
        if km == 0:
            raise DataError(f"{where}: parameter CA_ROTOR{n}_KM is 0: its sign gives the rotor's spin "
                            "(positive = counter-clockwise seen from above)")
        positions.append((px, py))
        spins.append("ccw" if km > 0 else "cw")
    return np.array(positions), spins


def symmetric_frame(positions: np.ndarray, where: str) -> tuple[str, np.ndarray, float, list[str]]:
    """(geometry 'x' or 'plus', (4, 2) symmetrised positions, arm length [m], rotor names).

    A vehicle config holds one arm length. x frame (one rotor per quadrant): each rotor at
    (±mean |PX|, ±mean |PY|), which keeps the summed roll and pitch moment arms and the frame's
    aspect; plus frame (two rotors on each body axis, within :data:`ON_AXIS`): each at the mean
    radius on its axis. Anything else is refused naming the positions."""
    x, y = positions[:, 0], positions[:, 1]
    radii = np.hypot(x, y)
    on_x, on_y = np.abs(y) <= ON_AXIS * radii, np.abs(x) <= ON_AXIS * radii
    quadrants = {(bool(a > 0), bool(b > 0)) for a, b in positions}
    side = {(True, True): "front_right", (False, False): "back_left", (True, False): "front_left", (False, True): "back_right"}
    if radii.min() > 0 and not (on_x | on_y).any() and len(quadrants) == ROTORS:
        half = np.array([np.abs(x).mean(), np.abs(y).mean()])
        names = [f"m{k + 1}_{side[(bool(a > 0), bool(b > 0))]}" for k, (a, b) in enumerate(positions)]
        return "x", np.sign(positions) * half, float(np.hypot(*half)), names
    if (radii.min() > 0 and on_x.sum() == 2 and on_y.sum() == 2 and np.sign(x[on_x]).sum() == 0
            and np.sign(y[on_y]).sum() == 0):
        arm = float(radii.mean())
        symmetric = np.where(on_x[:, None], [[1.0, 0.0]], [[0.0, 1.0]]) * np.sign(positions) * arm
        names = [f"m{k + 1}_" + (("front" if a > 0 else "back") if on_x[k] else ("right" if b > 0 else "left"))
                 for k, (a, b) in enumerate(positions)]
        return "plus", symmetric, arm, names
    raise DataError(f"{where}: rotors CA_ROTOR0..3 at (PX, PY) = {np.round(positions, 4).tolist()} m form neither an x frame "
                    "(one rotor per quadrant) nor a plus frame (two on each body axis)")


def pwm_disarmed(params: dict, channels: list[int]) -> tuple[float, str]:
    """(disarmed pulse [us] of the PWM outputs ``channels``, where it came from)."""
    for prefix in ("PWM_MAIN", "HIL_ACT"):
        values = [params.get(f"{prefix}_DIS{c + 1}") for c in channels]
        if None not in values and min(values) >= 0:
            return float(min(values)), f"{prefix}_DISn"
    if params.get("PWM_MAIN_DISARM") is not None:
        return float(params["PWM_MAIN_DISARM"]), "PWM_MAIN_DISARM"
    return PWM_DISARMED_DEFAULT_US, f"PX4's default PWM_MAIN_DISARM {PWM_DISARMED_DEFAULT_US:g} us, not in the log"


def _inputs(topic: str, params: dict, where: str) -> tuple[dict, str]:
    """(vehicle ``inputs`` mapping, comment) of the motor-command source ``topic``."""
    if topic == "actuator_motors":
        return {"min": 0, "max": 1, "unit": MOTOR_UNITS[topic]}, "inputs: actuator_motors.control range 0..1 (PX4 actuator_motors.msg)"
    channels, _ = motor_channels(params)
    found = pwm_range(params, channels)
    if found is None:
        raise DataError(f"{where}: motor commands are PWM (actuator_outputs) but the log has no PWM_MAIN_MIN/MAX or "
                        f"PWM_MAIN_MINn/MAXn parameters: the input range cannot be read; copy config/vehicles/px4_iris_pwm.yaml")
    low, high, named = found
    disarmed, disarmed_from = pwm_disarmed(params, channels)
    return ({"min": min(disarmed, low), "max": high, "unit": MOTOR_UNITS[topic]},
            f"inputs: PWM outputs {channels}: disarmed {disarmed:g} us ({disarmed_from}) .. max {high:g} us; "
            f"armed range {low:g}..{high:g} us ({named})")


def vehicle_from_ulog(path: str | Path, name: str) -> LogVehicle:
    """The vehicle document named ``name`` a PX4 log's parameters start (module doc, *Vehicle from the log*).

    Refused in one DataError line naming the file: a log that cannot be read, not a quadrotor, without
    motor commands, a PWM log without its range, rotors neither an x nor a plus frame."""
    ulog, _, _, _ = open_ulog(path, MOTOR_UNITS)
    return vehicle_document(topics_of(ulog.data_list)[0], ulog.initial_parameters, str(path), name)


def vehicle_document(topics: Topics, params: dict, where: str, name: str) -> LogVehicle:
    """:func:`vehicle_from_ulog` on a log already read: its topics (the motor topics suffice) and parameters."""
    path = Path(where)
    counted = four_rotors(topics, params, where)
    topic = next((t for t in MOTOR_UNITS if t in topics), None)
    if topic is None:
        raise DataError(f"{where}: no motor commands: neither actuator_motors nor actuator_outputs was logged")
    default = DEFAULT_VEHICLES[topic]
    base = load_vehicle(default)
    inputs, inputs_comment = _inputs(topic, params, where)
    comments = [f"Vehicle started from {Path(path).name} by quad-modelling convert --vehicle-from-log.",
                f"Rotor count {counted}; motor k = CA_ROTOR(k-1); commands from {topic}.", inputs_comment]
    warnings = []
    frame = rotor_frame(params, where)
    if frame is None:
        geometry, motors = base.geometry, [{"name": m.name, "position": list(m.position), "spin": "ccw" if m.yaw_sign > 0 else "cw"}
                                           for m in base.motors]
        arm = {"value": base.value("arm_length"), "unit": "m", "source": f"guess: {default}.yaml (no CA_ROTORn_PX/PY in the log)",
               "status": base.constants["arm_length"].status}
        warnings.append(f"{where}: no CA_ROTORn_PX/PY/KM parameters (PX4 before the control allocator): "
                        f"motor positions and spins copied from {default}.yaml")
        comments.append(f"Motor positions and spins: guessed from {default}.yaml (no CA_ROTORn_PX/PY/KM in the log).")
    else:
        positions, spins = frame
        geometry, symmetric, length, names = symmetric_frame(positions, where)
        radii = ", ".join(f"{r:.4f}" for r in np.hypot(*positions.T))
        logged = ", ".join(f"({a:.4f}, {b:.4f})" for a, b in positions)
        motors = [{"name": n, "position": [round(float(a), 6), round(float(b), 6)], "spin": s}
                  for n, (a, b), s in zip(names, symmetric, spins)]
        arm = {"value": round(length, 6), "unit": "m", "status": "measured",
               "source": f"log parameters CA_ROTOR0..3_PX/PY, {geometry} frame symmetrised (logged radii {radii} m, "
                         f"mean {np.hypot(*positions.T).mean():.4f} m)"}
        arm = {key: arm[key] for key in ("value", "unit", "source", "status")}
        comments += [f"Positions: CA_ROTORn_PX/PY (FRD, m) {logged}, radii {radii} m;",
                     f"symmetrised to one arm length {length:.4f} m ({geometry} frame, see io/ulog_vehicle.py symmetric_frame).",
                     "Spins: sign of CA_ROTORn_KM (positive = counter-clockwise seen from above)."]
    comments.append(f"Mass, inertia and motor constants are not in a log: guesses copied from {default}.yaml.")
    constants = {}
    for key in CONSTANT_KEYS:
        c = base.constants[key]
        constants[key] = arm if key == "arm_length" else {
            "value": c.value, "unit": c.unit, "source": f"guess: {default}.yaml (not in the log)", "status": c.status}
    from_log = "input range" if frame is None else "frame, spins and input range"
    document = {"name": name,
                "description": f"PX4 vehicle started from {Path(path).name}: {from_log} from the log's "
                               f"parameters; the rest guessed from {default}.yaml",
                "geometry": geometry, "motors": motors, "inputs": inputs, "constants": constants}
    try:
        VehicleConfig.from_dict(document, f"{where} (vehicle from the log)")
    except ConfigError as err:
        raise DataError(str(err)) from err
    return LogVehicle(document, comments, warnings)


def vehicle_yaml(vehicle: LogVehicle) -> str:
    """The YAML text of a :class:`LogVehicle`: its comments as the header, one line per motor and constant."""

    def flow(value) -> str:
        return yaml.safe_dump([value], default_flow_style=True, sort_keys=False, width=10**6, allow_unicode=True).strip()[1:-1]

    doc = vehicle.document
    lines = [f"# {c}" for c in vehicle.comments]
    lines += [f"{key}: {flow(doc[key])}" for key in ("name", "description", "geometry")]
    lines += ["motors:   # command order u1..u4; position [x forward, y right] in body FRD [m]; spin seen from above"]
    lines += [f"  - {flow(m)}" for m in doc["motors"]]
    lines += [f"inputs: {flow(doc['inputs'])}", "constants:"]
    lines += [f"  {key}: {flow(value)}" for key, value in doc["constants"].items()]
    return "\n".join(lines) + "\n"
