"""Spans and windows: the one span grammar and the window cutter shared by every evaluation."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.preprocess import (
    SMOOTH_CUTOFF_HZ,
    TrimConfig,
)
from quad_modelling.errors import ConfigError, DataError

_BOUND = re.compile(r"^\s*(-?\d+(?:\.\d*)?|-?\.\d+)\s*(%?)\s*$")


@dataclass(frozen=True)
class SpanSpec:
    """One span ``A:B``: seconds from the flight start, or percent (``%``) of the flying part."""

    name: str
    start: float
    end: float
    relative: bool

    @classmethod
    def parse(cls, name: str, text: str) -> SpanSpec:
        parts = text.split(":")
        if len(parts) != 2:
            raise ConfigError(f"span {name} {text!r}: expected START:END, e.g. 30:150 or 0%:60%")
        bounds = [_BOUND.match(p) for p in parts]
        if not all(bounds):
            raise ConfigError(f"span {name} {text!r}: bounds must be numbers of seconds or percentages")
        percent = [b.group(2) == "%" for b in bounds]
        if percent[0] != percent[1]:
            raise ConfigError(f"span {name} {text!r}: give both bounds in seconds or both in percent")
        start, end = (float(b.group(1)) for b in bounds)
        if percent[0]:
            start, end = start / 100.0, end / 100.0
            if not 0.0 <= start < end <= 1.0:
                raise ConfigError(f"span {name} {text!r}: percentages must satisfy 0 <= START < END <= 100")
        elif not 0.0 <= start < end:
            raise ConfigError(f"span {name} {text!r}: need 0 <= START < END seconds")
        return cls(name, start, end, percent[0])

    def text(self) -> str:
        if self.relative:
            return f"{self.start * 100:g}%:{self.end * 100:g}%"
        return f"{self.start:g}:{self.end:g}"

    def interval(self, log: FlightLog, drop_start: float, drop_end: float) -> tuple[float, float]:
        """Span [a, b) in seconds from the flight start, inside the flying part (may be empty: a >= b)."""
        fly_start, fly_end = drop_start, log.duration - drop_end
        if self.relative:
            length = max(fly_end - fly_start, 0.0)
            return fly_start + self.start * length, fly_start + self.end * length
        return max(self.start, fly_start), min(self.end, fly_end)


PRESETS: dict[str, dict] = {
    "thesis": {"drop": (30.0, 22.0), "train": "30:150", "eval": "150:190"},
    "short": {"drop": (5.0, 5.0), "train": "0%:60%", "eval": "60%:100%"},
}
"""Span presets: the thesis's (220 s flights) and one for short flights (NanoBench, ~40 s)."""


@dataclass(frozen=True)
class EvaluationConfig:
    """Everything that defines an evaluation; defaults are the thesis's values."""

    drop_start: float = 30.0
    drop_end: float = 22.0
    train: str = "30:150"
    eval: str = "150:190"
    window_s: float = 10.0
    warm_s: float = 0.2
    trim: TrimConfig = field(default_factory=TrimConfig)
    smooth_cutoff_hz: float = SMOOTH_CUTOFF_HZ
    horizons: tuple[int, ...] = (1, 10, 50)
    multistep_span: str = "eval"

    @classmethod
    def preset(cls, name: str, **overrides) -> EvaluationConfig:
        if name not in PRESETS:
            raise ConfigError(f"unknown span preset {name!r}; known: {', '.join(PRESETS)}")
        p = PRESETS[name]
        values = {"drop_start": p["drop"][0], "drop_end": p["drop"][1], "train": p["train"], "eval": p["eval"]}
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def spans(self) -> list[SpanSpec]:
        return [SpanSpec.parse("train", self.train), SpanSpec.parse("eval", self.eval)]

    def validate(self) -> None:
        if self.window_s <= 0 or self.warm_s < 0 or self.warm_s >= self.window_s:
            raise ConfigError(f"need window_s > warm_s >= 0, got window {self.window_s} s, warm {self.warm_s} s")
        if self.drop_start < 0 or self.drop_end < 0:
            raise ConfigError("take-off/landing drops must be >= 0 s")
        if not self.horizons or min(self.horizons) < 1:
            raise ConfigError(f"horizons must be positive step counts, got {self.horizons}")
        self.spans()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["horizons"] = list(self.horizons)
        return d


@dataclass(frozen=True)
class Window:
    """Rows [start, stop) of flight ``flight`` (index into the flights list), in span ``span``."""

    flight: int
    span: str
    start: int
    stop: int


def span_windows(log: FlightLog, span: SpanSpec, config: EvaluationConfig, flight: int = 0) -> list[Window]:
    """Consecutive full windows of ``config.window_s`` inside ``span`` of one flight."""
    a, b = span.interval(log, config.drop_start, config.drop_end)
    rate = log.sample_rate
    length = int(round(config.window_s * rate))
    t = log.t - log.t[0]
    first = int(np.searchsorted(t, a - 0.5 / rate))
    last = int(np.searchsorted(t, b - 0.5 / rate))  # exclusive
    return [Window(flight, span.name, s, s + length) for s in range(first, last - length + 1, length)]


def span_segment(log: FlightLog, span: SpanSpec, config: EvaluationConfig) -> tuple[int, int]:
    """Rows [start, stop) of a span in one flight (contiguous; empty when start >= stop)."""
    a, b = span.interval(log, config.drop_start, config.drop_end)
    rate = log.sample_rate
    t = log.t - log.t[0]
    return int(np.searchsorted(t, a - 0.5 / rate)), int(np.searchsorted(t, b - 0.5 / rate))


def warm_samples_for(window: FlightLog, warm_s: float) -> int:
    """Number of warm-start rows (>= 1: the state at the anchor is always given)."""
    return int(np.clip(round(warm_s * window.sample_rate), 1, len(window) - 1))


def plan_windows(flights: Sequence[FlightLog], config: EvaluationConfig) -> dict[str, list[Window]]:
    """Windows per span over all flights; DataError when no span holds a single window."""
    config.validate()
    plan: dict[str, list[Window]] = {}
    for span in config.spans():
        plan[span.name] = [w for i, log in enumerate(flights) for w in span_windows(log, span, config, i)]
    if not any(plan.values()):
        durations = ", ".join(f"{log.duration:.1f}" for log in flights)
        raise DataError(
            f"no {config.window_s:g} s window fits the spans train {config.train}, eval {config.eval} after dropping "
            f"{config.drop_start:g} s/{config.drop_end:g} s (flight durations {durations} s); for short flights use "
            f"--preset short or relative spans such as --drop 5:5 --train 0%:60% --eval 60%:100%"
        )
    return plan
