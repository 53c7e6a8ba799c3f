"""Identified constants as a user reads them: value, unit, 1-sigma, search bounds, whether the fit ended
on a bound, and the change from the vehicle file -- one record per constant (:class:`ConstantEstimate`),
for every fit (the linear greybox's, the physics model's), printed and written the same way.

A constant is *poorly determined* when its 1-sigma exceeds :data:`POOR_RELATIVE_SIGMA` of its value,
its sigma is unknown, or the fit ended on a search bound (the optimum is the bound, not the data's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

POOR_RELATIVE_SIGMA = 0.5
"""sigma / |value| above which a constant is reported as poorly determined (the task's 50 %)."""

AT_BOUND_RTOL = 1e-3
"""Relative distance to a bound below which a fitted value counts as on the bound."""

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
    def poorly_determined(self) -> bool:
        return (bool(self.held) or self.at_bound or not math.isfinite(self.sigma) or not math.isfinite(self.value)
                or self.sigma > POOR_RELATIVE_SIGMA * abs(self.value))

    def reason(self) -> str:
        """Why it is poorly determined ('' when it is not)."""
        if self.held:
            return f"held at {self.value:.3g} ({self.held})"
        if not math.isfinite(self.value):
            return "not identifiable from these flights"
        if self.at_bound:
            return f"ended on its search bound [{self.bounds[0]:.3g}, {self.bounds[1]:.3g}]" if self.bounds else "ended on a bound"
        if not math.isfinite(self.sigma):
            return "no uncertainty (the fit cannot separate it)"
        if self.sigma > POOR_RELATIVE_SIGMA * abs(self.value):
            if self.value == 0:
                return f"sigma {self.sigma:.2g} {self.unit} about a value of 0"
            return f"sigma {100.0 * self.sigma / abs(self.value):.0f} % of the value"
        return ""

    def lines(self, indent: str = "  ") -> list[str]:
        """'name value unit (sigma s), vehicle v: +c %' then bounds and flag, wrapped at 100 characters."""
        head = f"{indent}{self.name} {self.value:.3g} {self.unit} " + (f"(held: {self.held})" if self.held else f"(sigma {self.sigma:.2g})")
        change = self.change_percent
        if self.vehicle is not None:
            head += f", vehicle {self.vehicle:.3g}" + (f": {change:+.0f} %" if change is not None else "")
        tail = ""
        if self.bounds is not None:
            tail = f"bounds [{self.bounds[0]:.3g}, {self.bounds[1]:.3g}]"
        if self.at_bound:
            tail += " AT BOUND"
        tail = tail.strip()
        if not tail:
            return [head]
        if len(head) + 2 + len(tail) <= LINE_WIDTH:
            return [f"{head}, {tail}"]
        return [head, f"{indent}    {tail}"]

    def as_dict(self) -> dict:
        """Plain-YAML form (floats, lists, bools)."""
        change = self.change_percent
        return {"value": float(self.value), "unit": self.unit, "sigma": float(self.sigma),
                "bounds": None if self.bounds is None else [float(b) for b in self.bounds],
                "at_bound": bool(self.at_bound), "vehicle_value": None if self.vehicle is None else float(self.vehicle),
                "change_percent": None if change is None else round(float(change), 1),
                "poorly_determined": self.reason() or None, "held": self.held or None}


def at_bound(value: float, bounds: tuple[float, float]) -> bool:
    """Whether ``value`` is within :data:`AT_BOUND_RTOL` of either bound (relative to the bound, or to the
    range for a zero bound)."""
    span = abs(bounds[1] - bounds[0])
    return any(abs(value - b) <= AT_BOUND_RTOL * (abs(b) if b != 0 else span) for b in bounds)


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
                                                             f"    would help: {e.helps}"]
    return lines
