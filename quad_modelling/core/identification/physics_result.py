"""The physics model's identified constants as one record (:class:`PhysicsFit`), what
:func:`~quad_modelling.core.identification.physics_fit.identify_physics` returns, and how the disturbance observer
of a fit is chosen: the :data:`OBSERVERS`, each scored by the fitted model's open-loop multi-step error on its own
training span (:func:`training_score`, :func:`prediction_errors`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from quad_modelling.core.evaluation.multistep import ratio_to_naive, start_errors
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.identification.constants_report import ConstantEstimate, constant_lines, fitted_vehicle
from quad_modelling.core.models.base import ConstantStatePredictor
from quad_modelling.core.models.physics import Observer, PhysicsPredictor
from quad_modelling.core.physics.effects import TERMS
from quad_modelling.core.physics.parameters import PHYSICS_UNITS, PhysicsParameters, term_fields
from quad_modelling.core.preprocess import resample_uniform
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import DataError

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
                                 self.start[key], bool(self.at_bound[key]), helps=self._helps(key),
                                 held=self.held.get(key) or ("" if self.identifiable.get(key, True)
                                                             else "not identifiable from these flights"))
                for key in FITTED] + [
            ConstantEstimate(f"{name}.{key}", q["value"], q["unit"], q["sigma"], tuple(q["bounds"]), float("nan"), q["at_bound"],
                             held=q.get("held") or ("" if q["identifiable"] else "not identifiable from these flights"))
            for name, params in self.terms.items() for key, q in params.items()]

    def _helps(self, key: str) -> str:
        """What would determine constant ``key`` better: for a rotor lag or command delay on its lower bound (2 ms, 0), that
        the flights show none (simulated without it, or too slow to tell), so the switch belongs off; else excitation."""
        switch = {"rotor_time_constant": "motor_lag", "rotor_delay": "input_delay"}.get(key)
        low, high = self.bounds[key]  # the lag's lower bound is 2 ms, flagged within 10 % in log of it (not 0 itself)
        if switch and self.at_bound[key] and self.values[key] - low < high - self.values[key]:
            lag, period = "rotor_time_constant", 1.0 / self.diagnostics.get("sample_rate_hz", 100.0)
            if (key == "rotor_delay" and not self.at_bound[lag] and not self.held.get(lag) and self.identifiable.get(lag, True)
                    and self.values[lag] < TWIN_LAG_SAMPLES * period):
                # a lag of about a sample and a delay answer alike at the log rate: a delay-only flight fits as a lag
                # (simulated Crazyflie, 8 ms delay: lag 8.5 ms, delay 0 on its bound; review of session 34)
                return (f"a lag and a delay look alike at this log rate: the rotor lag ({1000 * self.values[lag]:.1f} ms) "
                        "may hold a command delay; with no rotor lag in the vehicle, switch motor_lag off "
                        "(effects.motor_lag: {enabled: false}) and identify again to find it")
            return f"none in the flights? switch {switch} off in the vehicle file (effects.{switch}: {{enabled: false}})"
        return ConstantEstimate.helps

    def summary(self) -> list[str]:
        """The printed block (lines <= 100 characters)."""
        d = self.diagnostics
        lines = constant_lines(self.estimates(), f"physics model constants ({d.get('anchors', 0)} anchors, "
                                                 f"{d.get('seconds', 0):.1f} s):")
        ratios = ", ".join(f"{c} {r:.2g}" for c, r in d.get("error_ratio", {}).items())  # 0.0041, not 0.00
        choice = d.get("observer_choice")
        observer = [] if choice is None else [
            f"  disturbance observer: {choice['chosen']} (error "
            + ", ".join(f"{name} {e:.3g}" for name, e in choice["errors"].items()) + ")"]
        return [lines[0], f"  multi-step error / the observer alone's: {ratios}", *observer, *lines[1:]]


TWIN_LAG_SAMPLES = 2.0
"""A rotor lag under this many sample periods beside a delay on its lower bound (0) may be a command delay: at the log
rate the two answer alike (simulated Crazyflie, 8 ms delay, no lag: lag 8.5 ms and delay 0; a real 50-105 ms lag
beside a delay of 0 is a lag). identify then says so instead of advising input_delay off."""


CHOICE_STRIDE = 10
"""Every 10th start (0.1 s at 100 Hz) of the training flights scores an observer (:func:`training_score`): the
horizon is 50 starts long, so neighbouring starts share most of their errors."""


def training_score(fit: PhysicsFit, flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig) -> float:
    """The fitted model's multi-step error on its own training span, the protocol's (open loop, SimErr over h = 1..50,
    :func:`~quad_modelling.core.evaluation.multistep.start_errors`, every :data:`CHOICE_STRIDE`-th start): the mean of
    velocity and angular velocity relative to naive, on the starts whose horizon does not touch the ground (as the
    fit's anchors); inf when no segment is long enough."""
    fitted = fitted_vehicle(vehicle, fit, "observer choice")
    models = [PhysicsPredictor(fitted, observer=fit.observer, trim=config.trim), ConstantStatePredictor(fitted, config.trim)]
    try:
        (errors, naive), _ = start_errors([resample_uniform(f) for f in flights], models, fitted,
                                          replace(config, multistep_span="train"), stride=CHOICE_STRIDE, airborne=True)
    except DataError:
        return float("inf")
    return ratio_to_naive(errors, naive)


def prediction_errors(fit: PhysicsFit, flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig,
                      known: dict[str, float] | None = None) -> dict[str, float]:
    """The :func:`training_score` of ``fit``'s constants predicting with each observer of :data:`OBSERVERS` (``known``:
    scores already computed, by observer name); the least is the observer the model predicts with."""
    known = known or {}
    return {name: known[name] if name in known else training_score(replace(fit, observer=o), flights, vehicle, config)
            for name, o in OBSERVERS.items()}


OBSERVERS = {"default": Observer(), "measured": Observer(angular_trim=False), "linear only": Observer(angular_s=0.0),
             "none": Observer(0.0, 0.0)}
"""The disturbance observers ``identify`` chooses among (:func:`~quad_modelling.core.identification.physics_fit.identify_physics`): the physics model's default
(0.5 s each, the angular part a trim), the angular part as measured minus modelled (``measured``), the linear part alone, and
none (a model that lacks no force or moment: held-out velocity SimErr ratio 0.51 against 0.62 with the linear
part on an effect-free simulated LinkQuad flight, seed 4711)."""

FIT_OBSERVERS = ("default", "measured", "linear only", "none")
"""The observers the constants are fitted with; the model may then predict with any of :data:`OBSERVERS` ("none"
since 2026-11-26, when gravity joined the velocity channel's known part: docs/models.md)."""
