"""Sample-by-sample prediction inside a window: what a live predictor node runs.

Live and offline must give the same numbers (DESIGN 2). A streaming predictor
therefore predicts a window in two causal steps, which both the ROS predictor
node and the offline evaluation call:

1. :meth:`StreamingPredictor.start_window` receives the window's warm-start
   rows (commands and measurements of the first ``warm_samples`` samples, the
   thesis's 0.2 s) and returns the predictions for those rows plus a
   :class:`WindowStream`;
2. :meth:`WindowStream.push` receives the command of each following sample and
   returns that sample's prediction at once. A stream that integrates over the real sample
   intervals also has ``push_at(command, t_s)`` with the sample's time [s] (the warm log's
   time base); :func:`push_sample` calls it when present, ``push`` otherwise.

Predictions are **absolute** values of the 18 variables in
:data:`quad_modelling.core.variables.VARIABLES` order (internal frames, SI), so
a published ``<model>/odom`` is a real pose; the evaluator trims measurement and
prediction alike at window close. :func:`predict_window_by_stream` is the
offline form: the same calls, in a loop.

:func:`predict_horizons_by_stream` is the generic multi-step (IDSIA) form of
every streaming predictor: from each start s, ``start_window`` on the
``warm_samples`` rows ending at s, then ``push`` the commands of s+1 .. s+H. It
is the live form itself, so it is causal by construction (nothing after s but
the commands is seen) and live and offline agree. :class:`StreamingHorizons`
wraps a streaming predictor as a
:class:`~quad_modelling.core.models.base.MultiStepPredictor` with it.

:class:`RecedingHorizon` is the live receding-horizon form (the predictor's
``horizon_s`` > 0). It holds the recent commands of the current time base and predicts, from an
anchor s, h = round(horizon_s / dt) steps ahead what the model's offline multi-step form
(``form_for(warm rows)``, the node passes :func:`~quad_modelling.core.evaluation.multistep.multistep_form`)
predicts from s on the rows up to s (measurements read at the command stamps, ``make_log``: the node's
message conversion) and h rows of commands after it. With the model's carried-state forecast
(``carried_for(dt, h)``, the node passes :func:`~quad_modelling.core.live.forms.carried_forecast`) the
rows since the previous anchor are added to the anchor it carries (one per input) and it is rolled out h
steps; without one (or for a flight without a gyro) the multi-step form is re-run over the last ``history_s``
of rows up to s (the same numbers once the model's trims and filters settle within it). The
two ``inputs`` modes differ only in the commands after s (one prediction path):

* ``"hold"`` (the forecast MPC and monitoring consume): every command s is an anchor as soon as it
  is in (and every measurement stream covers t_s); the commands after s are u_s held (zero-order
  hold) at t_s + k dt, k = 1..h, so the prediction is ready at input s and stamped t_s + h dt, the
  time it predicts. It equals the offline multi-step form on a copy of the data whose commands after s
  are u_s (:func:`hold_inputs`; rows after s at t_s + k dt), not the offline multi-step table, which
  flies the recorded commands.
* ``"flown"``: the anchor s waits for the h flown commands s+1..s+h and is predicted when command
  s+h is in, stamped t_{s+h}: the same numbers as the offline multi-step evaluation for the same
  start (carried: to rounding; re-run: as long as the model's multi-step form settles within ``history_s``,
  trims over 1 s, causal filters: 2 s gives 5e-12 on the bundled flight), but published when the predicted
  instant is already past (a replay of the protocol, not a forecast).

:class:`RecordedPrediction` wraps predictions received over ROS as a
:class:`~quad_modelling.core.models.Predictor`, so the live evaluator scores a
window with the same :func:`~quad_modelling.core.evaluation.evaluate_window`
as ``quad-modelling evaluate``.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Protocol, runtime_checkable

import numpy as np

from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.preprocess import trim_prediction
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import MIN_SAMPLE_PERIOD_S
from quad_modelling.errors import DataError, QuadModellingError


class WindowStream(Protocol):
    """Predicts the samples after the warm start, one command at a time."""

    def push(self, command: np.ndarray) -> np.ndarray:
        """Command (4,) of the next sample -> its prediction (18,), absolute."""
        ...


@runtime_checkable
class StreamingPredictor(Protocol):
    """A model that can run live (see module docstring)."""

    name: str

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, WindowStream]:
        """Warm-start rows of a window -> (their predictions (W, 18), stream for the rest)."""
        ...


def push_sample(stream: WindowStream, command: np.ndarray, t_s: float) -> np.ndarray:
    """Push one sample's command: ``stream.push_at(command, t_s)`` for streams that take the sample time
    (they integrate over the real interval since the previous sample), else ``stream.push(command)``."""
    push_at = getattr(stream, "push_at", None)
    return push_at(command, t_s) if push_at is not None else stream.push(command)


def predict_window_by_stream(predictor: StreamingPredictor, window: FlightLog, warm_samples: int) -> np.ndarray:
    """(N, 18) absolute predictions of a window, computed exactly as a live node does."""
    if not 1 <= warm_samples < len(window):
        raise DataError(f"{window.meta.source}: warm start of {warm_samples} samples does not fit a window of {len(window)}")
    warm_predictions, stream = predictor.start_window(window.slice(0, warm_samples))
    predictions = np.empty((len(window), len(VARIABLES)))
    predictions[:warm_samples] = warm_predictions
    for row in range(warm_samples, len(window)):
        predictions[row] = push_sample(stream, window.u[row], float(window.t[row]))
    return predictions


class WindowByStream:
    """The offline window forms of a streaming predictor (mixed into the physics, hybrid and direct predictors): its
    live calls over a window with each sample's real stamp, absolute (:meth:`predict_absolute`) and in the
    evaluation's trimmed convention (:meth:`predict_window`, the predictor's ``trim``)."""

    def predict_absolute(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) absolute prediction of a window: the live calls with each sample's real stamp."""
        return predict_window_by_stream(self, window, warm_samples)

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) prediction in the evaluation's trimmed convention."""
        return trim_prediction(window, self.predict_absolute(window, warm_samples), self.trim)


def predict_horizons_by_stream(predictor: StreamingPredictor, segment: FlightLog, starts: np.ndarray, horizon: int,
                               warm_samples: int) -> np.ndarray:
    """(S, horizon + 1, 18) absolute predictions from each start, by the live form (module docstring).

    Row ``[i, 0]`` is the predictor's own output at the anchor ``s = starts[i]`` (the last row
    ``start_window`` returns for the warm rows ``s - warm_samples + 1 .. s``); row ``[i, h]`` is
    what ``push(u[s + h])`` returns, h = 1..horizon. DataError when a start leaves no room for the
    warm rows before it or the horizon after it.
    """
    starts = np.asarray(starts, dtype=int)
    if warm_samples < 1:
        raise DataError(f"{segment.meta.source}: multi-step needs at least 1 warm-start row, got {warm_samples}")
    if starts.size and (starts.min() < warm_samples - 1 or starts.max() + horizon >= len(segment)):
        raise DataError(f"{segment.meta.source}: multi-step starts {starts.min()}..{starts.max()} with {warm_samples} warm rows "
                        f"and horizon {horizon} leave the segment of {len(segment)} rows")
    out = np.empty((starts.size, horizon + 1, len(VARIABLES)))
    for i, s in enumerate(starts):
        warm_predictions, stream = predictor.start_window(segment.slice(s - warm_samples + 1, s + 1))
        out[i, 0] = warm_predictions[-1]
        for h in range(1, horizon + 1):
            out[i, h] = stream.push(segment.u[s + h])
    return out


class StreamingHorizons:
    """A streaming predictor as a :class:`~quad_modelling.core.models.base.MultiStepPredictor`
    (:func:`predict_horizons_by_stream` with ``warm_samples`` warm rows); the name is the predictor's."""

    def __init__(self, predictor: StreamingPredictor, warm_samples: int):
        self.predictor = predictor
        self.name = predictor.name
        self.warm_samples = warm_samples

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        return predict_horizons_by_stream(self.predictor, segment, starts, horizon, self.warm_samples)


class RecordedPrediction:
    """A Predictor over absolute predictions already computed (e.g. received over ROS).

    ``predict_window`` returns them in the evaluation's trimmed convention
    (:func:`~quad_modelling.core.preprocess.trim_prediction`), as the offline
    predictors do.
    """

    def __init__(self, name: str, predictions: np.ndarray, trim=None):
        self.name = name
        self.predictions = np.asarray(predictions, dtype=float)
        self.trim = trim

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        from quad_modelling.core.preprocess import trim_prediction

        if self.predictions.shape != (len(window), len(VARIABLES)):
            raise DataError(f"model {self.name}: {self.predictions.shape[0]} recorded predictions for a window of {len(window)} samples")
        return trim_prediction(window, self.predictions, self.trim)



PRIME_PUSHES = 8
"""Commands pushed through the priming window (:func:`prime`)."""


def hover_at_rest(vehicle: VehicleConfig, sample_period_s: float, rows: int) -> FlightLog:
    """A ``rows``-sample log of the vehicle hovering still at 1 m [N, NED]: mid-range commands, level
    attitude, the specific force of hover (-g on body z, FRD), no motion."""
    t = np.arange(rows) * sample_period_s
    zeros = np.zeros((rows, 3))
    acc_b = zeros.copy()
    acc_b[:, 2] = -GRAVITY
    pos_n = zeros.copy()
    pos_n[:, 2] = -1.0
    return FlightLog(t=t, u=np.full((rows, 4), 0.5 * (vehicle.input_min + vehicle.input_max)), acc_b=acc_b,
                     gyro_b=zeros.copy(), pos_n=pos_n, vel_n=zeros.copy(), euler=zeros.copy(),
                     meta=FlightMeta(vehicle=vehicle.name, source="priming window (hover at rest)"))


def prime(predictor: StreamingPredictor, vehicle: VehicleConfig, sample_period_s: float, warm_rows: int) -> None:
    """Run one synthetic window (:func:`hover_at_rest`) through ``predictor`` and discard it.

    A model's first window pays one-time costs -- lazy imports inside scipy, the
    discretisation cache, torch's first forward pass: 10-20 ms measured for the
    greybox against about 1.5 ms for later windows. A live node primes its model
    at start-up so the first real window does not hold its answers back by that.
    A model trained at one sample period (``predictor.sample_period_s``: NARX) is
    primed at that period, whatever ``sample_period_s`` says: it refuses any other,
    and a NARX node left unprimed at 400 Hz held its first window's answers back by
    37 ms (bench_nodes, 17 inputs queued behind it). Models that reject the
    synthetic window (DataError, ValueError) are simply left unprimed.
    """
    sample_period_s = getattr(predictor, "sample_period_s", None) or sample_period_s
    warm = hover_at_rest(vehicle, sample_period_s, max(warm_rows, 2))
    try:
        _, stream = predictor.start_window(warm)
        for _ in range(PRIME_PUSHES):
            stream.push(warm.u[-1])
    except (DataError, ValueError):
        return


# --- receding horizon, live ----------------------------------------------------------------------

HORIZON_PERIOD_STEPS = 20
"""Command steps whose median gives dt (h = round(horizon_s / dt)) when ``sample_period_s`` is 0."""

MAX_LIVE_HORIZON_STEPS = 10_000
"""Most steps h of a live receding horizon (25 s at 400 Hz): each input rolls the model out h steps (a burst of
inputs 1 us apart made dt 1 us, h 100 000, and a predictor that answered nothing and ignored SIGINT)."""


HORIZON_INPUTS = ("hold", "flown")
"""Commands after a receding-horizon anchor (:class:`RecedingHorizon`): the last one held, or the flown ones."""


def hold_inputs(segment: FlightLog, s: int) -> FlightLog:
    """A copy of ``segment`` whose commands (and rotor speeds, when logged) after row ``s`` are those of row ``s``:
    the input log of a hold-mode prediction from anchor s (:class:`RecedingHorizon`), offline."""
    u = segment.u.copy()
    u[s + 1:] = u[s]
    omega = None
    if segment.omega is not None:
        omega = segment.omega.copy()
        omega[s + 1:] = omega[s]
    return dataclasses.replace(segment, u=u, omega=omega)


class RecedingHorizon:
    """Receding-horizon anchors and their multi-step predictions (module docstring).

    ``form_for(warm)`` -> the multi-step form with ``warm`` warm rows (None: the model has none);
    ``make_log(stamps [ns], rows (stamp, command, rotor speeds), measurements)`` -> FlightLog of those rows;
    ``measurements(ns)`` (in :meth:`ready`) -> the measurements at a stamp or None;
    ``covered(ns)`` -> True when every stream holds a sample at or after ``ns``; ``wait_s``: how long
    [wall s] an anchor waits for that before it is computed from what the streams give;
    ``inputs``: the commands after an anchor, ``"hold"`` (u_s held: a forecast at input s) or ``"flown"``
    (the recorded ones: predicted when command s + h is in), :data:`HORIZON_INPUTS`; ``carried_for(dt [s], h)``
    -> the model's carried-state forecast or None (module docstring); ``ends_only``: the predictions yielded are
    rows 0 (the anchor) and h only (what a forecast publishes and checks), not the h + 1 rows.
    """

    def __init__(self, form_for: Callable, make_log: Callable, horizon_s: float, warm_s: float, history_s: float,
                 sample_period_s: float, wait_s: float, inputs: str = "hold", carried_for: Callable | None = None,
                 ends_only: bool = False):
        if inputs not in HORIZON_INPUTS:
            raise ValueError(f"receding-horizon inputs {inputs!r}: expected one of {', '.join(HORIZON_INPUTS)}")
        self.form_for, self.make_log, self.carried_for, self.ends_only = form_for, make_log, carried_for, ends_only
        self.carried_form = self.carried = None  # the model's carried forecast (built once h is known); active one
        self._forget_carried()
        self.horizon_s, self.warm_s, self.history_s = horizon_s, warm_s, history_s
        self.sample_period_s, self.wait_s = sample_period_s, wait_s
        self.inputs = inputs
        self.rows: deque[tuple[int, np.ndarray, np.ndarray | None]] = deque()  # (stamp, command, rotor speeds)
        self.steps_seen: list[int] = []
        self.steps = None  # h, once dt is known
        self.period_ns = None  # dt [ns], once known: the step of the held commands' stamps
        self.too_long = False  # h over MAX_LIVE_HORIZON_STEPS at the measured dt: no horizon predictions (said once)
        self.form = None
        self.wait_since = None

    def reset(self) -> None:
        """A new time base (restart, clock jump): forget the commands (and the carried anchor); h and the form stay."""
        self.rows.clear()
        self.steps_seen = []
        self.wait_since = None
        self.too_long = False  # h is measured again on the new time base (while it is not known yet)
        if self.steps is not None:
            self.next, self.first = self.warm - 1, 0
        self._forget_carried()

    def _forget_carried(self) -> None:
        """Start the carried anchor over (a new time base): no row added yet."""
        self.carried = self.carried_form
        if self.carried is not None:
            self.carried.reset()
        self.context = None  # the last row added to the carried form and its measurement (the next log's first row)
        self.fed = 0  # index (as ``next``) of the first row not added yet

    def add(self, ns: int, u: np.ndarray, omega) -> tuple[str, str] | None:
        """Keep a command; learn h once dt is known. Returns a fault (kind, sentence) when the model has no multi-step
        form, when a measured dt is shorter than :data:`~quad_modelling.core.windows.MIN_SAMPLE_PERIOD_S` (measured
        again over the next steps), or once when dt makes h more than :data:`MAX_LIVE_HORIZON_STEPS` (then no horizon
        predictions; a given ``sample_period_s`` the node checks at start)."""
        if self.too_long:  # said once (add's fault): nothing kept
            return None
        if self.rows:
            self.steps_seen.append(ns - self.rows[-1][0])
            del self.steps_seen[:-HORIZON_PERIOD_STEPS]
        self.rows.append((ns, u, omega))
        if self.steps is not None:
            return None
        period_s = self.sample_period_s
        if not period_s and len(self.steps_seen) >= HORIZON_PERIOD_STEPS:
            period_s = float(np.median(self.steps_seen)) / 1e9
        if not period_s:
            return None
        if period_s < MIN_SAMPLE_PERIOD_S:  # a burst of inputs: dt measured again over the next steps
            self.steps_seen = []
            while len(self.rows) > 1:  # the rows kept until then: the last
                self.rows.popleft()
            return "horizon_period", (f"receding horizon: the median of the last {HORIZON_PERIOD_STEPS} motor_input steps is "
                                      f"{period_s:.3g} s, under {MIN_SAMPLE_PERIOD_S:g} s: measured again over the next ones")
        if self.horizon_s / period_s > MAX_LIVE_HORIZON_STEPS:  # for good: no horizon predictions on this time base
            self.steps_seen, self.too_long = [], True
            self.rows.clear()
            return "horizon_period", (f"receding horizon: horizon_s {self.horizon_s:g} s at dt {period_s:.3g} s is "
                                      f"{self.horizon_s / period_s:.0f} steps, more than {MAX_LIVE_HORIZON_STEPS}: no horizon predictions")
        self.steps = max(1, int(round(self.horizon_s / period_s)))
        self._ends = np.array([0, self.steps])  # the rows ends_only asks for: the anchor's and the last
        self.period_ns = int(round(period_s * 1e9))
        self.warm = max(1, int(round(self.warm_s / period_s)))
        self.keep = max(int(round(self.history_s / period_s)), self.warm)
        self.form = self.form_for(self.warm)
        self.next, self.first = self.warm - 1, 0  # the first anchor with warm rows up to it; index of rows[0]
        if self.carried_for is not None:
            try:
                self.carried_form = self.carried_for(period_s, self.steps)
            except (QuadModellingError, ValueError):
                self.carried_form = None  # the history re-run reports the model's error at each anchor
            self._forget_carried()
        return None if self.form is not None else ("no_multistep_form", "has no multi-step form: no horizon predictions")

    def waiting(self) -> bool:
        """True when an anchor's commands are in and it waits for its measurements (the node then decodes them at once)."""
        if self.steps is None or self.form is None:
            return False
        return self.next + (self.steps if self.inputs == "flown" else 0) < self.first + len(self.rows)

    def ready(self, covered: Callable[[int], bool], measurements: Callable) -> Iterator[tuple]:
        """Every anchor that is ready, in order: its command s (``hold``; s + h for ``flown``) is in and its
        measurements are covered. Yields ("prediction", stamp [ns], (h + 1, 18) prediction (rows 0 and h:
        (2, 18) with ``ends_only``), stamp - t_s [s]) with
        the stamp of the predicted time (t_s + h dt held, t_{s+h} flown) or ("fault", kind, sentence)."""
        if self.steps is None or self.form is None:
            return
        rows, h = self.rows, self.steps
        ahead = h if self.inputs == "flown" else 0  # commands after the anchor it waits for
        while self.next + ahead < self.first + len(rows):
            s = self.next - self.first  # the anchor's index in rows
            if not covered(rows[s][0]):
                self.wait_since = self.wait_since or time.monotonic()
                if time.monotonic() - self.wait_since < self.wait_s:
                    return
            self.wait_since = None
            yield self._predict(s, measurements)
            self.next += 1
            for _ in range(max(0, s - self.keep + 2)):  # rows the next anchor's history no longer holds
                rows.popleft()
                self.first += 1

    def _after(self, s: int) -> list[tuple]:
        """The h rows after anchor ``s`` (index in rows): the flown ones, or u_s (and its rotor speeds) held at t_s + k dt."""
        if self.inputs == "flown":
            return [self.rows[i] for i in range(s + 1, s + self.steps + 1)]
        ns, u, omega = self.rows[s]
        return [(ns + k * self.period_ns, u, omega) for k in range(1, self.steps + 1)]

    def _after_arrays(self, s: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_after` as (h,) stamps [ns] and (h, n_u) commands; held inputs built as arrays at once."""
        if self.inputs == "flown":
            after = self._after(s)
            return np.array([r[0] for r in after], dtype=np.int64), np.array([r[1] for r in after])
        ns, u, _ = self.rows[s]
        return ns + self.period_ns * np.arange(1, self.steps + 1, dtype=np.int64), np.repeat(np.asarray(u)[None, :], self.steps, axis=0)

    def _predict(self, s: int, measurements: Callable) -> tuple:
        if self.carried is not None:
            return self._predict_carried(s, measurements)
        return self._predict_history(s, measurements)

    def _predict_history(self, s: int, measurements: Callable) -> tuple:
        """Anchor ``s`` (index in rows) by the model's multi-step form over the history rows up to it."""
        rows, h = self.rows, self.steps
        first = max(0, s - self.keep + 1)
        history = [rows[i] for i in range(first, s + 1)] + self._after(s)
        measured = [measurements(row[0]) for row in history[:s - first + 1]]
        if measured[-1] is None:
            return "fault", "horizon_gap", "an anchor without a measurement within tolerance: skipped"
        # a row before the anchor without a measurement takes its successor's (inside tolerance gaps are rare); rows
        # after the anchor take the anchor's: the multi-step form reads nothing after the anchor but the commands
        filled = list(measured) + [measured[-1]] * h
        for i in range(len(filled) - 1, -1, -1):
            if filled[i] is None:
                filled[i] = filled[i + 1]
        stamps = np.array([row[0] for row in history], dtype=np.int64)
        try:
            log = self.make_log(stamps, history, filled)
            prediction = self.form.predict_horizons(log, np.array([s - first]), h)[0]
            if self.ends_only:
                prediction = prediction[[0, h]]
        except (QuadModellingError, ValueError) as err:
            return "fault", "model_error", f"failed: {err}"
        return "prediction", int(stamps[-1]), prediction, (stamps[-1] - stamps[s - first]) / 1e9

    def _predict_carried(self, s: int, measurements: Callable) -> tuple:
        """Anchor ``s`` (index in rows) by the carried form (:mod:`~quad_modelling.core.live.forecast`): the rows since
        the last one added (a row without a measurement takes its successor's, as in the history re-run) are added in
        one log behind the last added row, then the model is rolled out over the h rows after s."""
        row = self.rows[s]
        if measurements(row[0]) is None:  # stays unadded: it takes the next measured row's measurement
            return "fault", "horizon_gap", "an anchor without a measurement within tolerance: skipped"
        start = self.fed - self.first  # index in rows of the first row not added yet
        if start < 0:  # rows left the history before they could be added (a long run without measurements)
            self.carried = None
            return self._predict_history(s, measurements)
        new = [self.rows[i] for i in range(start, s + 1)]
        measured = [measurements(r[0]) for r in new]
        for i in range(len(measured) - 2, -1, -1):
            if measured[i] is None:
                measured[i] = measured[i + 1]
        rows = ([self.context] if self.context is not None else []) + list(zip(new, measured))
        if len(rows) < 2:  # a log needs 2 rows: the time base's first anchor alone is re-run
            return self._predict_history(s, measurements)
        stamps = np.array([r[0] for r, _ in rows], dtype=np.int64)
        after_ns, u_after = self._after_arrays(s)
        try:
            log = self.make_log(stamps, [r for r, _ in rows], [m for _, m in rows])
            if log.gyro_b is None:  # the carried forms need the gyro: this time base is re-run over its history
                self.carried = None
                return self._predict_history(s, measurements)
            self.carried.add(log, 1 if self.context is not None else 0)
            self.context, self.fed = rows[-1], self.first + s + 1
            prediction = self.carried.predict(after_ns / 1e9, u_after, self._ends if self.ends_only else None)
        except (QuadModellingError, ValueError) as err:
            self.carried = None  # its anchor may be half-added: the rest of this time base is re-run
            return "fault", "model_error", f"failed: {err}"
        return "prediction", int(after_ns[-1]), prediction, (after_ns[-1] - row[0]) / 1e9
