"""Streams on their own clocks: the coverage rule of a window, interpolation, measurement tracks, stamp gates.

A real flight stack publishes engine inputs, motion capture and IMU on independent clocks
(DESIGN 5a): commands at 50-500 Hz with +-2 ms jitter, motion capture at 100-360 Hz, IMU at
250-1000 Hz, no shared stamps, messages lost in bursts under load, and the odd stamp from the
future or the past, restarted publishers and clock jumps. Offline logs are on one time base but
drop the odd sample (NanoBench: single 20-30 ms steps). The live evaluator and the offline
evaluation score a window with the coverage rule and :func:`interpolate_at`; the live predictor
reads its measurements at each command from a :class:`MeasurementTrack` (the same interpolation
formula, :func:`lerp`); both nodes pass every stream's stamps through a :class:`StampGate` (one
rule, one confirm count). All pure logic (no rclpy), unit-tested without spinning a node.

Rows. The scored rows of a window are the engine-input stamps inside it (the predictors
answer at each input, so the prediction stamps are these stamps); a window is cut by time
with the shared :class:`~quad_modelling.core.windows.WindowClock`: a stamp t belongs to
window k when :math:`kW \\le t - t_0 + dt/2 < (k+1)W`, i.e. the window holds the stamps in
:math:`[t_0 + kW - dt/2,\\; t_0 + (k+1)W - dt/2)`.

Coverage rule (:func:`stream_coverage`, :data:`MIN_COVERAGE`, :data:`MAX_GAP_S`). For each
stream in a window of length W (engine inputs, motion capture, IMU, each model's predictions)
with received stamps :math:`t_1 < \\dots < t_n` inside the window's interval [a, b):

.. math::

    \\widehat{dt} = \\operatorname{median}\\{t_{i+1} - t_i \\;:\\; t_{i+1} - t_i \\ge \\bar{dt} / 2\\}, \\qquad
    N_{nom} = W / \\widehat{dt}, \\qquad c = n / N_{nom}, \\qquad
    g = \\max(t_1 - a,\\; \\max_i (t_{i+1} - t_i),\\; b - t_n)

(the stream's own nominal period, so a 500 Hz IMU and 100 Hz inputs are judged alike; the
median is robust while fewer than half the steps are lost; :math:`\\bar{dt}` the mean step: steps
shorter than half of it are a burst's, left out -- a link that delivers, or a stack that stamps on
receipt, two commands 0.1 ms apart every 20 ms has a median step of 0.1 ms or 20 ms by chance, and
read 1 % coverage with every command there). The window is scored when every
stream has :math:`c \\ge 0.95` and :math:`g \\le 50` ms; otherwise it is marked, the reason
naming each failing stream with its coverage and its longest gap (:meth:`StreamCoverage.describe`).
A uniform stream has c = 1 and g = dt (interior) or dt/2 (edges); one dropped sample gives
g = 2 dt. With :math:`\\widehat{dt}` from fewer than two stamps c = 0.

Interpolation (:func:`lerp`, the one formula; :func:`interpolate_at` many rows at once,
:meth:`MeasurementTrack.at` one time). Between the samples :math:`(t_a, y_a)`, :math:`(t_b, y_b)`
bracketing t, linear in time, column by column:

.. math::

    y(t) = y_a + (y_b - y_a) \\frac{t - t_a}{t_b - t_a}

with the quaternion columns (if any) a normalised lerp of the sign-aligned pair (:math:`q_b`
flipped when :math:`q_a \\cdot q_b < 0`, the shorter rotation; exact for the small rotations
between samples). A time that equals a sample stamp takes that sample unchanged, so on an aligned
replay (all streams share the stamps) the interpolated rows are the recorded rows bit for bit and
live equals offline exactly. A step longer than the stream's ``max_gap`` is never interpolated
through (DESIGN 4). Outside the bracketed range :func:`interpolate_at` holds the nearest sample
when it is at most :data:`MAX_GAP_S` away (the edge of a window whose neighbour was not received)
and is NaN otherwise (which the coverage rule has already marked); :meth:`MeasurementTrack.at`
returns the nearest sample within its ``tolerance`` (the anchor is newer than the last
motion-capture sample and the wait for the next one ran out), else None.

Stamp gate (:class:`StampGate`, :data:`CONFIRM`; both nodes' parameter ``max_stamp_step_s``).
A stream's stamps must increase: a stamp is *regular* when :math:`t_{last} < t \\le t_{last} +`
``max_step``. One publisher's header stamps increase and DDS keeps one writer's order (best
effort drops, it does not reorder), so a stamp at or before the last one is a duplicate or a
bad stamp, not a late sample. An irregular stamp (from the future, the past, or a duplicate)
is held as a suspect: a regular stamp after it shows it was a single bad stamp (it is dropped,
:attr:`StampGate.dropped`); :data:`CONFIRM` consecutive suspects that are regular among
themselves are a new time base -- a restarted publisher (stamps back to an earlier flight
time), a wall or simulated clock jump, the end of a silence longer than ``max_step`` -- and are
accepted (:attr:`Stamp.JUMPED`, the run handed back in :attr:`StampGate.confirmed`: the caller
resets its windows and buffers). A single stamp from the future therefore costs one sample,
not the flight.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from enum import Enum

import numpy as np

from quad_modelling.errors import DataError

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
        """``imu: 52.0 % of 2500 nominal samples (1300 received), longest gap 240 ms at 3.120 s into the window``; a
        stream with too few samples to tell its rate: ``motor_input: 1 sample received, too few to tell its rate``."""
        if self.nominal <= 0:
            return f"{self.stream}: {self.received} sample{'s' if self.received != 1 else ''} received, too few to tell its rate"
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
        dt = nominal_step(np.diff(stamps))
        nominal = length / dt if dt > 0 else 0.0
    return StreamCoverage(stream, len(stamps), nominal, float(steps[worst]) / 1e9, float(edges[worst] - start_ns) / 1e9)


LOST_STEP_RATIO = (0.15, 0.55)
"""Steps this fraction of the regular step :math:`\\widehat{dt}` are the stream's own period between lost samples
(:func:`nominal_step`): a burst's steps are far shorter (two commands 0.1 ms apart every 20 ms: 0.005), a jittered
step far longer."""

LOST_STEP_FRACTION = 0.1
"""Share of the steps that must lie in :data:`LOST_STEP_RATIO` for them to be the period (:func:`nominal_step`)."""

LOST_STEP_MULTIPLE_TOLERANCE = 0.15
"""... and the median distance of every step from a whole multiple of that period at most this [periods]: stamps
jittered by 25 % of the period have as many short steps (11 %) but their steps are no multiples (median 0.25)."""


def nominal_step(steps: np.ndarray) -> float:
    """A stream's nominal period from its steps (module doc, :math:`\\widehat{dt}`): the median of the steps at least
    half the mean step (a burst's short steps left out) -- unless at least :data:`LOST_STEP_FRACTION` of the steps
    are :data:`LOST_STEP_RATIO` of that and the steps whole multiples of their median: then samples were lost between
    regular ones and the period is those short steps' median (a 250 Hz IMU keeping 2 samples of every 5 has steps of 4 and 16 ms: it read "160 % of 125 nominal
    samples" and was scored; now 40 % of 500, marked)."""
    steps = np.asarray(steps, dtype=float)
    regular = float(np.median(steps[steps >= 0.5 * steps.mean()]))
    short = steps[(steps >= LOST_STEP_RATIO[0] * regular) & (steps <= LOST_STEP_RATIO[1] * regular)]
    if short.size < LOST_STEP_FRACTION * steps.size:
        return regular
    period = float(np.median(short))
    multiples = steps / period  # lost samples leave whole multiples of the period; stamp jitter leaves any ratio
    return period if np.median(np.abs(multiples - np.round(multiples))) <= LOST_STEP_MULTIPLE_TOLERANCE else regular


def coverage_reason(coverages: list[StreamCoverage]) -> str:
    """'' when every stream meets the rule; else the reason a window is marked, naming each failing stream."""
    failing = [c.describe() for c in coverages if not c.ok]
    if not failing:
        return ""
    return (f"coverage below the rule (>= {100 * MIN_COVERAGE:g} % of nominal samples, gaps <= {MAX_GAP_S * 1e3:g} ms): "
            + "; ".join(failing))


BATTERY_PAUSE_S = 2.0
"""Longest step [s] of a battery stream bridged without a note: battery monitors publish at 1-100 Hz (PX4
``battery_status`` 10 Hz, crazyswarm2's ``status`` 10 Hz), and a pack's voltage moves by millivolts in a second."""


def usable_voltages(volts) -> np.ndarray:
    """Which battery readings measure a pack: finite and above 0 V (a disconnected monitor or an unused PX4 battery
    instance reports 0 V). The one rule of the bag readers (:func:`battery_on_rows`, the ULog instance choice) and the
    live nodes (:func:`usable_voltage`)."""
    volts = np.asarray(volts, dtype=float)
    return np.isfinite(volts) & (volts > 0.0)


def usable_voltage(volts: float) -> bool:
    """:func:`usable_voltages` of one reading (a live message)."""
    return bool(usable_voltages(volts))


def battery_on_rows(stamps_s: np.ndarray, volts: np.ndarray, t: np.ndarray) -> tuple[np.ndarray | None, str | None]:
    """A battery stream (stamps [s], voltage [V]) on the rows ``t`` [s]: its usable readings (:func:`usable_voltage`)
    interpolated linearly, the first held before them and the last after them (a battery does not bound a flight:
    it is optional and slow), and a note of what was not measured -- readings skipped, a late start or early end
    longer than :data:`BATTERY_PAUSE_S`, pauses longer than it (with the longest) -- or None when the stream covers
    the rows. No usable reading: (None, the note), the flight is read without a voltage."""
    stamps_s, volts = np.asarray(stamps_s, dtype=float), np.asarray(volts, dtype=float)
    usable = usable_voltages(volts)
    skipped = int(len(volts) - usable.sum())
    said = f"{skipped} of {len(volts)} readings at or below 0 V or not finite skipped (a battery not connected)" if skipped else ""
    if not usable.any():
        return None, f"{said or 'no readings'}: no usable reading, the flight is read without a voltage"
    s, v = stamps_s[usable], volts[usable]
    parts = [said] if said else []
    if s[0] - t[0] > BATTERY_PAUSE_S:
        parts.append(f"starts {s[0] - t[0]:.1f} s after the first row (its first reading held before)")
    if t[-1] - s[-1] > BATTERY_PAUSE_S:
        parts.append(f"ends {t[-1] - s[-1]:.1f} s before the last row (its last reading held after)")
    steps = np.diff(s)
    inside = (s[1:] > t[0]) & (s[:-1] < t[-1])
    pauses = np.flatnonzero((steps > BATTERY_PAUSE_S) & inside)
    if len(pauses):
        worst = pauses[int(np.argmax(steps[pauses]))]
        parts.append(f"{len(pauses)} pause(s) longer than {BATTERY_PAUSE_S:g} s interpolated (longest {steps[worst]:.1f} s "
                     f"from {s[worst] - t[0]:.1f} s into the flight)")
    return np.interp(t, s, v), "; ".join(parts) or None


def lerp(y_a: np.ndarray, y_b: np.ndarray, fraction, quaternion: tuple[int, int] | None = None) -> np.ndarray:
    """The interpolation formula (module doc): :math:`y_a + (y_b - y_a) f` for samples ``y_a``, ``y_b`` (m,) or (r, m)
    at ``fraction`` f (a number, or (r, 1)); ``quaternion``: columns [start, stop) of a unit quaternion, taken from
    the sign-aligned pair and normalised. A new array; the inputs are not changed."""
    step = y_b - y_a
    if quaternion is not None:
        qs = slice(*quaternion)
        q_a, q_b = y_a[..., qs], y_b[..., qs]
        opposite = np.vecdot(q_a, q_b, keepdims=True) < 0.0
        if np.count_nonzero(opposite):  # take -q_b there (negation is exact)
            step[..., qs] = np.where(opposite, -q_b, q_b) - q_a
    y = y_a + step * fraction
    if quaternion is not None:
        q = y[..., qs]
        q /= np.sqrt(np.vecdot(q, q, keepdims=True))
    return y


def interpolate_at(stamps_ns: np.ndarray, values: np.ndarray, at_ns: np.ndarray, quaternion: tuple[int, int] | None = None,
                   max_gap_s: float = MAX_GAP_S, hold: bool = True) -> np.ndarray:
    """Samples (stamps_ns (n,) sorted unique [ns], values (n, m)) at the stamps ``at_ns`` (r,) -> (r, m) (module doc).

    :func:`lerp` between the two samples around a row, exact at sample stamps; ``quaternion``: columns [start, stop)
    of a unit quaternion; a row nearer than ``max_gap_s`` [s] outside the samples holds the nearest one (``hold``;
    else NaN: a truth must be bracketed); a row in a step longer than ``max_gap_s`` or farther outside is NaN.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    values = np.asarray(values, dtype=float)
    values = values if values.ndim == 2 else values.reshape(len(stamps), -1)  # (0, m): none of m numbers
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
        y = lerp(values[i0], values[i1], ((at[inner] - t0) / step)[:, None], quaternion)
        y[step > max_gap_ns] = np.nan
        out[inner] = y
    return out


class MeasurementTrack:
    """A bounded, time-ordered buffer of one measured stream's samples (module docstring).

    ``width``: numbers per sample; ``quaternion``: the columns (start, stop) of an xyzw quaternion
    inside a sample, or None; ``max_gap_ns``: the longest gap interpolated through; ``capacity``:
    samples kept (the oldest go first).
    """

    def __init__(self, width: int, max_gap_ns: int, capacity: int = 4096, quaternion: tuple[int, int] | None = None):
        self.width = width
        self.max_gap_ns = int(max_gap_ns)
        self.capacity = capacity
        self.quaternion = quaternion
        self.stamps: list[int] = []
        self.values: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def latest(self) -> int | None:
        return self.stamps[-1] if self.stamps else None

    def add(self, ns: int, values) -> bool:
        """Store a sample; False (not stored) for a stamp already held. Older stamps are inserted in order."""
        i = bisect.bisect_left(self.stamps, ns)
        if i < len(self.stamps) and self.stamps[i] == ns:
            return False
        self.stamps.insert(i, ns)
        self.values.insert(i, np.asarray(values, dtype=float).reshape(self.width))
        if len(self.stamps) > self.capacity:
            drop = len(self.stamps) - self.capacity
            del self.stamps[:drop], self.values[:drop]
        return True

    def clear(self) -> None:
        self.stamps, self.values = [], []

    def covers(self, ns: int) -> bool:
        """True when no later sample can change :meth:`at` (ns): a sample at or after ``ns`` is held."""
        return bool(self.stamps) and self.stamps[-1] >= ns

    def at(self, ns: int, tolerance_ns: int) -> np.ndarray | None:
        """The stream's value at ``ns`` (module docstring: exact, interpolated, nearest within tolerance) or None."""
        stamps = self.stamps
        i = bisect.bisect_left(stamps, ns)
        if i < len(stamps) and stamps[i] == ns:
            return self.values[i]
        before, after = i - 1, i
        if before >= 0 and after < len(stamps) and stamps[after] - stamps[before] <= self.max_gap_ns:
            return self._between(before, after, ns)
        nearest = [j for j in (before, after) if 0 <= j < len(stamps) and abs(stamps[j] - ns) <= tolerance_ns]
        if not nearest:
            return None
        return self.values[min(nearest, key=lambda j: abs(stamps[j] - ns))]

    def _between(self, before: int, after: int, ns: int) -> np.ndarray:
        ta, tb = self.stamps[before], self.stamps[after]
        return lerp(self.values[before], self.values[after], (ns - ta) / (tb - ta), self.quaternion)


CONFIRM = 3
"""Consecutive mutually regular irregular stamps that make a new time base (restart, clock jump)."""

MAX_STAMP_STEP_S = 1.0
"""Longest regular step of a stream's stamps [s] (:class:`StampGate`): the nodes' ``max_stamp_step_s`` default and
the offline topic-map reader's rule."""


class Stamp(Enum):
    """What :meth:`StampGate.admit` decided about a stamp."""

    ACCEPTED = "accepted"
    """Regular: use the sample."""
    SUSPECT = "suspect"
    """Irregular (future, past or duplicate): held, not used (yet)."""
    JUMPED = "jumped"
    """Confirmed new time base: use the sample and reset what depends on the old one."""


class StampGate:
    """In-order stamps [ns] of one stream with outlier rejection (module docstring).

    ``max_step_ns``: the longest regular step (a longer silence is a gap, its end a jump).
    After each :meth:`admit`, :attr:`dropped` holds the suspects found to be single bad stamps
    (for the caller's warning).
    """

    def __init__(self, max_step_ns: int):
        if max_step_ns <= 0:
            raise ValueError(f"stamp gate: max_step_ns must be positive, got {max_step_ns}")
        self.max_step_ns = int(max_step_ns)
        self.last: int | None = None
        self.suspects: list[tuple[int, object]] = []
        self.dropped: list[int] = []
        self.confirmed: list = []

    def _regular(self, previous: int, ns: int) -> bool:
        return previous < ns <= previous + self.max_step_ns

    def admit(self, ns: int, payload=None) -> Stamp:
        """Decide about the next stamp (module docstring). ``payload``: the sample, handed back in
        :attr:`confirmed` (oldest first, this one last) when its run of suspects makes a new time base."""
        self.dropped, self.confirmed = [], []
        if self.last is None:
            self.last = ns
            return Stamp.ACCEPTED
        if self._regular(self.last, ns):
            self.dropped, self.suspects = [s for s, _ in self.suspects], []
            self.last = ns
            return Stamp.ACCEPTED
        if self.suspects and not self._regular(self.suspects[-1][0], ns):
            self.dropped, self.suspects = [s for s, _ in self.suspects], []
        self.suspects.append((ns, payload))
        if len(self.suspects) >= CONFIRM:
            self.confirmed = [p for _, p in self.suspects]
            self.last, self.suspects = ns, []
            return Stamp.JUMPED
        return Stamp.SUSPECT

    def reset(self) -> None:
        self.last, self.suspects, self.dropped, self.confirmed = None, [], [], []


SAME_CLOCK_OVERLAP = 0.5
"""Fraction of the shorter span two streams on one clock overlap at least (a late-discovered topic is fine)."""


def check_one_clock(spans: dict[str, tuple[int, int]], base: str, where: str) -> None:
    """DataError when a stream's stamps [ns] (``spans``: topic -> first, last) do not overlap the base stream's for at
    least :data:`SAME_CLOCK_OVERLAP` of the shorter span: stamps from another clock (the topic-map reader's rule,
    :mod:`quad_modelling.io.mapped_flight`)."""
    if base not in spans:
        return
    b0, b1 = spans[base]
    for topic, (s0, s1) in spans.items():
        overlap = min(b1, s1) - max(b0, s0)
        shorter = min(b1 - b0, s1 - s0)
        if overlap < SAME_CLOCK_OVERLAP * shorter or (shorter == 0 and not b0 <= s0 <= b1 and not s0 <= b0 <= s1):
            raise DataError(
                f"{where}: topic {topic} stamps span {s0 / 1e9:.3f}..{s1 / 1e9:.3f} s, topic {base} {b0 / 1e9:.3f}..{b1 / 1e9:.3f} s: "
                "stamps from another clock; stamp every topic of the map on one clock (e.g. header.stamp everywhere)")
