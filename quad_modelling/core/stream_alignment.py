"""Streams on their own clocks: measurements at an anchor time, and stamps a real link delivers.

A real flight stack publishes each stream on its own clock (DESIGN 5a): commands at 50-500 Hz with
+-2 ms jitter, motion capture at 100-360 Hz, IMU at 250-1000 Hz, no two stamps equal across streams.
A live predictor anchors a window at a command's stamp, so it needs each measurement *at that
time*; and a link delivers the odd stamp from the future or the past, restarted publishers and
clock jumps. Both are pure logic here (no rclpy), unit-tested without spinning a node.

:class:`MeasurementTrack` -- one measured stream, value at any time t [ns]:

* an exact stamp returns the stored sample as it is (bit-equal: an aligned replay gives the
  offline numbers);
* between the two samples bracketing t, ``t_a <= t <= t_b`` with ``t_b - t_a <= max_gap``:
  linear interpolation

  .. math::

      y(t) = y_a + \\frac{t - t_a}{t_b - t_a} (y_b - y_a)

  with the quaternion columns (if any) interpolated as a normalised lerp of the sign-aligned
  pair (``q_b`` flipped when :math:`q_a \\cdot q_b < 0`), i.e. the shorter rotation; a gap longer
  than ``max_gap`` is never interpolated through (DESIGN 4);
* otherwise the nearest sample within ``tolerance`` of t (e.g. the anchor is newer than the last
  motion-capture sample and the wait for the next one ran out), else None.

:class:`StampGate` -- accepts a stream's stamps in order and tells a single bad stamp from a real
jump. A stamp is *regular* when ``last < t <= last + max_step``; an irregular one (from the future,
the past, or a duplicate) is held as a suspect: a regular stamp after it shows it was a single bad
stamp (it is dropped, :data:`DROPPED`); :data:`CONFIRM` consecutive suspects that are regular
among themselves are a new time base -- a restarted publisher (stamps back to an earlier flight
time), a wall or simulated clock jump -- and are accepted (:data:`JUMPED`: the caller resets its
windows and buffers). A single stamp from the future therefore costs one sample, not the flight.
"""

from __future__ import annotations

import bisect
from enum import Enum

import numpy as np

CONFIRM = 3
"""Consecutive mutually regular irregular stamps that make a new time base (restart, clock jump)."""


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
        ya, yb = self.values[before], self.values[after]
        if self.quaternion is not None:
            q0, q1 = self.quaternion
            if float(np.dot(ya[q0:q1], yb[q0:q1])) < 0.0:
                yb = yb.copy()
                yb[q0:q1] = -yb[q0:q1]
        fraction = (ns - ta) / (tb - ta)
        y = ya + fraction * (yb - ya)
        if self.quaternion is not None:
            q0, q1 = self.quaternion
            y[q0:q1] /= np.linalg.norm(y[q0:q1])
        return y
