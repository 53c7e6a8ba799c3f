"""Spans and windows: the one span grammar and the one window clock, offline and live.

Span grammar (:class:`SpanSpec`). A span is ``A:B``:

* plain numbers are seconds (offline: from the flight's first sample, clipped to
  the flying part; live: from the window origin t0);
* numbers with ``%`` are percent of the flying part (``0%:60%``), offline only
  (a live node does not know the flight's length);
* ``inf`` is an open end (``20:inf``), in seconds only.

``NAME:A:B`` is a named span (the evaluator node's ``spans`` parameter, e.g.
``eval:150:190`` or ``live:0:inf``), parsed by the same :meth:`SpanSpec.parse`.
``--drop START:END`` takes two finite non-negative seconds (:func:`parse_drop`).
Every malformed text is a :class:`~quad_modelling.errors.ConfigError` naming the
text and what is wrong with it.

Window clock (:class:`WindowClock`). Window k is the time interval
``[t0 + kW, t0 + (k+1)W)`` for an origin t0 and a length W, on integer
nanosecond stamps. Stamps jitter (real logs: microseconds) and a row stands for
the sample period dt around its stamp, so a stamp t is assigned to its window
after a shift of half a period:

.. math::

    k = \\lfloor (t - t_0 + dt/2) / W \\rfloor, \\qquad
    p = t - t_0 + dt/2 - k W

(``p``: the position in the window; the row is a warm-start row when
``p < warm_s``). Jitter below dt/2 never moves a stamp across a boundary: the
boundaries ``t0 + kW - dt/2`` lie half-way between nominal samples. Row
boundaries map to time the same way: a row range of a span ``[a, b)`` holds the
rows with ``a <= t - t_first + dt/2 < b``; a window holds the rows assigned to
it and is used only when they meet the coverage rule of
:mod:`~quad_modelling.core.alignment` (>= 95 % of the nominal W / dt rows, no
step over 50 ms, window edges included: a dropped sample of a real log keeps
the window, a gap or a late start leaves it out: offline it is skipped, live it
is marked), and only when it ends inside its span (its last nominal row before
the span's end). The rows are the recorded ones, never resampled, so the live
evaluator (which scores the engine-input stamps it received) and the offline
evaluation score the same rows the same way. A window with a row inside a measurement gap marked
in the flight's notes (a motion-capture or IMU dropout a reader did not bridge)
is left out offline (:func:`gap_rows`; live, the missing messages mark it), and
contiguous segments (multi-step evaluation, NARX training) are split there
(:func:`gap_free_runs`).

Offline (:func:`span_windows`) the clock's origin is the span start (windows
are consecutive from it, a remainder shorter than W is not used) and dt is the
flight's mean sample period (its duration over its steps; on a uniform grid
the same as the median). Live, the origin is the first engine-input stamp
(published on ``window_origin``) and dt the median of the first engine-input
steps; a window is scored in a span when it lies inside it
(:meth:`SpanSpec.covers`). Spans starting on multiples of W give the same
windows offline and live.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from quad_modelling.core.alignment import MAX_GAP_S, stream_coverage
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.preprocess import (
    SMOOTH_CUTOFF_HZ,
    TrimConfig,
    marked_gaps,
)
from quad_modelling.errors import ConfigError, DataError

_BOUND = re.compile(r"^\s*(?:(?P<inf>inf)|(?P<value>(?:\d+(?:\.\d*)?|\.\d+)(?:e[+-]?\d+)?)\s*(?P<percent>%?))\s*$", re.IGNORECASE)
"""One bound: non-negative seconds (``1e1`` too), a percentage, or ``inf``."""

SPAN_EXAMPLES = "e.g. 30:150, 0%:60% or 20:inf"


def _bound(text: str, what: str) -> tuple[float, bool]:
    """(value, is_percent) of one bound; ConfigError naming ``what`` when it is not a number, percentage or inf."""
    match = _BOUND.match(text)
    if not match:
        why = "negative" if text.strip().startswith("-") else "not a non-negative number of seconds, a percentage or inf"
        raise ConfigError(f"{what}: bound {text.strip()!r} is {why}; {SPAN_EXAMPLES}")
    if match.group("inf"):
        return math.inf, False
    return float(match.group("value")), bool(match.group("percent"))


@dataclass(frozen=True)
class SpanSpec:
    """One span ``A:B``: seconds (END may be ``inf``), or percent (``%``) of the flying part; see the module doc."""

    name: str
    start: float
    end: float
    relative: bool

    @classmethod
    def parse(cls, name: str, text: str) -> SpanSpec:
        """``A:B`` -> the span ``name``; ConfigError naming the text and what is wrong."""
        what = f"span {name} {text!r}"
        parts = str(text).split(":")
        if len(parts) != 2:
            raise ConfigError(f"{what}: expected START:END, {SPAN_EXAMPLES}")
        (start, start_pct), (end, end_pct) = (_bound(p, what) for p in parts)
        if start_pct != end_pct:
            raise ConfigError(f"{what}: give both bounds in seconds or both in percent")
        if math.isinf(start):
            raise ConfigError(f"{what}: START must be finite (only END may be inf)")
        if start_pct:
            if not 0.0 <= start < end <= 100.0:
                raise ConfigError(f"{what}: percentages must satisfy 0 <= START < END <= 100")
            return cls(name, start / 100.0, end / 100.0, True)
        if not start < end:
            raise ConfigError(f"{what}: need 0 <= START < END seconds")
        return cls(name, start, end, False)

    @classmethod
    def parse_named(cls, text: str) -> SpanSpec:
        """``NAME:A:B`` (e.g. ``eval:150:190``, ``live:0:inf``) -> the span NAME, bounds as :meth:`parse`."""
        name, sep, bounds = str(text).partition(":")
        if not sep or not name.strip() or bounds.count(":") != 1:
            raise ConfigError(f"span {text!r}: expected NAME:START:END, e.g. eval:150:190 or live:0:inf")
        return cls.parse(name.strip(), bounds)

    def text(self) -> str:
        """The span as ``A:B`` (parses back to itself)."""
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

    def covers(self, start_s: float, end_s: float) -> bool:
        """Whether the window [start_s, end_s) [s from t0] lies inside this seconds span (1 ns tolerance)."""
        if self.relative:
            raise ConfigError(f"span {self.name} {self.text()}: a percent span has no seconds bounds until a flight's length is known")
        return start_s >= self.start - 1e-9 and end_s <= self.end + 1e-9


MAX_HORIZON_STEPS = 1_000_000
"""Longest multi-step horizon [samples] (2.8 h at 100 Hz; the sums are (4, H) per model)."""

MAX_SECONDS = 1.0e6
"""The longest window, warm start or drop [s] (11.6 days, longer than any flight log): flight times are counted in
int64 nanoseconds, which a 1e10 s window overflowed."""


def parse_drop(text: str) -> tuple[float, float]:
    """``--drop START:END``: seconds dropped at take-off and landing (finite, >= 0); ConfigError otherwise."""
    what = f"--drop {text!r}"
    parts = str(text).split(":")
    if len(parts) != 2:
        raise ConfigError(f"{what}: expected START:END seconds, e.g. 30:22")
    for name, part in zip(("START", "END"), parts):
        if part.strip().startswith("-"):
            raise ConfigError(f"{what}: {name} {part.strip()} is negative; --drop START:END gives the seconds dropped at "
                              "take-off and at landing, each >= 0, e.g. 30:22 (0:0 drops nothing)")
    bounds = [_bound(p, what) for p in parts]
    if any(pct or math.isinf(value) for value, pct in bounds):
        raise ConfigError(f"{what}: both bounds must be finite seconds (no % or inf)")
    return bounds[0][0], bounds[1][0]


def seconds_spans(texts: Sequence[str]) -> list[SpanSpec]:
    """Named seconds spans (``NAME:A:B`` each, unique names, at least one): the live evaluator's ``spans``."""
    spans = [SpanSpec.parse_named(t) for t in texts]
    if not spans:
        raise ConfigError("give at least one span NAME:START:END")
    for span in spans:
        if span.relative:
            raise ConfigError(f"span {span.name} {span.text()}: live spans are seconds from t0 (a percentage needs the flight's length)")
    names = [s.name for s in spans]
    if len(set(names)) != len(names):
        raise ConfigError(f"span names must be unique, got {names}")
    return spans


def spans_without_a_window(texts: Sequence[str], duration_s: float, window_s: float) -> list[str]:
    """One sentence per named seconds span (``NAME:A:B``, :func:`seconds_spans`) that holds no whole window of
    ``window_s`` [s] within a flight of ``duration_s`` [s from its first sample]: nothing will be scored in it (run-bag
    said so only after the replay, as a coverage mark)."""
    out = []
    for span in seconds_spans(texts):
        end = min(span.end, duration_s)
        if end - span.start < window_s:
            out.append(f"span {span.name} {span.text()} holds no {window_s:g} s window of this {duration_s:.1f} s flight "
                       f"({max(end - span.start, 0.0):.1f} s of it): nothing will be scored there")
    return out


PRESETS: dict[str, dict] = {
    "thesis": {"drop": (30.0, 22.0), "train": "30:150", "eval": "150:190"},
    "short": {"drop": (5.0, 5.0), "train": "0%:60%", "eval": "60%:100%"},
}
"""Span presets: the thesis's (220 s flights) and one for short flights (NanoBench, ~40 s)."""


@dataclass(frozen=True)
class EvaluationConfig:
    """Everything that defines an evaluation; defaults are the thesis's values.

    ``trim`` and ``smooth_cutoff_hz`` are the one trim/smoothing configuration of
    a scoring (offline evaluation, the evaluator node, the diagnosis): measurement
    and predictions are trimmed with ``trim`` and low-passed at ``smooth_cutoff_hz``.
    """

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
        """The preset ``name`` with every override that is not None applied."""
        if name not in PRESETS:
            raise ConfigError(f"unknown span preset {name!r}; known: {', '.join(PRESETS)}")
        p = PRESETS[name]
        values = {"drop_start": p["drop"][0], "drop_end": p["drop"][1], "train": p["train"], "eval": p["eval"]}
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    @classmethod
    def from_options(cls, preset: str, drop: str | None = None, **overrides) -> EvaluationConfig:
        """The command-line form: a preset, ``--drop START:END`` text and overrides (None = the preset's); validated."""
        start, end = parse_drop(drop) if drop is not None else (None, None)  # '' is a malformed --drop, not none given
        config = cls.preset(preset, drop_start=start, drop_end=end, **overrides)
        config.validate()
        return config

    def with_drop(self, drop: str) -> EvaluationConfig:
        """This configuration with the take-off/landing drops of ``--drop START:END`` text."""
        start, end = parse_drop(drop)
        return replace(self, drop_start=start, drop_end=end)

    def spans(self) -> list[SpanSpec]:
        return [SpanSpec.parse("train", self.train), SpanSpec.parse("eval", self.eval)]

    def span_overlap(self) -> str | None:
        """A sentence when the training and evaluation spans share time (both in seconds or both in percent of the
        flying part; mixed kinds depend on each flight's length and are not judged), else None: what is fitted on
        the training span is then scored partly in-sample."""
        train, held_out = self.spans()
        if train.relative != held_out.relative:
            return None
        start, end = max(train.start, held_out.start), min(train.end, held_out.end)
        if start >= end:
            return None
        shared = SpanSpec("shared", start, end, train.relative).text()
        return (f"the training span {train.text()} and the evaluation span {held_out.text()} share {shared}: "
                "what is fitted there is scored partly in-sample")

    def flight_span_overlap(self, log: FlightLog) -> str | None:
        """:meth:`span_overlap` for spans of mixed kinds (one in seconds, one in percent), judged on ``log``'s flying
        part: a sentence naming the flight and the seconds both spans share, else None (same kinds: :meth:`span_overlap`)."""
        train, held_out = self.spans()
        if train.relative == held_out.relative:
            return None
        (a, b), (c, d) = (span.interval(log, self.drop_start, self.drop_end) for span in (train, held_out))
        start, end = max(a, c), min(b, d)
        if start >= end:
            return None
        return (f"{log.meta.source}: the training span {train.text()} ({a:.1f}-{b:.1f} s of this flight) and the evaluation "
                f"span {held_out.text()} ({c:.1f}-{d:.1f} s) share {start:.1f}-{end:.1f} s: what is fitted there is scored "
                "partly in-sample")

    def validate(self) -> None:
        for flag, value in (("--window", self.window_s), ("--warm", self.warm_s), ("--drop start", self.drop_start),
                            ("--drop end", self.drop_end), ("--smooth", self.smooth_cutoff_hz)):
            if not math.isfinite(value):
                raise ConfigError(f"{flag} {value}: must be a finite number")
        for flag, value in (("--window", self.window_s), ("--warm", self.warm_s), ("--drop start", self.drop_start),
                            ("--drop end", self.drop_end)):
            if value > MAX_SECONDS:  # times are counted in int64 nanoseconds: 1e10 s overflowed in a traceback (review)
                raise ConfigError(f"{flag} {value:g} s: must be at most {MAX_SECONDS:g} s ({MAX_SECONDS / 86400:.1f} days)")
        if self.window_s <= 0 or self.warm_s <= 0 or self.warm_s >= self.window_s:  # the warm start anchors on measurements
            raise ConfigError(f"need window_s > warm_s > 0 (--window, --warm), got window {self.window_s} s, warm {self.warm_s} s")
        if self.drop_start < 0 or self.drop_end < 0:
            raise ConfigError("take-off/landing drops must be >= 0 s")
        if not self.horizons or min(self.horizons) < 1:
            raise ConfigError(f"--horizons {','.join(map(str, self.horizons))}: give positive step counts")
        if list(self.horizons) != sorted(set(self.horizons)):
            raise ConfigError(f"--horizons {','.join(map(str, self.horizons))}: give each step count once, in increasing order")
        if self.horizons[-1] > MAX_HORIZON_STEPS:  # 1e20 steps was accepted and scored nothing, said in tables.md only
            raise ConfigError(f"--horizons {','.join(map(str, self.horizons))}: at most {MAX_HORIZON_STEPS} steps")
        if not self.smooth_cutoff_hz > 0:
            raise ConfigError(f"the smoothing cutoff must be a positive frequency in Hz, got {self.smooth_cutoff_hz:g}")
        self.spans()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["horizons"] = list(self.horizons)
        return d

    @classmethod
    def from_dict(cls, data: dict, where: str = "config") -> EvaluationConfig:
        """The inverse of :meth:`to_dict` (a results.json ``config``; other keys ignored), validated; ConfigError
        naming ``where`` for a missing or malformed field."""
        try:
            values = {f.name: data[f.name] for f in fields(cls)}
            values["trim"] = TrimConfig(**values["trim"])
            values["horizons"] = tuple(int(h) for h in values["horizons"])
            config = cls(**values)
        except (KeyError, TypeError, ValueError) as err:
            raise ConfigError(f"{where}: not an evaluation configuration ({type(err).__name__}: {err})") from err
        try:
            config.validate()
        except ConfigError as err:  # its words name the options that set the fields: here the file's fields are at fault
            raise ConfigError(f"{where}: {err} (the evaluation's configuration as the file holds it)") from err
        return config


# ----------------------------------------------------------------------------- the window clock


def seconds_to_ns(seconds) -> np.ndarray | int:
    """Seconds -> integer nanoseconds (rounded; arrays stay arrays)."""
    if np.ndim(seconds) == 0:
        return int(round(float(seconds) * 1e9))
    return np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64)


class WindowClock:
    """Window k = [t0 + kW, t0 + (k+1)W) on integer nanosecond stamps; the stamp rule of the module doc.

    ``dt`` is ``sample_period_s`` when given, otherwise the median of the first
    :data:`PERIOD_SAMPLES` steps fed to :meth:`observe`, then frozen.
    """

    PERIOD_SAMPLES = 5

    def __init__(self, window_s: float, warm_s: float, sample_period_s: float = 0.0, origin_ns: int | None = None):
        self.window_ns = seconds_to_ns(window_s)
        self.warm_ns = seconds_to_ns(warm_s)
        self.origin_ns = origin_ns
        self.half_period_ns = seconds_to_ns(sample_period_s * 0.5) if sample_period_s > 0 else None
        self._steps: list[int] = []
        self._last: int | None = None

    @property
    def period_s(self) -> float | None:
        return None if self.half_period_ns is None else 2 * self.half_period_ns / 1e9

    def observe(self, ns: int) -> None:
        """Feed each accepted stamp in order (estimates dt while unknown)."""
        if self.half_period_ns is None and self._last is not None and ns > self._last:
            self._steps.append(ns - self._last)
            if len(self._steps) >= self.PERIOD_SAMPLES:
                self._steps.sort()
                self.half_period_ns = self._steps[len(self._steps) // 2] // 2
        self._last = ns

    def shifted(self, ns):
        """t - t0 + dt/2 [ns] of a stamp or an array of stamps; the origin must be set."""
        return ns - self.origin_ns + (self.half_period_ns or 0)

    def locate(self, ns: int) -> tuple[int, int]:
        """(window index k, position in window [ns]) of a stamp."""
        shifted = self.shifted(ns)
        k = shifted // self.window_ns
        return int(k), int(shifted - k * self.window_ns)

    def is_warm(self, position_ns: int) -> bool:
        return position_ns < self.warm_ns

    def is_last_warm(self, position_ns: int) -> bool:
        """A warm row whose successor, one period dt later, is not: ``p < warm_s <= p + dt`` (False while dt is
        unknown). Positions carry the dt/2 shift, so stamp jitter below dt/2 does not change the answer."""
        return self.half_period_ns is not None and position_ns < self.warm_ns <= position_ns + 2 * self.half_period_ns

    def stamp_bounds(self, k: int) -> tuple[int, int]:
        """The stamps [ns] window k holds: [t0 + kW - dt/2, t0 + (k+1)W - dt/2) (the stamp rule of the module doc)."""
        start = self.origin_ns + k * self.window_ns - (self.half_period_ns or 0)
        return start, start + self.window_ns

    def window_start_s(self, k: int) -> float:
        """Start of window k in seconds from t0."""
        return k * self.window_ns / 1e9

    @property
    def window_rows(self) -> int:
        """Rows a complete window holds: round(W / dt) (dt must be known)."""
        return int(round(self.window_ns / (2 * self.half_period_ns)))

    def cut(self, stamps_ns: np.ndarray, end_ns: float = math.inf) -> list[tuple[int, int]]:
        """Rows [start, stop) of each window k >= 0 of sorted ``stamps_ns`` that meets the coverage rule
        (:func:`~quad_modelling.core.alignment.stream_coverage` on the shifted stamps) and whose rows all have
        ``t - t0 + dt/2 < end_ns`` (relative to t0), with ``(k+1) W < end_ns + dt/2``: the offline form of
        :meth:`locate`."""
        shifted = self.shifted(np.asarray(stamps_ns, dtype=np.int64))
        first = int(np.searchsorted(shifted, 0))
        last = len(shifted) if math.isinf(end_ns) else int(np.searchsorted(shifted, end_ns))
        if last <= first:
            return []
        windows = int((shifted[last - 1] // self.window_ns) + 1)
        if not math.isinf(end_ns):  # a window ends inside [.., end): its last nominal row lies before end
            windows = min(windows, int((end_ns + (self.half_period_ns or 0) - 1) // self.window_ns))
        bounds = np.searchsorted(shifted, np.arange(windows + 1, dtype=np.int64) * self.window_ns)
        return [(int(a), int(b)) for k, (a, b) in enumerate(itertools.pairwise(bounds))
                if b <= last and stream_coverage("rows", shifted[a:b], k * self.window_ns, (k + 1) * self.window_ns).ok]


def flight_clock(log: FlightLog, origin_s: float, window_s: float, warm_s: float = 0.0) -> WindowClock:
    """The clock of one flight: origin ``origin_s`` seconds after its first sample, dt its mean sample period."""
    period = (log.t[-1] - log.t[0]) / (len(log) - 1)
    return WindowClock(window_s, warm_s, period, origin_ns=seconds_to_ns(origin_s))


def flight_stamps(log: FlightLog) -> np.ndarray:
    """Stamps [ns] from the flight's first sample."""
    return seconds_to_ns(log.t - log.t[0])


def rows_between(log: FlightLog, start_s: float, end_s: float) -> tuple[int, int]:
    """Rows [i0, i1) of ``log`` with ``start_s <= t - t_first + dt/2 < end_s`` (the module doc's row rule; may be empty)."""
    clock = flight_clock(log, start_s, 1.0)
    shifted = clock.shifted(flight_stamps(log))
    stop = len(log) if math.isinf(end_s) else int(np.searchsorted(shifted, seconds_to_ns(end_s - start_s)))
    return int(np.searchsorted(shifted, 0)), stop


def gap_rows(log: FlightLog) -> np.ndarray:
    """(N,) mask of the rows strictly inside a measurement gap marked in the log's notes
    (:func:`~quad_modelling.core.preprocess.mark_measurement_gaps`): interpolated only to keep the log finite,
    never used: no window or training segment holds one."""
    inside = np.zeros(len(log), dtype=bool)
    for gap in marked_gaps(log):
        inside |= (log.t > gap.start_s) & (log.t < gap.end_s)
    return inside


def gap_free_runs(log: FlightLog, start: int, stop: int) -> list[tuple[int, int]]:
    """Rows [start, stop) split at the marked measurement gaps: the maximal runs [a, b) holding no gap row."""
    inside = gap_rows(log)[start:stop]
    if not inside.any():
        return [(start, stop)] if stop > start else []
    edges = np.flatnonzero(np.diff(np.concatenate([[True], inside, [True]]).astype(np.int8)))
    return [(start + int(a), start + int(b)) for a, b in zip(edges[::2], edges[1::2]) if b > a]


MIN_SAMPLE_PERIOD_S = 1.0e-4
"""Shortest nominal sample period [s] (10 kHz, beyond any flight stack's command rate): a window of shorter periods
would be allocated with billions of rows, a receding horizon's h steps would be as many."""

MIN_SAMPLE_RATE_HZ = 1.0 / MAX_GAP_S
"""Slowest flight that can be scored [Hz]: the coverage rule allows no step over
:data:`~quad_modelling.core.alignment.MAX_GAP_S` (50 ms) in a window."""


def check_window_rate(log: FlightLog) -> None:
    """DataError naming the flight, its rate and the rate needed when its median step is longer than
    :data:`~quad_modelling.core.alignment.MAX_GAP_S`: then at least half its steps are, so no window of any
    length in any span can meet the coverage rule (a PX4 ULog at the logger's default 10 Hz, for one).
    Checked before spans are blamed; also where the multi-step table, identification and NARX training
    take a flight (their windows and segments are in samples of the same rate)."""
    if len(log) < 2:
        return
    rate = log.sample_rate
    if rate < MIN_SAMPLE_RATE_HZ * (1 - 1e-6):
        raise DataError(
            f"{log.meta.source}: sampled at {rate:.3g} Hz (median step {1e3 / rate:.0f} ms); scoring needs "
            f"{MIN_SAMPLE_RATE_HZ:g} Hz or faster (a window allows no step over {MAX_GAP_S * 1e3:g} ms), whatever "
            f"the spans: record the flight at {MIN_SAMPLE_RATE_HZ:g} Hz or more"
            + (f"; PX4 logs {_ulog_motor_topic(log)} at 10 Hz by default: add `{_ulog_motor_topic(log)} 10` (interval ms) and "
               "the position and attitude topics to etc/logging/logger_topics.txt on the SD card (docs/px4.md)"
               if log.meta.notes.get("format") == "px4-ulog" else "")
        )


def _ulog_motor_topic(log: FlightLog) -> str:
    """The PX4 topic a ULog flight's commands came from (its ``time_base`` note: actuator_motors or actuator_outputs)."""
    base = str(log.meta.notes.get("time_base", ""))
    return "actuator_outputs" if base.startswith("actuator_outputs") else "actuator_motors"


def windows_between(log: FlightLog, start_s: float, end_s: float, window_s: float) -> list[tuple[int, int]]:
    """Rows [start, stop) of the complete windows of the clock with origin ``start_s`` inside [start_s, end_s),
    leaving out every window with a row inside a marked measurement gap (:func:`gap_rows`); DataError for a
    flight too slow for any window (:func:`check_window_rate`)."""
    check_window_rate(log)
    if end_s <= start_s:
        return []
    clock = flight_clock(log, start_s, window_s)
    windows = clock.cut(flight_stamps(log), math.inf if math.isinf(end_s) else seconds_to_ns(end_s - start_s))
    inside = gap_rows(log)
    return [(a, b) for a, b in windows if not inside[a:b].any()]


@dataclass(frozen=True)
class Window:
    """Rows [start, stop) of flight ``flight`` (index into the flights list), in span ``span``."""

    flight: int
    span: str
    start: int
    stop: int


def span_windows(log: FlightLog, span: SpanSpec, config: EvaluationConfig, flight: int = 0) -> list[Window]:
    """Consecutive full windows of ``config.window_s`` inside ``span`` of one flight (the clock from the span start);
    ConfigError when the window or its warm start holds too few rows (:func:`check_window_rows`)."""
    check_window_rows([log], config)
    a, b = span.interval(log, config.drop_start, config.drop_end)
    return [Window(flight, span.name, s, e) for s, e in windows_between(log, a, b, config.window_s)]


def span_segment(log: FlightLog, span: SpanSpec, config: EvaluationConfig) -> tuple[int, int]:
    """Rows [start, stop) of a span in one flight (contiguous; empty when start >= stop)."""
    return rows_between(log, *span.interval(log, config.drop_start, config.drop_end))


def span_segments(log: FlightLog, span: SpanSpec, config: EvaluationConfig) -> list[tuple[int, int]]:
    """Rows [start, stop) of the contiguous parts of a span in one flight: :func:`span_segment` split at the
    marked measurement gaps (:func:`gap_free_runs`)."""
    return gap_free_runs(log, *span_segment(log, span, config))


def warm_samples_for(window: FlightLog, warm_s: float) -> int:
    """Number of warm-start rows (>= 1: the state at the anchor is always given)."""
    return int(np.clip(round(warm_s * window.sample_rate), 1, len(window) - 1))


MIN_WARM_ROWS = 2
"""Fewest rows a warm start may hold (the greybox anchors on two); a window holds at least one more."""


def check_window_rows(flights: Sequence[FlightLog], config: EvaluationConfig) -> None:
    """ConfigError naming ``--warm`` or ``--window`` when, at the slowest flight's rate, the warm start holds fewer
    than :data:`MIN_WARM_ROWS` rows or the window fewer than 2 rows after it (a stamp's jitter may cut one row less; a
    model's own error named a 1-row warm start or a flight of 1 sample, and "no window fits" a 32 s flight)."""
    slowest = min(flights, key=lambda log: log.sample_rate, default=None)
    if slowest is None or len(slowest) < 2:
        return
    rate = slowest.sample_rate
    if round(config.warm_s * rate) < MIN_WARM_ROWS:
        raise ConfigError(f"--warm {config.warm_s:g}: {round(config.warm_s * rate)} row(s) of {slowest.meta.source} at "
                          f"{rate:.4g} Hz; a warm start holds at least {MIN_WARM_ROWS} rows ({MIN_WARM_ROWS / rate:.3g} s)")
    window_rows = math.floor(config.window_s * rate * (1 - 1e-9))  # a window's clock cuts this many, one fewer with jitter
    if window_rows < round(config.warm_s * rate) + 2:
        raise ConfigError(f"--window {config.window_s:g}: {window_rows} row(s) of {slowest.meta.source} at {rate:.4g} Hz "
                          f"or fewer; a window holds at least 2 rows more than its --warm {config.warm_s:g} s")


def plan_windows(flights: Sequence[FlightLog], config: EvaluationConfig) -> dict[str, list[Window]]:
    """Windows per span over all flights; DataError when no span holds a single window."""
    config.validate()
    plan: dict[str, list[Window]] = {}
    for span in config.spans():
        plan[span.name] = [w for i, log in enumerate(flights) for w in span_windows(log, span, config, i)]
    if not any(plan.values()):
        raise no_window_error(config, [log.duration for log in flights])
    return plan


def no_window_error(config: EvaluationConfig, durations: Sequence[float]) -> DataError:
    """The DataError of an evaluation in which no span of any flight (``durations`` [s]) holds a single window."""
    text = ", ".join(f"{d:.1f}" for d in durations)
    if all(span.relative for span in config.spans()):  # --preset short already: the window is what does not fit
        flying = max(durations, default=0.0) - config.drop_start - config.drop_end
        hint = (f"the longest flight flies {max(flying, 0.0):.1f} s after the drops: use a shorter --window, smaller "
                "--drop, or longer flights (a window touching a marked measurement gap is left out too: the warnings "
                "above name the gaps)")
    else:
        hint = "for short flights use --preset short or relative spans such as --drop 5:5 --train 0%:60% --eval 60%:100%"
    return DataError(
        f"no {config.window_s:g} s window fits the spans train {config.train}, eval {config.eval} after dropping "
        f"{config.drop_start:g} s/{config.drop_end:g} s (flight durations {text} s); {hint}"
    )
