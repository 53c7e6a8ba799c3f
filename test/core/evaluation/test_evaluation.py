import numpy as np
import pytest

from quad_modelling.core.evaluation.windowed import evaluate, evaluate_window
from quad_modelling.core.models.base import DummyPredictor
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.preprocess import smooth, trimmed_variables
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import (
    EvaluationConfig,
    SpanSpec,
    plan_windows,
    span_windows,
)
from quad_modelling.errors import ConfigError, DataError
from test.core.flightgen import linear_flight


@pytest.fixture(scope="module")
def linkquad():
    return load_vehicle("linkquad")


def test_span_parsing_absolute_relative_and_errors():
    s = SpanSpec.parse("train", "30:150")
    assert (s.start, s.end, s.relative) == (30.0, 150.0, False)
    r = SpanSpec.parse("eval", "60%:100%")
    assert (r.start, r.end, r.relative) == (0.6, 1.0, True)
    for bad in ("30", "a:b", "10%:20", "50:40", "0%:120%"):
        with pytest.raises(ConfigError):
            SpanSpec.parse("train", bad)


def test_thesis_windows_on_a_220_s_flight(linkquad):
    log = linear_flight(linkquad, duration=220.0)
    config = EvaluationConfig()
    train = span_windows(log, SpanSpec.parse("train", config.train), config)
    ev = span_windows(log, SpanSpec.parse("eval", config.eval), config)
    assert len(train) == 12 and len(ev) == 4
    assert train[0].start == 3000 and train[-1].stop == 15000 and ev[0].start == 15000 and ev[-1].stop == 19000


def test_windows_never_cross_flights_and_short_flights_need_relative_spans(linkquad):
    flights = [linear_flight(linkquad, duration=42.0, seed=s) for s in range(3)]
    with pytest.raises(DataError, match="--preset short"):
        plan_windows(flights, EvaluationConfig())
    plan = plan_windows(flights, EvaluationConfig.preset("short"))
    # flying part 32 s: train 19.2 s -> 1 window, eval 12.8 s -> 1 window, per flight
    assert [len(plan["train"]), len(plan["eval"])] == [3, 3]
    for w in plan["train"] + plan["eval"]:
        assert 0 <= w.start < w.stop <= len(flights[w.flight]) and w.stop - w.start == 1000


def test_dummy_has_tic_one_and_perfect_prediction_tic_zero(linkquad):
    log = linear_flight(linkquad, duration=12.0).slice(0, 1000)
    result = evaluate_window(DummyPredictor(), log, 20, vehicle=linkquad)
    moving = [INDEX["acc_z"], INDEX["vel_z"]]
    np.testing.assert_allclose(result.tic[moving], 1.0)
    measured = smooth(trimmed_variables(log, vehicle=linkquad), log.sample_rate)
    np.testing.assert_allclose(result.rms[moving], np.sqrt(np.mean(measured[20:, moving] ** 2, axis=0)))

    class Oracle:
        name = "oracle"

        def predict_window(self, window, warm_samples):
            return trimmed_variables(window, vehicle=linkquad)

    assert np.all(evaluate_window(Oracle(), log, 20, vehicle=linkquad).tic == 0.0)


def test_greybox_on_its_own_flight_beats_dummy_and_naive(linkquad):
    flights = [linear_flight(linkquad, duration=80.0, seed=s) for s in range(2)]
    config = EvaluationConfig(drop_start=5, drop_end=5, train="5:45", eval="45:75")
    models = [make_model(m, linkquad) for m in ("greybox", "dummy")]
    result = evaluate(flights, models, linkquad, config).to_json()
    grey, dummy = result["models"]["greybox"]["eval"], result["models"]["dummy"]["eval"]
    # The greybox trims its inputs over the 0.2 s warm start (causal, so live equals offline);
    # on these excited flights that trim is noisier than the thesis's first second: TIC 0.15, not 0.07.
    assert grey["acc_z"]["tic"] < 0.2 and dummy["acc_z"]["tic"] == pytest.approx(1.0)
    assert result["windows"]["greybox"] == {"train": 8, "eval": 4}  # flying part ends at 79.99 - 5 s
    h = result["horizons"]
    assert h["starts"] == 2 * (2999 - 50 - 19)  # every model from the same starts: the first with its 20 warm rows
    assert h["models"]["naive"]["velocity"]["ratio_sim_err"] == pytest.approx(1.0)
    # Multi-step trims are causal: the commands' mean over the second before each start. The collective here is
    # 2 Hz low-passed noise around the hover command, so that mean is off hover by the noise's local mean
    # (a trim over the whole segment knew the hover command from the future): 0.68, not 0.3.
    assert h["models"]["greybox"]["velocity"]["ratio_sim_err"] < 0.75
    assert h["models"]["greybox"]["position"]["mae"]["1"] < h["models"]["naive"]["position"]["mae"]["1"]
    assert list(h["not_multistep"]) == ["dummy"] and h["forms"] == {"naive": "predict_horizons", "greybox": "predict_horizons"}
