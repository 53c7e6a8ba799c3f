"""The sensor ceiling of a known-answer run: the shrink a perfect model would reach (DESIGN 8, point 4a).

A *perfect model* predicts the vehicle's physics exactly and is run the way the diagnosis runs the base model
(:func:`~quad_modelling.core.identification.base_model.predict_batch`): anchored on the measured warm start,
with the accelerations the modelled body force rotated by the measured attitude. What it cannot predict is
what the sensors add that no model sees: white noise in every sample, and the bias random walk after the
warm start. Everything else a sensor does -- the turn-on bias, the walk up to the warm start, the anti-alias
averaging over the log period -- is either a deterministic function of the physics or carried by the warm
start, exactly as the base model carries it.

So the perfect model's prediction is built from the simulator's *noise-free IMU* (``imu_noise_free_*`` in
``SimResult.truth``: the IMU output with every error the simulator applies except the white noise) put
through the same preprocessing (``sensor``, a :class:`WindowBatch` of the same windows), and re-anchored on
the measured warm start:

.. math::

    \\hat a_N(t) = a^s_N(t) + \\overline{a}^s_{trim} - \\overline{a}_{trim}
                   + R(\\eta_m(t))\\,(f_{B,0} - f^s_{B,0}), \\qquad
    \\hat{\\dot\\omega}(t) = \\dot\\omega^s(t) + o_{\\dot\\omega} - o^s_{\\dot\\omega}

(low-passed as the measurement): :math:`a^s_N` the noise-free sensor's trimmed acceleration in N,
:math:`\\overline a_{trim}` the window trims, :math:`f_{B,0}` the warm-start mean body specific force (the
base model's anchor, bias and warm-start noise included), :math:`R(\\eta_m)` the measured attitude,
:math:`o_{\\dot\\omega}` the angular-acceleration linearisation point (the gyro slope over the warm start,
:func:`~quad_modelling.core.identification.base_model.angular_acceleration_offsets`), superscript *s* the
same of the noise-free sensor. The previous ceiling compared the measurement with the *true* signals: it
charged the model for the accelerometer bias turning with the attitude, which the warm start carries (rotor
drag shrank 58.3 % against a "ceiling" of 55.5 % on seed 31337).

The ceiling of a run and variable v is :math:`1 - G_{perfect,v} / G_{base,v}` over the windows its shrink is
scored on; the run's is the same on the effect's affected variables, normalised as the shrink
(:func:`~quad_modelling.core.diagnosis.statistics.normalised_window_gap`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.diagnosis.statistics import normalised_window_gap, window_rms
from quad_modelling.core.identification.base_model import (
    ACCELERATION_COLUMNS,
    ANGULAR_ACCELERATION_COLUMNS,
    angular_acceleration_offsets,
)
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.preprocess import smooth
from quad_modelling.core.variables import INDEX
from quad_modelling.errors import DataError


def perfect_model_prediction(test: WindowBatch, sensor: WindowBatch) -> np.ndarray:
    """(W, N, 18) the perfect model's prediction of ``test`` (module docstring); valid on the accelerations and
    angular accelerations (the scored variables), the noise-free sensor's measurement elsewhere.

    ``sensor``: the same flights with the noise-free IMU, cut into the same windows (DataError otherwise).
    """
    if sensor.measured.shape != test.measured.shape or not np.array_equal(sensor.t0, test.t0) or sensor.sources != test.sources:
        raise DataError(f"the noise-free sensor flights cut into other windows ({len(sensor)}) than the test flights ({len(test)})")
    predicted = sensor.measured.copy()
    w, n = test.measured.shape[:2]
    rotation = frames.euler_ned_to_matrix(test.euler.reshape(-1, 3)).reshape(w, n, 3, 3)
    carried = np.einsum("wkij,wj->wki", rotation, test.specific_force0 - sensor.specific_force0)
    shift = carried + (sensor.acc_trim - test.acc_trim)[:, None, :]
    predicted[:, :, ACCELERATION_COLUMNS] += smooth(shift.transpose(1, 0, 2), 1.0 / test.dt, test.smooth_cutoff_hz).transpose(1, 0, 2)
    offsets = angular_acceleration_offsets(test) - angular_acceleration_offsets(sensor)
    predicted[:, :, ANGULAR_ACCELERATION_COLUMNS] += offsets[:, None, :]
    return predicted


def sensor_ceiling(test: WindowBatch, sensor: WindowBatch, base_test: np.ndarray, scales: np.ndarray, variables: Sequence[str],
                   scored: np.ndarray | None = None) -> dict:
    """The ceiling of one run (module docstring): {"sensor_ceiling": on ``variables`` normalised as the shrink,
    "by_variable": {v: ceiling}, "gap_perfect": mean normalised perfect-model gap per scored window}.

    ``scored``: (W,) bool, the windows the shrink is scored on (all when None or none)."""
    perfect = perfect_model_prediction(test, sensor)
    scored = np.ones(len(test), dtype=bool) if scored is None or not np.any(scored) else np.asarray(scored)
    cols = np.array([INDEX[v] for v in variables])
    g_base = normalised_window_gap(test, base_test, cols, scales)[scored]
    g_perfect = normalised_window_gap(test, perfect, cols, scales)[scored]
    rms_base = window_rms(test, base_test, cols)[scored].sum(axis=0)
    rms_perfect = window_rms(test, perfect, cols)[scored].sum(axis=0)
    by_variable = {v: float(1.0 - rms_perfect[i] / rms_base[i]) if rms_base[i] > 0 else 0.0 for i, v in enumerate(variables)}
    total = float(g_base.sum())
    return {"sensor_ceiling": 1.0 - float(g_perfect.sum()) / total if total > 0 else 0.0, "by_variable": by_variable,
            "gap_perfect": float(g_perfect.mean())}
