"""The models' live forms, above the models (:mod:`quad_modelling.core.models`) and their export
(:mod:`quad_modelling.core.export`), which they use: what the predictor node runs per input.

* :mod:`~quad_modelling.core.live.forms`: which live form a model has (:func:`~quad_modelling.core.live.forms.carried_forecast`,
  :func:`~quad_modelling.core.live.forms.compiled_window_stream`, :func:`~quad_modelling.core.live.forms.prepare_compiled_step`);
* :mod:`~quad_modelling.core.live.forecast`: the receding horizon's carried forecasts;
* :mod:`~quad_modelling.core.live.compiled`: the models' CasADi steps compiled to C, and the window stream stepped by them;
* :mod:`~quad_modelling.core.live.direct`: the direct model's carried forecast and compiled window stream.
"""
