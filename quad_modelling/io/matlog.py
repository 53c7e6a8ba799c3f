"""Thesis-style MATLAB flight logs (``.mat``, v5/v7, scipy.io).

A thesis log holds one time vector and one variable per measured column. The
default variable names (:data:`THESIS_VARIABLES`) are what :func:`write_matlog`
writes and what :func:`read_matlog` expects without a mapping; all in the
internal convention (NED/FRD, SI, rad). Logs from other labs are read through a
YAML mapping file, one entry per FlightLog field::

    time:  {variable: t, unit: s}
    u:     {variable: PWM, columns: [0, 1, 2, 3], unit: us}
    acc_b: {variables: [ax, ay, az], unit: g, frame: FLU}
    euler: {variables: [roll, pitch, yaw], unit: deg, frame: NED}

``columns`` are 0-based columns of a matrix variable; ``frame`` is required for
vector fields: FRD/FLU for body fields (acc_b, gyro_b), NED/ENU for world
fields (pos_n, vel_n) and for the attitude (ENU means roll/pitch/yaw of the
FLU body in ENU). Units: any of :data:`quad_modelling.core.frames.UNIT_FACTORS`.
``acc_b``, ``gyro_b``, ``vbat`` and ``omega`` are optional (:data:`OPTIONAL_FIELDS`): a
pose-only motion-capture log maps time, u, pos_n, vel_n and euler only.

Also stored: ``vehicle`` (config name) and ``meta_json`` (notes as JSON, e.g.
the simulator's effects and seed).
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io

from quad_modelling.atomic import atomic_output
from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog, FlightMeta, chosen_vehicle
from quad_modelling.core.input_files import read_yaml
from quad_modelling.core.preprocess import marked_gaps
from quad_modelling.errors import ConfigError, DataError, reason

THESIS_VARIABLES: dict[str, tuple[str, ...]] = {
    "time": ("time",),
    "u": ("u1", "u2", "u3", "u4"),
    "acc_b": ("ddXB", "ddYB", "ddZB"),
    "gyro_b": ("dPhi", "dTheta", "dPsi"),
    "pos_n": ("XN", "YN", "ZN"),
    "vel_n": ("dXN", "dYN", "dZN"),
    "euler": ("Phi", "Theta", "Psi"),
    "vbat": ("Vbat",),
    "omega": ("Omega1", "Omega2", "Omega3", "Omega4"),
}
"""Default variable names per field (thesis symbols: ddXB = onboard X acceleration...)."""

MAX_MAT_ELEMENTS = 200_000_000
"""Most array elements a .mat file may declare (1.6 GB of float64; a day at 100 Hz of every field is 2.6e8 / 10):
a corrupt or hostile size field is refused before scipy allocates it."""

OPTIONAL_FIELDS = ("acc_b", "gyro_b", "vbat", "omega")
"""Fields a log may lack (a pose-only motion-capture log has no acc_b/gyro_b): left out of a mapping,
or their variables absent from the file, they are None in the FlightLog."""
BODY_FIELDS = ("acc_b", "gyro_b")
WORLD_FIELDS = ("pos_n", "vel_n", "euler")
SI_UNITS = {"time": "s", "acc_b": "m/s2", "gyro_b": "rad/s", "pos_n": "m", "vel_n": "m/s", "euler": "rad", "vbat": "V", "omega": "rad/s"}


@dataclass(frozen=True)
class FieldMapping:
    """Where one FlightLog field lives in a .mat file, and in which unit/frame."""

    variables: tuple[str, ...]
    columns: tuple[int, ...] | None
    unit: str
    frame: str | None


def default_mapping() -> dict[str, FieldMapping]:
    """The mapping of :data:`THESIS_VARIABLES` (internal frames, SI units, raw u)."""
    mapping = {}
    for name, variables in THESIS_VARIABLES.items():
        frame = "FRD" if name in BODY_FIELDS else "NED" if name in WORLD_FIELDS else None
        mapping[name] = FieldMapping(variables, None, SI_UNITS.get(name, "1"), frame)
    return mapping


FIELD_WIDTHS = {"time": 1, "u": 4, "acc_b": 3, "gyro_b": 3, "pos_n": 3, "vel_n": 3, "euler": 3, "vbat": 1, "omega": 4}
"""Columns of each FlightLog field."""

COMMAND_DIMENSIONS = ("s", "1", "PWM")
"""Dimensions a raw engine command may have: a pulse length, a ratio or PWM counts (the vehicle's input unit)."""


def _field_mapping(path: Path, name: str, entry) -> FieldMapping:
    """One validated mapping entry: its unit has the field's dimension, its variables/columns fit the field."""
    if not isinstance(entry, dict) or "unit" not in entry:
        raise ConfigError(f"{path}: field {name!r} needs a 'unit'")
    unit = entry["unit"]
    if not isinstance(unit, str) or unit not in frames.UNIT_FACTORS:
        raise ConfigError(f"{path}: field {name!r} has unknown unit {str(unit)[:40]!r}; known: {list(frames.UNIT_FACTORS)}")
    dimension = frames.UNIT_FACTORS[unit][0]
    allowed = COMMAND_DIMENSIONS if name == "u" else (SI_UNITS[name],)
    if dimension not in allowed:
        fitting = [u for u, (d, _) in frames.UNIT_FACTORS.items() if d in allowed]
        raise ConfigError(f"{path}: field {name!r} unit {unit!r} is a {dimension} unit; {name} needs one of {fitting}")
    width = FIELD_WIDTHS[name]
    if "variable" in entry:
        if not isinstance(entry["variable"], str):
            raise ConfigError(f"{path}: field {name!r}: 'variable' must be one variable name, got {str(entry['variable'])[:40]!r}")
        variables = (entry["variable"],)
        columns = entry.get("columns")
        if columns is not None:
            if (not isinstance(columns, list) or len(columns) != width
                    or not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in columns)):
                raise ConfigError(f"{path}: field {name!r}: 'columns' must list {width} non-negative 0-based column "
                                  f"numbers, got {str(columns)[:60]}")
            columns = tuple(columns)
    elif "variables" in entry:
        names = entry["variables"]
        if not isinstance(names, list) or len(names) != width or not all(isinstance(v, str) for v in names):
            raise ConfigError(f"{path}: field {name!r}: 'variables' must list {width} variable names, got {str(names)[:60]}")
        variables, columns = tuple(names), None
    else:
        raise ConfigError(f"{path}: field {name!r} needs 'variable' (with optional 'columns') or 'variables'")
    frame = entry.get("frame")
    allowed_frames = ("FRD", "FLU") if name in BODY_FIELDS else ("NED", "ENU") if name in WORLD_FIELDS else (None,)
    if frame not in allowed_frames:
        raise ConfigError(f"{path}: field {name!r} needs frame one of {allowed_frames}, got {str(frame)[:20]!r}")
    return FieldMapping(variables, columns, unit, frame)


VEHICLE_INPUT_DIMENSIONS = {"normalised": "1"}
"""Vehicle input units that are not in :data:`~quad_modelling.core.frames.UNIT_FACTORS`, with their dimension
(a normalised command 0..1 is a ratio)."""


def commands_in_vehicle_unit(u: np.ndarray, mapping_unit: str, vehicle, where: str) -> np.ndarray:
    """The engine commands ``u`` (read in SI by :func:`read_matlog`, from a mapping's ``mapping_unit``)
    expressed in the vehicle's input unit, or one ConfigError naming both units when the dimensions differ.

    :math:`u_{vehicle} = u_{SI} / f_{vehicle}` with :math:`f` the unit's factor to SI
    (:data:`~quad_modelling.core.frames.UNIT_FACTORS`): a mapping in ``us`` for a vehicle taking
    ``us`` (``px4_iris_pwm``) gives the logged pulse widths, for one taking ``s`` (``linkquad``) seconds.
    """
    vehicle_unit = vehicle.input_unit
    mapped = frames.UNIT_FACTORS[mapping_unit][0]
    wanted = VEHICLE_INPUT_DIMENSIONS.get(vehicle_unit) or frames.UNIT_FACTORS.get(vehicle_unit, (None,))[0]
    if mapped != wanted:
        raise ConfigError(f"{where}: mapping field 'u' unit {mapping_unit!r} does not fit vehicle {vehicle.name}'s input unit "
                          f"{vehicle_unit!r}; map u in {vehicle_unit!r} (or a unit of the same kind) or choose the vehicle "
                          "the commands were logged for")
    return u if vehicle_unit in VEHICLE_INPUT_DIMENSIONS else frames.from_si(u, vehicle_unit)


def load_mapping(path: str | Path) -> dict[str, FieldMapping]:
    """Read and validate a YAML mapping file (see module docstring)."""
    path = Path(path)
    doc = read_yaml(path, "mapping file")
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: mapping file must be a mapping of field -> {{variable, unit, ...}}")
    unknown = [str(key) for key in doc if key not in THESIS_VARIABLES]
    if unknown:
        raise ConfigError(f"{path}: unknown fields {sorted(unknown)[:5]}; known: {list(THESIS_VARIABLES)}")
    mapping = {}
    for name in THESIS_VARIABLES:
        entry = doc.get(name)
        if entry is None:
            if name in OPTIONAL_FIELDS:
                continue
            raise ConfigError(f"{path}: mapping has no entry for required field {name!r}")
        mapping[name] = _field_mapping(path, name, entry)
    return mapping


def _short(value) -> str:
    """``repr`` of a mapping value, cut to one short line for a message."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


def _name(value, path: Path, key: str) -> str:
    """A MATLAB variable name of the mapping (``key`` names where it stood)."""
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{path}: {key} must be a MATLAB variable name, got {_short(value)}")
    return value


def _columns(value, path: Path, name: str) -> tuple[int, ...]:
    """The 0-based column list of a matrix variable."""
    if not isinstance(value, list) or not value or not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in value):
        raise ConfigError(f"{path}: field {name!r}: 'columns' must be a list of 0-based column numbers, got {_short(value)}")
    return tuple(value)


def _user_variables(contents: dict) -> dict[str, np.ndarray]:
    return {k: v for k, v in contents.items() if not k.startswith("__")}


def _extract(name: str, field: FieldMapping, found: dict, n: int | None, where: str, mapped: bool = False) -> np.ndarray | None:
    missing = [v for v in field.variables if v not in found]
    if missing:
        if name in OPTIONAL_FIELDS and len(missing) == len(field.variables):
            return None  # an optional sensor the log does not have
        if name in OPTIONAL_FIELDS:  # part of a sensor: its other axes were dropped with no word
            raise DataError(f"{where}: field {name} has variable(s) {[v for v in field.variables if v in found]} but not "
                            f"{missing}: give all of {list(field.variables)} or none")
        raise DataError(
            f"{where}: field {name} needs variable(s) {missing}, not in the file; found: {sorted(found)} "
            + ("(check the --mapping file's variable names)" if mapped else "(give a --mapping file for foreign logs)")
        )
    complex_ = [v for v in field.variables if np.iscomplexobj(found[v])]
    if complex_:
        raise DataError(f"{where}: variable(s) {complex_} of field {name} are complex-valued, expected real numbers")
    try:
        arrays = [np.asarray(found[v], dtype=float) for v in field.variables]
    except (TypeError, ValueError) as err:
        raise DataError(f"{where}: variable(s) {list(field.variables)} of field {name} are not numeric") from err
    if len(arrays) == 1:
        data = arrays[0]
        if data.ndim == 2 and data.shape[0] == 1 and n is not None and data.shape[1] == n:
            data = data.T
        if data.ndim == 2 and data.shape[1] == 1:
            data = data[:, 0]
        if field.columns is not None:
            if data.ndim != 2 or max(field.columns) >= data.shape[1]:
                raise DataError(f"{where}: variable {field.variables[0]} (shape {data.shape}) has no columns {list(field.columns)} for field {name}")
            data = data[:, list(field.columns)]
    else:
        arrays = [a.reshape(-1) for a in arrays]
        lengths = {len(a) for a in arrays}
        if len(lengths) != 1:
            raise DataError(f"{where}: variables {list(field.variables)} of field {name} have different lengths {sorted(lengths)}")
        data = np.column_stack(arrays)
    if n is not None and len(data) != n:
        raise DataError(f"{where}: field {name} has {len(data)} rows, time has {n}")
    try:
        return frames.to_si(data, field.unit)
    except KeyError as err:
        raise DataError(f"{where}: field {name}: {err.args[0]}") from err


def read_matlog(path: str | Path, vehicle: str | None = None, mapping: dict[str, FieldMapping] | None = None) -> FlightLog:
    """Read a thesis-style .mat log into a FlightLog (internal frames, SI).

    ``vehicle`` overrides the ``vehicle`` variable stored in the file.
    """
    path = Path(path)
    where = str(path)
    mapped = mapping is not None
    mapping = mapping or default_mapping()
    if not path.is_file():
        raise DataError(f"{where}: no such file")
    try:
        declared = sum(math.prod(shape) for _, shape, _ in scipy.io.whosmat(path))  # headers only
        if declared > MAX_MAT_ELEMENTS:
            raise DataError(f"{where}: the variables declare {declared} elements, more than the {MAX_MAT_ELEMENTS} read")
        contents = scipy.io.loadmat(path, squeeze_me=True, chars_as_strings=True)
    except DataError:
        raise
    except NotImplementedError as err:
        raise DataError(f"{where}: MATLAB v7.3 (HDF5) files are not supported; save with -v7") from err
    except FileNotFoundError as err:
        raise DataError(f"{where}: no such file") from err
    except (ValueError, TypeError, OSError, EOFError, IndexError, KeyError, AttributeError, OverflowError, MemoryError,
            zlib.error, scipy.io.matlab.MatReadError) as err:  # scipy's parser meets a corrupt file with any of these
        raise DataError(f"{where}: not a readable MATLAB file ({reason(err)})") from err
    found = _user_variables(contents)
    time = _extract("time", mapping["time"], found, None, where, mapped)
    if time is None or time.ndim != 1:
        raise DataError(f"{where}: time variable {mapping['time'].variables} must be a vector")
    n = len(time)
    fields = {name: _extract(name, mapping[name], found, n, where, mapped) for name in mapping if name != "time"}
    for name in BODY_FIELDS:
        if fields.get(name) is not None and mapping[name].frame == "FLU":
            fields[name] = frames.flu_to_frd(fields[name])
    for name in ("pos_n", "vel_n"):
        if mapping[name].frame == "ENU":
            fields[name] = frames.enu_to_ned(fields[name])
    if mapping["euler"].frame == "ENU":
        from scipy.spatial.transform import Rotation

        quat = Rotation.from_euler("ZYX", fields["euler"][:, ::-1]).as_quat()
        fields["euler"] = frames.quat_enu_to_euler_ned(quat)
        fields["euler"][:, 2] = frames.unwrap_angles(fields["euler"][:, 2])
    notes = {}
    if "meta_json" in found:
        try:
            notes = json.loads(str(found["meta_json"]))
        except json.JSONDecodeError as err:
            raise DataError(f"{where}: variable meta_json is not valid JSON ({err.msg})") from err
        except RecursionError as err:
            raise DataError(f"{where}: variable meta_json nests deeper than JSON can be read") from err
        if not isinstance(notes, dict):
            raise DataError(f"{where}: variable meta_json must hold a JSON object, got {type(notes).__name__}")
    if "vehicle" in found and not vehicle and isinstance(found["vehicle"], np.ndarray) and found["vehicle"].size == 0:
        raise DataError(f"{where}: variable vehicle is empty; store the vehicle config name in it or pass --vehicle NAME")
    if "vehicle" in found and not vehicle and not isinstance(found["vehicle"], str):
        raise DataError(f"{where}: variable vehicle must be a vehicle config name (text), got a {type(found['vehicle']).__name__}")
    named = found.get("vehicle")
    named = None if named is None or (isinstance(named, np.ndarray) and named.size == 0) else str(named)  # '' is none
    vehicle_name = chosen_vehicle(vehicle, named, where)
    if not vehicle_name:
        raise DataError(f"{where}: no 'vehicle' variable in the file; pass --vehicle NAME")
    return FlightLog(
        t=time,
        u=fields["u"],
        acc_b=fields.get("acc_b"),
        gyro_b=fields.get("gyro_b"),
        pos_n=fields["pos_n"],
        vel_n=fields["vel_n"],
        euler=fields["euler"],
        vbat=fields.get("vbat"),
        omega=fields.get("omega"),
        meta=FlightMeta(vehicle=vehicle_name, source=where, notes=notes),
    )


def check_one_time_base(log: FlightLog) -> None:
    """DataError when ``log`` has marked measurement gaps with rows inside them, which a .mat log (one time base)
    cannot keep; a gap of the time base itself (rows missing from every column: a CSV's dropout) has none and is kept
    as the missing rows it is (it refused a 70 ms dropout)."""
    gaps = [g for g in marked_gaps(log) if np.any((log.t > g.start_s) & (log.t < g.end_s))]
    if gaps:
        listing = ", ".join(f"{g.topic} {g.start_s - log.t[0]:.2f}..{g.end_s - log.t[0]:.2f}" for g in gaps)
        raise DataError(f"{log.meta.source} has measurement gaps ({listing} s): a .mat log has one time base; "
                        f"convert to a bag")


def write_matlog(log: FlightLog, path: str | Path, force: bool = False) -> Path:
    """Write ``log`` with the default thesis variable names, atomically.

    A log with marked measurement gaps holding rows is refused (:func:`check_one_time_base`): every variable of a
    .mat log shares its one time base, so the gap could only be written as the interpolated rows it must never be
    used as (a bag keeps it).
    """
    path = Path(path)
    check_one_time_base(log)
    contents: dict[str, object] = {"time": log.t, "vehicle": log.meta.vehicle, "meta_json": json.dumps(log.meta.notes)}
    for name, variables in THESIS_VARIABLES.items():
        if name == "time":
            continue
        data = getattr(log, name)
        if data is None:
            continue
        data = data.reshape(len(log), -1)
        for column, variable in enumerate(variables):
            contents[variable] = data[:, column]
    with atomic_output(path, force) as tmp:
        with open(tmp, "wb") as stream:
            scipy.io.savemat(stream, contents, do_compression=True, oned_as="column")
    return path
