"""Sufficient statistics of an evaluation and their merge (#19): the averages are the protocol's, merges are exact."""

from __future__ import annotations

import json

import numpy as np
import pytest

from quad_modelling.core.evaluation.statistics import EvaluationStatistics, WindowSums
from quad_modelling.core.evaluation.windowed import evaluate, evaluate_flight, merge_flights
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import DataError
from test.core.flightgen import linear_flight


def test_window_sums_give_numpy_mean_over_windows_bit_for_bit():
    """The span score stays the mean over windows of the per-window scores (thesis 5.1), to the last bit."""
    rng = np.random.default_rng(7)
    for windows in (1, 2, 5, 17):
        rms, tic = rng.random((windows, 18)) * 40.0, rng.random((windows, 18))
        rms[:, 3] = np.nan  # a variable the sensors do not measure stays NaN
        sums = WindowSums()
        for r, t in zip(rms, tic):
            sums.add_window(r, t)
        mean_rms, mean_tic = sums.means()
        np.testing.assert_array_equal(mean_rms, np.mean(rms, axis=0))
        np.testing.assert_array_equal(mean_tic, np.mean(tic, axis=0))
        assert sums.windows == windows


@pytest.fixture(scope="module")
def two_flights():
    vehicle = load_vehicle("linkquad")
    return vehicle, [linear_flight(vehicle, duration=40.0, seed=s) for s in (3, 4)]


def test_merge_of_per_flight_statistics_through_json_is_the_evaluation_of_all_flights(two_flights):
    vehicle, flights = two_flights
    config = EvaluationConfig.preset("short", window_s=6.0)
    models = [make_model(spec, vehicle) for spec in ("greybox", "naive", "dummy")]
    whole = evaluate(flights, models, vehicle, config).to_json()
    parts = []
    for log in flights:  # each flight's statistics written and read back as results.json stores them
        part = evaluate_flight(log, models, vehicle, config)
        part.statistics = EvaluationStatistics.from_json(json.loads(json.dumps(part.statistics.to_json())))
        parts.append(part)
    merged = merge_flights(parts, config).to_json()
    assert merged["models"] == whole["models"] and merged["horizons"] == whole["horizons"]
    assert merged["statistics"] == whole["statistics"]
    assert whole["windows"]["greybox"] == {"train": 4, "eval": 4}  # two windows per flight and span
    stats = whole["statistics"]["multistep"]
    assert stats["starts"] == whole["horizons"]["starts"] > 0 and stats["order"][0] == "naive"


def test_statistics_of_other_models_or_vehicles_do_not_merge(two_flights):
    vehicle, flights = two_flights
    config = EvaluationConfig.preset("short")
    first = evaluate_flight(flights[0], [make_model("greybox", vehicle)], vehicle, config).statistics
    other = evaluate_flight(flights[1], [make_model("naive", vehicle)], vehicle, config).statistics
    with pytest.raises(DataError, match=r"models \['naive'\] into those of \['greybox'\]"):
        first.merge(other)
    other.models, other.windowed, other.vehicle = first.models, first.windowed, "crazyflie21"
    with pytest.raises(DataError, match="vehicle 'crazyflie21' into one on 'linkquad'"):
        first.merge(other)
