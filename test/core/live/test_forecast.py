"""Carried-state forecasts (core/live/forecast.py, the direct model's core/live/direct.py) through the receding horizon: every model kind's forecast from each
anchor equals its offline multi-step form on all the rows up to the anchor (flown commands: the offline table's own
numbers; held commands: the same form on a copy whose commands after s are u_s). That it reads nothing after its
anchor is held by test_causality.py with every other form.

A real NanoBench flight in the air (the fixture's rows 250..) on an exact 10 ms clock (the held rows' stamps are then
the rows'), h = 50 as the issue's target. Tolerance 1e-9: the carried forms compute the offline anchor with other float
operation orders only (module docstring of forecast.py); measured differences are ~1e-12."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import yaml

from quad_modelling.core.evaluation.multistep import multistep_form
from quad_modelling.core.live.direct import DirectForecast
from quad_modelling.core.live.forecast import GreyboxForecast, NarxForecast, PhysicsForecast
from quad_modelling.core.live.forms import carried_forecast
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.models.streaming import RecedingHorizon, hold_inputs
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle, vehicle_file
from quad_modelling.io.loader import load_flight
from test.core.models.test_causality import FLIGHT, _train_direct, _train_hybrid

HORIZON = 50
WARM = 20
PERIOD_NS = 10_000_000
TOLERANCE = 1e-9

TERMS = {
    "battery": {"enabled": True,
                "kappa": {"value": 0.2, "unit": "1/V", "bounds": [-1.0, 1.0], "source": "test", "status": "identified"},
                "reference_voltage": {"value": 3.9, "unit": "V", "bounds": [0.0, 100.0], "source": "test", "status": "measured"}},
    "ground_effect": {"enabled": True,
                      "coefficient": {"value": 3.3e-5, "unit": "m2", "bounds": [0.0, 2e-3], "source": "test", "status": "identified"},
                      "offset": {"value": 0.02, "unit": "m", "bounds": [0.0, 0.2], "source": "test", "status": "measured"}},
    "gyroscopic": {"enabled": True,
                   "body_scale": {"value": 1.0, "unit": "1", "bounds": [0.0, 5.0], "source": "test", "status": "identified"},
                   "rotor_scale": {"value": 1.0, "unit": "1", "bounds": [0.0, 5.0], "source": "test", "status": "identified"}},
}
"""Optional terms switched on for the ``physics+terms`` kind (the battery term reads the flight's voltage)."""


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("crazyflie21")


@pytest.fixture(scope="module")
def flight(vehicle):
    """250 rows in flight on an exact 10 ms clock."""
    log = load_flight(FLIGHT, vehicle).slice(250, 500)
    return dataclasses.replace(log, t=(5_000_000_000 + np.arange(len(log), dtype=np.int64) * PERIOD_NS) / 1e9)


def _train_narx(directory, vehicle):
    """A tiny NARX with lags (3 output delays, commands delayed 0 and 4 rows) trained in a second."""
    from quad_modelling.core.models.narx import NarxConfig
    from quad_modelling.core.training.narx import train_narx_on_flights

    config = NarxConfig(hidden=3, output_delays=3, input_delays=(0, 4), epochs=2, iterations_per_epoch=5, noise_snr_db=(None,) * 6)
    return train_narx_on_flights([load_flight(FLIGHT, vehicle)], [None], config, seed=3).save(directory / "narx.npz")


@pytest.fixture(scope="module")
def models(tmp_path_factory, vehicle):
    """kind -> (streaming predictor, its vehicle)."""
    doc = yaml.safe_load(vehicle_file("crazyflie21").read_text())
    doc["effects"] = copy.deepcopy(TERMS)
    with_terms = VehicleConfig.from_dict(doc, "cf_terms.yaml")
    hybrid = make_model(f"hybrid:{_train_hybrid(tmp_path_factory.mktemp('hybrid'), vehicle)}", vehicle)
    assert not hybrid.model.net.is_zero() and hybrid.model.filters  # a trained net (its correction and command filters in the forecast)
    return {
        "greybox": (make_model("greybox", vehicle), vehicle),
        "greybox:euler": (make_model("greybox:euler", vehicle), vehicle),
        "physics": (make_model("physics", vehicle), vehicle),
        "physics+terms": (make_model("physics", with_terms), with_terms),
        "hybrid": (hybrid, vehicle),
        "narx": (make_model(f"narx:{_train_narx(tmp_path_factory.mktemp('narx'), vehicle)}", vehicle), vehicle),
        "direct": (make_model(f"direct:{_train_direct(tmp_path_factory.mktemp('direct'), vehicle)}", vehicle), vehicle),
    }


def receding(model, vehicle, log, inputs: str, ends_only: bool = False) -> tuple[dict, RecedingHorizon]:
    """Feed ``log`` to a receding horizon with the model's carried form, one command at a time (measurements always
    covered): {anchor row: (stamp [ns], (h + 1, 18) prediction)}."""
    stamps = np.round(log.t * 1e9).astype(np.int64)
    row_of = {int(ns): i for i, ns in enumerate(stamps)}

    def make_log(rows_ns, rows, measured):  # the node's conversion: the rows' commands, their measured rows
        at = np.array(measured)
        return dataclasses.replace(log, t=np.asarray(rows_ns) / 1e9, u=np.array([r[1] for r in rows]), omega=None,
                                   acc_b=None if log.acc_b is None else log.acc_b[at], gyro_b=log.gyro_b[at], pos_n=log.pos_n[at], vel_n=log.vel_n[at],
                                   euler=log.euler[at], vbat=log.vbat[at])

    horizon = RecedingHorizon(lambda warm: multistep_form(model, warm), make_log, horizon_s=HORIZON * 0.01, warm_s=0.2,
                              history_s=0.3, sample_period_s=0.0, wait_s=0.5, inputs=inputs,
                              carried_for=lambda period, steps: carried_forecast(model, vehicle, period, steps),
                              ends_only=ends_only)
    out = {}
    for i, ns in enumerate(stamps.tolist()):
        horizon.add(ns, log.u[i], None)
        for event in horizon.ready(lambda s: s <= ns, lambda s: row_of[s]):
            assert event[0] == "prediction", event
            anchor = row_of[event[1]] - HORIZON if inputs == "flown" else row_of[event[1] - HORIZON * PERIOD_NS]
            out[anchor] = (event[1], event[2])
    return out, horizon


@pytest.mark.parametrize("kind", ["greybox", "greybox:euler", "physics", "physics+terms", "hybrid", "narx", "direct"])
def test_carried_forecast_equals_the_offline_multistep_form_flown_and_held(models, flight, kind):
    model, vehicle = models[kind]
    form = multistep_form(model, WARM)
    flown, horizon = receding(model, vehicle, flight, "flown")
    assert horizon.carried is not None and horizon.steps == HORIZON  # the carried form ran every anchor
    starts = np.arange(WARM - 1, len(flight) - HORIZON)
    assert sorted(flown) == starts.tolist()
    got = np.array([flown[s][1] for s in starts])
    expected = form.predict_horizons(flight, starts, HORIZON)
    print(f"{kind} flown: max |carried - offline| = {np.abs(got - expected).max():.2e}")
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOLERANCE)

    held, _ = receding(model, vehicle, flight, "hold")
    checked = starts[::23]  # every 23rd anchor: one offline call per anchor on its own held copy
    got = np.array([held[s][1] for s in checked])
    expected = np.array([form.predict_horizons(hold_inputs(flight, s), np.array([s]), HORIZON)[0] for s in checked])
    print(f"{kind} held: max |carried - offline on held inputs| = {np.abs(got - expected).max():.2e}")
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOLERANCE)
    assert [held[s][0] for s in checked] == [int(round(flight.t[s] * 1e9)) + HORIZON * PERIOD_NS for s in checked]
    ends, _ = receding(model, vehicle, flight, "hold", ends_only=True)  # what the node asks for: rows 0 and h
    assert sorted(ends) == sorted(held)
    np.testing.assert_array_equal(np.array([ends[s][1] for s in held]), np.array([held[s][1][[0, HORIZON]] for s in held]))


def test_the_direct_forecast_without_an_accelerometer_integrates_v_d_as_the_offline_form(models, flight):
    """The vertical map reads the accelerometer: without it the carried form, as the multi-step form, lets the physics
    integrate the down velocity."""
    model, vehicle = models["direct"]
    assert model.model.vertical is not None
    no_imu = dataclasses.replace(flight, acc_b=None)
    flown, horizon = receding(model, vehicle, no_imu, "flown")
    assert horizon.carried is not None
    starts = np.arange(WARM - 1, len(flight) - HORIZON)
    got = np.array([flown[s][1] for s in starts])
    np.testing.assert_allclose(got, multistep_form(model, WARM).predict_horizons(no_imu, starts, HORIZON), rtol=0, atol=TOLERANCE)


def test_every_registered_model_with_a_multistep_table_row_has_its_carried_form(models, vehicle):
    forms = {kind: type(carried_forecast(model, v, 0.01, HORIZON)) for kind, (model, v) in models.items()}
    assert forms == {"greybox": GreyboxForecast, "greybox:euler": GreyboxForecast, "physics": PhysicsForecast,
                     "physics+terms": PhysicsForecast, "hybrid": PhysicsForecast, "narx": NarxForecast,
                     "direct": DirectForecast}
    assert carried_forecast(make_model("naive", vehicle), vehicle, 0.01, HORIZON) is None  # the history re-run


def test_a_new_time_base_starts_the_carried_anchor_over(models, flight):
    """After ``reset`` (a clock jump) the carried form forgets its rows: the forecasts of the second run are those of
    a fresh receding horizon on it, not continued from the first."""
    model, vehicle = models["physics"]
    first = flight.slice(0, 120)
    second = dataclasses.replace(flight.slice(120, 250), t=flight.t[120:250] + 100.0)
    fresh, _ = receding(model, vehicle, second, "hold")
    stamps = np.round(second.t * 1e9).astype(np.int64)
    _, horizon = receding(model, vehicle, first, "hold")
    horizon.reset()
    row_of = {int(ns): i for i, ns in enumerate(stamps)}
    horizon.make_log = lambda rows_ns, rows, measured: dataclasses.replace(
        second, t=np.asarray(rows_ns) / 1e9, u=np.array([r[1] for r in rows]), omega=None,
        **{f: getattr(second, f)[np.array(measured)] for f in ("acc_b", "gyro_b", "pos_n", "vel_n", "euler", "vbat")})
    again = {}
    for i, ns in enumerate(stamps.tolist()):
        horizon.add(ns, second.u[i], None)
        for event in horizon.ready(lambda s: s <= ns, lambda s: row_of[s]):
            again[int(event[1])] = event[2]
    assert len(again) == len(fresh)
    np.testing.assert_array_equal(np.array(list(again.values())), np.array([p for _, p in fresh.values()]))
