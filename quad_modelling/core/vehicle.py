"""VehicleConfig: one airframe's constants, loaded from ``config/vehicles/*.yaml``.

One value per physical constant (``constants:``): mass, geometry, the airframe's inertias, the rotor inertia and the
rotor constants of the one physics (:mod:`quad_modelling.core.physics`). Every entry is a mapping ``{value, unit,
source, status}`` with an optional ``sigma`` (1-sigma, same unit); ``status`` is ``measured`` (from the airframe or
literature), ``identified`` (a starting value that ``quad-modelling identify`` refines from flight data) or
``effective`` (a value that makes one model fit, not the airframe's: it stands in for something that model lacks). A
file that ``identify`` wrote records what it fitted in its ``identification`` section; a constant marked
``identified`` that no such record names still holds its starting value (:meth:`VehicleConfig.never_identified`: the
CasADi export refuses to hand those to a controller). There are no silent defaults: a missing key is a ConfigError
naming the file and key.

Values named for what they are, both optional:

* ``effective_ixx``/``effective_iyy`` (:data:`EFFECTIVE_KEYS`): the roll/pitch inertias the physics fit
  identifies; absent, the physics model uses the airframe's ``ixx``/``iyy``;
* a ``greybox:`` section (:data:`GREYBOX_KEYS`): the thesis greybox's own identified constants A_m, B_m, a, d
  (e.g. thesis Table 3-1 for the LinkQuad, or what ``identify`` fits for the linear model); absent, the
  greybox derives them from the physical constants (:meth:`VehicleConfig.greybox_constants`).

Old key names (before one value per constant) are read with one warning line naming the file and each old -> new key
(:data:`RENAMED_KEYS`, :data:`MOVED_TO_GREYBOX`).

Motors are listed in command order (u1..u4); each has a position in the body frame FRD [m] and a spin direction seen
from above. A rotor spinning counter-clockwise seen from above pushes the body clockwise, i.e. a positive yaw torque
about the FRD z axis (down): ``yaw_sign = +1``; clockwise: ``-1``.

Thrust and yaw torque per rotor (thesis Eq 3-3, 3-13; :mod:`quad_modelling.core.physics.rotors`):

.. math::

    T_i = k_f \\Omega_i^2, \\qquad Q_i = k_m \\Omega_i^2, \\qquad
    \\Omega_0 = \\sqrt{m g / (4 k_f)}
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from quad_modelling.core.input_files import read_yaml, yaml_number
from quad_modelling.core.physics.effects import EffectTerm, effects_document, parse_effects
from quad_modelling.core.physics.parameters import PHYSICS_KEYS
from quad_modelling.core.physics.rigid_body import GRAVITY, allocation_matrix
from quad_modelling.core.physics.rotors import hover_rotor_speed, linear_motor, steady_rotor_speed
from quad_modelling.errors import ConfigError, VehicleKeyWarning


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


CONSTANT_KEYS = ("mass", "arm_length", "ixx", "iyy", "izz", "prop_inertia", "rotor_speed_gain", "rotor_speed_offset",
                 "rotor_time_constant", "rotor_thrust_constant", "rotor_torque_constant")
"""Physical constants every vehicle file must give (docs/formats.md, vehicle configs): mass, arm, the airframe's
inertias, rotor inertia, the command-to-rotor-speed map Ω_ss = k_u u + Ω_off, the rotor time constant τ_m and
the thrust and yaw-torque constants k_f, k_m (T = k_f Ω², Q = k_m Ω²)."""

HELD_BY_IDENTIFY = ("rotor_speed_gain", "rotor_speed_offset")
"""Physics constants ``identify`` never fits (its ``identification.fit.held``): the speed map Ω_ss = k_u u + Ω_off,
whose scale the thrust constant k_f absorbs (T = k_f Ω_ss²). Marked ``identified`` in a vehicle file they are not
starting values it left behind (:meth:`VehicleConfig.never_identified` passes them over)."""

EFFECTIVE_KEYS = ("effective_ixx", "effective_iyy")
"""Optional effective values (status ``effective``): the roll/pitch inertias the physics fit identifies, which stand
in for what the physics model lacks (docs/models.md, effective inertia); absent, the physics model uses the
airframe's ``ixx``/``iyy``."""

AIRFRAME_OF = {"effective_ixx": "ixx", "effective_iyy": "iyy"}
"""The airframe constant each effective value stands in for."""

GREYBOX_KEYS = ("motor_a_m", "motor_b_m", "thrust_constant", "torque_constant")
"""The thesis greybox's constants (thesis Table 3-1 symbols A_m, B_m, a, d) in a vehicle file's optional
``greybox:`` section: the linear model's own identified (effective) values. Absent, they are derived from the
physical constants (:meth:`VehicleConfig.greybox_constants`)."""

RENAMED_KEYS = {"physics_ixx": "effective_ixx", "physics_iyy": "effective_iyy"}
"""Old ``constants`` keys read as new ``constants`` keys (with one warning line)."""

MOVED_TO_GREYBOX = {"motor_a_m": "motor_a_m", "motor_b_m": "motor_b_m", "thrust_constant": "thrust_constant",
                    "drag_constant": "torque_constant"}
"""Old ``constants`` keys (the thesis greybox's, next to the physical ones) read as ``greybox`` section keys."""

STATUSES = ("measured", "identified", "effective")

CONSTANT_RANGES: dict[str, tuple[float, float, str]] = {
    "mass": (1e-5, 1000.0, "kg"), "arm_length": (1e-3, 10.0, "m"),
    "ixx": (1e-12, 1000.0, "kg m2"), "iyy": (1e-12, 1000.0, "kg m2"), "izz": (1e-12, 1000.0, "kg m2"),
    "prop_inertia": (0.0, 10.0, "kg m2"), "rotor_speed_gain": (0.0, np.inf, "rad/s per input unit"),
    "rotor_speed_offset": (-1.0e5, 1.0e5, "rad/s"), "rotor_time_constant": (0.0, 10.0, "s"), "rotor_delay": (0.0, 1.0, "s"),
    "rotor_thrust_constant": (0.0, 1.0, "N s2/rad2"), "rotor_torque_constant": (0.0, 1.0, "N m s2/rad2"),
    "rotor_drag_xy": (0.0, 1.0, "N s/(m rad)"), "rotor_drag_z": (0.0, 1.0, "N s/(m rad)"),
    "rotor_drag_arm": (-10.0, 10.0, "m"), "effective_ixx": (1e-12, 1000.0, "kg m2"),
    "effective_iyy": (1e-12, 1000.0, "kg m2"), "motor_a_m": (-1.0e5, 0.0, "1/s"),
    "motor_b_m": (0.0, np.inf, "rad/s2 per input unit"), "thrust_constant": (0.0, 1.0, "N s2/rad2"),
    "torque_constant": (0.0, 1.0, "N m s2/rad2"),
}
"""Open interval (low, high) each constant must lie in, and its unit: positive masses, lengths, inertias and
rotor constants, a stable motor pole (negative, faster than 10 us), nothing beyond what a multirotor of up
to a tonne and 10 m arms could have, nothing below 10 mg, 1 mm arms and 1e-12 kg m² (an insect-scale flyer: the
RoboBee weighs 80 mg, its inertias ~1e-9 kg m²; a mass of 1e-300 kg ended a diagnosis in a traceback). ``prop_inertia`` may be 0 (rotor inertia neglected). Values must be
finite. Rotor time constant, delay and drag may be 0 (no lag, no delay, no drag)."""

DOCUMENT_KEYS = ("name", "description", "geometry", "motors", "inputs", "constants", "greybox", "effects", "identification")
"""The top-level keys of a vehicle file; any other (a typo: ``geomtery``) is refused, not ignored."""

MOTOR_KEYS = ("name", "position", "spin")  # one motors entry's; any other (tilt_deg) is refused: no model reads it
INPUT_KEYS = ("min", "max", "unit")  # the inputs'; any other (offset) is refused

CONSTANT_FIELDS = ("value", "unit", "source", "status", "sigma", "bounds", "at_bound", "vehicle_value", "change_percent",
                   "poorly_determined", "held")
"""The fields of one constant entry (``identify`` writes those after ``sigma``); any other (``vlaue``) is refused."""

ANY_INPUT_UNIT = "input unit"
"""In :data:`CONSTANT_RANGES`: per unit of the vehicle's own command (``rad/s per PWM``, ``rad/s per us``)."""

MAX_ROTOR_SPEED = 1.0e5
"""Fastest rotor speed [rad/s] a vehicle file may imply at full command (a Crazyflie's tops out near 2500, an Iris's
near 1000): a rotor_speed_gain of 1e300 overflowed every prediction into warnings and a NaN identification."""

ON_AXIS = 0.02
"""A rotor whose |x| or |y| is under this fraction of its radius sits on a body axis: a plus frame's all do, an x's none."""

MIN_TIME_CONSTANT_S = 1.0e-6  # shortest nonzero motor lag [s]: 1/τ_m of a 5e-324 s (denormal) lag overflows

ZERO_ALLOWED = ("prop_inertia", "rotor_time_constant", "rotor_delay", "rotor_drag_arm", "rotor_drag_xy", "rotor_drag_z")
"""Constants whose range includes its lower end 0 (the effect neglected)."""


@dataclass(frozen=True)
class Constant:
    """One physical constant with its unit, its source and how it was obtained."""

    value: float
    unit: str
    source: str
    status: str
    sigma: float | None = None
    """1-sigma in ``unit`` when the file gives one (NaN: not determined)."""


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
    greybox: dict[str, Constant] = field(default_factory=dict)
    """The file's ``greybox:`` section (:data:`GREYBOX_KEYS`), empty when the greybox derives its constants."""

    @property
    def file_path(self) -> str:
        """The file this vehicle was read from as an absolute path (what a model file records, so that a hint to pass
        it works from any directory); :attr:`path` unchanged when it names no file."""
        return str(Path(self.path).resolve()) if Path(self.path).is_file() else self.path

    def numbers(self) -> dict[str, float]:
        """Every number the models read from this vehicle, by name: constants, greybox constants (``greybox.KEY``),
        motor positions and spin signs (``motor.NAME.x``...), effect switches and parameters (``effect.NAME.on``,
        ``effect.NAME.PARAM``) and the input range. Two vehicles with equal numbers predict alike whatever their files'
        names (what ``merge`` compares)."""
        out = {name: float(c.value) for name, c in self.constants.items()}
        out.update({f"greybox.{name}": float(c.value) for name, c in self.greybox_constants().items()})
        for m in self.motors:
            out.update({f"motor.{m.name}.x": float(m.position[0]), f"motor.{m.name}.y": float(m.position[1]),
                        f"motor.{m.name}.yaw_sign": float(m.yaw_sign)})
        for name, term in self.effects.items():
            out[f"effect.{name}.on"] = float(term.on)
            out.update({f"effect.{name}.{key}": float(v.value) for key, v in term.parameters.items()})
        out.update({"input_min": float(self.input_min), "input_max": float(self.input_max)})
        return out

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
        """Ω0 = sqrt(m g / (4 k_f)) [rad/s] (:func:`~quad_modelling.core.physics.rotors.hover_rotor_speed`)."""
        return hover_rotor_speed(self.mass, self.value("rotor_thrust_constant"), GRAVITY)

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

    def effective_value(self, key: str) -> float:
        """The value a model fits for ``key``: an :data:`EFFECTIVE_KEYS` value the file lacks is the airframe's
        (``effective_ixx`` -> ``ixx``); any other key as :meth:`value`."""
        if key in AIRFRAME_OF and key not in self.constants:
            return self.value(AIRFRAME_OF[key])
        return self.value(key)

    def greybox_constants(self) -> dict[str, Constant]:
        """The thesis greybox's A_m [1/s], B_m [rad/s² per input unit], a [N s²/rad²], d [N m s²/rad²]
        (:data:`GREYBOX_KEYS`): the ``greybox:`` section when the file has one, else derived from the physical
        constants -- A_m = -1/τ_m, B_m = k_u/τ_m (:func:`~quad_modelling.core.physics.rotors.linear_motor`),
        a = k_f, d = k_m. ConfigError when a derivation needs τ_m > 0 and the file has 0."""
        if self.greybox:
            return dict(self.greybox)
        tau = self.constants["rotor_time_constant"]
        if not tau.value > 0:
            raise ConfigError(f"{self.path}: the linear greybox needs constants.rotor_time_constant > 0 (its motor pole "
                              f"A_m = -1/tau_m) or a greybox section with motor_a_m")
        gain = self.constants["rotor_speed_gain"]
        a_m, b_m = linear_motor(tau.value, gain.value)
        thrust, torque = self.constants["rotor_thrust_constant"], self.constants["rotor_torque_constant"]
        status = "identified" if "identified" in (tau.status, gain.status) else "measured"
        return {
            "motor_a_m": Constant(a_m, "1/s", "derived: -1/rotor_time_constant", tau.status),
            "motor_b_m": Constant(b_m, f"rad/s2 per {self.input_unit}", "derived: rotor_speed_gain/rotor_time_constant", status),
            "thrust_constant": Constant(thrust.value, thrust.unit, "derived: rotor_thrust_constant", thrust.status),
            "torque_constant": Constant(torque.value, torque.unit, "derived: rotor_torque_constant", torque.status),
        }

    def greybox_value(self, key: str) -> float:
        """One of :meth:`greybox_constants` by key (e.g. ``'motor_a_m'``)."""
        try:
            return self.greybox_constants()[key].value
        except KeyError as err:
            raise ConfigError(f"{self.path}: vehicle {self.name} has no greybox constant {key!r}") from err

    def with_greybox(self, values: dict[str, float], source: str) -> VehicleConfig:
        """A copy whose ``greybox:`` section holds :meth:`greybox_constants` with some replaced (e.g. identified)."""
        section = self.greybox_constants()
        for key, value in values.items():
            if key not in section:
                raise ConfigError(f"{self.path}: cannot set unknown greybox constant {key!r} (known: {', '.join(GREYBOX_KEYS)})")
            check_constant(key, float(value), f"{self.path} ({source})", "greybox")
            section[key] = Constant(float(value), section[key].unit, source, "effective")
        return replace(self, greybox=section)

    def missing(self, keys) -> list[str]:
        """Those of ``keys`` this vehicle file does not give (e.g. :data:`PHYSICS_KEYS`)."""
        return [k for k in keys if k not in self.constants]

    def identified(self) -> list[str]:
        """Names of the constants to identify from flight data."""
        return [k for k, c in self.constants.items() if c.status == "identified"]

    def never_identified(self, keys) -> list[str]:
        """Those of ``keys`` whose status is ``identified`` (to be identified from flight data) but that no
        identification record names: the file still holds their starting values (module docstring). The constants
        ``identify`` holds (:data:`HELD_BY_IDENTIFY`) are never among them: no run of it would fit them."""
        return [k for k in keys if k in self.constants and self.constants[k].status == "identified" and k not in self.fitted
                and k not in HELD_BY_IDENTIFY]

    def with_values(self, values: dict[str, float], source: str) -> VehicleConfig:
        """A copy with some constants replaced (e.g. identified ones), noting the source."""
        constants = dict(self.constants)
        for key, value in values.items():
            old = self.constants.get(key)
            if old is None and key in AIRFRAME_OF:
                old = Constant(self.value(AIRFRAME_OF[key]), self.constants[AIRFRAME_OF[key]].unit, source, "effective")
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

        _refuse_unknown(doc, DOCUMENT_KEYS, f"{where}: ", "a key of a vehicle file")
        name = _text(need(doc, "name", ""), "name", where)  # null was read as the vehicle "None"
        geometry = need(doc, "geometry", "")
        if geometry not in ("plus", "x"):
            raise ConfigError(f"{where}: geometry must be 'plus' or 'x', got {geometry!r}")
        constants_doc = need(doc, "constants", "")
        if not isinstance(constants_doc, dict):
            raise ConfigError(f"{where}: constants must be a mapping of constant name to {{value, unit, source, status}}")
        greybox_doc = {} if doc.get("greybox") is None else doc["greybox"]  # 0 or false is no section
        if not isinstance(greybox_doc, dict):
            raise ConfigError(f"{where}: greybox must be a mapping of {', '.join(GREYBOX_KEYS)} to {{value, unit, source, status}}")
        constants_doc, greybox_doc, old = _read_old_keys(constants_doc, greybox_doc, where)
        _refuse_unknown(constants_doc, tuple(dict.fromkeys((*CONSTANT_KEYS, *PHYSICS_KEYS, *EFFECTIVE_KEYS))), f"{where}: constants.",
                        "a vehicle constant")  # a typo (effective_ixx_) flew on the airframe's value without a word
        optional = [k for k in (*PHYSICS_KEYS, *EFFECTIVE_KEYS) if k in constants_doc and k not in CONSTANT_KEYS]
        for key in CONSTANT_KEYS:
            if key not in constants_doc and old:
                raise ConfigError(f"{where}: missing required key constants.{key} (an old vehicle file: its "
                                  f"{', '.join(old)} are the greybox section's now; the physical rotor constants "
                                  f"{', '.join(k for k in CONSTANT_KEYS if k.startswith('rotor_'))} are required, docs/formats.md)")
        constants = {key: _constant(need(constants_doc, key, "constants."), key, "constants", where, need)
                     for key in (*CONSTANT_KEYS, *optional)}
        _refuse_unknown(greybox_doc, GREYBOX_KEYS, f"{where}: greybox.", "a greybox constant")
        greybox = {key: _constant(need(greybox_doc, key, "greybox."), key, "greybox", where, need)
                   for key in GREYBOX_KEYS if greybox_doc}
        motors_doc = need(doc, "motors", "")
        if not isinstance(motors_doc, list) or len(motors_doc) != 4:
            raise ConfigError(f"{where}: motors must list exactly 4 rotors in command order u1..u4")
        motors = []
        for i, m in enumerate(motors_doc):
            _refuse_unknown(m, MOTOR_KEYS, f"{where}: motors[{i}].", "a key of a motor")
            position = need(m, "position", f"motors[{i}].")
            spin = need(m, "spin", f"motors[{i}].")
            if spin not in ("cw", "ccw"):
                raise ConfigError(f"{where}: motors[{i}].spin must be 'cw' or 'ccw' (seen from above), got {spin!r}")
            if not (isinstance(position, list) and len(position) == 2):
                raise ConfigError(f"{where}: motors[{i}].position must be [x, y] in body FRD metres")
            try:
                xy = (yaml_number(position[0]), yaml_number(position[1]))
            except (TypeError, ValueError) as err:
                raise ConfigError(f"{where}: motors[{i}].position is not two numbers: {str(position)[:60]}") from err
            if not np.all(np.isfinite(xy)):
                raise ConfigError(f"{where}: motors[{i}].position must be finite, got {list(xy)}")
            motors.append(Motor(_text(need(m, "name", f"motors[{i}]."), f"motors[{i}].name", where), xy, 1 if spin == "ccw" else -1))
        radii = np.hypot(*np.array([m.position for m in motors]).T)
        arm = constants["arm_length"].value
        if not np.allclose(radii, arm, rtol=0.02):
            raise ConfigError(f"{where}: motor positions lie at {np.round(radii, 4).tolist()} m from the centre, not arm_length {arm} m")
        if sum(m.yaw_sign for m in motors) != 0:
            raise ConfigError(f"{where}: two rotors must spin cw and two ccw")
        xy = np.array([m.position for m in motors])  # the mixer sets thrust, roll, pitch and yaw each on its own
        ratio = constants["rotor_torque_constant"].value / constants["rotor_thrust_constant"].value  # k_m/k_f [m]
        if np.linalg.matrix_rank(allocation_matrix(xy, [m.yaw_sign for m in motors], ratio)) < 4:
            raise ConfigError(f"{where}: motor positions {xy.round(4).tolist()} with their spins cannot set thrust, roll, pitch "
                              "and yaw apart (rotors coincide or pair up): give each rotor its own place")
        on_axis = np.abs(xy).min(axis=1) <= ON_AXIS * np.hypot(*xy.T)  # the label's one rule (io.ulog_vehicle's too)
        if on_axis.any() if geometry == "x" else not on_axis.all():
            raise ConfigError(f"{where}: geometry {geometry} but rotor(s) {(np.flatnonzero(on_axis != (geometry == 'plus')) + 1).tolist()} "
                              f"lie {'on' if geometry == 'x' else 'off'} a body axis ('plus': every rotor on one, 'x': none)")
        names = [m.name for m in motors]
        if len(set(names)) != len(names):
            raise ConfigError(f"{where}: motors name {sorted({n for n in names if names.count(n) > 1})[0]!r} twice; name each rotor once")
        inputs = need(doc, "inputs", "")
        _refuse_unknown(inputs, INPUT_KEYS, f"{where}: inputs.", "a key of inputs")
        try:
            input_min = yaml_number(need(inputs, "min", "inputs."))
            input_max = yaml_number(need(inputs, "max", "inputs."))
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{where}: inputs.min and inputs.max must be numbers") from err
        if not (np.isfinite(input_min) and np.isfinite(input_max)):
            raise ConfigError(f"{where}: inputs.min and inputs.max must be finite, got [{input_min}, {input_max}]")
        if not input_max > input_min:
            raise ConfigError(f"{where}: inputs.max must exceed inputs.min")
        gain, offset = constants["rotor_speed_gain"].value, constants["rotor_speed_offset"].value  # both required
        fastest = float(steady_rotor_speed(SimpleNamespace(speed_gain=gain, speed_offset=offset), input_max))  # full command
        if not fastest < MAX_ROTOR_SPEED:
            raise ConfigError(f"{where}: constants.rotor_speed_gain.value {gain:g} turns the rotors at {fastest:.3g} rad/s at "
                              f"inputs.max {input_max:g}, beyond {MAX_ROTOR_SPEED:g} rad/s")
        return cls(
            name=name,
            description=str(doc.get("description", "")),
            geometry=geometry,
            motors=tuple(motors),
            constants=constants,
            input_min=input_min,
            input_max=input_max,
            input_unit=_text(need(inputs, "unit", "inputs."), "inputs.unit", where),
            path=where,
            effects=parse_effects(doc.get("effects"), where),
            fitted=_fitted_constants(doc.get("identification"), where),
            greybox=greybox,
        )


def _text(value, key: str, where: str) -> str:
    """A name or unit of a vehicle file: text, or a number YAML read (``name: 2021``) as text; else ConfigError."""
    if isinstance(value, bool) or not isinstance(value, (str, int, float)) or not str(value).strip():
        raise ConfigError(f"{where}: {key} must be text, got {str(value)[:40]!r}")
    return str(value)


def _refuse_unknown(mapping, known, context: str, what: str) -> None:
    """ConfigError naming the first key of ``mapping`` not in ``known``: '<context><key> is not <what> (known: ...)'."""
    unknown = sorted(str(k) for k in mapping if k not in known) if isinstance(mapping, dict) else []
    if unknown:
        raise ConfigError(f"{context}{unknown[0]} is not {what} (known: {', '.join(known)})")


def _fitted_constants(record, where: str) -> frozenset[str]:
    """The constant names of a vehicle document's ``identification.constants`` record (None: none); each entry must be
    the fit's record identify writes (a mapping with a finite ``value``): a name alone does not make a value fitted."""
    if record is None:
        return frozenset()
    fitted = record.get("constants", {}) if isinstance(record, dict) else None
    if not isinstance(fitted, dict):
        raise ConfigError(f"{where}: identification.constants must be a mapping of constant names (as identify writes it)")
    for name, entry in fitted.items():
        value = entry.get("value") if isinstance(entry, dict) else None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise ConfigError(f"{where}: identification.constants.{name} must be the fit's record with a finite value "
                              f"(as identify writes it), got {str(entry)[:40]!r}")
    return frozenset(str(k) for k in fitted)


def _constant(entry, key: str, section: str, where: str, need) -> Constant:
    """One ``{value, unit, source, status[, sigma]}`` entry of ``section`` validated (ConfigError naming the key)."""
    for sub in ("value", "unit", "source", "status"):
        need(entry, sub, f"{section}.{key}.")
    _refuse_unknown(entry, CONSTANT_FIELDS, f"{where}: {section}.{key}.", "a field of a constant")
    check_unit(key, str(entry["unit"]), f"{where}: {section}.{key}")
    if entry["status"] not in STATUSES:
        raise ConfigError(f"{where}: {section}.{key}.status must be one of {STATUSES}, got {entry['status']!r}")
    try:
        value = yaml_number(entry["value"])
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{where}: {section}.{key}.value is not a number: {str(entry['value'])[:40]!r}") from err
    check_constant(key, value, where, section)
    sigma = entry.get("sigma")
    if sigma is not None:
        try:
            sigma = yaml_number(sigma)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{where}: {section}.{key}.sigma is not a number: {str(sigma)[:40]!r}") from err
        if sigma < 0 or np.isinf(sigma):
            raise ConfigError(f"{where}: {section}.{key}.sigma must be a finite number >= 0 (or .nan: not determined), got {sigma:g}")
    return Constant(value, str(entry["unit"]), str(entry["source"]), entry["status"], sigma)


def check_unit(key: str, unit: str, where: str) -> None:
    """ConfigError (one line) when a constant's ``unit`` is not the one this program reads it in
    (:data:`CONSTANT_RANGES`): a mass in g would be read as kg. Units per command accept the vehicle's own command
    unit (``rad/s per PWM``)."""
    if key not in CONSTANT_RANGES:
        return
    expected = CONSTANT_RANGES[key][2]
    given = " ".join(unit.split())
    if expected.endswith(ANY_INPUT_UNIT):
        ok = given.startswith(expected[: -len(ANY_INPUT_UNIT)]) and len(given) > len(expected) - len(ANY_INPUT_UNIT)
    else:
        ok = given == expected
    if not ok:
        raise ConfigError(f"{where}.unit is {unit!r}; {key} is read in {expected} (convert the value and write that unit)")


def _read_old_keys(constants_doc: dict, greybox_doc: dict, where: str) -> tuple[dict, dict, list[str]]:
    """(constants, greybox section, old keys found) with the old key names read as the new ones
    (:data:`RENAMED_KEYS`, :data:`MOVED_TO_GREYBOX`) and one :class:`VehicleKeyWarning` line naming ``where`` and
    each old -> new key; ConfigError when a file gives both an old key and its replacement."""
    old = [k for k in constants_doc if k in RENAMED_KEYS or k in MOVED_TO_GREYBOX]
    if not old:
        return constants_doc, greybox_doc, old
    constants_doc, greybox_doc = dict(constants_doc), dict(greybox_doc)
    moves = []
    for key in old:
        section, new = ("constants", RENAMED_KEYS[key]) if key in RENAMED_KEYS else ("greybox", MOVED_TO_GREYBOX[key])
        target = constants_doc if section == "constants" else greybox_doc
        if new in target:
            raise ConfigError(f"{where}: constants.{key} is the old name of {section}.{new}, and the file gives both; keep {section}.{new}")
        target[new] = constants_doc.pop(key)
        moves.append(f"constants.{key} -> {section}.{new}")
    warnings.warn(VehicleKeyWarning(f"{where}: old vehicle keys read as the new ones (rename them, docs/formats.md): {', '.join(moves)}"),
                  stacklevel=3)
    return constants_doc, greybox_doc, old


def check_constant(key: str, value: float, where: str, section: str = "constants") -> None:
    """ConfigError naming ``where`` and ``<section>.<key>.value`` unless the value is finite and inside
    :data:`CONSTANT_RANGES` (a motor lag 0 or at least :data:`MIN_TIME_CONSTANT_S`)."""
    if not np.isfinite(value):
        raise ConfigError(f"{where}: {section}.{key}.value must be a finite number, got {value}")
    if key == "rotor_time_constant" and 0 < value < MIN_TIME_CONSTANT_S:
        raise ConfigError(f"{where}: {section}.{key}.value {value:g} s: 0 (no motor lag) or at least {MIN_TIME_CONSTANT_S:g} s")
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
        raise ConfigError(f"{where}: {section}.{key}.value {rule}, got {value:g}")


def effective_source(source: str, value: float, airframe: float, airframe_key: str) -> str:
    """The source text of an effective value (e.g. ``effective_ixx``): where it was fitted and its ratio to the
    airframe's constant ``airframe_key``."""
    return (f"effective value of the physics fit, {value / airframe:.2f} x the airframe's {airframe_key} {airframe:.4g} "
            f"(stands in for what the physics model lacks, docs/models.md): {source}")


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
    if "/" in str(name_or_path):  # ./crazyflie21 read the shipped file
        raise ConfigError(f"vehicle {name_or_path!r}: a path to a vehicle file ends in .yaml; a shipped vehicle is a bare name")
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
        "constants": {k: _constant_document(c) for k, c in vehicle.constants.items()},
        **({"greybox": {k: _constant_document(c) for k, c in vehicle.greybox.items()}} if vehicle.greybox else {}),
        "effects": effects_document(vehicle.effects),
    }


def _constant_document(c: Constant) -> dict:
    return {"value": c.value, "unit": c.unit, "source": c.source, "status": c.status, **({} if c.sigma is None else {"sigma": c.sigma})}
