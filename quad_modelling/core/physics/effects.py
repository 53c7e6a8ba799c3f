r"""Optional terms of the physics model, switched on in the vehicle file (DESIGN 6.1b, 6.2): one definition each.

The base physics (:mod:`~quad_modelling.core.physics.rigid_body`) is the rigid body with the rotors' thrust and
yaw torque, their lag and command delay, and rotor drag. The terms below extend it; each is off unless the
vehicle file's ``effects`` section switches it on with identified parameters (``quad-modelling identify --effects
LIST`` fits them with the base constants). Their forms are the model's, simpler than the truth simulator's
(``docs/simulator.md``); the code of each form is in the module named:

====================  ==========================================================================  ==========================
term                  form (the module's symbols)                                                  parameters
====================  ==========================================================================  ==========================
``ground_effect``     :math:`T_i \to k_{GE}(h) T_i`, :math:`k_{GE} = 1 + c_{ge}/(h + h_{off})^2`,   coefficient c_ge [m2],
                      h = -z_N the height above the ground plane z_N = 0 [m] (:mod:`.aero`)          offset h_off [m]
``battery``           :math:`\Omega_{ss} \to (1 + \kappa (V - V_{ref})) \Omega_{ss}`, V the measured  kappa [1/V],
                      battery voltage, held at the anchor's over a prediction (:mod:`.rotors`)       reference_voltage [V]
``motor_imbalance``   :math:`u_i \to g_i u_i`: each motor answers its logged command times its gain  gain_1..gain_4 [1],
                      (mean 1: the collective gain is the thrust constant's) (:mod:`.rotors`); and  cg_offset_x,
                      the CG at :math:`c = (c_x, c_y, 0)` from the geometric centre the rotor        cg_offset_y [m]
                      positions are measured from: the rotor forces' moment about the CG gains       (absent: 0)
                      :math:`-c \times F` (:func:`~.rigid_body.cg_offset_moment`)
``gyroscopic``        the gyroscopic torques :math:`-\omega \times (k_b I\omega + k_p h_r)`,        body_scale k_b [1],
                      :math:`h_r = (0, 0, -I_p \sum_i s_i \Omega_i)` (:mod:`.rigid_body`). No       rotor_scale k_p [1]
                      entry or off: the body's term alone (k_b = 1, k_p = 0), as rigid-body physics has
``disturbance_observer``  how the model anchors (:class:`~quad_modelling.core.models.physics.Observer`):  linear_history [s],
                      constant disturbances held over a horizon, estimated over the histories;      angular_history [s],
                      ``angular_trim`` 1 removes the model's own mean angular acceleration (a       angular_trim [1]
                      constant moment it lacks), 0 holds measured - modelled. Off: no observer.
                      No entry: 0.5 s, 0.5 s, trim (``identify`` chooses it by the data)
====================  ==========================================================================  ==========================

Three terms are switches over base constants (:data:`BASE_SWITCHES`): their parameters are those constants, in
the vehicle file's ``constants`` with value, sigma, unit, bounds, source and status (one value per physical
constant); an entry ``{enabled: false}`` holds them at 0 -- in every prediction and in ``identify``'s fit -- and
no entry, or ``enabled: true``, uses them as identified:

====================  ==========================================================================  ==========================
``rotor_drag``        :math:`F_d = -\sum_i D\,\Omega_i v_B` and its moment about the CG           ``rotor_drag_xy``, ``_z``,
                      (:mod:`.rigid_body`)                                                        ``rotor_drag_arm``
``motor_lag``         first-order rotor lag :math:`\dot\Omega = (\Omega_{ss} - \Omega)/\tau_m`;    ``rotor_time_constant``
                      off: :math:`\tau_m = 0`, each rotor at its steady speed (:mod:`.rotors`)
``input_delay``       :math:`u(t) \to u(t - \delta)`; off: :math:`\delta = 0` (:mod:`.rotors`)        ``rotor_delay``
====================  ==========================================================================  ==========================

The rest of the catalogue (:data:`~quad_modelling.core.effect_names.CATALOGUE_EFFECTS`) is the physics itself --
the thrust nonlinearity (:math:`T = k_f \Omega^2` of a speed affine in the command) -- or what the physics model's
disturbance observer absorbs (trim drift: a constant trim over the observer's history; ``disturbance_observer``).

A vehicle file's ``effects`` section (validated by :func:`parse_effects`; every error one line naming the file,
the term and the key)::

    effects:
      ground_effect:
        enabled: true
        coefficient: {value: 3.1e-5, sigma: 4e-6, unit: m2, bounds: [0, 0.0021], source: "...", status: identified}
        offset: {value: 0.023, unit: m, bounds: [0, 0.46], source: "...", status: identified}
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from quad_modelling.core.input_files import yaml_number
from quad_modelling.errors import ConfigError


@dataclass(frozen=True)
class TermParameter:
    """One parameter of a term: name, unit (as written in vehicle files), what it is."""

    name: str
    unit: str
    doc: str
    default: float | None = None
    """The value a vehicle file's entry without this parameter reads as (a parameter added to a term after files
    were written: the motor imbalance's CG offset, 0); None: required."""
    admissible: tuple[float, float] = (-math.inf, math.inf)
    """The closed range a value must lie in whatever bounds the file gives (an observer history under 1000 s): a
    file's own bounds [-1, 10] let an observer history of -0.5 s through to a traceback."""
    positive: bool = False
    """The value must be above 0 (a motor's gain, a reference voltage)."""


OBSERVER_HISTORY_MAX_S = 999.0
"""Longest disturbance-observer history a vehicle file may give [s] (:class:`~quad_modelling.core.models.physics.Observer`
takes 0 .. 1000 s)."""

TERMS: dict[str, tuple[TermParameter, ...]] = {
    "ground_effect": (TermParameter("coefficient", "m2", "c_ge: thrust gain (h + h_off)^2 near the ground", admissible=(0.0, math.inf)),
                      TermParameter("offset", "m", "h_off: height offset of the ground-effect law", admissible=(0.0, math.inf))),
    "battery": (TermParameter("kappa", "1/V", "rotor-speed change per volt of battery voltage"),
                TermParameter("reference_voltage", "V", "V_ref: voltage at which the base constants hold",
                              positive=True)),
    "motor_imbalance": (*(TermParameter(f"gain_{i}", "1", f"motor {i}'s gain on its logged command", positive=True)
                          for i in range(1, 5)),
                        TermParameter("cg_offset_x", "m", "c_x: the CG forward of the geometric centre (FRD x)", 0.0),
                        TermParameter("cg_offset_y", "m", "c_y: the CG right of the geometric centre (FRD y)", 0.0)),
    "gyroscopic": (TermParameter("body_scale", "1", "k_b: scale of the body's gyroscopic torque -ω × Iω"),
                   TermParameter("rotor_scale", "1", "k_p: scale of the rotors' gyroscopic torque -ω × h_r")),
    "rotor_drag": (),
    "motor_lag": (),
    "input_delay": (),
    "disturbance_observer": (TermParameter("linear_history", "s", "history of the linear disturbance estimate",
                                           admissible=(0.0, OBSERVER_HISTORY_MAX_S)),
                             TermParameter("angular_history", "s", "history of the angular disturbance estimate",
                                           admissible=(0.0, OBSERVER_HISTORY_MAX_S)),
                             TermParameter("angular_trim", "1", "1: remove the model's mean angular acceleration "
                                                                "(a moment the model lacks); 0: hold measured - modelled",
                                           admissible=(0.0, 1.0))),
}
"""The physics model's optional terms and their parameters (module docstring), in the order they are applied; the
switches of :data:`BASE_SWITCHES` have none of their own."""

BASE_SWITCHES: dict[str, tuple[str, ...]] = {
    "rotor_drag": ("rotor_drag_xy", "rotor_drag_z", "rotor_drag_arm"),
    "motor_lag": ("rotor_time_constant",),
    "input_delay": ("rotor_delay",),
}
"""Terms that switch base constants (module docstring): the vehicle-file constants each holds at 0 when off."""


@dataclass(frozen=True)
class TermValue:
    """A term parameter's value as a vehicle file holds it."""

    value: float
    unit: str
    bounds: tuple[float, float]
    source: str
    status: str
    sigma: float = float("nan")


@dataclass(frozen=True)
class EffectTerm:
    """One term of the vehicle file's ``effects`` section: switched ``on`` or not, its parameters by name."""

    name: str
    on: bool
    parameters: dict[str, TermValue]

    def values(self) -> tuple[float, ...]:
        """The parameter values in :data:`TERMS` order (a parameter the file lacks: its default)."""
        return tuple(self.parameters[p.name].value if p.name in self.parameters else p.default for p in TERMS[self.name])


def parse_term_names(names, where: str = "--effects", listed: tuple[str, ...] = TERMS) -> tuple[str, ...]:
    """Term names of an ``identify --effects`` list, validated: known (:data:`TERMS`), each named once, no empty item
    between commas (a whole list left empty is no term); ``listed`` the names an unknown one's error offers (the
    verb's own)."""
    names = [str(n).strip() for n in names]
    if len(names) > 1 and not all(names):
        raise ConfigError(f"{where} {','.join(names)}: an empty name in the list (a comma too many?); name each term once")
    names = [n for n in names if n]
    unknown = [n for n in names if n not in TERMS]
    if unknown:
        raise ConfigError(f"{where}: unknown physics-model term {', '.join(map(repr, unknown))}; known: {', '.join(listed)} "
                          f"(docs/models.md)")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"{where}: {', '.join(twice)} named more than once")
    return tuple(n for n in TERMS if n in names)


def parse_effects(doc, where: str) -> dict[str, EffectTerm]:
    """The ``effects`` section of a vehicle document (None: no terms), validated (module docstring): every term known,
    every parameter present with its unit (the term's), finite bounds low <= high and a value inside them, a known
    status; a term switched on must have every parameter identified or measured (a value, not null), except one
    with a :attr:`TermParameter.default`, which an entry may lack (read as the default: an older file's motor
    imbalance without a CG offset has offset 0)."""
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError(f"{where}: effects must be a mapping of term names")
    terms = {}
    for name, entry in doc.items():
        if name not in TERMS:
            raise ConfigError(f"{where}: effects.{name}: unknown physics-model term; known: {', '.join(TERMS)}")
        if not isinstance(entry, dict) or not isinstance(entry.get("enabled"), bool):
            raise ConfigError(f"{where}: effects.{name}.enabled must be true or false")
        known = {p.name: p for p in TERMS[name]}
        extra = sorted(map(str, set(entry) - set(known) - {"enabled"}))  # a YAML key may be a number
        if extra:
            has = (f"{name} has {', '.join(known)}" if known else
                   f"{name} is a switch: its values are the constants {', '.join(BASE_SWITCHES[name])}")
            raise ConfigError(f"{where}: effects.{name}.{extra[0]}: unknown parameter; {has}")
        parameters = {}
        for key, spec in known.items():
            context = f"{where}: effects.{name}.{key}"
            value = entry.get(key)
            if value is None:
                if entry["enabled"] and spec.default is None:
                    raise ConfigError(f"{context}: {name} is switched on but its parameter {key} was never identified "
                                      f"(quad-modelling identify --effects {name})")
                continue
            parameters[key] = _term_value(value, spec, context, entry["enabled"], name)
        terms[name] = EffectTerm(name, entry["enabled"], parameters)
    return terms


def _term_value(entry, spec: TermParameter, context: str, on: bool, name: str) -> TermValue:
    if not isinstance(entry, dict):
        raise ConfigError(f"{context} must be a mapping {{value, unit, bounds, source, status}}")
    for key in ("unit", "bounds", "source", "status"):
        if key not in entry:
            raise ConfigError(f"{context}: missing {key}")
    if entry["unit"] != spec.unit:
        raise ConfigError(f"{context}.unit must be {spec.unit!r}, got {entry['unit']!r}")
    if entry["status"] not in ("measured", "identified", "not identified"):
        raise ConfigError(f"{context}.status must be measured, identified or 'not identified', got {entry['status']!r}")
    if on and entry["status"] == "not identified":
        raise ConfigError(f"{context}: {name} is switched on but this parameter was never identified "
                          f"(quad-modelling identify --effects {name})")
    try:
        value = yaml_number(entry.get("value"))
        low, high = (yaml_number(b) for b in entry["bounds"])
        sigma = yaml_number(entry.get("sigma", "nan"))
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{context}: value, bounds [low, high] and sigma must be numbers") from err
    if not (np.isfinite(low) and np.isfinite(high) and low <= high):
        raise ConfigError(f"{context}.bounds must be finite [low, high] with low <= high, got [{low:g}, {high:g}]")
    if not (np.isfinite(value) and low <= value <= high):
        raise ConfigError(f"{context}.value {value:g} {spec.unit} lies outside its bounds [{low:g}, {high:g}]")
    least, most = spec.admissible
    if not least <= value <= most or (spec.positive and value <= 0) or (spec.name == "angular_trim" and value not in (0.0, 1.0)):
        allowed = "0 or 1" if spec.name == "angular_trim" else "above 0" if spec.positive else f"in [{least:g}, {most:g}]"
        raise ConfigError(f"{context}.value {value:g} {spec.unit}: must be {allowed}, whatever the bounds")
    if not (np.isnan(sigma) or 0 <= sigma < np.inf):
        raise ConfigError(f"{context}.sigma {sigma:g}: must be a finite number >= 0 (or .nan: not determined)")
    return TermValue(value, spec.unit, (low, high), str(entry["source"]), entry["status"], sigma)


def effects_document(terms: dict[str, EffectTerm]) -> dict:
    """The ``effects`` section of a vehicle document holding ``terms`` (the inverse of :func:`parse_effects`)."""
    section = {}
    for name, term in terms.items():
        entry: dict = {"enabled": term.on}
        for key, v in term.parameters.items():
            entry[key] = {"value": v.value, "sigma": v.sigma, "unit": v.unit, "bounds": list(v.bounds), "source": v.source,
                          "status": v.status}
        section[name] = entry
    return section


def switched_off(terms: dict[str, EffectTerm], name: str) -> bool:
    """Whether the vehicle file switches term ``name`` off explicitly (``enabled: false``); for the switches of
    :data:`BASE_SWITCHES`, whose default (no entry) is on."""
    term = terms.get(name)
    return term is not None and not term.on


def held_at_zero(terms: dict[str, EffectTerm]) -> tuple[str, ...]:
    """The base constants the vehicle's switched-off :data:`BASE_SWITCHES` hold at 0."""
    return tuple(key for name, keys in BASE_SWITCHES.items() if switched_off(terms, name) for key in keys)


def switched_on(terms: dict[str, EffectTerm], name: str) -> tuple[float, ...] | None:
    """The parameter values of term ``name`` when it is switched on, else None."""
    term = terms.get(name)
    return term.values() if term is not None and term.on else None
