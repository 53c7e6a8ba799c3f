"""The thesis's evaluation protocol (chapter 5, DESIGN 7) and the IDSIA multi-step mode.

Spans. Each flight loses its take-off and landing (``drop_start``, ``drop_end``
seconds; thesis: 30 s and 22 s); what remains is the *flying part*. Spans are
given as ``A:B``:

* plain numbers are seconds from the flight's first sample (thesis: training
  ``30:150``, evaluation ``150:190``), clipped to the flying part;
* numbers with ``%`` are fractions of the flying part (``0%:60%``), for short
  flights such as NanoBench's ~42 s ones (preset ``short``: drop 5 s / 5 s,
  training ``0%:60%``, evaluation ``60%:100%``).

Windows. Each span of each flight is cut into consecutive ``window_s`` windows
(thesis 10 s) that never cross a flight boundary; a remainder shorter than a
window is not used. Each window is predicted separately by each model
(:class:`~quad_modelling.core.models.Predictor`), given the first ``warm_s``
= 0.2 s of measurements; both measurement and prediction are trimmed
(:func:`~quad_modelling.core.preprocess.trimmed_variables`), smoothed
(:func:`~quad_modelling.core.preprocess.smooth`), and RMS/TIC are computed over
the rows after the warm start (:func:`evaluate_window`, also what a live
evaluator calls per closed window). Span scores are the mean over windows.

Multi-step mode (IDSIA nano-drone benchmark). From every start sample s of
a span segment with s + H inside it, each model predicts open loop
(:class:`~quad_modelling.core.models.MultiStepPredictor`); for the groups
position, velocity, orientation (geodesic angle) and angular velocity,
``MAE_h`` = mean over s of the error norm at s + h and ``SimErr`` = sum of
``MAE_h`` for h = 1..H, reported with the naive constant-state prediction and
the ratio model/naive.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.metrics import rms, sim_err, tic, vector_error_norm
from quad_modelling.core.models import ConstantStatePredictor, MultiStepPredictor, Predictor
from quad_modelling.core.preprocess import (
    SMOOTH_CUTOFF_HZ,
    TrimConfig,
    measured_variables,
    resample_uniform,
    smooth,
    trimmed_inputs,
    trimmed_variables,
)
from quad_modelling.core.variables import EVAL_VARIABLES, VARIABLES
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError, DataError

GROUPS: dict[str, slice] = {
    "position": slice(0, 3),
    "velocity": slice(3, 6),
    "orientation": slice(9, 12),
    "angular_velocity": slice(12, 15),
}
"""Multi-step groups and their VARIABLES columns (orientation: the Euler angles)."""

GROUP_UNITS = {"position": "m", "velocity": "m/s", "orientation": "rad", "angular_velocity": "rad/s"}

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


@dataclass
class WindowResult:
    """One model on one window: smoothed trimmed measurement and prediction, RMS and TIC per variable (SI)."""

    measured: np.ndarray
    predicted: np.ndarray
    rms: np.ndarray
    tic: np.ndarray
    warm_samples: int


def warm_samples_for(window: FlightLog, warm_s: float) -> int:
    """Number of warm-start rows (>= 1: the state at the anchor is always given)."""
    return int(np.clip(round(warm_s * window.sample_rate), 1, len(window) - 1))


def evaluate_window(
    predictor: Predictor,
    window: FlightLog,
    warm_samples: int,
    trim: TrimConfig | None = None,
    vehicle: VehicleConfig | None = None,
    smooth_cutoff_hz: float = SMOOTH_CUTOFF_HZ,
    measured: np.ndarray | None = None,
) -> WindowResult:
    """Score one model on one window (the unit the live evaluator also uses).

    ``measured``: the smoothed trimmed measurement if already computed (it is
    the same for every model).
    """
    trim = trim or TrimConfig()
    if measured is None:
        measured = smooth(trimmed_variables(window, trim, vehicle), window.sample_rate, smooth_cutoff_hz)
    predicted = np.asarray(predictor.predict_window(window, warm_samples), dtype=float)
    if predicted.shape != (len(window), len(VARIABLES)):
        raise DataError(f"model {predictor.name}: predicted shape {predicted.shape}, expected {(len(window), len(VARIABLES))}")
    if not np.all(np.isfinite(predicted)):
        raise DataError(f"model {predictor.name}: non-finite prediction on window starting t={window.t[0]:.2f} s of {window.meta.source}")
    predicted = smooth(predicted, window.sample_rate, smooth_cutoff_hz)
    scored = slice(warm_samples, None)
    return WindowResult(measured, predicted, rms(measured[scored], predicted[scored]), tic(measured[scored], predicted[scored]), warm_samples)


@dataclass
class SpanScores:
    """Mean over windows of RMS and TIC per variable (SI), with the window count."""

    rms: np.ndarray
    tic: np.ndarray
    windows: int

    def to_json(self, variables: Sequence[str] = EVAL_VARIABLES) -> dict:
        idx = {v: i for i, v in enumerate(VARIABLES)}
        return {v: {"rms": float(self.rms[idx[v]]), "tic": float(self.tic[idx[v]])} for v in variables}


@dataclass
class ExampleWindow:
    """Data for the thesis-style figures: one window, measured vs each model (trimmed, smoothed)."""

    source: str
    span: str
    t: np.ndarray
    inputs: np.ndarray
    measured: np.ndarray
    predicted: dict[str, np.ndarray]
    warm_samples: int


@dataclass
class EvaluationResult:
    scores: dict[str, dict[str, SpanScores]]
    horizons: dict
    config: EvaluationConfig
    flights: list[dict]
    examples: list[ExampleWindow]

    def to_json(self) -> dict:
        return {
            "models": {m: {s: sc.to_json() for s, sc in spans.items()} for m, spans in self.scores.items()},
            "windows": {m: {s: sc.windows for s, sc in spans.items()} for m, spans in self.scores.items()},
            "horizons": self.horizons,
            "config": {**self.config.to_dict(), "flights": self.flights, "units": "SI (m/s, m/s2, rad/s, rad/s2)"},
        }


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


def evaluate(
    flights: Sequence[FlightLog],
    models: Sequence[Predictor],
    vehicle: VehicleConfig,
    config: EvaluationConfig | None = None,
    multistep: bool = True,
    progress: Callable[[str], None] | None = None,
) -> EvaluationResult:
    """Run the protocol of the module docstring on several flights and models."""
    config = config or EvaluationConfig()
    flights = [resample_uniform(log) for log in flights]
    plan = plan_windows(flights, config)
    names = [m.name for m in models]
    if len(set(names)) != len(names):
        raise ConfigError(f"model names must be unique, got {names}")
    sums = {m.name: {s: [np.zeros(len(VARIABLES)), np.zeros(len(VARIABLES)), 0] for s in plan} for m in models}
    examples: list[ExampleWindow] = []
    for span_name, windows in plan.items():
        for k, w in enumerate(windows):
            window = flights[w.flight].slice(w.start, w.stop)
            warm = warm_samples_for(window, config.warm_s)
            measured = smooth(trimmed_variables(window, config.trim, vehicle), window.sample_rate, config.smooth_cutoff_hz)
            predicted = {}
            for model in models:
                result = evaluate_window(model, window, warm, config.trim, vehicle, config.smooth_cutoff_hz, measured)
                acc = sums[model.name][span_name]
                acc[0] += result.rms
                acc[1] += result.tic
                acc[2] += 1
                predicted[model.name] = result.predicted
            if k == 0:
                examples.append(
                    ExampleWindow(window.meta.source, span_name, window.t - window.t[0], trimmed_inputs(window, config.trim), measured, predicted, warm)
                )
        if progress:
            progress(f"{span_name}: {len(windows)} windows x {len(models)} models")
    scores = {
        name: {s: SpanScores(a[0] / max(a[2], 1), a[1] / max(a[2], 1), a[2]) for s, a in spans.items() if a[2] > 0}
        for name, spans in sums.items()
    }
    horizons = multistep_evaluation(flights, models, vehicle, config) if multistep else {}
    flight_info = [{"source": log.meta.source, "duration_s": log.duration, "sample_rate_hz": log.sample_rate} for log in flights]
    return EvaluationResult(scores, horizons, config, flight_info, examples)


def multistep_errors(predictor: MultiStepPredictor, segment: FlightLog, max_horizon: int, vehicle: VehicleConfig | None = None, chunk: int = 2048) -> tuple[np.ndarray, int]:
    """Sum over starts of each group's error norm at h = 1..H: ((4, H) sums, number of starts)."""
    measured = measured_variables(segment, vehicle)
    n_starts = len(segment) - max_horizon
    sums = np.zeros((len(GROUPS), max_horizon))
    if n_starts <= 0:
        return sums, 0
    steps = np.arange(1, max_horizon + 1)
    for first in range(0, n_starts, chunk):
        starts = np.arange(first, min(first + chunk, n_starts))
        predicted = np.asarray(predictor.predict_horizons(segment, starts, max_horizon))[:, 1:, :]
        truth = measured[starts[:, None] + steps[None, :]]
        for g, (group, cols) in enumerate(GROUPS.items()):
            if group == "orientation":
                err = frames.geodesic_angle(truth[..., cols].reshape(-1, 3), predicted[..., cols].reshape(-1, 3))
                err = err.reshape(len(starts), max_horizon)
            else:
                err = vector_error_norm(truth[..., cols], predicted[..., cols])
            sums[g] += err.sum(axis=0)
    return sums, n_starts


def multistep_evaluation(flights: Sequence[FlightLog], models: Sequence[Predictor], vehicle: VehicleConfig, config: EvaluationConfig) -> dict:
    """The IDSIA multi-step table: MAE at ``config.horizons``, SimErr, naive baseline and ratios (SI units)."""
    span = next(s for s in config.spans() if s.name == config.multistep_span)
    max_h = max(max(config.horizons), 50)
    naive = ConstantStatePredictor(vehicle, config.trim)
    candidates = [naive] + [m for m in models if isinstance(m, MultiStepPredictor) and m.name != naive.name]
    totals = {m.name: np.zeros((len(GROUPS), max_h)) for m in candidates}
    count = 0
    for log in flights:
        start, stop = span_segment(log, span, config)
        if stop - start <= max_h:
            continue
        segment = log.slice(start, stop)
        for m in candidates:
            sums, n = multistep_errors(m, segment, max_h, vehicle)
            totals[m.name] += sums
        count += n
    if count == 0:
        return {"span": span.name, "starts": 0, "note": f"no {span.name} segment longer than {max_h} samples"}
    out: dict = {"span": span.name, "starts": count, "horizons": list(config.horizons), "sim_err_horizon": max_h,
                 "units": GROUP_UNITS, "models": {}}
    mae = {name: t / count for name, t in totals.items()}
    for name, values in mae.items():
        entry = {}
        for g, group in enumerate(GROUPS):
            model_se = sim_err(values[g, :50])
            naive_se = sim_err(mae[naive.name][g, :50])
            entry[group] = {
                "mae": {str(h): float(values[g, h - 1]) for h in config.horizons},
                "sim_err": model_se,
                "naive_mae": {str(h): float(mae[naive.name][g, h - 1]) for h in config.horizons},
                "naive_sim_err": naive_se,
                "ratio_sim_err": model_se / naive_se if naive_se > 0 else None,
                "ratio_mae": {str(h): (float(values[g, h - 1] / mae[naive.name][g, h - 1]) if mae[naive.name][g, h - 1] > 0 else None) for h in config.horizons},
            }
        out["models"][name] = entry
    skipped = [m.name for m in models if m not in candidates and m.name != naive.name]
    if skipped:
        out["not_multistep"] = skipped
    return out
