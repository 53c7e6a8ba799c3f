"""Constants of the nonlinear physics model (:mod:`quad_modelling.core.physics`), read from a vehicle file.

The physics constants are the vehicle file's :data:`PHYSICS_KEYS` (optional in a vehicle file; the ``physics`` model
needs them all and names the missing ones) plus its mass, yaw inertia
``izz``, rotor inertia ``prop_inertia``, motor positions and spins:

================================  ==========================  ===========================================
symbol (code)                     key                         unit
================================  ==========================  ===========================================
k_u (``speed_gain``)              ``rotor_speed_gain``        rad/s per input unit
Ω_off (``speed_offset``)          ``rotor_speed_offset``      rad/s
τ_m (``time_constant``)           ``rotor_time_constant``     s
δ (``delay``)                     ``rotor_delay``             s
k_f (``thrust_constant``)         ``rotor_thrust_constant``   N s²/rad²
k_m (``torque_constant``)         ``rotor_torque_constant``   N m s²/rad²
d_xy, d_z (``drag``)              ``rotor_drag_xy``/``_z``    N s/(m rad)
h_d (``drag_arm``)                ``rotor_drag_arm``          m (FRD z from the CG; < 0: above it)
I_xx, I_yy (``inertia[:2]``)      ``effective_ixx``/``_iyy``  kg m² (absent: the airframe's ``ixx``/``iyy``)
================================  ==========================  ===========================================

The roll/pitch inertias the physics fit identifies are effective values (status ``effective``, 3-10x the
airframe's on the NanoBench flights: docs/models.md, effective inertia) with their own keys; the airframe's
``ixx``/``iyy`` stay the measured ones (the thesis greybox uses those). Only the
products k_f k_u² and k_m k_u² are identifiable from motion without rotor-speed measurements, so
``identify`` holds k_u and Ω_off (literature, a thrust-stand measurement) and fits the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from quad_modelling.core.physics import rotors
from quad_modelling.core.physics.effects import held_at_zero, switched_on
from quad_modelling.errors import ConfigError

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
)
"""The vehicle-file keys of the nonlinear physics model's constants (:class:`PhysicsParameters`); those not in
:data:`~quad_modelling.core.vehicle.CONSTANT_KEYS` are optional in a vehicle file (validated when present; the
``physics`` model names the missing ones): the command delay δ, the linear rotor drag d_xy, d_z and its arm h_d (FRD z
of where it acts). Here, beside their units (:data:`PHYSICS_UNITS`): the vehicle file (``core/vehicle.py``) reads them."""

PHYSICS_UNITS: dict[str, str] = {
    "rotor_speed_gain": "rad/s per input unit",
    "rotor_speed_offset": "rad/s",
    "rotor_time_constant": "s",
    "rotor_delay": "s",
    "rotor_thrust_constant": "N s2/rad2",
    "rotor_torque_constant": "N m s2/rad2",
    "rotor_drag_xy": "N s/(m rad)",
    "rotor_drag_z": "N s/(m rad)",
    "rotor_drag_arm": "m",
    "effective_ixx": "kg m2",
    "effective_iyy": "kg m2",
}
"""Unit of each physics constant (as written in vehicle files)."""


@dataclass(frozen=True)
class PhysicsParameters:
    """Everything the physics model needs, SI units, body FRD (see module docstring for the keys).

    mass [kg]; inertia (I_xx, I_yy, I_zz) [kg m²]; prop_inertia I_p [kg m²]; positions (4, 2) rotor (x, y)
    in FRD [m]; spins (4,) s_i = +1 for a rotor spinning counter-clockwise seen from above (positive
    reaction torque about FRD z); speed_gain k_u, speed_offset Ω_off, time_constant τ_m, delay δ [s], thrust_constant
    k_f, torque_constant k_m, drag (d_xy, d_xy, d_z), drag_arm h_d [m]; input_min/max: the command range.

    The optional terms (:mod:`quad_modelling.core.physics.effects`), None when off: ground_effect (c_ge [m²],
    h_off [m]); battery (κ [1/V], V_ref [V]); motor imbalance: motor_gains (g_1..g_4) [1] and cg_offset (c_x, c_y) [m]
    (FRD, the CG from the geometric centre the positions are measured from; :func:`term_fields`); gyroscopic (k_b,
    k_p) [1]: with no ``gyroscopic`` entry or the entry switched off, the body's term alone, (1, 0) -- the body's
    -ω × Iω is Euler's equations, as the simulator keeps it (None, no gyroscopic torque at all, is only the fit's
    known part while it fits k_b and k_p as columns).
    The switches ``rotor_drag``, ``motor_lag``, ``input_delay`` switched off hold drag and drag_arm, τ_m, δ at 0.
    """

    mass: float
    inertia: tuple[float, float, float]
    prop_inertia: float
    positions: np.ndarray
    spins: np.ndarray
    speed_gain: float
    speed_offset: float
    time_constant: float
    delay: float
    thrust_constant: float
    torque_constant: float
    drag: tuple[float, float, float]
    drag_arm: float
    input_min: float
    input_max: float
    ground_effect: tuple[float, float] | None = None
    battery: tuple[float, float] | None = None
    motor_gains: tuple[float, float, float, float] | None = None
    cg_offset: tuple[float, float] | None = None
    gyroscopic: tuple[float, float] | None = (1.0, 0.0)

    @classmethod
    def from_vehicle(cls, vehicle) -> PhysicsParameters:
        """The physics constants of ``vehicle`` (a :class:`~quad_modelling.core.vehicle.VehicleConfig`, which sits above
        this module: it reads the constants this one names); ConfigError naming the file and every missing key."""
        held = held_at_zero(vehicle.effects)  # base constants of a switched-off rotor_drag, motor_lag, input_delay
        missing = [key for key in vehicle.missing(PHYSICS_KEYS) if key not in held]
        if missing:
            raise ConfigError(f"{vehicle.path}: the physics model needs the vehicle constants {', '.join(missing)} "
                              f"(docs/formats.md, physics constants): add starting values for them to the vehicle file "
                              f"(config/vehicles/crazyflie21.yaml has each), then `quad-modelling identify` fits them")

        def v(key: str) -> float:
            return 0.0 if key in held else vehicle.value(key)

        return cls(
            mass=vehicle.mass,
            inertia=(vehicle.effective_value("effective_ixx"), vehicle.effective_value("effective_iyy"), v("izz")),
            prop_inertia=v("prop_inertia"),
            positions=vehicle.motor_positions,
            spins=vehicle.yaw_signs,
            speed_gain=v("rotor_speed_gain"),
            speed_offset=v("rotor_speed_offset"),
            time_constant=v("rotor_time_constant"),
            delay=v("rotor_delay"),
            thrust_constant=v("rotor_thrust_constant"),
            torque_constant=v("rotor_torque_constant"),
            drag=(v("rotor_drag_xy"), v("rotor_drag_xy"), v("rotor_drag_z")),
            drag_arm=v("rotor_drag_arm"),
            input_min=vehicle.input_min,
            input_max=vehicle.input_max,
            **{key: value for name in ("ground_effect", "battery", "motor_imbalance")
               for key, value in term_fields(name, switched_on(vehicle.effects, name)).items()},
            gyroscopic=switched_on(vehicle.effects, "gyroscopic") or (1.0, 0.0),  # off: the body's term (docstring)
        )

    @property
    def terms_on(self) -> tuple[str, ...]:
        """The optional terms switched on (:data:`~quad_modelling.core.physics.effects.TERMS` names)."""
        on = {"ground_effect": self.ground_effect is not None, "battery": self.battery is not None,
              "motor_imbalance": self.motor_gains is not None, "gyroscopic": self.gyroscopic is not None}
        return tuple(name for name, is_on in on.items() if is_on)

    def with_term(self, name: str, values: tuple[float, ...] | None) -> PhysicsParameters:
        """A copy with term ``name`` switched on with ``values`` (:data:`~quad_modelling.core.physics.effects.TERMS`
        order), or off (None): :func:`term_fields`."""
        return replace(self, **term_fields(name, values))

    def with_values(self, **changes) -> PhysicsParameters:
        """A copy with some fields replaced."""
        return replace(self, **changes)

    def vehicle_values(self) -> dict[str, float]:
        """These parameters as vehicle-file constants (:data:`PHYSICS_KEYS` and the
        effective roll/pitch inertias, :data:`~quad_modelling.core.vehicle.EFFECTIVE_KEYS`)."""
        return {
            "rotor_speed_gain": self.speed_gain, "rotor_speed_offset": self.speed_offset,
            "rotor_time_constant": self.time_constant, "rotor_delay": self.delay, "rotor_thrust_constant": self.thrust_constant,
            "rotor_torque_constant": self.torque_constant, "rotor_drag_xy": self.drag[0], "rotor_drag_z": self.drag[2], "rotor_drag_arm": self.drag_arm,
            "effective_ixx": self.inertia[0], "effective_iyy": self.inertia[1],
        }

    def hover_rotor_speed(self, gravity: float) -> float:
        """Ω_H = sqrt(m g / (4 k_f)) [rad/s]: each rotor's speed in a level hover
        (:func:`~quad_modelling.core.physics.rotors.hover_rotor_speed`)."""
        return rotors.hover_rotor_speed(self.mass, self.thrust_constant, gravity)

    def hover_command(self, gravity: float) -> float:
        """u_H = (Ω_H - Ω_off) / k_u [input unit]: the command of a level hover (all rotors equal)."""
        return float(rotors.command_for_rotor_speed(self.hover_rotor_speed(gravity), self.speed_gain, self.speed_offset))


def term_fields(name: str, values: tuple[float, ...] | None) -> dict:
    """The :class:`PhysicsParameters` fields of term ``name`` (:data:`~quad_modelling.core.physics.effects.TERMS`)
    with its parameter ``values`` in TERMS order (None: off): the one mapping from a term's parameters to the
    fields the physics reads. The motor imbalance's six are two fields: ``motor_gains`` (g_1..g_4) and
    ``cg_offset`` (c_x, c_y) [m]."""
    if name == "motor_imbalance":
        return {"motor_gains": None if values is None else tuple(float(v) for v in values[:4]),
                "cg_offset": None if values is None else tuple(float(v) for v in values[4:6])}
    if name in ("ground_effect", "battery", "gyroscopic"):
        return {name: None if values is None else tuple(float(v) for v in values)}
    raise ValueError(f"{name} is not a physics-model term with parameters")
