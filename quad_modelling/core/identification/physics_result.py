"""The physics model's identified constants as one record (:class:`PhysicsFit`), what
:func:`~quad_modelling.core.identification.physics_fit.identify_physics` returns."""

from __future__ import annotations

from dataclasses import dataclass, field

from quad_modelling.core.identification.constants_report import ConstantEstimate, constant_lines
from quad_modelling.core.models.physics import Observer
from quad_modelling.core.physics.effects import TERMS
from quad_modelling.core.physics.parameters import PHYSICS_UNITS, PhysicsParameters, term_fields

FITTED = ("rotor_time_constant", "rotor_delay", "rotor_thrust_constant", "rotor_torque_constant", "rotor_drag_xy",
          "rotor_drag_z", "rotor_drag_arm", "effective_ixx", "effective_iyy")
"""The physics constants ``identify`` fits (the speed map k_u, Ω_off and I_zz are held)."""


@dataclass
class PhysicsFit:
    """Identified physics constants: value, 1-sigma, unit, bounds, at-bound flag per key; fit diagnostics."""

    values: dict[str, float]
    sigma: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    at_bound: dict[str, bool]
    start: dict[str, float]
    diagnostics: dict = field(default_factory=dict)
    identifiable: dict[str, bool] = field(default_factory=dict)
    terms: dict[str, dict] = field(default_factory=dict)
    """The fitted optional terms (:func:`~quad_modelling.core.identification.physics_terms.term_estimates`)."""
    observer: Observer = field(default_factory=Observer)
    """The disturbance observer the model predicts with (:func:`identify_physics` chooses it; the one the constants
    were fitted with is ``diagnostics["observer_choice"]["fitted_with"]``)."""
    held: dict[str, str] = field(default_factory=dict)
    """Constants held at 0 by a switched-off term (:data:`~quad_modelling.core.physics.effects.BASE_SWITCHES`), and why."""
    switches: dict[str, bool] = field(default_factory=dict)
    """The state of each :data:`~quad_modelling.core.physics.effects.BASE_SWITCHES` term the vehicle file has or the
    fit was asked for: its ``effects`` entry in the identified vehicle."""

    def parameters(self, base: PhysicsParameters) -> PhysicsParameters:
        """``base`` with the identified values (and the fitted terms switched on where identified)."""
        v = self.values
        terms = {}
        for name, params in self.terms.items():
            if all(q["identifiable"] for q in params.values()):
                terms.update(term_fields(name, tuple(params[p.name]["value"] for p in TERMS[name])))
        return base.with_values(**terms,
            time_constant=v["rotor_time_constant"], delay=v["rotor_delay"], thrust_constant=v["rotor_thrust_constant"],
            torque_constant=v["rotor_torque_constant"], drag=(v["rotor_drag_xy"], v["rotor_drag_xy"], v["rotor_drag_z"]),
            drag_arm=v["rotor_drag_arm"], inertia=(v["effective_ixx"], v["effective_iyy"], base.inertia[2]))

    def to_dict(self) -> dict:
        return {key: {"value": self.values[key], "sigma": self.sigma[key], "unit": PHYSICS_UNITS[key],
                      "bounds": [float(b) for b in self.bounds[key]], "at_bound": self.at_bound[key], "start": self.start[key],
                      "identifiable": self.identifiable.get(key, True), "held": self.held.get(key, "")}
                for key in FITTED} | {"diagnostics": self.diagnostics, "terms": self.terms}

    def estimates(self) -> list[ConstantEstimate]:
        """The fitted constants as the one constant record every fit reports
        (:class:`~quad_modelling.core.identification.constants_report.ConstantEstimate`)."""
        return [ConstantEstimate(key, self.values[key], PHYSICS_UNITS[key], self.sigma[key], tuple(self.bounds[key]),
                                 self.start[key], bool(self.at_bound[key]),
                                 held=self.held.get(key) or ("" if self.identifiable.get(key, True)
                                                             else "not identifiable from these flights"))
                for key in FITTED] + [
            ConstantEstimate(f"{name}.{key}", q["value"], q["unit"], q["sigma"], tuple(q["bounds"]), float("nan"), q["at_bound"],
                             held=q.get("held") or ("" if q["identifiable"] else "not identifiable from these flights"))
            for name, params in self.terms.items() for key, q in params.items()]

    def summary(self) -> list[str]:
        """The printed block (lines <= 100 characters)."""
        d = self.diagnostics
        lines = constant_lines(self.estimates(), f"physics model constants ({d.get('anchors', 0)} anchors, "
                                                 f"{d.get('seconds', 0):.1f} s):")
        ratios = ", ".join(f"{c} {r:.2f}" for c, r in d.get("error_ratio", {}).items())
        choice = d.get("observer_choice")
        observer = [] if choice is None else [
            f"  disturbance observer: {choice['chosen']} (error "
            + ", ".join(f"{name} {e:.3g}" for name, e in choice["errors"].items()) + ")"]
        return [lines[0], f"  multi-step error / the observer alone's: {ratios}", *observer, *lines[1:]]
