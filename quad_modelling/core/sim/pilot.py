"""The seeded pilot script of the truth simulator: take-off, manoeuvres, landing.

Phases (times in s, T = flight duration), shaped like the thesis's flights
(take-off within the first 30 s, landing within the last 22 s, manoeuvres
between, thesis 5.1):

=============  ==========================================================
motors off     0 <= t < t_arm
idle           t_arm <= t < t_lift (armed, rotors at idle speed)
flying         t_lift <= t < t_cut: PID stabiliser on; the height reference
               climbs from the rest height to the hover height over
               ``climb_time``, manoeuvres run in [manoeuvre_start,
               manoeuvre_end], the descent starts at ``land_start``
idle, off      t_cut <= t < t_off, t >= t_off (on the ground)
=============  ==========================================================

Manoeuvres (:class:`Manoeuvre`) are drawn from a seeded generator as a flight
test card: rounds (:data:`CARD`) in which every class of :data:`CHANNELS` (roll,
pitch, yaw, throttle, low_hover) comes once and turns twice, in random order, so
every flight long enough for one round has each class (a low pass near the
ground, turns...).
Shape (step, doublet, sweep), size, duration and frequency are drawn per
manoeuvre; manoeuvres are separated by 1.5-5 s of hover. Each adds to its
channel's reference: roll/pitch angles [rad], yaw angle [rad], height [m].
Stick ramps take :data:`STICK_RAMP` s; sweeps are linear chirps with 0.5 s
cosine tapers.

A *turn* is a combined manoeuvre, as pilots fly them: the yaw stick held at a
rate r (``PilotParams.turn_rate``, 1-2 rad/s on the LinkQuad) for 5-10 s,
entered and left over :data:`TURN_RAMP` s (a yaw reference of shape ``turn``,
the integral of that rate profile, so the heading ends turned by r (T - ramp)),
with roll and pitch doublets flown while it yaws. Only such simultaneous yaw
and roll/pitch rates excite the body gyroscopic torques
((I_yy - I_zz) q r / I_xx ...), which one-axis manoeuvres leave at noise level.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import signal

from quad_modelling.core.sim.params import SimParams
from quad_modelling.errors import ConfigError

CHANNELS = ("roll", "pitch", "yaw", "throttle", "low_hover", "turn")
"""Manoeuvre classes. ``turn`` writes yaw, roll and pitch."""
CARD = ("roll", "pitch", "yaw", "throttle", "low_hover", "turn", "turn")
"""One round of the test card: every class once, turns twice (they are the only manoeuvres that
excite the coupled rotational dynamics)."""
SHAPES = ("step", "doublet", "sweep")
SHAPE_WEIGHTS = (0.4, 0.4, 0.2)
STICK_RAMP = 0.1
"""Time a pilot takes to move a stick to a new position [s]."""
TURN_RAMP = 0.5
"""Time to enter (and leave) a turn's yaw rate, cosine-shaped [s]."""
TURN_DURATION = (5.0, 10.0)
"""Range of a turn's length, ramps included [s]."""
LOW_PASS_RAMP = 2.0
"""Time a ``smooth_step`` low pass takes to go down to its height, and to come back up [s]: a cosine ramp whose rate
and acceleration a stabiliser with ``height_feedforward`` feeds forward (:meth:`PilotScript.height_feedforward`):
at most 0.33 m/s and 0.52 m/s² on the Crazyflie's deepest pass (0.42 m). Without it (the LinkQuad) a low pass is a ``step``
whose 1 s linear ramps the loop follows as it can."""
STICK_NOISE_TIME = 0.5
"""Correlation time of the pilot's small corrections [s]."""
MIN_DURATION = 5.0
"""Shortest simulated flight [s]: arm, lift, climb and land."""

MAX_DURATION = 3600.0
"""Longest simulated flight [s]: an hour (a battery's worth many times over) takes minutes to fly and
about 100 MB of log; a longer or infinite duration is refused, never started."""

PHASE_OFF, PHASE_IDLE, PHASE_FLYING = 0, 1, 2


def _ramp(t: np.ndarray, start: float, length: float) -> np.ndarray:
    return np.clip((t - start) / length, 0.0, 1.0)


def _smooth_ramp(t: np.ndarray, start: float, length: float) -> np.ndarray:
    return 0.5 - 0.5 * np.cos(np.pi * _ramp(t, start, length))


def _smooth_ramp_derivatives(t: np.ndarray, start: float, length: float) -> tuple[np.ndarray, np.ndarray]:
    """First and second time derivatives of :func:`_smooth_ramp` [1/s, 1/s²]: (pi / 2L) sin(pi x / L) and
    (pi² / 2L²) cos(pi x / L) on the ramp (x = t - start), 0 off it."""
    x = np.asarray(t) - start
    on = (x > 0.0) & (x < length)
    phase = np.pi * np.clip(x, 0.0, length) / length
    return np.where(on, 0.5 * np.pi / length * np.sin(phase), 0.0), np.where(on, 0.5 * (np.pi / length) ** 2 * np.cos(phase), 0.0)


def _smooth_ramp_integral(t: np.ndarray, start: float, length: float) -> np.ndarray:
    """Integral from ``start`` to t of :func:`_smooth_ramp` [s]: 0 before, x/2 - L sin(pi x/L)/(2 pi)
    on the ramp (x = t - start), x - L/2 after it."""
    x = np.clip(t - start, 0.0, None)
    on_ramp = 0.5 * np.minimum(x, length) - length / (2.0 * np.pi) * np.sin(np.pi * np.minimum(x, length) / length)
    return on_ramp + np.clip(x - length, 0.0, None)


@dataclass(frozen=True)
class Manoeuvre:
    """One pilot input: ``amplitude`` [rad or m] on ``channel`` from ``start`` for ``duration`` [s]."""

    channel: str
    shape: str  # step, doublet, sweep; ``turn`` (yaw only): ``amplitude`` is a yaw rate [rad/s]; ``smooth_step`` (low passes)
    start: float
    duration: float
    amplitude: float
    f0: float = 0.0  # sweep start frequency [Hz]
    f1: float = 0.0  # sweep end frequency [Hz]

    def smooth_ramps(self) -> list[tuple[float, float, float]]:
        """(size, start, length) [m, s, s] of the cosine ramps a ``smooth_step`` is made of (down, then back up); none
        for another shape. The one list its value and its fed-forward derivatives (:meth:`PilotScript.height_feedforward`) read."""
        if self.shape != "smooth_step":
            return []
        return [(self.amplitude, self.start, LOW_PASS_RAMP), (-self.amplitude, self.start + self.duration - LOW_PASS_RAMP, LOW_PASS_RAMP)]

    def value(self, t: np.ndarray) -> np.ndarray:
        """The reference offset at times ``t``."""
        t0, dur, amp = self.start, self.duration, self.amplitude
        if self.shape == "smooth_step":  # a low pass down and back up along cosine ramps (fed forward: height_feedforward)
            return sum(size * _smooth_ramp(t, start, length) for size, start, length in self.smooth_ramps())
        ramp = 1.0 if self.channel == "low_hover" else STICK_RAMP
        if self.shape == "step":
            return amp * (_ramp(t, t0, ramp) - _ramp(t, t0 + dur - ramp, ramp))
        if self.shape == "turn":  # yaw reference = integral of a rate held between two cosine ramps
            return amp * (_smooth_ramp_integral(t, t0, TURN_RAMP) - _smooth_ramp_integral(t, t0 + dur - TURN_RAMP, TURN_RAMP))
        if self.shape == "doublet":
            half = dur / 2
            return amp * (_ramp(t, t0, STICK_RAMP) - 2 * _ramp(t, t0 + half - STICK_RAMP / 2, STICK_RAMP) + _ramp(t, t0 + dur - STICK_RAMP, STICK_RAMP))
        tau = np.clip(t - t0, 0.0, dur)
        phase = self.f0 * tau + (self.f1 - self.f0) * tau**2 / (2 * dur)
        taper = _smooth_ramp(t, t0, 0.5) * (1.0 - _smooth_ramp(t, t0 + dur - 0.5, 0.5))
        return amp * np.sin(2 * np.pi * phase) * taper


@dataclass(frozen=True)
class PilotScript:
    """Phase times [s] and the manoeuvre list of one flight (see module docstring)."""

    duration: float
    t_arm: float
    t_lift: float
    manoeuvre_start: float
    manoeuvre_end: float
    land_start: float
    t_cut: float
    t_off: float
    rest_height: float
    hover_height: float
    climb_time: float
    descent_time: float
    manoeuvres: tuple[Manoeuvre, ...]

    def phases(self, t: np.ndarray) -> np.ndarray:
        """PHASE_OFF / PHASE_IDLE / PHASE_FLYING per time."""
        phase = np.full(t.shape, PHASE_OFF, dtype=np.int8)
        phase[(t >= self.t_arm) & (t < self.t_lift)] = PHASE_IDLE
        phase[(t >= self.t_lift) & (t < self.t_cut)] = PHASE_FLYING
        phase[(t >= self.t_cut) & (t < self.t_off)] = PHASE_IDLE
        return phase

    @property
    def touchdown_height(self) -> float:
        """Where the descent's height reference ends [m]: below the ground, so the gear carries the weight."""
        return self.rest_height - 0.1

    def phase_ramps(self) -> list[tuple[float, float, float]]:
        """(size, start, length) [m, s, s] of the height reference's climb to the hover height and descent to the
        touchdown height: cosine ramps (:meth:`references`, :meth:`height_feedforward`)."""
        return [(self.hover_height - self.rest_height, self.t_lift, self.climb_time),
                (self.touchdown_height - self.hover_height, self.land_start, self.descent_time)]

    def references(self, t: np.ndarray) -> np.ndarray:
        """(N, 4) references: roll [rad], pitch [rad], yaw [rad], CG height above ground [m]."""
        refs = np.zeros((len(t), 4))
        refs[:, 3] = self.rest_height
        for size, start, length in self.phase_ramps():  # the climb, then the descent
            refs[:, 3] += size * _smooth_ramp(t, start, length)
        column = {"roll": 0, "pitch": 1, "yaw": 2, "throttle": 3, "low_hover": 3}
        for manoeuvre in self.manoeuvres:
            refs[:, column[manoeuvre.channel]] += manoeuvre.value(t)
        return refs

    def height_feedforward(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((N,) rate [m/s], (N,) acceleration [m/s²]), both up, of the smooth height references at times ``t``: the
        climb, the descent and the ``smooth_step`` low passes (a stabiliser with ``height_feedforward`` feeds them
        forward, :mod:`~quad_modelling.core.sim.control`);
        not the throttle manoeuvres, stick steps a pilot flies without (their rate would kick the thrust)."""
        rate, acceleration = np.zeros(len(t)), np.zeros(len(t))
        for size, start, length in self.phase_ramps() + [r for m in self.manoeuvres for r in m.smooth_ramps()]:
            first, second = _smooth_ramp_derivatives(t, start, length)
            rate += size * first
            acceleration += size * second
        return rate, acceleration

    def short_flight(self) -> str | None:
        """Why this flight is too short for its script, or None: the descent starts (``land_start``, the last
        max(8 s, 10 %) of the flight) before the vehicle lifts or before its climb to the hover height ends."""
        climbed = self.t_lift + self.climb_time
        if self.land_start >= climbed:
            return None
        enough = self.duration + climbed - self.land_start
        what = "never leaves the ground" if self.land_start < self.t_lift else "lands before it reaches the hover height"
        return (f"a {self.duration:g} s flight {what} (its descent starts at {self.land_start:g} s, the climb ends at "
                f"{climbed:g} s): fly at least {enough:g} s for a take-off, a hover and a landing")

    def to_notes(self) -> dict:
        """JSON-ready description (phase times and manoeuvres)."""
        out = {k: v for k, v in asdict(self).items() if k != "manoeuvres"}
        out["manoeuvres"] = [asdict(m) for m in self.manoeuvres]
        return out


def check_duration(duration: float) -> None:
    """ConfigError unless a simulated flight of ``duration`` [s] can be flown (:data:`MIN_DURATION`..:data:`MAX_DURATION`)."""
    if not MIN_DURATION <= duration <= MAX_DURATION:
        raise ConfigError(f"simulation duration must be at least {MIN_DURATION:g} s and at most {MAX_DURATION:g} s, got {duration:g}")


def make_pilot_script(params: SimParams, duration: float, rng: np.random.Generator) -> PilotScript:
    """Draw one flight's script; same generator state -> same script."""
    check_duration(duration)
    pilot = params.pilot
    t_arm, t_lift = 1.0, 2.0
    hovering = t_lift + pilot.climb_time + 3.0
    manoeuvre_start = min(30.0, max(hovering, duration * 30.0 / 220.0))
    land_start = duration - min(20.0, max(8.0, 0.1 * duration))
    manoeuvre_end = land_start - 2.0
    t_cut = land_start + pilot.descent_time + 2.0
    t_off = min(t_cut + 3.0, duration - 0.5)
    unknown = [c for c in pilot.leading if c not in CHANNELS]
    if unknown:
        raise ConfigError(f"pilot.leading: {unknown[0]!r} is not a manoeuvre class; known: {', '.join(CHANNELS)}")
    manoeuvres: list[Manoeuvre] = []
    t = manoeuvre_start + rng.uniform(0.5, 2.0)
    card: list[str] = list(reversed(pilot.leading))  # flown first (popped from the end), then the random rounds
    while True:
        if not card:  # a new round of the test card: every class once, in random order
            card = [str(c) for c in rng.permutation(CARD)]
        drawn = _draw(params, rng, t, card.pop())
        end = max(m.start + m.duration for m in drawn)
        if end > manoeuvre_end:
            break
        manoeuvres.extend(drawn)
        t = end + rng.uniform(1.5, 5.0)
    return PilotScript(
        duration=float(duration), t_arm=t_arm, t_lift=t_lift, manoeuvre_start=manoeuvre_start,
        manoeuvre_end=manoeuvre_end, land_start=land_start, t_cut=t_cut, t_off=t_off,
        rest_height=params.rest_height, hover_height=pilot.hover_height, climb_time=pilot.climb_time,
        descent_time=pilot.descent_time, manoeuvres=tuple(manoeuvres),
    )


def _draw(params: SimParams, rng: np.random.Generator, start: float, channel: str) -> list[Manoeuvre]:
    """One manoeuvre of class ``channel`` from ``start`` (a turn: its yaw part and its doublets)."""
    pilot = params.pilot
    if channel == "turn":
        return _draw_turn(params, rng, start)
    if channel == "low_hover":  # along the references a stabiliser feeding them forward follows (LOW_PASS_RAMP)
        shape = "smooth_step" if params.control.height_feedforward else "step"
    else:
        shape = str(rng.choice(SHAPES, p=SHAPE_WEIGHTS))
    sign = 1.0 if rng.random() < 0.5 else -1.0
    f0 = f1 = 0.0
    if channel in ("roll", "pitch"):
        if shape == "sweep":
            amplitude, duration, f0, f1 = rng.uniform(*pilot.tilt_sweep), rng.uniform(5.0, 10.0), 0.2, rng.uniform(1.0, 2.5)
        else:
            amplitude = sign * rng.uniform(*pilot.tilt_step)
            duration = rng.uniform(0.3, 1.2) if shape == "step" else rng.uniform(0.5, 2.0)
    elif channel == "yaw":
        if shape == "sweep":
            amplitude, duration, f0, f1 = rng.uniform(*pilot.yaw_sweep), rng.uniform(6.0, 12.0), 0.1, rng.uniform(0.4, 1.0)
        else:
            amplitude = sign * rng.uniform(*pilot.yaw_step) * (1.0 if shape == "step" else 0.5)
            duration = rng.uniform(2.0, 6.0) if shape == "step" else rng.uniform(1.5, 4.0)
    elif channel == "throttle":
        if shape == "sweep":
            amplitude, duration, f0, f1 = 0.5 * rng.uniform(*pilot.height_step), rng.uniform(6.0, 12.0), 0.1, rng.uniform(0.5, 1.5)
        else:
            amplitude, duration = sign * rng.uniform(*pilot.height_step), rng.uniform(2.0, 5.0)
    else:  # low_hover: a pass close to the ground
        amplitude, duration = rng.uniform(*pilot.low_hover) - pilot.hover_height, rng.uniform(5.0, 9.0)
    return [Manoeuvre(channel, shape, round(float(start), 3), float(duration), float(amplitude), float(f0), float(f1))]


def _draw_turn(params: SimParams, rng: np.random.Generator, start: float) -> list[Manoeuvre]:
    """A turn (module docstring): yaw rate ``turn_rate`` [rad/s] of either sign for TURN_DURATION s, and
    roll/pitch doublets (``tilt_step`` amplitudes, 0.5-2 s, 0.2-1 s apart) while the rate is held."""
    pilot = params.pilot
    start = round(float(start), 3)
    duration = float(rng.uniform(*TURN_DURATION))
    rate = (1.0 if rng.random() < 0.5 else -1.0) * float(rng.uniform(*pilot.turn_rate))
    out = [Manoeuvre("yaw", "turn", start, duration, rate)]
    t = start + TURN_RAMP + float(rng.uniform(0.0, 0.5))
    while True:
        axis = "roll" if rng.random() < 0.5 else "pitch"
        amplitude = (1.0 if rng.random() < 0.5 else -1.0) * float(rng.uniform(*pilot.tilt_step))
        length = float(rng.uniform(0.5, 2.0))
        if t + length > start + duration - TURN_RAMP:
            break
        out.append(Manoeuvre(axis, "doublet", round(t, 3), length, amplitude))
        t += length + float(rng.uniform(0.2, 1.0))
    return out


def stick_noise(n: int, rate: float, sigmas: tuple[float, float, float], rng: np.random.Generator) -> np.ndarray:
    """(n, 4) small pilot corrections (roll, pitch, yaw, height): first-order Gauss-Markov
    processes with correlation time STICK_NOISE_TIME and standard deviations ``sigmas``
    (roll and pitch share the first)."""
    alpha = float(np.exp(-1.0 / (rate * STICK_NOISE_TIME)))
    white = rng.standard_normal((n, 4)) * np.sqrt(1.0 - alpha**2)
    noise = signal.lfilter([1.0], [1.0, -alpha], white, axis=0)
    return noise * np.array([sigmas[0], sigmas[0], sigmas[1], sigmas[2]])
