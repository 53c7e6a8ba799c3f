"""The models' compiled steps (core/live/compiled.py, picked by core/live/forms.py): the window stream stepped by the
compiled step equals the model's own stream; without a C compiler CasADi's virtual machine gives the carried
forecast the same numbers. The models are test_forecast's (a trained hybrid with command filters, a direct model,
physics with every term on)."""

from __future__ import annotations

import dataclasses
import weakref

import numpy as np
import pytest

from quad_modelling.core.export import casadi_model
from quad_modelling.core.live import compiled
from quad_modelling.core.live.compiled import CompiledWindowStream
from quad_modelling.core.live.forms import carried_forecast, compiled_window_stream
from quad_modelling.core.models.streaming import push_sample
from quad_modelling.io.loader import load_flight
from test.core.live.test_forecast import FLIGHT, WARM, flight, models, vehicle  # noqa: F401 (fixtures)


def test_without_a_c_compiler_the_rollout_runs_in_casadis_virtual_machine_with_the_same_numbers(models, monkeypatch):
    """The compiled step and the virtual machine's give the same forecast (the compiler is an option, not a need)."""
    model, vehicle = models["hybrid"]
    log = load_flight(FLIGHT, vehicle).slice(250, 400)
    period = float(np.median(np.diff(log.t)))
    t_after, u_after = log.t[99] + period * np.arange(1, 11), np.tile(log.u[99], (10, 1))
    with_c = carried_forecast(model, vehicle, period, 10)
    assert compiled.model_step(model, vehicle).compiled  # this machine has a C compiler
    monkeypatch.setattr(casadi_model, "JIT_OPTIONS", {"compiler": "/nonexistent/cc", "flags": []})
    monkeypatch.setattr(compiled, "_STEPS", weakref.WeakKeyDictionary())
    interpreted = carried_forecast(model, vehicle, period, 10)
    assert not compiled.model_step(model, vehicle).compiled
    for carried in (with_c, interpreted):
        carried.add(log.slice(0, 100), 0)
    np.testing.assert_allclose(interpreted.predict(t_after, u_after), with_c.predict(t_after, u_after), rtol=0, atol=1e-12)



@pytest.mark.parametrize("kind", ["physics", "physics+terms", "hybrid", "direct"])
def test_the_live_window_stream_through_the_compiled_step_equals_the_models_own(models, flight, kind):
    """Window mode: the physics models' stream stepped by the compiled step (what the predictor node runs) gives the
    model's own stream's predictions, sample for sample over a window with a jittered and a dropped sample."""
    model, vehicle = models[kind]
    t = flight.t + np.where(np.arange(len(flight)) % 7 == 3, 0.002, 0.0)  # jitter
    keep = np.arange(len(flight)) != 120  # a dropped sample: a 20 ms step
    window = dataclasses.replace(flight, t=t)
    window = dataclasses.replace(window, **{f: getattr(window, f)[keep] for f in ("t", "u", "acc_b", "gyro_b", "pos_n", "vel_n", "euler", "vbat")})
    _, own = model.start_window(window.slice(0, WARM))
    _, stream = model.start_window(window.slice(0, WARM))
    stepped = compiled_window_stream(model, vehicle, stream)
    assert isinstance(stepped, CompiledWindowStream)
    expected = np.array([push_sample(own, window.u[i], float(window.t[i])) for i in range(WARM, len(window))])
    got = np.array([push_sample(stepped, window.u[i], float(window.t[i])) for i in range(WARM, len(window))])
    print(f"{kind}: max |compiled - numpy stream| = {np.abs(got - expected).max():.2e}")
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    assert compiled_window_stream(models["greybox"][0], vehicle, own) is own  # other models keep their stream
