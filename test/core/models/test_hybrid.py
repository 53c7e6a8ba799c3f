"""Hybrid greybox + residual NARX model: decomposition, learning the residual, files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core.models import hybrid
from quad_modelling.core.models.greybox import GreyboxPredictor
from quad_modelling.core.models.narx import (
    DIFFERENTIATED,
    INTEGRATED,
    OUTPUTS,
    NarxConfig,
    load_narx,
)
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.preprocess import trimmed_variables
from quad_modelling.core.variables import columns
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import SpanSpec, warm_samples_for
from quad_modelling.errors import ModelError
from quad_modelling.io.loader import load_flight

BAG = Path(__file__).resolve().parents[3] / "bags" / "nanobench_B7_oval_medium_rep2"
SMALL = NarxConfig(hidden=4, output_delays=5, input_delays=tuple(range(5)), epochs=6, iterations_per_epoch=20)
RATES = columns(("roll_rate", "pitch_rate", "yaw_rate"))


@pytest.fixture(scope="module")
def flight():
    return load_flight(BAG)


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("crazyflie21")


@pytest.fixture(scope="module")
def trained(flight, vehicle):
    span = SpanSpec.parse("train", "0%:60%").interval(flight, 5.0, 5.0)
    return hybrid.train_hybrid_on_flights([flight], [span], vehicle, SMALL, seed=0), span


def test_zero_residual_nets_give_the_greybox_exactly(trained, flight, vehicle):
    model, _ = trained
    silent = dataclasses.replace(model.residual, w_2=np.zeros_like(model.residual.w_2), b_2=np.zeros(6), y_mean=np.zeros(6))
    window = flight.slice(500, 1500)
    greybox = GreyboxPredictor(vehicle).predict_window(window, 20)
    residual_only = hybrid.HybridModel(silent, vehicle).predict_window(window, 20)
    # the warm-up residual is the measured one; afterwards the silent nets add nothing
    outputs, accelerations = columns(OUTPUTS), columns(DIFFERENTIATED)
    assert np.array_equal(residual_only[20:, outputs], greybox[20:, outputs])
    assert np.allclose(residual_only[21:, accelerations], greybox[21:, accelerations], rtol=0, atol=1e-12)
    assert not np.allclose(residual_only[:20, outputs], greybox[:20, outputs])


def test_correction_is_added_integrated_and_differentiated(flight):
    window = flight.slice(0, 300)
    greybox = np.zeros((300, 18))
    residual = np.tile([0.0, 0.0, 0.0, 0.1, -0.2, 0.3], (300, 1)) * (window.t - window.t[0])[:, None]
    out = hybrid.corrected(window, greybox, residual)
    elapsed = window.t - window.t[0]
    assert np.allclose(out[:, columns(OUTPUTS)], residual)
    assert np.allclose(out[:, columns(INTEGRATED)][:, 3:], 0.5 * np.outer(elapsed**2, [0.1, -0.2, 0.3]), atol=1e-12)
    assert np.allclose(out[:, columns(DIFFERENTIATED)][:, 3:], [0.1, -0.2, 0.3])


def test_learns_the_greybox_residual_on_its_training_windows(trained, flight, vehicle):
    model, (a, b) = trained
    start = int(np.searchsorted(flight.t - flight.t[0], a))
    window = flight.slice(start, start + 1000)
    warm = warm_samples_for(window, 0.2)
    measured = trimmed_variables(window, vehicle=vehicle)
    greybox = GreyboxPredictor(vehicle).predict_window(window, warm)
    combined = model.predict_window(window, warm)
    error_greybox = np.sqrt(((greybox[warm:, RATES] - measured[warm:, RATES]) ** 2).mean(axis=0))
    error_hybrid = np.sqrt(((combined[warm:, RATES] - measured[warm:, RATES]) ** 2).mean(axis=0))
    # the open-loop linear greybox drifts far from a stabilised flight; the residual nets remove most of it
    assert np.all(error_hybrid < 0.5 * error_greybox), (error_hybrid, error_greybox)


def test_save_load_and_registry_give_identical_predictions(trained, flight, vehicle, tmp_path):
    model, _ = trained
    path = model.save(tmp_path / "hybrid.npz")
    window = flight.slice(1000, 2000)
    loaded = hybrid.load_hybrid(path, vehicle)
    assert np.array_equal(loaded.predict_window(window, 20), model.predict_window(window, 20))
    predictor = make_model(f"hybrid:{path}", vehicle)
    assert predictor.name == "hybrid"
    assert np.array_equal(predictor.predict_window(window, 20), model.predict_window(window, 20))


def test_refuses_changed_vehicle_constants_and_wrong_kind(trained, vehicle, tmp_path):
    model, _ = trained
    path = model.save(tmp_path / "hybrid.npz")
    key = sorted(vehicle.constants)[0]
    changed = dataclasses.replace(vehicle, constants={**vehicle.constants, key: dataclasses.replace(vehicle.constants[key], value=vehicle.constants[key].value * 2)})
    with pytest.raises(ModelError, match=f"constants of vehicle 'crazyflie21' changed since training \\({key}"):
        hybrid.load_hybrid(path, changed)
    with pytest.raises(ModelError, match="is a 'hybrid' model, expected 'narx'"):
        load_narx(path)
    with pytest.raises(ModelError, match="trained for vehicle 'crazyflie21', not 'linkquad'"):
        hybrid.load_hybrid(path, load_vehicle("linkquad"))
