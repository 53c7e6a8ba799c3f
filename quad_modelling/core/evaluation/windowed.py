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
evaluator calls per closed window). Span scores are the mean over windows
(:func:`window_mean`, also the live evaluator's and the diagnosis's).

Flights. An evaluation of several flights is :func:`evaluate_flight` per flight (its
sufficient statistics: window counts and sums of the per-window scores, multi-step sums;
:mod:`~quad_modelling.core.evaluation.statistics`) and :func:`merge_flights` over them in flight
order: the serial run, a fan-out over Dask workers and ``quad-modelling merge`` of results.json
files give the same numbers, bit for bit.

Multi-step mode (IDSIA nano-drone benchmark). From every start sample s of
a span segment with s + H inside it, each model predicts open loop
(:class:`~quad_modelling.core.models.MultiStepPredictor`); for the groups
position, velocity, orientation (geodesic angle) and angular velocity,
``MAE_h`` = mean over s of the error norm at s + h and ``SimErr`` = sum of
``MAE_h`` for h = 1..H, reported with the naive constant-state prediction and
the ratio model/naive.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from quad_modelling.core.evaluation.metrics import rms, tic
from quad_modelling.core.evaluation.multistep import flight_multistep_sums, multistep_table
from quad_modelling.core.evaluation.statistics import EvaluationStatistics
from quad_modelling.core.flight_log import SENSORS, FlightLog
from quad_modelling.core.models.base import Predictor
from quad_modelling.core.preprocess import (
    NEEDS,
    SMOOTH_CUTOFF_HZ,
    TrimConfig,
    resample_uniform,
    smooth,
    trimmed_inputs,
    trimmed_variables,
)
from quad_modelling.core.variables import EVAL_VARIABLES, INDEX, VARIABLES
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import (EvaluationConfig, check_window_rate, check_window_rows, no_window_error, span_windows,
                                         warm_samples_for)
from quad_modelling.errors import ConfigError, DataError


@dataclass
class WindowResult:
    """One model on one window: smoothed trimmed measurement and prediction, RMS and TIC per variable (SI)."""

    measured: np.ndarray
    predicted: np.ndarray
    rms: np.ndarray
    tic: np.ndarray
    warm_samples: int


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
    the same for every model). A predictor that trims its own prediction must
    trim as the evaluation does (``trim``): ConfigError otherwise.
    """
    trim = trim or TrimConfig()
    if hasattr(predictor, "trim") and (predictor.trim or TrimConfig()) != trim:  # a trim of None is the default TrimConfig()
        raise ConfigError(f"model {predictor.name} trims its prediction with {predictor.trim or TrimConfig()}, the evaluation its "
                          f"measurement with {trim}; build the model with the evaluation's trim")
    if measured is None:
        measured = smooth(trimmed_variables(window, trim, vehicle), window.sample_rate, smooth_cutoff_hz)
    predicted = np.asarray(predictor.predict_window(window, warm_samples), dtype=float)
    if predicted.shape != (len(window), len(VARIABLES)):
        raise DataError(f"model {predictor.name}: predicted shape {predicted.shape}, expected {(len(window), len(VARIABLES))}")
    measurable = np.isfinite(measured).all(axis=0)  # the variables the flight's sensors measure (preprocess.NEEDS)
    if not np.all(np.isfinite(predicted[:, measurable])):
        raise DataError(f"model {predictor.name}: non-finite prediction on window starting t={window.t[0]:.2f} s of {window.meta.source}")
    predicted = smooth(np.where(measurable, predicted, np.nan), window.sample_rate, smooth_cutoff_hz)
    scored = slice(warm_samples, None)
    rms_values = np.where(measurable, rms(measured[scored], predicted[scored]), np.nan)
    tic_values = np.where(measurable, tic(measured[scored], predicted[scored]), np.nan)
    return WindowResult(measured, predicted, rms_values, tic_values, warm_samples)


def window_mean(per_window) -> np.ndarray:
    """Span score from per-window scores, (W, ...) -> (...): the mean over the W windows,
    :math:`\\bar s = \\frac{1}{W} \\sum_{w=1}^{W} s_w` (thesis 5.1: errors averaged over windows)."""
    return np.mean(np.asarray(per_window, dtype=float), axis=0)


@dataclass
class SpanScores:
    """Mean over windows of RMS and TIC per variable (SI), with the window count."""

    rms: np.ndarray
    tic: np.ndarray
    windows: int

    @classmethod
    def over_windows(cls, rms: Sequence[np.ndarray], tic: Sequence[np.ndarray]) -> SpanScores:
        """The span score of per-window RMS and TIC rows (:func:`window_mean`)."""
        return cls(window_mean(rms), window_mean(tic), len(rms))

    def to_json(self, variables: Sequence[str] = EVAL_VARIABLES) -> dict:
        """``{variable: {"rms", "tic"}}``; a variable the flights' sensors do not measure (NaN score) is
        ``{"rms": null, "tic": null, "needs": "gyro"}`` (:data:`~quad_modelling.core.preprocess.NEEDS`)."""
        out = {}
        for v in variables:
            r, t = float(self.rms[INDEX[v]]), float(self.tic[INDEX[v]])
            out[v] = {"rms": r, "tic": t} if np.isfinite(r) else {"rms": None, "tic": None, "needs": SENSORS[NEEDS[v]]}
        return out


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
    """Span scores, the multi-step table, the configuration, the flights, example windows for the figures and,
    for an offline evaluation, the statistics the scores are computed from (results.json ``statistics``)."""

    scores: dict[str, dict[str, SpanScores]]
    horizons: dict
    config: EvaluationConfig
    flights: list[dict]
    examples: list[ExampleWindow]
    statistics: EvaluationStatistics | None = None

    def to_json(self) -> dict:
        data = {
            "models": {m: {s: sc.to_json() for s, sc in spans.items()} for m, spans in self.scores.items()},
            "windows": {m: {s: sc.windows for s, sc in spans.items()} for m, spans in self.scores.items()},
            "horizons": self.horizons,
            "config": {**self.config.to_dict(), "flights": self.flights, "units": "SI (m/s, m/s2, rad/s, rad/s2)"},
        }
        if self.statistics is not None:
            data["statistics"] = self.statistics.to_json()
        return data


@dataclass
class FlightEvaluation:
    """One flight's share of an evaluation: its statistics, its entry of results.json ``flights`` and the
    first window of each span it has (for the figures). Small: no flight data but one window per span."""

    statistics: EvaluationStatistics
    flight: dict
    examples: list[ExampleWindow]


def evaluate_flight(
    log: FlightLog,
    models: Sequence[Predictor],
    vehicle: VehicleConfig,
    config: EvaluationConfig,
    multistep: bool = True,
    examples: bool = True,
) -> FlightEvaluation:
    """The statistics of one flight (module docstring): every window of every span scored by every model,
    and the multi-step sums; merged over flights by :func:`merge_flights`. ``examples``: also keep the first
    window of each span for the figures (about 0.6 MB per span at 100 Hz; a fleet asks one flight for them)."""
    names = [m.name for m in models]
    if len(set(names)) != len(names):
        raise ConfigError(f"model names must be unique, got {names}: name them, --model NAME=SPEC (a=narx:a.npz)")
    config.validate()
    check_window_rate(log)  # before the multi-step table: a flight no window can score is refused for its rate
    check_window_rows([log], config)  # and a window or warm start of too few rows at its rate
    for model in models:  # a model that predicts only some flights (the truth model: simulated ones) says so first
        check = getattr(model, "check_flight", None)
        if check is not None:
            check(log)
    # Windows score the recorded rows (the coverage rule of core.alignment, as the live evaluator); the multi-step
    # horizons count steps, so they run on the uniform grid (and resample_uniform refuses a gap over 50 ms).
    uniform = resample_uniform(log)
    spans = config.spans()
    steps = flight_multistep_sums(uniform, models, vehicle, config) if multistep else None
    stats = EvaluationStatistics.empty(vehicle.name, names, [s.name for s in spans], steps, vehicle.numbers())
    stats.durations.append(log.duration)
    kept: list[ExampleWindow] = []
    for span in spans:
        for k, w in enumerate(span_windows(log, span, config)):
            window = log.slice(w.start, w.stop)
            warm = warm_samples_for(window, config.warm_s)
            measured = smooth(trimmed_variables(window, config.trim, vehicle), window.sample_rate, config.smooth_cutoff_hz)
            predicted = {}
            for model in models:
                result = evaluate_window(model, window, warm, config.trim, vehicle, config.smooth_cutoff_hz, measured)
                stats.windowed[model.name][span.name].add_window(result.rms, result.tic)
                predicted[model.name] = result.predicted
            if k == 0 and examples:
                kept.append(
                    ExampleWindow(window.meta.source, span.name, window.t - window.t[0], trimmed_inputs(window, config.trim), measured, predicted, warm)
                )
    flight = {"source": log.meta.source, "duration_s": log.duration, "sample_rate_hz": log.sample_rate,
              "fingerprint": log.fingerprint()}
    return FlightEvaluation(stats, flight, kept)


def merge_flights(parts: Iterable[FlightEvaluation], config: EvaluationConfig,
                  progress: Callable[[str], None] | None = None) -> EvaluationResult:
    """One evaluation of many flights: their statistics merged in the order given
    (:meth:`EvaluationStatistics.merge`), the first example window of each span kept; DataError when no
    span of any flight holds a window. ``parts`` may be a generator: one flight is held at a time."""
    total: EvaluationStatistics | None = None
    flights: list[dict] = []
    examples: dict[str, ExampleWindow] = {}
    for part in parts:
        if total is None:
            total = part.statistics.empty_like([s.name for s in config.spans()])
        total.merge(part.statistics)
        flights.append(part.flight)
        for example in part.examples:
            examples.setdefault(example.span, example)
        if progress:
            progress(f"{part.flight['source']}: {part.statistics.windows} windows")
    if total is None:
        raise DataError("no flight to evaluate")
    return result_from_statistics(total, config, flights, [examples[s.name] for s in config.spans() if s.name in examples])


def result_from_statistics(stats: EvaluationStatistics, config: EvaluationConfig, flights: list[dict],
                           examples: list[ExampleWindow] | None = None) -> EvaluationResult:
    """The evaluation result (span scores = sums / windows, the multi-step table) of merged statistics."""
    if stats.windows == 0:
        raise no_window_error(config, stats.durations)
    scores = {}
    for model in stats.models:
        scores[model] = {}
        for span in config.spans():
            sums = stats.windowed[model].get(span.name)
            if sums is not None and sums.windows:
                scores[model][span.name] = SpanScores(*sums.means(), sums.windows)
    horizons = multistep_table(stats.multistep, config) if stats.multistep is not None else {}
    return EvaluationResult(scores, horizons, config, flights, examples or [], stats)


def evaluate(
    flights: Sequence[FlightLog],
    models: Sequence[Predictor],
    vehicle: VehicleConfig,
    config: EvaluationConfig | None = None,
    multistep: bool = True,
    progress: Callable[[str], None] | None = None,
) -> EvaluationResult:
    """Run the protocol of the module docstring on several flights and models: :func:`evaluate_flight` per
    flight, :func:`merge_flights` over them (what ``--jobs`` and ``quad-modelling merge`` do too)."""
    config = config or EvaluationConfig()
    return merge_flights((evaluate_flight(log, models, vehicle, config, multistep) for log in flights), config, progress)
