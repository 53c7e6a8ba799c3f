"""The predictor contracts every model implements, and the two baselines (dummy, naive).

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

**Causality rule** (every mode, every model): a prediction anchored at row s (the last warm
row of a window, a multi-step start) is computed from the measurements of rows <= s and the
commands up to the predicted row, nothing later -- trims, detrending, filters and derivatives
included (a zero-phase filter or a centred derivative reads rows after s: only their causal,
past-only forms may feed an anchor). The *evaluation* may use the whole window: the truth is
smoothed with a zero-phase filter, and both measurement and prediction are trimmed with the
measured mean over the window's first ``trim_s`` seconds (a shift of both, so the error is the
absolute prediction's error). ``test/core/models/test_causality.py`` checks every model.

Predictors may carry ``label`` (a short tag for tables, e.g. the greybox's "thesis reproduction")
and ``description`` (one sentence for a report's model notes).

Predictors that can also run the IDSIA multi-step protocol implement
:class:`MultiStepPredictor` as well (absolute values, not trimmed); those that
can run live implement
:class:`~quad_modelling.core.models.streaming.StreamingPredictor`.

Baselines, reported next to every model (DESIGN 7): :class:`DummyPredictor`
(zero, thesis Fig 5.2) and :class:`ConstantStatePredictor` (naive: the last
measured state held). Specs are built by :mod:`quad_modelling.core.models.registry`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.streaming import predict_window_by_stream
from quad_modelling.core.preprocess import (
    TrimConfig,
    measured_variables,
    trim_prediction,
)
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

        Causal (the causality rule of the module docstring): ``[s, h]`` may read the
        measurements of rows ``<= starts[s]`` and the commands of rows ``<= starts[s] + h``,
        nothing later, although the whole segment is passed (one call serves many starts).
        """
        ...


class DummyPredictor:
    """Predicts zero for every trimmed variable: the baseline always reported (thesis Fig 5.2: TIC = 1 always).

    The one dummy of offline evaluation and of the live evaluator node, which scores it at window
    close without a predictor node. It has no streaming form: its absolute prediction is the
    window's trim value, known only once the trim interval has passed.
    """

    name = "dummy"
    label = "baseline"
    description = "dummy = predicts zero for every trimmed variable (thesis Fig 5.2: TIC = 1)"

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        return np.zeros((len(window), len(VARIABLES)))


class HeldState:
    """The naive baseline's :class:`~quad_modelling.core.models.streaming.WindowStream`: every sample repeats ``state``."""

    def __init__(self, state: np.ndarray):
        self.state = state

    def push(self, command: np.ndarray) -> np.ndarray:
        return self.state


class ConstantStatePredictor:
    """The naive baseline: holds the last measured state, :math:`\\hat y(s + h) = y_m(s)`.

    The one naive model of every mode:

    * live (:meth:`start_window`, the predictor node's ``naive``): the measurement of the warm
      rows (absolute), then the last warm row held for every later sample;
    * offline window (:meth:`predict_window`): the same calls through
      :func:`~quad_modelling.core.models.streaming.predict_window_by_stream`, trimmed, so offline
      and live give the same numbers;
    * multi-step (:meth:`predict_horizons`, the reference of the IDSIA ratios): the measured state
      at each start, held for every horizon.

    The measurement is :func:`~quad_modelling.core.preprocess.measured_variables` with the vehicle's config,
    causal at the anchor: live and window forms see the warm rows only (the anchor's angular acceleration
    is the end of a fit over them); multi-step differentiates from past rows (``causal=True``), the same
    fit, so every mode holds the same state at the same anchor.
    """

    name = "naive"
    label = "baseline"
    description = "naive = the measured state at the anchor, held (the reference of the multi-step ratios)"

    def __init__(self, vehicle: VehicleConfig, trim: TrimConfig | None = None):
        self.vehicle = vehicle
        self.trim = trim or TrimConfig()

    def start_window(self, warm: FlightLog) -> tuple[np.ndarray, HeldState]:
        """Live form: (the warm rows' measurement (W, 18), a stream holding its last row), absolute."""
        measured = measured_variables(warm, self.vehicle)
        return measured, HeldState(measured[-1].copy())

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        return trim_prediction(window, predict_window_by_stream(self, window, warm_samples), self.trim)

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        measured = measured_variables(segment, self.vehicle, causal=True)
        return np.repeat(measured[np.asarray(starts)][:, None, :], horizon + 1, axis=1)
