"""Model specs -> streaming predictors for the predictor node and run-bag.

Every spec (``naive``, ``greybox``, ``greybox:euler``, ``narx:PATH``, ...) is built
by the core registry through :func:`quad_modelling.core.models.streaming.streaming_predictor`,
the same objects ``quad-modelling evaluate`` uses.
"""

from __future__ import annotations

from quad_modelling.core.models.registry import streaming_predictor
from quad_modelling.core.models.streaming import StreamingPredictor
from quad_modelling.core.vehicle import VehicleConfig


def model_name(spec: str) -> str:
    """Default topic prefix of a spec: its kind (``narx:model.npz`` -> ``narx``)."""
    return spec.partition(":")[0].strip()


def make_streaming_predictor(spec: str, vehicle: VehicleConfig) -> StreamingPredictor:
    """Build the live form of ``spec``; ConfigError naming the spec when unknown or not streamable."""
    return streaming_predictor(spec, vehicle)
