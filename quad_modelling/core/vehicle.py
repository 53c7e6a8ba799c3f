"""VehicleConfig: one airframe's constants, loaded from ``config/vehicles/*.yaml``.

Every constant in the YAML is a mapping ``{value, unit, source, status}`` where
``status`` is ``measured`` (from the airframe or literature) or ``identified``
(a starting value that ``quad-modelling identify`` refines from flight data). A file that
``identify`` wrote records what it fitted in its ``identification`` section; a constant marked
``identified`` that no such record names still holds its starting value
(:meth:`VehicleConfig.never_identified`: the CasADi export refuses to hand those to a controller).
There are no silent defaults: a missing key is a ConfigError naming the file
and key.

Motors are listed in command order (u1..u4); each has a position in the body
frame FRD [m] and a spin direction seen from above. A rotor spinning
counter-clockwise seen from above pushes the body clockwise, i.e. a positive
yaw torque about the FRD z axis (down): ``yaw_sign = +1``; clockwise: ``-1``.

Thrust and drag torque per rotor (thesis Eq 3-3, 3-13):

.. math::

    T_i = a \\Omega_i^2, \\qquad Q_i = d \\Omega_i^2, \\qquad
    \\Omega_0 = \\sqrt{m g / (4 a)}
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from quad_modelling.core.input_files import read_yaml
from quad_modelling.core.physics.effects import EffectTerm, effects_document, parse_effects
from quad_modelling.core.physics.rotors import hover_rotor_speed
from quad_modelling.errors import ConfigError

GRAVITY = 9.81
"""Local gravity used by the models [m/s²] (thesis value, Eq 3-10)."""


def config_dir() -> Path:
    """Where the shipped configuration files are.

    In a source checkout or editable install: ``<repo>/config``. In a colcon
    install: ``share/quad_modelling/config`` (setup.py data_files).
    """
    source_tree = Path(__file__).resolve().parents[2] / "config"
    if (source_tree / "vehicles").is_dir():
        return source_tree
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("quad_modelling")) / "config"
    except (ImportError, LookupError) as err:
        raise ConfigError("cannot find the shipped configs (no source tree, no ament share)") from err


def vehicle_dir() -> Path:
    """Where the shipped vehicle configs are: ``config/vehicles`` of :func:`config_dir`."""
    return config_dir() / "vehicles"


CONSTANT_KEYS = (
    "mass",
    "arm_length",
    "ixx",
    "iyy",
    "izz",
    "prop_inertia",
    "motor_a_m",
    "motor_b_m",
    "thrust_constant",
    "drag_constant",
)
"""Constants every vehicle file must give (thesis Table 3-1 names; docs/formats.md, vehicle configs)."""

PHYSICS_KEYS = (
    "rotor_speed_gain",
    "rotor_speed_offset",
    "rotor_time_constant",
    "rotor_delay",
    "rotor_thrust_constant",
    "rotor_torque_constant",
    "rotor_drag_xy",
    "rotor_drag_z",
    "rotor_drag_arm",
    "physics_ixx",
    "physics_iyy",
)
"""Constants of the nonlinear physics model (:mod:`quad_modelling.core.physics.parameters`), optional in a
vehicle file (validated when present; the ``physics`` model names the missing ones): the motor map
Ω_ss = k_u u + Ω_off, the rotor time constant τ_m and command delay δ, thrust/torque k_f, k_m (T = k_f Ω², Q = k_m Ω²), the linear
rotor drag d_xy, d_z and its arm h_d (FRD z of where it acts) and the roll/pitch inertias the physics model uses (identified separately from the
thesis's ``ixx``/``iyy``, which the linear greybox keeps)."""

STATUSES = ("measured", "identified")

CONSTANT_RANGES: dict[str, tuple[float, float, str]] = {
    "mass": (0.0, 1000.0, "kg"),
    "arm_length": (0.0, 10.0, "m"),
    "ixx": (0.0, 1000.0, "kg m2"),
    "iyy": (0.0, 1000.0, "kg m2"),
    "izz": (0.0, 1000.0, "kg m2"),
    "prop_inertia": (0.0, 10.0, "kg m2"),
    "motor_a_m": (-1.0e5, 0.0, "1/s"),
    "motor_b_m": (0.0, np.inf, "per input unit"),
    "thrust_constant": (0.0, 1.0, "N s2/rad2"),
    "drag_constant": (0.0, 1.0, "N m s2/rad2"),
    "rotor_speed_gain": (0.0, np.inf, "rad/s per input unit"),
    "rotor_speed_offset": (-1.0e5, 1.0e5, "rad/s"),
    "rotor_time_constant": (0.0, 10.0, "s"),
    "rotor_delay": (0.0, 1.0, "s"),
    "rotor_thrust_constant": (0.0, 1.0, "N s2/rad2"),
    "rotor_torque_constant": (0.0, 1.0, "N m s2/rad2"),
    "rotor_drag_xy": (0.0, 1.0, "N s/(m rad)"),
    "rotor_drag_z": (0.0, 1.0, "N s/(m rad)"),
    "rotor_drag_arm": (-10.0, 10.0, "m"),
    "physics_ixx": (0.0, 1000.0, "kg m2"),
    "physics_iyy": (0.0, 1000.0, "kg m2"),
}
"""Open interval (low, high) each constant must lie in, and its unit: positive masses, lengths, inertias and
rotor constants, a stable motor pole (negative, faster than 10 us), nothing beyond what a multirotor of up
to a tonne and 10 m arms could have. ``prop_inertia`` may be 0 (rotor inertia neglected). Values must be
finite. Rotor time constant, delay and drag may be 0 (no lag, no delay, no drag)."""

ZERO_ALLOWED = ("prop_inertia", "rotor_time_constant", "rotor_delay", "rotor_drag_arm", "rotor_drag_xy", "rotor_drag_z")
"""Constants whose range includes its lower end 0 (the effect neglected)."""


@dataclass(frozen=True)
class Constant:
    """One physical constant with its unit, its source and how it was obtained."""

    value: float
    unit: str
    source: str
    status: str


@dataclass(frozen=True)
class Motor:
    """One rotor: position (x, y) in body FRD [m] and yaw torque sign (+1 = spins CCW from above)."""

    name: str
    position: tuple[float, float]
    yaw_sign: int


@dataclass(frozen=True)
class VehicleConfig:
    """A validated vehicle description (see module docstring)."""

    name: str
    description: str
    geometry: str
    motors: tuple[Motor, ...]
    constants: dict[str, Constant]
    input_min: float
    input_max: float
    input_unit: str
    path: str
    effects: dict[str, EffectTerm] = field(default_factory=dict)
    """The physics model's optional terms (:mod:`quad_modelling.core.physics.effects`), by name."""
    fitted: frozenset[str] = frozenset()
    """The constants the file's ``identification`` record names (``identification.constants``: what
    ``quad-modelling identify`` fitted, or held and said why); empty for a hand-written file."""

    def value(self, key: str) -> float:
        """The numeric value of a constant, e.g. ``cfg.value('mass')``."""
        try:
            return self.constants[key].value
        except KeyError as err:
            raise ConfigError(f"{self.path}: vehicle {self.name} has no constant {key!r}") from err

    @property
    def mass(self) -> float:
        return self.value("mass")

    @property
    def hover_thrust_per_rotor(self) -> float:
        """T_H = m g / 4 [N]."""
        return self.mass * GRAVITY / 4.0

    @property
    def hover_rotor_speed(self) -> float:
        """Ω0 = sqrt(m g / (4 a)) [rad/s] (:func:`~quad_modelling.core.physics.rotors.hover_rotor_speed`)."""
        return hover_rotor_speed(self.mass, self.value("thrust_constant"), GRAVITY)

    @property
    def motor_positions(self) -> np.ndarray:
        """(4, 2) rotor positions (x forward, y right) in FRD [m]."""
        return np.array([m.position for m in self.motors], dtype=float)

    @property
    def yaw_signs(self) -> np.ndarray:
        """(4,) yaw reaction torque signs (+1 = rotor spins CCW seen from above)."""
        return np.array([m.yaw_sign for m in self.motors], dtype=float)

    @property
    def inertia(self) -> np.ndarray:
        """Diagonal inertia (Ixx, Iyy, Izz) [kg m²]."""
        return np.array([self.value("ixx"), self.value("iyy"), self.value("izz")])

    def missing(self, keys) -> list[str]:
        """Those of ``keys`` this vehicle file does not give (e.g. :data:`PHYSICS_KEYS`)."""
        return [k for k in keys if k not in self.constants]

    def identified(self) -> list[str]:
        """Names of the constants to identify from flight data."""
        return [k for k, c in self.constants.items() if c.status == "identified"]

    def never_identified(self, keys) -> list[str]:
        """Those of ``keys`` whose status is ``identified`` (to be identified from flight data) but that no
        identification record names: the file still holds their starting values (module docstring)."""
        return [k for k in keys if k in self.constants and self.constants[k].status == "identified" and k not in self.fitted]

    def with_values(self, values: dict[str, float], source: str) -> VehicleConfig:
        """A copy with some constants replaced (e.g. identified ones), noting the source."""
        constants = dict(self.constants)
        for key, value in values.items():
            old = self.constants.get(key)
            if old is None:
                raise ConfigError(f"{self.path}: cannot set unknown constant {key!r}")
            check_constant(key, float(value), f"{self.path} ({source})")
            constants[key] = Constant(float(value), old.unit, source, old.status)
        return replace(self, constants=constants)

    @classmethod
    def from_yaml(cls, path: str | Path) -> VehicleConfig:
        """Load and validate a vehicle file; ConfigError names the file and key at fault."""
        path = Path(path)
        doc = read_yaml(path, "vehicle config")
        if not isinstance(doc, dict):
            raise ConfigError(f"{path}: expected a mapping at the top level")
        return cls.from_dict(doc, str(path))

    @classmethod
    def from_dict(cls, doc: dict, where: str) -> VehicleConfig:
        """Validate an already-parsed vehicle document (``where`` names it in errors)."""

        def need(mapping: dict, key: str, context: str):
            if not isinstance(mapping, dict) or key not in mapping:
                raise ConfigError(f"{where}: missing required key {context}{key}")
            return mapping[key]

        name = str(need(doc, "name", ""))
        geometry = need(doc, "geometry", "")
        if geometry not in ("plus", "x"):
            raise ConfigError(f"{where}: geometry must be 'plus' or 'x', got {geometry!r}")
        constants_doc = need(doc, "constants", "")
        constants: dict[str, Constant] = {}
        optional = [k for k in PHYSICS_KEYS if isinstance(constants_doc, dict) and k in constants_doc]
        for key in (*CONSTANT_KEYS, *optional):
            entry = need(constants_doc, key, "constants.")
            for sub in ("value", "unit", "source", "status"):
                need(entry, sub, f"constants.{key}.")
            if entry["status"] not in STATUSES:
                raise ConfigError(f"{where}: constants.{key}.status must be one of {STATUSES}, got {entry['status']!r}")
            try:
                value = float(entry["value"])
            except (TypeError, ValueError) as err:
                raise ConfigError(f"{where}: constants.{key}.value is not a number: {str(entry['value'])[:40]!r}") from err
            check_constant(key, value, where)
            constants[key] = Constant(value, str(entry["unit"]), str(entry["source"]), entry["status"])
        motors_doc = need(doc, "motors", "")
        if not isinstance(motors_doc, list) or len(motors_doc) != 4:
            raise ConfigError(f"{where}: motors must list exactly 4 rotors in command order u1..u4")
        motors = []
        for i, m in enumerate(motors_doc):
            position = need(m, "position", f"motors[{i}].")
            spin = need(m, "spin", f"motors[{i}].")
            if spin not in ("cw", "ccw"):
                raise ConfigError(f"{where}: motors[{i}].spin must be 'cw' or 'ccw' (seen from above), got {spin!r}")
            if not (isinstance(position, list) and len(position) == 2):
                raise ConfigError(f"{where}: motors[{i}].position must be [x, y] in body FRD metres")
            try:
                xy = (float(position[0]), float(position[1]))
            except (TypeError, ValueError) as err:
                raise ConfigError(f"{where}: motors[{i}].position is not two numbers: {str(position)[:60]}") from err
            if not np.all(np.isfinite(xy)):
                raise ConfigError(f"{where}: motors[{i}].position must be finite, got {list(xy)}")
            motors.append(Motor(str(need(m, "name", f"motors[{i}].")), xy, 1 if spin == "ccw" else -1))
        radii = np.hypot(*np.array([m.position for m in motors]).T)
        arm = constants["arm_length"].value
        if not np.allclose(radii, arm, rtol=0.02):
            raise ConfigError(f"{where}: motor positions lie at {np.round(radii, 4).tolist()} m from the centre, not arm_length {arm} m")
        if sum(m.yaw_sign for m in motors) != 0:
            raise ConfigError(f"{where}: two rotors must spin cw and two ccw")
        inputs = need(doc, "inputs", "")
        try:
            input_min = float(need(inputs, "min", "inputs."))
            input_max = float(need(inputs, "max", "inputs."))
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{where}: inputs.min and inputs.max must be numbers") from err
        if not (np.isfinite(input_min) and np.isfinite(input_max)):
            raise ConfigError(f"{where}: inputs.min and inputs.max must be finite, got [{input_min}, {input_max}]")
        if not input_max > input_min:
            raise ConfigError(f"{where}: inputs.max must exceed inputs.min")
        return cls(
            name=name,
            description=str(doc.get("description", "")),
            geometry=geometry,
            motors=tuple(motors),
            constants=constants,
            input_min=input_min,
            input_max=input_max,
            input_unit=str(need(inputs, "unit", "inputs.")),
            path=where,
            effects=parse_effects(doc.get("effects"), where),
            fitted=_fitted_constants(doc.get("identification"), where),
        )


def _fitted_constants(record, where: str) -> frozenset[str]:
    """The constant names of a vehicle document's ``identification.constants`` record (None: none)."""
    if record is None:
        return frozenset()
    fitted = record.get("constants", {}) if isinstance(record, dict) else None
    if not isinstance(fitted, dict):
        raise ConfigError(f"{where}: identification.constants must be a mapping of constant names (as identify writes it)")
    return frozenset(str(k) for k in fitted)


def check_constant(key: str, value: float, where: str) -> None:
    """ConfigError naming ``where`` and ``constants.<key>.value`` unless the value is finite and inside
    :data:`CONSTANT_RANGES`."""
    if not np.isfinite(value):
        raise ConfigError(f"{where}: constants.{key}.value must be a finite number, got {value}")
    if key not in CONSTANT_RANGES:
        return
    low, high, unit = CONSTANT_RANGES[key]
    if key in ZERO_ALLOWED:
        inside = low <= value < high
    else:
        inside = low < value < high
    if not inside:
        if key == "motor_a_m":
            rule = f"must be negative (a stable motor pole) and above {low:g} {unit}"
        elif high == np.inf:
            rule = "must be positive"
        else:
            rule = f"must lie in {'[' if key in ZERO_ALLOWED else '('}{low:g}, {high:g}) {unit}"
        raise ConfigError(f"{where}: constants.{key}.value {rule}, got {value:g}")


def vehicle_file(name_or_path: str | Path | None) -> Path | None:
    """The YAML file a ``--vehicle`` value reads (a path, or a shipped name's file); None for None."""
    if name_or_path is None:
        return None
    candidate = Path(name_or_path)
    if candidate.suffix in (".yaml", ".yml"):
        return candidate
    return vehicle_dir() / f"{name_or_path}.yaml"


def load_vehicle(name_or_path: str | Path) -> VehicleConfig:
    """A vehicle by shipped name (``linkquad``, ``crazyflie21``) or by YAML path."""
    candidate = Path(name_or_path)
    if candidate.suffix in (".yaml", ".yml"):
        return VehicleConfig.from_yaml(candidate)
    directory = vehicle_dir()
    path = directory / f"{name_or_path}.yaml"
    if not path.exists():
        known = sorted(p.stem for p in directory.glob("*.yaml"))
        raise ConfigError(f"unknown vehicle {name_or_path!r}; shipped: {', '.join(known)} (or give a .yaml path)")
    return VehicleConfig.from_yaml(path)


def vehicle_document(vehicle: VehicleConfig, description: str | None = None) -> dict:
    """The YAML document of ``vehicle`` (the inverse of :meth:`VehicleConfig.from_dict`), optionally re-described."""
    return {
        "name": vehicle.name,
        "description": description or vehicle.description,
        "geometry": vehicle.geometry,
        "motors": [{"name": m.name, "position": list(m.position), "spin": "ccw" if m.yaw_sign > 0 else "cw"} for m in vehicle.motors],
        "inputs": {"min": vehicle.input_min, "max": vehicle.input_max, "unit": vehicle.input_unit},
        "constants": {k: {"value": c.value, "unit": c.unit, "source": c.source, "status": c.status} for k, c in vehicle.constants.items()},
        "effects": effects_document(vehicle.effects),
    }
