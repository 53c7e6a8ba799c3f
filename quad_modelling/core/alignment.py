"""Streams on their own clocks: the coverage rule of a window and interpolation to the scored rows.

A real flight stack publishes engine inputs, motion capture and IMU on independent clocks
(DESIGN 5a): different rates, jitter, no shared stamps, messages lost in bursts under load.
Offline logs are on one time base but drop the odd sample (NanoBench: single 20-30 ms
steps). Both the live evaluator and the offline evaluation score a window with the rules
of this module, so both paths score the same rows the same way.

Rows. The scored rows of a window are the engine-input stamps inside it (the predictors
answer at each input, so the prediction stamps are these stamps); a window is cut by time
with the shared :class:`~quad_modelling.core.windows.WindowClock`: a stamp t belongs to
window k when :math:`kW \\le t - t_0 + dt/2 < (k+1)W`, i.e. the window holds the stamps in
:math:`[t_0 + kW - dt/2,\\; t_0 + (k+1)W - dt/2)`.

Coverage rule (:func:`stream_coverage`, :data:`MIN_COVERAGE`, :data:`MAX_GAP_S`). For each
stream in a window of length W (engine inputs, motion capture, IMU, each model's predictions)
with received stamps :math:`t_1 < \\dots < t_n` inside the window's interval [a, b):

.. math::

    \\widehat{dt} = \\operatorname{median}(t_{i+1} - t_i), \\qquad
    N_{nom} = W / \\widehat{dt}, \\qquad c = n / N_{nom}, \\qquad
    g = \\max(t_1 - a,\\; \\max_i (t_{i+1} - t_i),\\; b - t_n)

(the stream's own nominal period, so a 500 Hz IMU and 100 Hz inputs are judged alike; the
median is robust while fewer than half the steps are lost). The window is scored when every
stream has :math:`c \\ge 0.95` and :math:`g \\le 50` ms; otherwise it is marked, the reason
naming each failing stream with its coverage and its longest gap (:meth:`StreamCoverage.describe`).
A uniform stream has c = 1 and g = dt (interior) or dt/2 (edges); one dropped sample gives
g = 2 dt. With :math:`\\widehat{dt}` from fewer than two stamps c = 0.

Interpolation (:func:`interpolate_at`). Each measurement (and prediction) stream is linearly
interpolated to the rows' stamps, component by component; quaternion columns are normalised
after interpolation with the sign of neighbours aligned (nlerp, exact for the small rotations
between samples). A row stamp that equals a sample stamp takes that sample unchanged, so on
an aligned replay (all streams share the stamps) the interpolated rows are the recorded rows
bit for bit and live equals offline exactly. Outside the sampled range a row holds the nearest
sample when it is at most :data:`MAX_GAP_S` away (the edge of a window whose neighbour was not
received) and is NaN otherwise; interpolation never bridges a step longer than ``max_gap_s``
(NaN there), which the coverage rule has already marked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_COVERAGE = 0.95
"""A stream must deliver at least this fraction of its nominal samples in a window for it to be scored."""

MAX_GAP_S = 0.05
"""No step between a stream's samples in a window (window edges included) may be longer [s]."""


@dataclass(frozen=True)
class StreamCoverage:
    """How completely one stream covers one window: samples received, nominal samples W/dt, longest gap [s]
    and where it starts [s from the window start]."""

    stream: str
    received: int
    nominal: float
    longest_gap_s: float
    gap_at_s: float

    @property
    def coverage(self) -> float:
        """Fraction of the nominal samples received, :math:`c = n / N_{nom}` (0 without a rate)."""
        return self.received / self.nominal if self.nominal > 0 else 0.0

    @property
    def ok(self) -> bool:
        """Meets the coverage rule: :math:`c \\ge` :data:`MIN_COVERAGE` and longest gap :math:`\\le` :data:`MAX_GAP_S`."""
        return self.coverage >= MIN_COVERAGE and self.longest_gap_s <= MAX_GAP_S + 1e-9

    def describe(self) -> str:
        """``imu: 52.0 % of 2500 nominal samples (1300 received), longest gap 240 ms at 3.120 s into the window``."""
        return (f"{self.stream}: {100 * self.coverage:.1f} % of {self.nominal:.0f} nominal samples ({self.received} received), "
                f"longest gap {self.longest_gap_s * 1e3:.0f} ms at {self.gap_at_s:.3f} s into the window")


def stream_coverage(stream: str, stamps_ns: np.ndarray, start_ns: int, end_ns: int) -> StreamCoverage:
    """The coverage (module doc) of one stream's sorted, unique stamps [ns] inside the window [start_ns, end_ns)."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    stamps = stamps[(stamps >= start_ns) & (stamps < end_ns)]
    edges = np.concatenate([[start_ns], stamps, [end_ns]])
    steps = np.diff(edges)
    worst = int(np.argmax(steps))
    length = end_ns - start_ns
    nominal = 0.0
    if len(stamps) >= 2:
        dt = float(np.median(np.diff(stamps)))
        nominal = length / dt if dt > 0 else 0.0
    return StreamCoverage(stream, len(stamps), nominal, float(steps[worst]) / 1e9, float(edges[worst] - start_ns) / 1e9)


def coverage_reason(coverages: list[StreamCoverage]) -> str:
    """'' when every stream meets the rule; else the reason a window is marked, naming each failing stream."""
    failing = [c.describe() for c in coverages if not c.ok]
    if not failing:
        return ""
    return (f"coverage below the rule (>= {100 * MIN_COVERAGE:g} % of nominal samples, gaps <= {MAX_GAP_S * 1e3:g} ms): "
            + "; ".join(failing))


def interpolate_at(stamps_ns: np.ndarray, values: np.ndarray, at_ns: np.ndarray, quaternion: tuple[int, int] | None = None,
                   max_gap_s: float = MAX_GAP_S, hold: bool = True) -> np.ndarray:
    """Samples (stamps_ns (n,) sorted unique [ns], values (n, m)) at the stamps ``at_ns`` (r,) -> (r, m) (module doc).

    Linear in time per column, :math:`y(t) = y_i + (y_{i+1} - y_i)(t - t_i)/(t_{i+1} - t_i)`, exact at sample
    stamps; ``quaternion``: columns [start, stop) of a unit quaternion (normalised, sign-aligned to the earlier sample);
    a row nearer than ``max_gap_s`` [s] outside the samples holds the nearest one (``hold``; else NaN: a truth
    must be bracketed); a row in a step longer than ``max_gap_s`` or farther outside is NaN.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    values = np.asarray(values, dtype=float).reshape(len(stamps), -1)
    at = np.asarray(at_ns, dtype=np.int64)
    out = np.full((len(at), values.shape[1]), np.nan)
    if len(stamps) == 0 or len(at) == 0:
        return out
    max_gap_ns = int(round(max_gap_s * 1e9))
    hi = np.searchsorted(stamps, at, side="left")  # first sample >= row
    exact = (hi < len(stamps)) & (stamps[np.minimum(hi, len(stamps) - 1)] == at)
    out[exact] = values[hi[exact]]
    before = ~exact & (hi == 0)
    after = ~exact & (hi == len(stamps))
    if hold:
        out[before & (stamps[0] - at <= max_gap_ns)] = values[0]
        out[after & (at - stamps[-1] <= max_gap_ns)] = values[-1]
    inner = ~exact & ~before & ~after
    if inner.any():
        i1 = hi[inner]
        i0 = i1 - 1
        t0, t1 = stamps[i0], stamps[i1]
        step = t1 - t0
        f = ((at[inner] - t0) / step)[:, None]
        y0, y1 = values[i0].copy(), values[i1].copy()
        if quaternion is not None:
            qs = slice(*quaternion)
            flip = np.sum(y0[:, qs] * y1[:, qs], axis=1) < 0
            q1 = y1[:, qs]
            q1[flip] *= -1.0
            y1[:, qs] = q1
        y = y0 + (y1 - y0) * f
        if quaternion is not None:
            q = y[:, qs]
            y[:, qs] = q / np.linalg.norm(q, axis=1, keepdims=True)
        y[step > max_gap_ns] = np.nan
        out[inner] = y
    return out


class StampGuard:
    """Tells a stream's single outlier stamps from a real clock jump (a restarted publisher, a replay restarted,
    a sim clock reset).

    A stamp within ``max_jump_s`` [s] of the stream's latest accepted stamp is accepted (:data:`ACCEPT`). One
    farther away, into the future or the past, is an outlier (:data:`OUTLIER`: drop it, say so) unless
    ``confirm`` consecutive outliers lie within ``max_jump_s`` of each other: then the stream has jumped
    (:data:`JUMP`: the stream's clock restarts at that stamp, the outliers before it are lost).
    """

    ACCEPT, OUTLIER, JUMP = "accept", "outlier", "jump"

    def __init__(self, max_jump_s: float, confirm: int = 5):
        self.max_jump_ns = int(round(max_jump_s * 1e9))
        self.confirm = confirm
        self.last: int | None = None
        self.pending: list[int] = []

    def check(self, ns: int) -> str:
        """Classify stamp ``ns`` [ns] and update the guard."""
        if self.last is None or abs(ns - self.last) <= self.max_jump_ns:
            self.pending.clear()
            self.last = ns if self.last is None else max(self.last, ns)
            return self.ACCEPT
        if self.pending and abs(ns - self.pending[-1]) <= self.max_jump_ns:
            self.pending.append(ns)
        else:
            self.pending = [ns]
        if len(self.pending) >= self.confirm:
            self.last = ns
            self.pending.clear()
            return self.JUMP
        return self.OUTLIER

    def reset(self) -> None:
        self.last = None
        self.pending.clear()
