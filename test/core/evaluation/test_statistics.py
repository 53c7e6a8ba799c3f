"""Sufficient statistics of an evaluation and their merge (#19): the averages are the protocol's, merges are exact."""

from __future__ import annotations

import json
from fractions import Fraction

import numpy as np
import pytest

from quad_modelling.core.evaluation.statistics import EvaluationStatistics, ExactSum, WindowSums
from quad_modelling.core.evaluation.windowed import evaluate, evaluate_flight, merge_flights
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import ConfigError, DataError
from test.core.flightgen import linear_flight


def test_window_sums_give_the_correctly_rounded_mean_over_windows():
    """The span score stays the mean over windows of the per-window scores (thesis 5.1), rounded once:
    within one rounding of numpy's float mean, and equal to the exact rational mean."""
    rng = np.random.default_rng(7)
    for windows in (1, 2, 5, 17):
        rms, tic = rng.random((windows, 18)) * 40.0, rng.random((windows, 18))
        rms[:, 3] = np.nan  # a variable the sensors do not measure stays NaN
        sums = WindowSums()
        for r, t in zip(rms, tic):
            sums.add_window(r, t)
        mean_rms, mean_tic = sums.means()
        np.testing.assert_allclose(mean_rms, np.mean(rms, axis=0), rtol=4e-16 * windows)
        np.testing.assert_allclose(mean_tic, np.mean(tic, axis=0), rtol=4e-16 * windows)
        exact = [float(sum(Fraction(v) for v in column) / windows) for column in tic.T]
        assert mean_tic.tolist() == exact
        assert np.isnan(mean_rms[3])
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


def test_exact_sums_do_not_depend_on_grouping_or_order():
    """(a + b) + c and a + (b + c) differ in float64; the exact sums of shards merged in any order do not."""
    values = np.array([[1e16, 1.0, 0.1], [1.0, 1.0, 0.2], [-1e16, 1e-300, 0.3]])
    assert (values[0, 2] + values[1, 2]) + values[2, 2] != values[0, 2] + (values[1, 2] + values[2, 2])  # float is not associative
    one_by_one = ExactSum()
    for row in values:
        one_by_one.add(row)
    shards = [ExactSum().add(values[2]), ExactSum().add(values[0]).add(values[1])]  # merged in another order
    merged = ExactSum().merge(shards[0]).merge(shards[1])
    assert merged == one_by_one
    mean = merged.mean(3)
    assert mean.tolist() == [float(sum(Fraction(v) for v in values[:, c]) / 3) for c in range(3)]
    assert mean[0] == 1.0 / 3.0 and (values[0, 0] + values[1, 0]) + values[2, 0] == 0.0  # a float running sum loses the 1
    back = ExactSum.from_json(json.loads(json.dumps(merged.to_json())), "sums")
    assert back == merged and back.mean(3).tolist() == mean.tolist()


def test_exact_sums_keep_nan_and_refuse_malformed_text():
    sums = ExactSum().add([np.nan, 2.5]).add([1.0, -0.5])
    stored = sums.to_json()
    assert stored["sums"] == [None, "0x1p+1"]
    assert np.isnan(ExactSum.from_json(stored, "s").mean(1)[0])
    with pytest.raises(DataError, match="rms_sum"):
        ExactSum.from_json({"shape": [1], "sums": ["12.5"]}, "rms_sum")
    # no sum of float64 values (an OverflowError at the mean), a shape held before its sums were counted (MemoryError)
    for data in ({"shape": [1], "sums": ["0x1p+5000"]}, {"shape": [1], "sums": ["0x" + "f" * 200_000 + "p+0"]},
                 {"shape": [10**12], "sums": ["0x1p+0"]}, {"shape": [-1], "sums": ["0x1p+0"]}):
        with pytest.raises(DataError, match=r"^rms_sum: expected an exact sum"):
            ExactSum.from_json(data, "rms_sum")
    largest = ExactSum().add([np.finfo(float).max])
    assert ExactSum.from_json(largest.to_json(), "s").mean(1)[0] == np.finfo(float).max


def test_vehicles_that_agree_on_a_nan_number_do_not_differ_in_it():
    """merge said "mass nan vs nan" and named the same file twice: NaN compares unequal to itself."""
    one = EvaluationStatistics("v", [], {}, None, [], {"mass": float("nan"), "izz": 1.0})
    assert one.vehicle_difference(EvaluationStatistics("v", [], {}, None, [], {"mass": float("nan"), "izz": 1.0})) is None
    assert one.vehicle_difference(EvaluationStatistics("v", [], {}, None, [], {"mass": 0.027, "izz": 1.0})) == "mass nan vs 0.027"


def test_a_bad_configuration_in_a_results_file_is_named_as_the_files_not_as_an_option():
    data = EvaluationConfig.preset("short").to_dict()
    data["window_s"] = float("nan")
    with pytest.raises(ConfigError, match=r"^r.json: config: --window nan: must be a finite number \(the evaluation's "
                                          r"configuration as the file holds it\)$"):
        EvaluationConfig.from_dict(data, "r.json: config")


@pytest.mark.parametrize("windows", [-5, 1.5, 2**60, True, "3"])
def test_a_count_that_is_not_a_whole_number_of_windows_is_malformed_statistics(two_flights, windows):
    """merge took -5 windows (its table said eval -4 windows and TIC -0.50), truncated 1.5 to 1: one DataError."""
    vehicle, flights = two_flights
    config = EvaluationConfig.preset("short")
    data = json.loads(json.dumps(evaluate_flight(flights[0], [make_model("greybox", vehicle)], vehicle, config).statistics.to_json()))
    data["windowed"]["greybox"]["eval"]["windows"] = windows
    with pytest.raises(DataError, match=r"^results.json: malformed statistics \(ValueError: .*windows is .*, not a whole number >= 0\)$"):
        EvaluationStatistics.from_json(data, "results.json")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["windowed"]["greybox"]["eval"].update(windows=0),
     r"statistics\.windowed\.greybox\.eval\.rms_sum: sums of shape \(18,\) for 0 windows \(expected None\)"),
    (lambda d: d["windowed"]["greybox"]["eval"].update(windows=d["windowed"]["greybox"]["eval"]["windows"] * 10**6),
     None),  # the means shrink: still a possible evaluation
    (lambda d: d["windowed"]["greybox"]["train"].update(windows=1),
     r"statistics\.windowed\.greybox\.train: mean RMS .* or mean TIC .* over 1 windows: the sums and the window count "
     r"disagree \(RMS >= 0, TIC in \[0, 1\]\)"),
    (lambda d: d.update(durations_s=[-1.0]), r"malformed statistics \(ValueError: statistics\.durations_s\[0\] is -1\.0, not a duration >= 0 s\)"),
    (lambda d: d.update(durations_s=["inf"]), r"statistics\.durations_s\[0\] is 'inf', not a duration >= 0 s"),
    (lambda d: d["multistep"].update(starts=0), r"statistics\.multistep\.error_sums\.naive: sums of absolute errors below 0 or over "
                                                r"0 starts: they and the start count disagree"),
])
def test_sums_that_contradict_their_counts_are_refused_naming_the_field(two_flights, edit, message):
    """A results file whose window count was set to 0 with its sums kept merged into TIC 2.0 and RMS 3944 m/s, a
    negative duration merged silently (a review, session 44): the sums must be those of their count."""
    vehicle, flights = two_flights
    config = EvaluationConfig.preset("short")
    stats = [evaluate_flight(f, [make_model("greybox", vehicle)], vehicle, config).statistics for f in flights]
    stats[0].merge(stats[1])
    data = json.loads(json.dumps(stats[0].to_json()))
    assert data["windowed"]["greybox"]["eval"]["windows"] > 0 and data["windowed"]["greybox"]["train"]["windows"] > 1
    edit(data)
    if message is None:
        EvaluationStatistics.from_json(data)
        return
    with pytest.raises(DataError, match=message):
        EvaluationStatistics.from_json(data)


def test_a_tic_a_rounding_above_1_reads_back():
    """TIC(y, -3.7 y) is 1.0000000000000002 in floats: evaluate writes it, merge must read it (a review, session 44)."""
    from quad_modelling.core.evaluation.metrics import tic

    y = np.linspace(0.1, 2.0, 50)
    value = tic(y, -3.7 * y)
    assert value > 1.0
    sums = WindowSums()
    sums.add_window(np.full(18, 0.5), np.full(18, value))
    assert WindowSums.from_json(json.loads(json.dumps(sums.to_json())), "w").means()[1][0] == value
