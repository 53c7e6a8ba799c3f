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

:class:`RecordedPrediction` wraps predictions received over ROS as a
:class:`~quad_modelling.core.models.Predictor`, so the live evaluator scores a
window with the same :func:`~quad_modelling.core.evaluation.evaluate_window`
as ``quad-modelling evaluate``.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.vehicle import GRAVITY, VehicleConfig
from quad_modelling.errors import DataError


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
    Models that reject the synthetic window (DataError, ValueError) are simply
    left unprimed.
    """
    warm = hover_at_rest(vehicle, sample_period_s, max(warm_rows, 2))
    try:
        _, stream = predictor.start_window(warm)
        for _ in range(PRIME_PUSHES):
            stream.push(warm.u[-1])
    except (DataError, ValueError):
        return
