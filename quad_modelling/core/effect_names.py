"""The one list of effect names (DESIGN 6.2), shared by the truth simulator and the gap diagnosis.

The diagnosis catalogue (:data:`quad_modelling.core.diagnosis.catalogue.CATALOGUE`) holds one
identifiable model form per name of :data:`CATALOGUE_EFFECTS`; the truth simulator
(:mod:`quad_modelling.core.sim.dynamics`) holds one switch per name of :data:`SIM_EFFECTS`.
The two sets differ explicitly, never by a second list:

* :data:`IDENTIFIABLE_ONLY` -- catalogue entries with no simulator switch: the simulator's thrust is
  always :math:`T = a\\Omega^2` (thrust nonlinearity), and its trim drift comes with the battery drain;
* :data:`DISTURBANCES` -- simulator switches outside the catalogue, which a diagnosis must report as
  unexplained, not as a catalogue effect (DESIGN 8): ``wind`` (moving air, airframe drag), ``com_offset``
  (the centre of mass a distance *below* the IMU, a battery hung under the frame: lever-arm terms in the
  accelerometer, a longer rotor-drag moment arm; the catalogue's motor_imbalance offset is horizontal) and
  ``bent_arm`` (motor 1 tilted about its arm: a yaw torque and a body-fixed horizontal force that scale
  with its thrust; no catalogue form has either). Physics: :mod:`quad_modelling.core.sim.dynamics`.

:data:`SWITCHED_EFFECTS` (the catalogue effects the simulator can switch on) is what the known-answer
validation withholds. :func:`parse_effect_names` is the one grammar of an ``--effects`` option
(``quad-modelling simulate`` with :data:`SIMULATOR`, ``quad-modelling diagnose`` with :data:`DIAGNOSIS`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from quad_modelling.errors import ConfigError

CATALOGUE_EFFECTS: tuple[str, ...] = (
    "rotor_drag",
    "battery",
    "motor_lag",
    "input_delay",
    "ground_effect",
    "gyroscopic",
    "thrust_nonlinearity",
    "motor_imbalance",
    "trim_drift",
)
"""The effect catalogue's names, in catalogue order (the order every parsed list comes back in)."""

IDENTIFIABLE_ONLY: tuple[str, ...] = ("thrust_nonlinearity", "trim_drift")
"""Catalogue effects the simulator has no switch for (module docstring)."""

DISTURBANCES: tuple[str, ...] = ("wind", "com_offset", "bent_arm")
"""Simulator switches that are no catalogue effect (module docstring)."""

SWITCHED_EFFECTS: tuple[str, ...] = tuple(name for name in CATALOGUE_EFFECTS if name not in IDENTIFIABLE_ONLY)
"""Catalogue effects the simulator switches on: the known answers of the diagnosis validation."""

SIGNATURES: dict[str, tuple[str, ...]] = {"battery": ("battery", "trim_drift")}
"""Catalogue effects a simulator switch shows as besides its own name (the others show as themselves): the
simulated battery drains during the flight and the stabiliser raises its commands to hold the height, so within a
window the commands drift against the thrust they give -- the catalogue's trim drift, "input trim drift within a
window (e.g. battery drain)". The validation reports a run right by the strict rule (its own name first) and,
separately, by these signatures."""

SIM_EFFECTS: tuple[str, ...] = SWITCHED_EFFECTS + DISTURBANCES
"""Every switch of the truth simulator, in order: the switched catalogue effects, then the disturbances."""

SIM_DEFAULT_EFFECTS: tuple[str, ...] = SWITCHED_EFFECTS
"""The simulator's default: a realistic indoor (motion-capture lab) flight of an undamaged airframe, every
effect but the disturbances."""


@dataclass(frozen=True)
class EffectChoice:
    """What an ``--effects`` option may name: ``known`` names (in order), the ``default`` set, and the
    ``kind`` of name an error message speaks of."""

    kind: str
    known: tuple[str, ...]
    default: tuple[str, ...]
    hint: str = ""


SIMULATOR = EffectChoice("simulator effect", SIM_EFFECTS, SIM_DEFAULT_EFFECTS)
"""Effects ``quad-modelling simulate`` (and the simulator) accept; default every effect but the disturbances."""

DIAGNOSIS = EffectChoice("catalogue effect", CATALOGUE_EFFECTS, CATALOGUE_EFFECTS,
                         hint=f"{', '.join(DISTURBANCES)}: simulator disturbances, not catalogue effects")
"""Effects ``quad-modelling diagnose`` can assess; default the whole catalogue."""


def normalise_effect_names(names: Iterable[str], choice: EffectChoice) -> tuple[str, ...]:
    """Validate effect names against ``choice``; return them once each, in ``choice.known`` order.

    ConfigError naming every unknown name and the known ones.
    """
    names = [str(name).strip() for name in names]
    unknown = [name for name in dict.fromkeys(names) if name not in choice.known]
    if unknown:
        hint = f"; {choice.hint}" if choice.hint and set(unknown) & set(DISTURBANCES) else ""
        raise ConfigError(f"unknown {choice.kind} {', '.join(map(repr, unknown))}; known: {', '.join(choice.known)} "
                          f"(or none, all, default){hint}")
    return tuple(name for name in choice.known if name in names)


def parse_effect_names(text: str | None, choice: EffectChoice) -> tuple[str, ...]:
    """The ``--effects`` grammar: ``none`` -> (); ``all`` -> ``choice.known``; ``default`` or None ->
    ``choice.default``; else a comma list of names, each once (:func:`normalise_effect_names`). An empty text is
    refused (ConfigError): ``--effects ""`` reads as "no effects" to some and "the default" to others."""
    text = "default" if text is None else text.strip()
    if not text:
        raise ConfigError("--effects '': give none, all, default or a comma list of names")
    if text == "default":
        return choice.default
    if text == "none":
        return ()
    if text == "all":
        return choice.known
    names = [part.strip() for part in text.split(",")]
    if not all(names):
        raise ConfigError(f"--effects {text}: an empty name in the list (a comma too many?); name each effect once")
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise ConfigError(f"--effects {text}: {', '.join(twice)} named more than once; name each once")
    return normalise_effect_names(names, choice)
