"""Hybrid model (beyond the thesis): linear greybox + a NARX net on its residual.

The greybox (:class:`~quad_modelling.core.models.greybox.GreyboxPredictor`) predicts
the trimmed 18 variables ``g`` of a window. Six NARX nets (the architecture of
:mod:`quad_modelling.core.models.narx`) predict the greybox's residual on the six
velocities/rates,

.. math::

    r_k(t) = y_{m,k}(t) − g_k(t),

    r_k(t) = f_k\\big([u(t−d), g_{1..6}(t−d)]_{d ∈ D_u},\\ r_k(t−n_y), …, r_k(t−1)\\big),

i.e. the exogenous inputs are the four engine commands *and* the greybox's six
predicted velocities/rates. Training is series-parallel on windows cut from the
training spans exactly as the evaluation cuts them (``window_s``, greybox
re-anchored on the first ``warm_s`` of each window), so the residual the net
learns is the one it will meet. Prediction: greybox, then the residual nets in
closed loop from the first measured residuals, and

.. math::

    ŷ_k = g_k + r̂_k,\\quad  ŝ = g_s + ∫ r̂ \\,dt,\\quad  â = g_a + dr̂/dt

for velocities/rates, positions/angles and accelerations respectively (the
greybox's own accelerations are kept and corrected, not re-derived).

Model files are NARX model files of kind ``hybrid``; their header also stores
the greybox discretisation, window settings and the vehicle constants the
greybox used, and loading refuses a vehicle whose constants changed.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.model_files import read_model_file
from quad_modelling.core.models.narx import (
    DIFFERENTIATED,
    INTEGRATED,
    OUTPUTS,
    NarxConfig,
    NarxModel,
    check_sample_rate,
    model_from_parts,
)
from quad_modelling.core.models.narx_training import (
    Segment,
    common_sample_period,
    span_indices,
    train_narx,
)
from quad_modelling.core.preprocess import trimmed_variables
from quad_modelling.core.variables import columns
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import windows_between
from quad_modelling.errors import ConfigError, DataError, ModelError, reason

WINDOW_S = 10.0
"""Training window length [s] (the evaluation's, thesis 5.2)."""
WARM_S = 0.2
"""Warm start given to the greybox and the residual nets [s] (thesis: 0.2 s)."""


def vehicle_constants(vehicle: VehicleConfig) -> dict[str, float]:
    """The vehicle constants the greybox uses, as stored in a hybrid model file."""
    return {key: float(c.value) for key, c in sorted(vehicle.constants.items())}


class HybridModel:
    """A greybox plus residual NARX nets (see module doc)."""

    def __init__(self, residual: NarxModel, vehicle: VehicleConfig, discretisation: str = "zoh") -> None:
        from quad_modelling.core.models.greybox import GreyboxPredictor

        if residual.kind != "hybrid":
            raise ModelError(f"hybrid model needs residual nets of kind 'hybrid', got {residual.kind!r}")
        self.residual = residual
        self.vehicle = vehicle
        self.greybox = GreyboxPredictor(vehicle, discretisation=discretisation)
        self.discretisation = discretisation

    @property
    def warm_samples(self) -> int:
        return self.residual.config.output_delays

    @property
    def trim(self):
        """The trim of the prediction: the greybox's."""
        return self.greybox.trim

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) trimmed prediction: greybox plus closed-loop residual correction."""
        window.require(("gyro_b",), "model hybrid (its residual nets are seeded with measured gyro rates)")
        check_sample_rate(self.residual, window)
        warm = max(int(warm_samples), self.warm_samples)
        if warm >= len(window):
            raise DataError(f"{window.meta.source}: window of {len(window)} samples is shorter than the {warm} warm-up samples")
        greybox = self.greybox.predict_window(window, warm_samples)
        measured = trimmed_variables(window, self.greybox.trim, self.vehicle)
        out = columns(OUTPUTS)
        residual_warm = measured[:warm, out] - greybox[:warm, out]
        residual = self.residual.simulate(exogenous_inputs(window, greybox), residual_warm)
        return corrected(window, greybox, residual)

    def save(self, path: str | Path, force: bool = False) -> Path:
        return self.residual.save(path, force)


def exogenous_inputs(window: FlightLog, greybox: np.ndarray) -> np.ndarray:
    """(N, 10) exogenous inputs of the residual nets: engine commands and greybox velocities/rates."""
    return np.concatenate([window.u, greybox[:, columns(OUTPUTS)]], axis=1)


def corrected(window: FlightLog, greybox: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Greybox prediction plus residual r̂ (N, 6): added to rates, integrated into angles, differentiated into accelerations."""
    from scipy.integrate import cumulative_trapezoid

    out = greybox.copy()
    out[:, columns(OUTPUTS)] += residual
    out[:, columns(INTEGRATED)] += cumulative_trapezoid(residual, window.t, axis=0, initial=0.0)
    out[:, columns(DIFFERENTIATED)] += np.gradient(residual, window.t, axis=0)
    return out


def residual_segments(
    logs: list[FlightLog],
    spans: list[tuple[float, float] | None],
    vehicle: VehicleConfig,
    discretisation: str = "zoh",
    window_s: float = WINDOW_S,
    warm_s: float = WARM_S,
) -> list[Segment]:
    """Training segments of the residual nets: one per full window of each span (inputs u ⊕ g, output r)."""
    from quad_modelling.core.models.greybox import GreyboxPredictor

    greybox = GreyboxPredictor(vehicle, discretisation=discretisation)
    segments = []
    for log, span in zip(logs, spans):
        log.require(("gyro_b",), "hybrid training (the residual nets learn gyro rates)")
        if span is not None:
            span_indices(log, span)  # DataError when the span holds no data
        a, b = (0.0, math.inf) if span is None else span
        warm = max(1, int(round(warm_s * log.sample_rate)))
        for start, stop in windows_between(log, a, b, window_s):
            window = log.slice(start, stop)
            g = greybox.predict_window(window, warm)
            measured = trimmed_variables(window, greybox.trim, vehicle)
            r = measured[:, columns(OUTPUTS)] - g[:, columns(OUTPUTS)]
            t0 = float(window.t[0] - log.t[0])
            segments.append(Segment(exogenous_inputs(window, g), r, log.meta.source, (t0, t0 + window_s)))
    if not segments:
        raise DataError(
            f"hybrid training: no {window_s:g} s window fits the training spans of "
            + ", ".join(f"{log.meta.source} ({log.duration:.1f} s)" for log in logs)
        )
    return segments


def train_hybrid_on_flights(
    logs: list[FlightLog],
    spans: list[tuple[float, float] | None],
    vehicle: VehicleConfig,
    config: NarxConfig = NarxConfig(),
    seed: int = 0,
    progress: bool = False,
    discretisation: str = "zoh",
    window_s: float = WINDOW_S,
    warm_s: float = WARM_S,
) -> HybridModel:
    """Train the residual nets of a hybrid model on windows of the training spans."""
    names = sorted({log.meta.vehicle for log in logs})
    if names != [vehicle.name]:
        raise DataError(f"hybrid training: flights are for vehicle(s) {names}, the greybox for {vehicle.name!r}")
    segments = residual_segments(logs, spans, vehicle, discretisation, window_s, warm_s)
    info = {"greybox": {"discretisation": discretisation, "constants": vehicle_constants(vehicle)},
            "window_s": window_s, "warm_s": warm_s}
    residual = train_narx(segments, common_sample_period(logs), vehicle.name, config, seed, progress, kind="hybrid", training=info)
    return HybridModel(residual, vehicle, discretisation)


def load_hybrid(path: str | Path, vehicle: VehicleConfig) -> HybridModel:
    """Load a hybrid model file for ``vehicle``; ModelError when it was made for another vehicle or constants."""
    path = Path(path)
    header, contents = read_model_file(path, "hybrid", OUTPUTS, vehicle.name)
    residual = model_from_parts(path, header, contents)
    try:
        greybox = header["training"]["greybox"]
        discretisation = str(greybox["discretisation"])
        stored = {k: float(v) for k, v in greybox["constants"].items()}
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as err:
        raise ModelError(f"{path}: hybrid model file lacks its greybox settings ({reason(err)})") from err
    current = vehicle_constants(vehicle)
    changed = sorted(k for k in set(stored) | set(current) if stored.get(k) != current.get(k))
    if changed:
        raise ModelError(
            f"{path}: the greybox constants of vehicle {vehicle.name!r} changed since training ({', '.join(changed)}); retrain the hybrid model"
        )
    if residual.u_mean.shape != (4 + len(OUTPUTS),):
        raise ModelError(f"{path}: hybrid residual nets take {residual.u_mean.shape[0]} exogenous inputs, expected {4 + len(OUTPUTS)}")
    return HybridModel(residual, vehicle, discretisation)


class HybridPredictor:
    """:class:`~quad_modelling.core.models.base.Predictor` over a hybrid model file."""

    def __init__(self, model: HybridModel, name: str = "hybrid") -> None:
        self.model = model
        self.name = name

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        return self.model.predict_window(window, warm_samples)


def make_hybrid_predictor(arg: str, vehicle: VehicleConfig) -> HybridPredictor:
    """Registry factory for ``hybrid:PATH``."""
    if not arg:
        raise ConfigError("model spec hybrid needs a model file: hybrid:PATH")
    return HybridPredictor(load_hybrid(arg, vehicle))

