"""Which live form a model has: its carried forecast (:func:`carried_forecast`), its window stream stepped by a
compiled step (:func:`compiled_window_stream`), and those steps built at start-up (:func:`prepare_compiled_step`).
The one place that maps the registry's predictors to :mod:`~quad_modelling.core.live.forecast`,
:mod:`~quad_modelling.core.live.compiled` and :mod:`~quad_modelling.core.live.direct`; the models themselves know
nothing of them (they sit below, :mod:`quad_modelling.core.models`).
"""

from __future__ import annotations

from quad_modelling.core.live.compiled import CompiledWindowStream, model_derivative, model_step, window_step
from quad_modelling.core.live.direct import compiled_direct_stream, direct_forecast, direct_steps
from quad_modelling.core.live.forecast import CarriedForecast, GreyboxForecast, NarxForecast, PhysicsForecast
from quad_modelling.core.models.direct import DirectPredictor
from quad_modelling.core.models.greybox import GreyboxPredictor
from quad_modelling.core.models.hybrid import HybridPredictor
from quad_modelling.core.models.narx import NarxPredictor
from quad_modelling.core.models.physics import PhysicsPredictor
from quad_modelling.core.vehicle import VehicleConfig


def carried_forecast(model, vehicle: VehicleConfig, period_s: float, steps: int) -> CarriedForecast | None:
    """The carried form of ``model`` (a streaming predictor of the registry) for h = ``steps`` at the sample period
    ``period_s`` [s] (:mod:`~quad_modelling.core.live.forecast`), or None when it has none: the receding horizon then
    re-runs the model's multi-step form over its history."""
    if isinstance(model, DirectPredictor):
        return direct_forecast(model, vehicle, steps)
    if isinstance(model, PhysicsPredictor):
        return PhysicsForecast(model_step(model, vehicle), model_derivative(model, vehicle), model.params, model.observer, steps)
    if isinstance(model, HybridPredictor):
        return PhysicsForecast(model_step(model, vehicle), model_derivative(model, vehicle), model.model.params,
                               model.model.observer, steps, model.model)
    if isinstance(model, GreyboxPredictor):
        return GreyboxForecast(model, period_s)
    if isinstance(model, NarxPredictor):
        return NarxForecast(model, period_s, steps, model_step(model, vehicle))
    return None


def compiled_window_stream(model, vehicle: VehicleConfig, stream):
    """``stream`` (what ``model.start_window`` returned) stepped by the compiled step when the model is a physics,
    hybrid or direct model whose step compiled (:func:`~quad_modelling.core.live.compiled.window_step`,
    :func:`~quad_modelling.core.live.direct.direct_steps`); else ``stream`` itself."""
    if isinstance(model, DirectPredictor):
        return compiled_direct_stream(model, vehicle, stream)
    if not isinstance(model, (PhysicsPredictor, HybridPredictor)):
        return stream
    step = window_step(model, vehicle)
    if not step.compiled:
        return stream
    return CompiledWindowStream(stream, step, model.model if isinstance(model, HybridPredictor) else None)


def prepare_compiled_step(model, vehicle: VehicleConfig, forecast: bool) -> None:
    """Build (and compile) the model's step now, not at its first window or anchor: the predictor node calls it at
    start-up with its model, as it primes the model (the compilation takes about half a second once): the carried
    forecast's (``forecast``, :func:`~quad_modelling.core.live.compiled.model_step`) or the window stream's
    (:func:`~quad_modelling.core.live.compiled.window_step`); a direct model's both (one build)."""
    if isinstance(model, DirectPredictor):
        direct_steps(model, vehicle)
    elif forecast:
        model_step(model, vehicle)
        if isinstance(model, (PhysicsPredictor, HybridPredictor)):
            model_derivative(model, vehicle)
    elif isinstance(model, (PhysicsPredictor, HybridPredictor)):
        window_step(model, vehicle)
