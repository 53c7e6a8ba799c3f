"""Preprocessing of flight logs for modelling and evaluation (thesis 2.1-2.2).

Best measurement per variable (thesis 2.2: "the Vicon measurements were used for all entities but position
accelerations, angle rotation rates and angle rotation accelerations"):

==============  ==============================================================
variables       best measurement
==============  ==============================================================
pos, vel        motion capture ``pos_n``, ``vel_n`` (N = NED)
acc             onboard accelerometer rotated to N, gravity added:
                :math:`a_N = R_{NB}(\\phi,\\theta,\\psi)\\, f_B + g\\, e_z`
angles          motion capture ``euler`` (yaw unwrapped)
rates           onboard gyros ``gyro_b`` (p, q, r)
angular acc     gyros differentiated with a Savitzky-Golay filter
==============  ==============================================================

A flight without an accelerometer or gyro (``acc_b``/``gyro_b`` None, e.g. a
motion-capture-only log) has no best measurement of the variables that need it:
:func:`measured_variables` gives NaN there and :func:`unmeasured_variables` names
the sensor (:data:`NEEDS`); the evaluation marks those variables instead of
scoring them. A model's warm start needs a state, not a score:
:func:`state_measurement` fills missing rates from the motion-capture attitude.

The accelerometer measures specific force :math:`f_B = R^T (a_N - g e_z)` in
body FRD (at rest, level: :math:`f_B = (0, 0, -g)`), hence the formula above.

Trimming (thesis 2.2): every signal has its trim value, the mean over a stable
interval, subtracted -- the first ``trim_s`` = 1 s of the window. Engine
inputs of windows longer than ``detrend_above_s`` = 50 s have their linear
trend (battery drain, thesis Fig 2.2/2.3) removed instead, with
:func:`scipy.signal.detrend`.

Smoothing before errors (thesis 5.1: "smoothened to remove the impact from
white noise"): a zero-phase Butterworth low-pass (:func:`scipy.signal.butter`
order :data:`SMOOTH_ORDER`, cutoff :data:`SMOOTH_CUTOFF_HZ`, applied with
:func:`scipy.signal.filtfilt`), the same on measurement and prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from quad_modelling.core import frames
from quad_modelling.core.flight_log import SENSORS, FlightLog
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError, DataError

SMOOTH_CUTOFF_HZ = 5.0
"""Cutoff of the error smoothing low-pass [Hz]: quadrotor rigid-body motion of
interest lies below ~5 Hz; rotor/frame vibration and sensor noise above it."""

SMOOTH_ORDER = 2
"""Order of the Butterworth smoothing filter (applied forward and backward: 4th-order magnitude)."""

DERIVATIVE_WINDOW_S = 0.11
"""Savitzky-Golay window for differentiating gyros [s] (11 samples at 100 Hz)."""

DERIVATIVE_POLYORDER = 2
"""Savitzky-Golay polynomial order for differentiating gyros."""


@dataclass(frozen=True)
class TrimConfig:
    """How windows are trimmed (thesis 2.2; DESIGN 7).

    trim_s: length of the stable interval at the window start [s] whose mean is
        the trim value of every signal (thesis: the first second).
    detrend_above_s: windows longer than this [s] get their engine inputs
        linearly detrended instead of mean-trimmed (thesis: > 50 s).
    """

    trim_s: float = 1.0
    detrend_above_s: float = 50.0

    def trim_samples(self, window: FlightLog) -> int:
        """Number of rows of the stable interval (at least 1, at most the window)."""
        return int(np.clip(round(self.trim_s * window.sample_rate), 1, len(window)))


NEEDS: dict[str, str] = {
    **{name: "acc_b" for name in ("acc_x", "acc_y", "acc_z")},
    **{name: "gyro_b" for name in ("roll_rate", "pitch_rate", "yaw_rate", "roll_acc", "pitch_acc", "yaw_acc")},
}
"""Variables whose best measurement comes from an optional field: variable -> FlightLog field."""


def unmeasured_variables(log: FlightLog) -> dict[str, str]:
    """Variables ``log`` cannot measure -> the sensor they need (``{"roll_rate": "gyro", ...}``), VARIABLES order."""
    return {name: SENSORS[field] for name, field in NEEDS.items() if getattr(log, field) is None}


MAX_INTERPOLATION_GAP_S = 0.5
"""Longest gap [s] of a measurement stream that a reader interpolates through onto the command time base
(PX4: five periods of the slowest kinematic topic at 10 Hz). A longer motion-capture or IMU dropout is
marked (:func:`mark_measurement_gaps`), never bridged by a straight line that something then uses."""

GAP_MARK = "marked as a measurement gap"
"""The phrase of every gap warning in ``meta.notes['warnings']`` (a re-read replaces them: gaps are found in the data)."""


TIME_BASE_HOLE = "time base"
"""The ``topic`` of a measurement gap :func:`resample_uniform` marks: a hole in every column of the log."""

FIELDS_OF_A_ROW = ("u", "pos_n", "vel_n", "euler", "acc_b", "gyro_b")
"""The FlightLog fields a row holds (a hole in the time base is a gap of each)."""


@dataclass(frozen=True)
class MeasurementGap:
    """A dropout of one measurement stream: no message of ``topic`` strictly between ``start_s`` and ``end_s``
    (the stamps of the real samples around it, in the FlightLog's own time ``t`` [s]); ``fields`` are the
    FlightLog fields that stream feeds (interpolated inside the gap only so the log stays finite)."""

    topic: str
    start_s: float
    end_s: float
    fields: tuple[str, ...]

    def to_note(self) -> dict:
        return {"topic": self.topic, "start_s": self.start_s, "end_s": self.end_s, "fields": list(self.fields)}


def interpolation_gaps(source_t: np.ndarray, t: np.ndarray, max_gap_s: float = MAX_INTERPOLATION_GAP_S) -> list[tuple[float, float]]:
    """(start, end) [s, the time of ``source_t``] of each step between consecutive stream stamps ``source_t`` longer
    than ``max_gap_s`` with a time of ``t`` strictly inside it (a row that would be interpolated through it)."""
    source_t, t = np.asarray(source_t, dtype=float), np.asarray(t, dtype=float)
    if len(source_t) < 2 or len(t) == 0:
        return []
    long = np.flatnonzero(np.diff(source_t) > max_gap_s)
    starts, ends = source_t[long], source_t[long + 1]
    inside = np.searchsorted(t, ends, side="left") > np.searchsorted(t, starts, side="right")
    return [(float(a), float(b)) for a, b in zip(starts[inside], ends[inside])]


def gap_warning(where: str, gap: MeasurementGap, t0: float, max_gap_s: float = MAX_INTERPOLATION_GAP_S) -> str:
    """The one-line warning of a marked gap: file, topic, length and time (seconds into the flight, from ``t0``)."""
    return (f"{where}: topic {gap.topic} has no message for {gap.end_s - gap.start_s:.2f} s "
            f"(t={gap.start_s - t0:.3f}..{gap.end_s - t0:.3f} s into the flight), longer than {max_gap_s:.3g} s: "
            f"{GAP_MARK}, not interpolated through; windows and training segments overlapping it are left out")


def mark_measurement_gaps(log: FlightLog, gaps: list[MeasurementGap], max_gap_s: float = MAX_INTERPOLATION_GAP_S) -> None:
    """Record ``gaps`` in ``log.meta.notes['measurement_gaps']`` with one warning each (replacing the gaps and gap
    warnings the notes carried: a reader finds them again in the data, e.g. a bag written from a marked log).

    The window clock (:mod:`quad_modelling.core.windows`) leaves out every window and training segment
    with a row strictly inside a marked gap.
    """
    notes = log.meta.notes
    if not gaps and "measurement_gaps" not in notes and not gap_warnings(log):
        return
    kept = [w for w in notes.get("warnings", []) if not (isinstance(w, str) and GAP_MARK in w)]
    notes.pop("measurement_gaps", None)
    notes.pop("gap_rule_s", None)
    notes.pop("warnings", None)
    if kept:
        notes["warnings"] = kept
    gaps = sorted(gaps, key=lambda g: (g.start_s, g.topic))
    if gaps:
        notes["measurement_gaps"] = [gap.to_note() for gap in gaps]
        notes["gap_rule_s"] = float(max_gap_s)  # the rule they were found by: a bag written from the log re-finds them by it
        for gap in gaps:
            log.warn(gap_warning(log.meta.source, gap, float(log.t[0]), max_gap_s))


def add_measurement_gaps(log: FlightLog, gaps: list[MeasurementGap], max_gap_s: float) -> None:
    """Add ``gaps``, found by the rule ``max_gap_s`` [s], to those ``log`` marks (:func:`mark_measurement_gaps`), with one
    warning each by that rule; the gaps marked before keep their warnings, worded by the rule that found them (a
    reader's 0.5 s), so each hole is said once, by the rule that marked it. ``gap_rule_s`` becomes the finer rule (a bag
    written from the log re-finds every gap by it)."""
    if not gaps:
        return
    notes, known = log.meta.notes, marked_gaps(log)
    notes["gap_rule_s"] = float(min(recorded_gap_rule(notes), max_gap_s) if known else max_gap_s)
    notes["measurement_gaps"] = [gap.to_note() for gap in sorted(known + gaps, key=lambda g: (g.start_s, g.topic))]
    notes["warnings"] = [*notes.get("warnings", []), *(gap_warning(log.meta.source, g, float(log.t[0]), max_gap_s) for g in gaps)]


def recorded_gap_rule(notes: dict, default_s: float = MAX_INTERPOLATION_GAP_S) -> float:
    """The gap rule [s] the notes' measurement gaps were found by (``gap_rule_s``, :func:`mark_measurement_gaps`): a
    contract bag converted from a topic-map bag (50 ms rule) re-finds its gaps by it; ``default_s`` without one (a
    value outside (0, default_s] is not taken)."""
    rule = notes.get("gap_rule_s")
    return float(rule) if isinstance(rule, (int, float)) and 0 < rule <= default_s else default_s


def marked_gaps(log: FlightLog) -> list[MeasurementGap]:
    """The measurement gaps marked in ``log.meta.notes`` (:func:`mark_measurement_gaps`); DataError for a malformed entry."""
    entries = log.meta.notes.get("measurement_gaps", [])
    if not isinstance(entries, list):
        raise DataError(f"{log.meta.source}: notes measurement_gaps is {type(entries).__name__}, expected a list")
    gaps = []
    for i, g in enumerate(entries):
        try:
            gap = MeasurementGap(str(g["topic"]), float(g["start_s"]), float(g["end_s"]), tuple(map(str, g.get("fields", ()))))
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise DataError(f"{log.meta.source}: notes measurement_gaps entry {i} is not a {{topic, start_s, end_s}} mapping: {g!r:.80}") from err
        if not (np.isfinite(gap.start_s) and np.isfinite(gap.end_s) and gap.start_s < gap.end_s):
            raise DataError(f"{log.meta.source}: notes measurement_gaps entry {i} spans {gap.start_s:g}..{gap.end_s:g} s: not a time interval")
        gaps.append(gap)
    return gaps


def flight_warnings(log: FlightLog) -> list[str]:
    """Every warning the reader recorded about ``log`` (``notes['warnings']``: marked gaps, clipped commands, a cut
    tail, a damaged file), what every verb that reads flights prints; DataError when the notes' ``warnings`` is not a
    list."""
    warnings = log.meta.notes.get("warnings", [])
    if not isinstance(warnings, list):
        raise DataError(f"{log.meta.source}: notes warnings is {type(warnings).__name__}, expected a list")
    return [w for w in warnings if isinstance(w, str)]


def gap_warnings(log: FlightLog) -> list[str]:
    """The warnings of ``log`` about its marked measurement gaps (:func:`flight_warnings` naming a gap)."""
    return [w for w in flight_warnings(log) if GAP_MARK in w]


def check_same_clock(topic: str, source_t: np.ndarray, base: str, t: np.ndarray, where: str,
                     max_gap_s: float = MAX_INTERPOLATION_GAP_S) -> None:
    """DataError when the stream stamps ``source_t`` [s] start later or end earlier than the base time ``t`` [s]
    by more than ``max_gap_s``: a stream on another clock would be held constant, not interpolated."""
    late, early = source_t[0] - t[0], t[-1] - source_t[-1]
    if late > max_gap_s or early > max_gap_s:
        offset = late if late > max_gap_s else -early
        raise DataError(
            f"{where}: topic {topic} stamps are offset by {offset:+.3f} s from {base} "
            f"(spans {source_t[0] - t[0]:.3f}..{source_t[-1] - t[0]:.3f} s of a {t[-1] - t[0]:.3f} s flight): another clock?"
        )


SMOOTH_NYQUIST_FRACTION = 0.8
"""The highest low-pass cutoff :func:`smooth` designs, as a fraction of the Nyquist frequency (a 2nd-order Butterworth
closer to it is ill-conditioned); a default cutoff above it (5 Hz on a 10 Hz log) is lowered to it."""


def check_cutoff(cutoff_hz: float, log: FlightLog, window_s: float, flag: str = "--smooth") -> None:
    """ConfigError unless the low-pass ``cutoff_hz`` the user gave lies below :data:`SMOOTH_NYQUIST_FRACTION` of the
    Nyquist frequency of ``log`` (above it :func:`smooth` would use that limit instead: a cutoff given and not used)
    and at or above 1 / ``window_s`` (a window holds less than one period of a slower one; 1e-6 Hz was a singular
    filter design in a traceback, review)."""
    if cutoff_hz < 1.0 / window_s:
        raise ConfigError(f"{flag} {cutoff_hz:g} Hz: must be at least 1 / --window = {1.0 / window_s:g} Hz "
                          "(a window holds less than one period of a slower cutoff)")
    nyquist = log.sample_rate / 2.0
    limit = SMOOTH_NYQUIST_FRACTION * nyquist
    if not cutoff_hz < limit:
        raise ConfigError(
            f"{flag} {cutoff_hz:g} Hz: must be below {limit:.4g} Hz, {SMOOTH_NYQUIST_FRACTION:g} x the Nyquist frequency "
            f"{nyquist:.4g} Hz of {log.meta.source} ({log.sample_rate:.4g} Hz samples)"
        )


def sample_period(log: FlightLog) -> float:
    """Median sample period [s]."""
    return 1.0 / log.sample_rate


def nav_acceleration(log: FlightLog, gravity: float = GRAVITY, rows: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) acceleration in N [m/s²] from the body specific force: a_N = R f_B + g e_z (at ``rows`` only, if given)."""
    log.require(("acc_b",), "the acceleration")
    at = slice(None) if rows is None else np.asarray(rows, dtype=int)
    return frames.kinematic_acceleration(log.acc_b[at], log.euler[at], gravity)


def differentiate(values: np.ndarray, dt: float, window_s: float = DERIVATIVE_WINDOW_S, causal: bool = False) -> np.ndarray:
    """Time derivative of (N, k) ``values`` sampled every ``dt`` [s] (Savitzky-Golay).

    Uses a local quadratic fit over ``window_s`` (odd number of samples, shrunk
    for short signals); fewer than 3 samples fall back to :func:`numpy.gradient`.
    The fit is centred on each row (zero phase, it reads rows after it), or with
    ``causal`` one-sided: :func:`causal_derivative`.
    """
    values = np.asarray(values, dtype=float)
    if causal:
        return causal_derivative(values, dt, window_s)
    n = values.shape[0]
    length = int(round(window_s / dt)) | 1
    length = min(length, n if n % 2 else n - 1)
    if length <= DERIVATIVE_POLYORDER:
        return np.gradient(values, dt, axis=0) if n > 1 else np.zeros_like(values)
    return signal.savgol_filter(values, length, DERIVATIVE_POLYORDER, deriv=1, delta=dt, axis=0, mode="interp")


def causal_derivative(values: np.ndarray, dt: float, window_s: float = DERIVATIVE_WINDOW_S) -> np.ndarray:
    """Time derivative of (N, k) ``values`` at each row from that row and the rows before it only.

    Row j: the slope at row j of the least-squares polynomial of order
    min(:data:`DERIVATIVE_POLYORDER`, m - 1) through the m = min(j + 1, L) rows
    j - m + 1 .. j, L = ``window_s`` / ``dt`` rounded up to odd (the same L as the
    centred fit; :func:`scipy.signal.savgol_coeffs` with ``pos`` = m - 1); row 0
    is 0. With L <= :data:`DERIVATIVE_POLYORDER` (a sample period longer than ``window_s`` / 2) every row is
    the backward difference. On a log of at least L rows, the last row of the centred fit (``interp`` mode) is the
    same fit, so a warm start's last row (a window's anchor) gets the same derivative either way.
    """
    values = np.asarray(values, dtype=float)
    n = values.shape[0]
    length = int(round(window_s / dt)) | 1
    out = np.zeros_like(values)
    if length <= DERIVATIVE_POLYORDER:  # dt longer than the window (a log slower than ~18 Hz): backward differences
        out[1:] = np.diff(values, axis=0) / dt
        return out
    for m in range(2, min(length, n + 1)):  # the first L - 1 rows: all the m rows up to row m - 1
        coeffs = signal.savgol_coeffs(m, min(DERIVATIVE_POLYORDER, m - 1), deriv=1, delta=dt, pos=m - 1, use="dot")
        out[m - 1] = np.tensordot(coeffs, values[:m], axes=(0, 0))
    if n >= length:
        coeffs = signal.savgol_coeffs(length, DERIVATIVE_POLYORDER, deriv=1, delta=dt, pos=length - 1, use="dot")
        windows = np.lib.stride_tricks.sliding_window_view(values, length, axis=0)  # (N - L + 1, ..., L)
        out[length - 1:] = windows @ coeffs
    return out


def measured_variables(log: FlightLog, vehicle: VehicleConfig | None = None, causal: bool = False) -> np.ndarray:
    """(N, 18) best measurement of each variable in VARIABLES order (untrimmed, SI, N frame).

    ``vehicle`` is accepted for symmetry with the models; gravity is the models' :data:`quad_modelling.core.physics.rigid_body.GRAVITY`.
    Every column is the raw row but the angular accelerations, differentiated gyros; ``causal`` differentiates
    them from past rows only (:func:`causal_derivative`): what a model is given at
    an anchor (the causality rule, :func:`state_measurement`), while the truth it is
    scored against may be centred.
    """
    out = np.full((len(log), len(VARIABLES)), np.nan)  # NaN: not measured (unmeasured_variables)
    out[:, 0:3] = log.pos_n
    out[:, 3:6] = log.vel_n
    if log.acc_b is not None:
        out[:, 6:9] = nav_acceleration(log)
    out[:, 9:12] = log.euler
    out[:, 11] = frames.unwrap_angles(log.euler[:, 2])
    if log.gyro_b is not None:
        out[:, 12:15] = log.gyro_b
        out[:, 15:18] = differentiate(log.gyro_b, sample_period(log), causal=causal)
    return out


def attitude_rates(log: FlightLog, causal: bool = False) -> np.ndarray:
    """(N, 3) body rates p, q, r [rad/s] from the motion-capture attitude (no gyro needed).

    The Euler angle derivatives (:func:`differentiate`, yaw unwrapped) through the ZYX kinematics
    (:func:`~quad_modelling.core.frames.euler_rates_to_body_rates`); ``causal``: the derivatives from past rows only
    (:func:`causal_derivative`).
    """
    euler = log.euler.copy()
    euler[:, 2] = frames.unwrap_angles(euler[:, 2])
    return frames.euler_rates_to_body_rates(euler, differentiate(euler, sample_period(log), causal=causal))


def state_measurement(log: FlightLog, vehicle: VehicleConfig | None = None, causal: bool = False) -> np.ndarray:
    """:func:`measured_variables`, with the rates and angular accelerations of a flight without a gyro
    taken from the motion-capture attitude (:func:`attitude_rates`): the state a model starts from.

    Accelerations stay NaN without an accelerometer (no model state is an acceleration).
    ``causal``: every row from that row and the rows before it only (the causality rule:
    a model anchored at row s is given nothing after s); rows 0..11 (positions, velocities,
    accelerations, angles) and gyro rates are raw rows either way.
    """
    out = measured_variables(log, vehicle, causal=causal)
    if log.gyro_b is None:
        rates = attitude_rates(log, causal=causal)
        out[:, 12:15] = rates
        out[:, 15:18] = differentiate(rates, sample_period(log), causal=causal)
    return out


def trim_values(values: np.ndarray, trim_samples: int) -> np.ndarray:
    """Trim value of each column: the mean over the first ``trim_samples`` rows."""
    if trim_samples < 1:
        raise DataError(f"trim interval must hold at least one sample, got {trim_samples}")
    return np.asarray(values, dtype=float)[:trim_samples].mean(axis=0)


def trailing_means(values: np.ndarray, ends: np.ndarray, rows: int) -> np.ndarray:
    """Causal trim values: (S, k) mean of (N, k) ``values`` over rows max(0, e - rows + 1) .. e for each
    row e of ``ends`` (S,), i.e. over the last ``rows`` rows up to and including e (fewer near row 0).

    Vectorised with a running sum of ``values - values[0]`` (the offset keeps the sum small for
    large signals such as PWM commands); row e's mean reads rows <= e only.
    """
    values = np.asarray(values, dtype=float)
    ends = np.asarray(ends, dtype=int)
    if rows < 1:
        raise DataError(f"trim interval must hold at least one sample, got {rows}")
    ref = values[0]
    total = np.concatenate([np.zeros((1,) + values.shape[1:]), np.cumsum(values - ref, axis=0)])
    first = np.maximum(ends - rows + 1, 0)
    count = (ends + 1 - first).reshape((-1,) + (1,) * (values.ndim - 1))
    return ref + (total[ends + 1] - total[first]) / count


def trimmed_variables(window: FlightLog, trim: TrimConfig | None = None, vehicle: VehicleConfig | None = None) -> np.ndarray:
    """(N, 18) best measurement of ``window`` minus its trim values (the evaluation reference)."""
    trim = trim or TrimConfig()
    measured = measured_variables(window, vehicle)
    return measured - trim_values(measured, trim.trim_samples(window))


def trim_prediction(window: FlightLog, prediction: np.ndarray, trim: TrimConfig | None = None) -> np.ndarray:
    """Absolute (N, 18) prediction -> the evaluation's trimmed convention.

    Subtracts the *measured* trim values of the window (the same as
    :func:`trimmed_variables`), so trimmed prediction and trimmed measurement
    differ exactly by the absolute prediction error. Live predictors publish
    absolute values; the evaluator and the offline predictors both trim here.
    """
    trim = trim or TrimConfig()
    return np.asarray(prediction, dtype=float) - trim_values(measured_variables(window), trim.trim_samples(window))


def trimmed_inputs(window: FlightLog, trim: TrimConfig | None = None) -> np.ndarray:
    """(N, 4) engine commands minus their trim values (linearly detrended for long windows).

    Windows up to ``trim.detrend_above_s`` long: u - mean(u over the stable
    interval). Longer windows: u minus its least-squares line over the whole
    window (:func:`scipy.signal.detrend`, thesis Fig 2.3).
    """
    trim = trim or TrimConfig()
    if window.duration > trim.detrend_above_s:
        return signal.detrend(window.u, axis=0, type="linear")
    return window.u - trim_values(window.u, trim.trim_samples(window))


def smooth(values: np.ndarray, sample_rate: float, cutoff_hz: float = SMOOTH_CUTOFF_HZ) -> np.ndarray:
    """Zero-phase Butterworth low-pass of (N, ...) ``values`` along rows.

    The cutoff is limited to :data:`SMOOTH_NYQUIST_FRACTION` x Nyquist; signals too short for filtfilt's
    padding are returned unchanged (nothing to smooth over).
    """
    values = np.asarray(values, dtype=float)
    nyquist = sample_rate / 2.0
    b, a = signal.butter(SMOOTH_ORDER, min(cutoff_hz, SMOOTH_NYQUIST_FRACTION * nyquist) / nyquist)
    if values.shape[0] <= 3 * max(len(a), len(b)):
        return values.copy()
    return signal.filtfilt(b, a, values, axis=0)


STAMP_JITTER_TOLERANCE = 0.5
"""Largest deviation of a sample step from the median step, as a fraction of it, that :func:`uniform_time_check` takes
for stamp jitter: a stack stamping its messages on receipt (crazyswarm2's ``header.stamp``) spreads 100 Hz samples
over 6-14 ms steps (+-2 ms), which the live nodes score as they come; a missing sample is a step of twice the median
(deviation 1) and is refused. 0.25 before: such a bag was scored by run-bag and refused by evaluate."""


def uniform_time_check(log: FlightLog, tolerance: float = STAMP_JITTER_TOLERANCE) -> None:
    """Raise DataError if any sample step deviates from the median by more than ``tolerance`` (fraction).

    The discrete models and filters assume uniform sampling; steps within the tolerance are stamp jitter of uniformly
    sampled data (:data:`STAMP_JITTER_TOLERANCE`) and are treated as the median step.
    """
    steps = np.diff(log.t)
    dt = np.median(steps)
    bad = np.abs(steps - dt) > tolerance * dt
    if bad.any():
        row = int(np.argmax(bad)) + 1
        raise DataError(
            f"{log.meta.source}: sample step at row {row} ({log.t[row] - log.t[0]:.3f} s into the flight) is "
            f"{steps[row - 1] * 1e3:.2f} ms, median {dt * 1e3:.2f} ms: more than {tolerance:.0%} off, not stamp jitter "
            "(a missing sample or a pause of the time-base stream)"
        )


MAX_FILL_GAP_S = 0.05
"""Longest time gap [s] :func:`resample_uniform` fills by interpolation (5 samples at 100 Hz)."""


GROUND_CONTACT_M = 0.01
"""A row whose height comes within 1 cm of the flight's lowest point -- where the vehicle
stood before take-off -- touches the ground (:func:`ground_contact`); the identification leaves out windows that touch
it, the diagnosis the starts whose horizon does: no model here has ground contact, and the
contact forces read as a height-dependent thrust. On a simulated effects-off flight whose low pass
touched down (test seed 2001), ground effect fitted the two contact windows and was 'found' with a
40 % shrink. The simulator's feet compress ~1 mm at rest (15 Hz gear); the LinkQuad's low passes touch down on
some seeds (its altitude loop undershoots, docs/simulator.md), the Crazyflie's hold their height within 1 cm.

The test uses the motion-capture height through a 5-sample running median (:data:`CONTACT_MEDIAN_SAMPLES`:
robust to a single bad sample, no smearing), not the 1 Hz regime signal, over the window and
:data:`~quad_modelling.core.identification.window_batch.CONTACT_GUARD_S` either side of it (windows). With the zero-phase 1 Hz low-pass inside the window alone, on
150 s validation flights the window in which the vehicle touched down and the throttle was cut to idle
(an acc_z step of ~g in its last samples, the feet still 2 cm above their resting height) stayed in, and
pulled the base model's identification to a 70 ms motor time constant and the arm scale to its bound.

A flight whose height never rises :data:`GROUND_CONTACT_M` above its lowest point has no take-off in it: its
height cannot tell standing from hovering, so none of its windows is dropped (the linear model's own
flights in ``test/core/test_identification.py`` move 1.7 mm; before, every window of such a flight was
dropped and the flight refused)."""


CONTACT_MEDIAN_SAMPLES = 5
"""[rows] of the running median of the height in :func:`height_above_ground`."""


def height_above_ground(log: FlightLog) -> np.ndarray:
    """(N,) height [m] above the flight's lowest point (where it stood before take-off; NED z down), through a
    :data:`CONTACT_MEDIAN_SAMPLES`-sample running median of the motion-capture height (:data:`GROUND_CONTACT_M`)."""
    kernel = CONTACT_MEDIAN_SAMPLES if len(log) >= CONTACT_MEDIAN_SAMPLES else 1  # shorter: none (scipy warns, 2 lines)
    return signal.medfilt(float(np.max(log.pos_n[:, 2])) - log.pos_n[:, 2], kernel)


def ground_contact(log: FlightLog) -> np.ndarray:
    """(N,) True where the vehicle touches the ground: :func:`height_above_ground` below :data:`GROUND_CONTACT_M`;
    nowhere in a flight whose height never rises that far (no take-off: standing and hovering look alike)."""
    height = height_above_ground(log)
    return height < GROUND_CONTACT_M if float(np.max(height)) >= GROUND_CONTACT_M else np.zeros(len(height), dtype=bool)


MAX_FILLED_ROWS = 2_000_000
"""Most rows a uniform grid may add to a log, or 10 times its rows if more (a stamp 1e9 s off asked 745 GiB)."""


def _uniform_grid(log: FlightLog) -> np.ndarray:
    """t0 + k dt up to the last sample, dt the median step: :func:`resample_uniform`'s grid (:data:`MAX_FILLED_ROWS`)."""
    dt = float(np.median(np.diff(log.t)))
    n = int(np.floor((log.t[-1] - log.t[0]) / dt + 0.5)) + 1
    if n - len(log) > max(MAX_FILLED_ROWS, 10 * len(log)):
        i = int(np.argmax(np.diff(log.t)))
        raise DataError(f"{log.meta.source}: the time jumps by {log.t[i + 1] - log.t[i]:.6g} s after sample {i + 1} (t = {log.t[i] - log.t[0]:.6g} "
                        f"s into the flight): a uniform time base would fill {n - len(log)} rows (at most {max(MAX_FILLED_ROWS, 10 * len(log))}); a stamp is wrong")
    grid = log.t[0] + dt * np.arange(n)
    return grid[grid <= log.t[-1] + 1e-9]


HOLE_STEPS = 2.5
"""A step of the time base is a hole only beyond this many median steps too (at 100 Hz the 50 ms rule decides; a
10 Hz log's every 100 ms step was a "hole", 97 warnings for one missing row)."""


def hole_rule(log: FlightLog, max_gap_s: float = MAX_FILL_GAP_S) -> float:
    """The step [s] beyond which ``log``'s time base has a hole: ``max_gap_s``, or HOLE_STEPS median steps if longer."""
    return max(max_gap_s, HOLE_STEPS * float(np.median(np.diff(log.t))))


def time_base_holes(log: FlightLog, max_gap_s: float = MAX_FILL_GAP_S) -> list[MeasurementGap]:
    """The holes of ``log``'s time base, steps longer than :func:`hole_rule` (rows missing from every column: a CSV's
    dropout) with a row of the uniform grid (:func:`resample_uniform`'s) outside every marked measurement gap: a hole
    inside a reader's gap (the same hole, on a topic stamped a few ms later) is that gap."""
    steps = np.diff(log.t)
    if len(log) < 3 or np.all(np.abs(steps - np.median(steps)) <= 0.25 * np.median(steps)):
        return []  # uniform
    rule = hole_rule(log, max_gap_s)
    grid = _uniform_grid(log)
    edge = 1e-9  # [s] inside the real rows around a hole: the uniform grid's row on one is not a filled row
    marked = np.zeros(len(grid), dtype=bool)
    for gap in marked_gaps(log):  # a hole marked as a gap is filled: the rows inside it are left out downstream
        marked |= (grid > gap.start_s) & (grid < gap.end_s)
    holes = [MeasurementGap(TIME_BASE_HOLE, float(log.t[i]) + edge, float(log.t[i + 1]) - edge, FIELDS_OF_A_ROW)
             for i in np.flatnonzero(steps > rule)]
    return [h for h in holes if not marked[(grid > h.start_s) & (grid < h.end_s)].all()]


def mark_time_base_holes(log: FlightLog, max_gap_s: float = MAX_FILL_GAP_S) -> None:
    """Mark :func:`time_base_holes` in ``log``'s notes with one warning each, as :func:`resample_uniform` marks them on
    its copy: what ``convert`` and ``info`` do to a flight they do not resample (a CSV's 5 s hole converted and was
    described at 100 Hz with no word; only a scoring verb said it)."""
    add_measurement_gaps(log, time_base_holes(log, max_gap_s), hole_rule(log, max_gap_s))


def resample_uniform(log: FlightLog, max_gap_s: float = MAX_FILL_GAP_S) -> FlightLog:
    """The log on a uniform grid t0 + k dt (dt = median step), linearly interpolated.

    Real logs drop the odd sample (NanoBench: one to five 20-30 ms steps per
    flight). The discrete models and filters need uniform sampling, so missing
    samples are filled by linear interpolation (yaw unwrapped first). A hole longer than ``max_gap_s`` with a filled
    row outside every marked measurement gap (a logging dropout of every column: a CSV's missing rows) becomes one, of
    the ``time base``, with a warning by this rule (:func:`add_measurement_gaps`; the reader's gaps keep theirs): the
    rows filled inside it are gap rows, left out by the windows and training segments, as a bag reader's marked holes
    are (a 110 ms hole refused the whole flight, a 1 s one was accepted once converted to a bag). A hole whose filled
    rows lie inside a reader's gap (the same hole, on a topic stamped a few ms later) is that gap, not said again. A
    log that is already uniform is returned unchanged. The number of filled samples is recorded in
    ``meta.notes['resampled_filled_samples']``.
    """
    steps = np.diff(log.t)
    dt = float(np.median(steps))
    if np.all(np.abs(steps - dt) <= 0.25 * dt):
        return log
    grid, holes = _uniform_grid(log), time_base_holes(log, max_gap_s)
    n = int(np.floor((log.t[-1] - log.t[0]) / dt + 0.5)) + 1  # the filled count as before the grid's end was trimmed

    def interp(values: np.ndarray) -> np.ndarray:
        if values.ndim == 1:
            return np.interp(grid, log.t, values)
        return np.column_stack([np.interp(grid, log.t, values[:, i]) for i in range(values.shape[1])])

    euler = log.euler.copy()
    euler[:, 2] = frames.unwrap_angles(euler[:, 2])
    euler = interp(euler)
    euler[:, 2] = (euler[:, 2] + np.pi) % (2 * np.pi) - np.pi
    notes = dict(log.meta.notes)
    notes["resampled_filled_samples"] = int(n - len(log.t)) if n >= len(log.t) else 0
    meta = type(log.meta)(log.meta.vehicle, log.meta.source, notes)
    out = FlightLog(
        t=grid, u=interp(log.u), acc_b=None if log.acc_b is None else interp(log.acc_b),
        gyro_b=None if log.gyro_b is None else interp(log.gyro_b), pos_n=interp(log.pos_n),
        vel_n=interp(log.vel_n), euler=euler, meta=meta,
        vbat=None if log.vbat is None else interp(log.vbat), omega=None if log.omega is None else interp(log.omega),
    )
    add_measurement_gaps(out, holes, hole_rule(log, max_gap_s))  # the notes are a copy: the input log keeps its own
    return out
