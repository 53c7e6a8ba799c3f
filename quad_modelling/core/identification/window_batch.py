"""Diagnosis windows: the flights cut into a batch of trimmed, smoothed windows (:class:`WindowBatch`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.greybox import (
    MEASURED_STATE_COLUMNS,
    trim_motion,
)
from quad_modelling.core.preprocess import (
    GROUND_CONTACT_M,
    SMOOTH_CUTOFF_HZ,
    height_above_ground,
    measured_variables,
    resample_uniform,
    smooth,
    trim_values,
    uniform_time_check,
)
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import (
    EvaluationConfig,
    SpanSpec,
    span_windows,
    warm_samples_for,
)
from quad_modelling.errors import DataError

REGIME_CUTOFF_HZ = 1.0
"""Low-pass of the height that drives ground effect [Hz] (it changes slowly; removes motion-capture noise).
Battery voltage keeps the evaluation bandwidth: its sag follows the throttle."""


COMMAND_HISTORY_S = 0.5
"""Commands kept from before each window [s] for the input maps with memory (lag, delay): a lag started in
steady state at the window's first command is wrong by exp(-t/tau) of the difference to the true rotor
state, and with the motors' 105 ms lag (LinkQuad) that error is still 15 % at the end of a 0.2 s warm start.
0.5 s is 5 time constants of that lag and beyond the catalogue's 0.2 s delay bound."""


CONTACT_GUARD_S = 0.5
"""[s] either side of a window in which ground contact also excludes it (touchdown and lift-off transients,
the throttle cut when the feet meet the ground)."""


# ----------------------------------------------------------------------------- windows


@dataclass
class WindowBatch:
    """Equal-length windows of several flights, preprocessed once (SI units, N = NED, B = FRD).

    Arrays are (W, N, ...) for W windows of N samples. ``measured`` is the
    smoothed trimmed best measurement (the evaluation reference),
    ``anchor_states`` the 12 measured states (pos, vel, angles, rates) at the
    last warm sample, from the trimmed measurement low-passed over the warm
    samples only (as :class:`~quad_modelling.core.models.greybox.GreyboxPredictor`).
    """

    sources: list[str]
    t0: np.ndarray  # (W,) window start [s from the flight's first sample]
    dt: float
    warm: int
    u: np.ndarray  # (W, N, 4) trimmed commands
    u_history: np.ndarray  # (W, H, 4) trimmed commands of the H samples before each window (COMMAND_HISTORY_S)
    u_trim: np.ndarray  # (W, 4) trim values (absolute commands)
    u_span: float
    measured: np.ndarray  # (W, N, 18)
    anchor_states: np.ndarray  # (W, 12)
    velocity: np.ndarray  # (W, N, 3) smoothed trimmed velocity in N
    velocity_abs: np.ndarray  # (W, N, 3) absolute velocity in N
    velocity_smooth: np.ndarray  # (W, N, 3) absolute velocity in N, smoothed as ``measured``
    euler: np.ndarray  # (W, N, 3) absolute attitude (yaw unwrapped)
    rates: np.ndarray  # (W, N, 3) absolute gyro rates, smoothed
    height: np.ndarray  # (W, N) above the flight's lowest point, low-passed
    vbat: np.ndarray | None  # (W, N) low-passed, or None when a flight has no voltage
    input_min: float

    def __len__(self) -> int:
        return len(self.sources)

    @property
    def samples(self) -> int:
        return self.u.shape[1]

    offsets: np.ndarray = None  # (W, 18) linearisation point (warm-start mean) minus the window trim
    trim_motion: np.ndarray = None  # (W, 18) rate of change of the linearisation point (greybox.trim_motion) [SI/s]
    warm_rows: np.ndarray = None  # (W, warm, 18) unsmoothed measurement of the warm start minus the window trim
    trim_samples: int = 100  # rows of the trim interval
    ground_contact_dropped: int = 0  # windows left out because the vehicle touched the ground (GROUND_CONTACT_M)
    smooth_cutoff_hz: float = SMOOTH_CUTOFF_HZ  # the evaluation low-pass ``measured`` went through [Hz]
    specific_force0: np.ndarray = None  # (W, 3) measured body specific force, mean over the warm start [m/s², B]
    acc_trim: np.ndarray = None  # (W, 3) window trim of acc_x/y/z (absolute, N) [m/s²]
    angacc_trim: np.ndarray = None  # (W, 3) window trim of roll/pitch/yaw acceleration [rad/s²]

    def subset(self, index: np.ndarray) -> WindowBatch:
        """The windows at ``index`` (same preprocessing)."""
        index = np.asarray(index, dtype=int)
        picked = {}
        for name in ("t0", "u", "u_history", "u_trim", "measured", "anchor_states", "velocity", "velocity_abs", "velocity_smooth", "euler", "rates", "height", "warm_rows", "offsets",
                     "trim_motion", "specific_force0", "acc_trim", "angacc_trim"):
            picked[name] = getattr(self, name)[index]
        picked["vbat"] = None if self.vbat is None else self.vbat[index]
        return replace(self, sources=[self.sources[i] for i in index], **picked)


def flying_span(text: str = "0%:100%") -> SpanSpec:
    """The span of each flight the diagnosis uses (relative to its flying part by default)."""
    return SpanSpec.parse("diagnosis", text)


def prepare_windows(
    flights: Sequence[FlightLog], vehicle: VehicleConfig, config: EvaluationConfig, span: SpanSpec | None = None
) -> WindowBatch:
    """Cut each flight's ``span`` (after the take-off/landing drops of ``config``) into windows and preprocess them;
    windows that touch the ground (:data:`GROUND_CONTACT_M`) are left out and counted.

    DataError when no window fits.
    """
    span = span or flying_span()
    windows: list[FlightLog] = []
    starts: list[float] = []
    grounds: list[float] = []
    histories: list[np.ndarray] = []  # absolute commands before each window, rows [start - H, start)
    contact_height: list[float] = []  # lowest height above ground in and around each window [m]
    for log in flights:
        log = resample_uniform(log)
        uniform_time_check(log)
        ground = float(np.max(log.pos_n[:, 2]))  # NED: the lowest point of the flight
        h = int(round(COMMAND_HISTORY_S * log.sample_rate))
        guard = int(round(CONTACT_GUARD_S * log.sample_rate))
        height = height_above_ground(log)
        took_off = float(np.max(height)) >= GROUND_CONTACT_M
        for w in span_windows(log, span, config):
            windows.append(log.slice(w.start, w.stop))
            contact_height.append(float(np.min(height[max(w.start - guard, 0) : w.stop + guard])) if took_off else np.inf)
            starts.append(float(log.t[w.start] - log.t[0]))
            grounds.append(ground)
            before = log.u[max(w.start - h, 0) : w.start]
            pad = np.repeat(log.u[w.start : w.start + 1], h - len(before), axis=0)  # flight starts: repeat the first command
            histories.append(np.concatenate([pad, before]))
    if not windows:
        durations = ", ".join(f"{log.duration:.1f} s" for log in flights)
        raise DataError(
            f"no {config.window_s:g} s window fits span {span.text()} after dropping {config.drop_start:g} s/"
            f"{config.drop_end:g} s (flight durations {durations}); shorten --window or the drops (a window touching "
            "a marked measurement gap or the ground is left out too)"
        )
    lengths = {len(w) for w in windows}
    n = min(lengths)
    rates = np.array([w.sample_rate for w in windows])
    if rates.max() > 1.01 * rates.min():
        raise DataError(f"flights have different sample rates ({rates.min():.2f}..{rates.max():.2f} Hz); resample them to one rate first")
    rate = float(np.median(rates))
    dt = 1.0 / rate
    warm = warm_samples_for(windows[0].slice(0, n), config.warm_s)
    trim_rows = config.trim.trim_samples(windows[0].slice(0, n))
    has_vbat = all(w.vbat is not None for w in windows)
    history_rows = min(len(h) for h in histories)
    sources = [w.meta.source for w in windows]
    fields: dict[str, np.ndarray] = {}  # (W, ...) arrays filled window by window: no per-window list copied at the end

    def put(name: str, i: int, value: np.ndarray) -> None:
        if name not in fields:
            fields[name] = np.empty((len(windows), *np.shape(value)), dtype=np.result_type(value))
        fields[name][i] = value

    for i, (ground, history) in enumerate(zip(grounds, histories)):
        w, windows[i] = windows[i].slice(0, n), None  # each window's copy goes once its rows are in the batch
        raw = measured_variables(w)
        window_trim = trim_values(raw, trim_rows)
        put("measured", i, smooth(raw - window_trim, rate, config.smooth_cutoff_hz))
        # linearisation point: the warm start (as GreyboxPredictor._anchor)
        warm_log = w.slice(0, warm)
        warm_measured = measured_variables(warm_log)
        output_trim = warm_measured.mean(axis=0)
        input_trim = warm_log.u.mean(axis=0)
        put("anchor_states", i, smooth(warm_measured - output_trim, rate)[-1, MEASURED_STATE_COLUMNS])
        put("offsets", i, output_trim - window_trim)
        put("trim_motion", i, trim_motion(output_trim))
        put("specific_force0", i, warm_log.acc_b.mean(axis=0))
        put("acc_trim", i, window_trim[6:9])
        put("angacc_trim", i, window_trim[15:18])
        put("warm_rows", i, warm_measured - window_trim)
        put("u", i, w.u - input_trim)
        put("u_history", i, history[len(history) - history_rows :] - input_trim)
        put("u_trim", i, input_trim)
        put("velocity", i, smooth(raw[:, 3:6] - output_trim[3:6], rate, config.smooth_cutoff_hz))
        put("velocity_abs", i, raw[:, 3:6])
        put("velocity_smooth", i, smooth(raw[:, 3:6], rate, config.smooth_cutoff_hz))
        put("euler", i, raw[:, 9:12])
        put("rates", i, smooth(raw[:, 12:15], rate, config.smooth_cutoff_hz))
        put("height", i, smooth(ground - w.pos_n[:, 2], rate, REGIME_CUTOFF_HZ))
        if has_vbat:
            put("vbat", i, smooth(w.vbat, rate, config.smooth_cutoff_hz))  # sag follows the throttle: keep its bandwidth
    batch = WindowBatch(
        sources=sources, t0=np.array(starts), dt=dt, warm=warm,
        u_span=float(vehicle.input_max - vehicle.input_min), vbat=fields.pop("vbat", None),
        input_min=float(vehicle.input_min), trim_samples=trim_rows, smooth_cutoff_hz=float(config.smooth_cutoff_hz), **fields,
    )
    airborne = np.array(contact_height) >= GROUND_CONTACT_M
    if not airborne.any():
        raise DataError(f"every {config.window_s:g} s window touches the ground (height within {GROUND_CONTACT_M * 100:g} cm of the "
                        f"flight's lowest point); nothing to diagnose")
    if airborne.all():
        return batch
    return replace(batch.subset(np.where(airborne)[0]), ground_contact_dropped=int(np.sum(~airborne)))


# ----------------------------------------------------------------------------- the catalogue


def _trim_mean(values: np.ndarray, rows: int) -> np.ndarray:
    """Mean over the first ``rows`` samples (the warm start, the model's linearisation point) along axis 1, kept."""
    return values[:, :rows].mean(axis=1, keepdims=True)
