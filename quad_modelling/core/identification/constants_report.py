"""Identified constants as a user reads them: value, unit, 1-sigma, search bounds, whether the fit ended
on a bound, and the change from the vehicle file -- one record per constant (:class:`ConstantEstimate`),
for every fit (the linear greybox's, the physics model's), printed and written the same way.

A constant is *poorly determined* by the one fitting engine's rule
(:func:`~quad_modelling.core.identification.least_squares.poorly_determined`): held, not finite, ended on a
search bound (the optimum is the bound, not the data's), sigma unknown, or sigma above half its value or half
its search range.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, replace

import numpy as np

from quad_modelling.core.identification.least_squares import poorly_determined
from quad_modelling.core.identification.physics_terms import effects_section
from quad_modelling.core.physics.effects import effects_document, parse_effects
from quad_modelling.core.vehicle import AIRFRAME_OF, VehicleConfig, effective_source

LINE_WIDTH = 100


@dataclass(frozen=True)
class ConstantEstimate:
    """One identified constant. ``bounds`` = (low, high) of its search range in its own unit (None: not
    searched directly); ``vehicle`` = the vehicle file's value (None: not in the file); ``helps`` = what
    would determine it better."""

    name: str
    value: float
    unit: str
    sigma: float
    bounds: tuple[float, float] | None = None
    vehicle: float | None = None
    at_bound: bool = False
    helps: str = "more excitation of the variables it drives"
    held: str = ""  # why the fit held it at its starting value ('' = fitted)

    @property
    def change_percent(self) -> float | None:
        """100 (value - vehicle) / |vehicle| [%], None without a (non-zero) vehicle value."""
        if self.vehicle is None or self.vehicle == 0 or not math.isfinite(self.vehicle):
            return None
        return 100.0 * (self.value - self.vehicle) / abs(self.vehicle)

    @property
    def delay_at_zero(self) -> bool:
        """A command delay on its lower bound 0: flagged AT BOUND, but what flights whose commands act at their stamps
        give -- a value measured, not a search run out (the diagnosis' fold stability and observer refits count it)."""
        return self.name.split(".")[-1] == "rotor_delay" and self.bounds is not None and self.value <= self.bounds[0]

    @property
    def poorly_determined(self) -> bool:
        return bool(self.reason())

    def reason(self) -> str:
        """Why it is poorly determined ('' when it is not; the engine's rule)."""
        return poorly_determined(self.value, self.sigma, self.unit, self.bounds, self.at_bound, self.held)

    def lines(self, indent: str = "  ") -> list[str]:
        """'name value unit (sigma s), vehicle v: +c %, bounds [a, b] AT BOUND', each part after the first moved to a
        continuation line where the line would pass 100 characters."""
        unit = "" if self.unit == "1" else f" {self.unit}"  # a ratio: "gain_3 1.0048 (sigma ...)", not "gain_3 1 1"
        held = self.held if self.held.startswith("held") else f"held: {self.held}"  # "held at 0: ..." said once
        parts = [f"{self.name} {value_text(self.value, self.sigma)}{unit} " + (f"({held})" if self.held else f"(sigma {self.sigma:.2g})")]
        change = self.change_percent
        if self.vehicle is not None and not math.isfinite(self.vehicle):
            parts.append("new (not in the vehicle file)")  # an effect term the file did not have
        elif self.vehicle is not None:
            parts.append(f"vehicle {self.vehicle:.3g}" + (f": {change:+.0f} %" if change is not None else ""))
        tail = (f"bounds [{self.bounds[0]:.3g}, {self.bounds[1]:.3g}]" if self.bounds is not None else "") \
            + (" AT BOUND" if self.at_bound else "")
        if tail.strip():
            parts.append(tail.strip())
        lines = [f"{indent}{parts[0]}"]
        if len(lines[0]) > LINE_WIDTH:  # a long held reason: wrapped onto continuation lines
            lines = textwrap.wrap(lines[0], LINE_WIDTH, initial_indent="", subsequent_indent=f"{indent}    ", drop_whitespace=True)
            lines[0] = f"{indent}{lines[0].lstrip()}" if not lines[0].startswith(indent) else lines[0]
        for part in parts[1:]:
            if len(lines[-1]) + 2 + len(part) <= LINE_WIDTH:
                lines[-1] += f", {part}"
            else:
                lines.append(f"{indent}    {part}")
        return lines

    def as_dict(self) -> dict:
        """Plain-YAML form (floats, lists, bools)."""
        change = self.change_percent
        return {"value": float(self.value), "unit": self.unit, "sigma": float(self.sigma),
                "bounds": None if self.bounds is None else [float(b) for b in self.bounds],
                "at_bound": bool(self.at_bound), "vehicle_value": None if self.vehicle is None else float(self.vehicle),
                "change_percent": None if change is None else round(float(change), 1),
                "poorly_determined": self.reason() or None, "held": self.held or None}


def value_text(value: float, sigma: float) -> str:
    """``value`` with 3 significant digits, more when its 1-sigma ``sigma`` is finer (a gain 1.0048 +- 7e-5 printed
    "1" before): digits to the place of sigma's first digit, at most 8."""
    digits = 3
    if math.isfinite(value) and value != 0 and math.isfinite(sigma) and sigma > 0:
        digits = min(8, max(3, math.ceil(math.log10(abs(value) / sigma)) + 1))
    return f"{value:.{digits}g}"


def constant_lines(estimates: list[ConstantEstimate], title: str) -> list[str]:
    """The printed block: a title, one entry per constant, then one line per poorly determined constant."""
    lines = [title]
    for e in estimates:
        lines += e.lines()
    for e in estimates:
        if e.poorly_determined:
            if e.held:
                continue  # its line already says why
            text = f"  poorly determined: {e.name}: {e.reason()}; would help: {e.helps}"
            lines += [text] if len(text) <= LINE_WIDTH else [f"  poorly determined: {e.name}: {e.reason()};",
                                                             *textwrap.wrap(f"would help: {e.helps}", LINE_WIDTH, initial_indent="    ",
                                                                            subsequent_indent="      ")]
    return lines


def estimate_source(estimate: ConstantEstimate, source: str) -> str:
    """The source text of an identified constant: where, its 1-sigma, its change from the vehicle file."""
    text = f"{source}, sigma {estimate.sigma:.2g} {estimate.unit}"
    if estimate.change_percent is not None:
        text += f"; vehicle file {estimate.vehicle:.3g} ({estimate.change_percent:+.0f} %)"
    if estimate.poorly_determined:
        text += f"; poorly determined: {estimate.reason()}"
    return text


def add_physics_constants(document: dict, fit, note: str, source: str) -> None:
    """Write the identified physics constants (value, 1-sigma, bounds, at-bound flag, the vehicle file's value and the
    change from it, why poorly determined, source) into a vehicle ``document``'s
    ``constants`` and the fit's details into ``identification.physics``; without a fit only the note."""
    identification = document.setdefault("identification", {})
    if fit is None:
        identification["physics"] = {"note": note}
        return
    for estimate in fit.estimates():
        if "." in estimate.name:
            continue  # a term's parameter: the effects section below
        entry = document["constants"].setdefault(estimate.name, {"value": estimate.value, "unit": estimate.unit, "source": "the airframe's", "status": "effective"})
        if estimate.held:
            entry.update(source=f"{entry['source']}; kept: {estimate.held}", held=estimate.held)
            continue
        entry.update({k: v for k, v in estimate.as_dict().items() if k != "unit"})  # bounds, change... as the greybox's
        entry["source"] = estimate_source(estimate, source)
        if estimate.name in AIRFRAME_OF:
            entry["source"] = effective_source(entry["source"], estimate.value, document["constants"][AIRFRAME_OF[estimate.name]]["value"], AIRFRAME_OF[estimate.name])
        if estimate.at_bound:
            entry["source"] = f"{entry['source']}; AT BOUND {list(estimate.bounds)} {estimate.unit}"
    identification.setdefault("constants", {}).update({e.name: e.as_dict() for e in fit.estimates()})
    identification["physics"] = _plain(fit.to_dict())
    if fit.terms:
        document.setdefault("effects", {}).update(_plain(effects_section(fit.terms, source)))
    document.setdefault("effects", {}).update({name: {"enabled": on} for name, on in fit.switches.items()})
    choice = fit.diagnostics.get("observer_choice")
    why = (f"chosen by the data: {choice['chosen']} (multi-step error "
           + ", ".join(f"{name} {e:.3g}" for name, e in choice["errors"].items()) + ")") if choice else "as fitted"
    document.setdefault("effects", {})["disturbance_observer"] = observer_entry(fit.observer, f"{source}; {why}")


def _plain(value):
    """``value`` with numpy scalars and tuples made YAML-plain (floats, lists)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def fitted_vehicle(vehicle: VehicleConfig, fit, source: str) -> VehicleConfig:
    """``vehicle`` with the fit's constants, its fitted terms and its disturbance observer (in memory)."""
    fitted = vehicle.with_values({k: v for k, v in fit.values.items() if np.isfinite(v)}, source)
    section = effects_document(vehicle.effects)
    section.update(effects_section(fit.terms, source))
    section.update({name: {"enabled": on} for name, on in fit.switches.items()})
    section["disturbance_observer"] = observer_entry(fit.observer, source)
    return replace(fitted, effects=parse_effects(section, f"{vehicle.path} ({source})"))


def observer_entry(observer, source: str) -> dict:
    """The vehicle file's ``disturbance_observer`` entry of an :class:`~quad_modelling.core.models.physics.Observer`."""
    o = observer
    values = {"linear_history": (o.linear_s, "s"), "angular_history": (o.angular_s, "s"), "angular_trim": (float(o.angular_trim), "1")}
    return {"enabled": o.linear_s > 0 or o.angular_s > 0, **{
        key: {"value": float(value), "unit": unit, "bounds": [0.0, 10.0 if unit == "s" else 1.0], "status": "identified",
              "source": source} for key, (value, unit) in values.items()}}


def motor_command_gains(fit) -> dict:
    """``summary.motor_command_gains`` of ``diagnose``: the factor on each motor's logged command the model needs
    (mean 1), from a fit with the motor-imbalance term (gains 1, sigma NaN without one, or for ``fit`` None)."""
    if fit is None or "motor_imbalance" not in fit.terms:
        return {"value": [1.0] * 4, "sigma": [float("nan")] * 4, "fitted": False}
    terms = fit.terms["motor_imbalance"]
    return {"value": [terms[f"gain_{i}"]["value"] for i in range(1, 5)],
            "sigma": [terms[f"gain_{i}"]["sigma"] for i in range(1, 5)], "fitted": True}
