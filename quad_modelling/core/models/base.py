"""The predictor contract every model implements, and the model registry.

A predictor predicts one evaluation window (thesis 2.2, DESIGN 7): it is given
the whole window as a :class:`~quad_modelling.core.flight_log.FlightLog` and
may use

* the engine commands ``window.u`` of the entire window (they are the model
  input), and
* the measurements of the first ``warm_samples`` rows only (the thesis gives
  the models the first 0.2 s of measurements "so they had the correct start
  values").

It returns an (N, 18) array in :data:`quad_modelling.core.variables.VARIABLES`
column order, in the *trimmed* convention of
:func:`quad_modelling.core.preprocess.trimmed_variables`: every variable is the
deviation from its trim value, the mean over the window's stable interval
(the first ``TrimConfig.trim_s`` seconds). The evaluator compares it with the
trimmed best measurement of the same window; rows ``< warm_samples`` are not
scored.

Predictors that can also run the IDSIA multi-step protocol implement
:class:`MultiStepPredictor` as well (absolute values, not trimmed).

Specs such as ``greybox`` or ``narx:PATH`` are built by :mod:`quad_modelling.core.models.registry`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.preprocess import TrimConfig
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.vehicle import VehicleConfig


@runtime_checkable
class Predictor(Protocol):
    """Predicts one window of the 18 variables (see module docstring)."""

    name: str

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) trimmed prediction of ``window`` in VARIABLES order."""
        ...


@runtime_checkable
class MultiStepPredictor(Protocol):
    """Open-loop predictions from many start times (IDSIA multi-step protocol)."""

    name: str

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute predictions (not trimmed).

        Row ``[s, h]`` predicts sample ``starts[s] + h`` of ``segment`` from the
        measured state at ``starts[s]`` and the commands from ``starts[s]`` on;
        ``[s, 0]`` is the starting state. Every ``starts[s] + horizon`` is a
        valid row of ``segment``.
        """
        ...


class DummyPredictor:
    """Predicts zero for every trimmed variable (thesis Fig 5.2: TIC = 1 always)."""

    name = "dummy"

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        return np.zeros((len(window), len(VARIABLES)))


class ConstantStatePredictor:
    """Holds the last warm-start measurement: the naive baseline.

    predict_window: the measurement of the warm rows, then the one at row
    ``warm_samples - 1`` for all later rows (trimmed; the live form
    :meth:`start_window` gives the same numbers); predict_horizons: the measured
    state at each start, constant.
    """

    name = "naive"

    def __init__(self, vehicle: VehicleConfig, trim: TrimConfig | None = None):
        self.vehicle = vehicle
        self.trim = trim or TrimConfig()

    def start_window(self, warm: FlightLog):
        """Live form: the warm measurement, then its last row held (absolute)."""
        from quad_modelling.core.models.streaming import HoldLastMeasurement
        from quad_modelling.core.preprocess import measured_variables

        return HoldLastMeasurement(lambda log: measured_variables(log, self.vehicle)).start_window(warm)

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        from quad_modelling.core.models.streaming import predict_window_by_stream
        from quad_modelling.core.preprocess import trim_prediction

        return trim_prediction(window, predict_window_by_stream(self, window, warm_samples), self.trim)

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        from quad_modelling.core.preprocess import measured_variables

        measured = measured_variables(segment, self.vehicle)
        return np.repeat(measured[np.asarray(starts)][:, None, :], horizon + 1, axis=1)



