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


def check_spec_without_vehicle(spec: str) -> None:
    """Refuse, before the vehicle is known, a spec that is wrong whatever the vehicle: an unknown kind, a
    bad argument, a missing or unreadable model file (ConfigError/DataError from the registry).

    The registry is asked with no vehicle: what it checks before using the vehicle is reported; a
    factory that needs the vehicle to go further fails with AttributeError/TypeError, which only says
    the rest is checked once the vehicle is known (:func:`make_streaming_predictor`).
    """
    try:
        streaming_predictor(spec, None)
    except (AttributeError, TypeError):
        pass
