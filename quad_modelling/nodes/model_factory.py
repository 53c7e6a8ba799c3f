"""Model specs -> streaming predictors for the predictor node.

``naive`` is the streaming baseline :class:`~quad_modelling.core.streaming.HoldLastMeasurement`
(the last warm-start measurement, held). Every other spec (``greybox``,
``greybox:euler``, ``narx:PATH``, ``hybrid:PATH`` ...) is built by the core's
``quad_modelling.core.streaming.streaming_predictor(spec, vehicle)``.
"""

from __future__ import annotations

from quad_modelling.core.preprocess import measured_variables
from quad_modelling.core.streaming import HoldLastMeasurement, StreamingPredictor
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError


def model_name(spec: str) -> str:
    """Default topic prefix of a spec: its kind (``narx:model.npz`` -> ``narx``)."""
    return spec.partition(":")[0].strip()


def make_streaming_predictor(spec: str, vehicle: VehicleConfig) -> StreamingPredictor:
    """Build the streaming predictor for ``spec``; ConfigError naming the spec when unknown."""
    kind, _, arg = spec.partition(":")
    if kind == "naive":
        if arg:
            raise ConfigError(f"model spec {spec!r}: the naive model takes no argument")
        return HoldLastMeasurement(lambda log: measured_variables(log, vehicle))
    try:
        from quad_modelling.core.streaming import streaming_predictor
    except ImportError:
        raise ConfigError(f"unknown model {spec!r}: this build streams only 'naive' "
                          "(quad_modelling.core.streaming.streaming_predictor is not available)") from None
    predictor = streaming_predictor(spec, vehicle)
    if not isinstance(predictor, StreamingPredictor):
        raise ConfigError(f"model spec {spec!r}: {type(predictor).__name__} has no start_window(); it cannot run live")
    return predictor
