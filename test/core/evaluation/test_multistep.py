"""The multi-step table lists every model: its own predict_horizons, else its live form from each start."""

import numpy as np
import pytest

from quad_modelling.core.evaluation.multistep import multistep_evaluation, multistep_form
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.models.base import ConstantStatePredictor, DummyPredictor
from quad_modelling.core.models.greybox import GreyboxPredictor
from quad_modelling.core.models.streaming import (
    StreamingHorizons,
    predict_horizons_by_stream,
    predict_window_by_stream,
)
from quad_modelling.core.preprocess import measured_variables
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import DataError
from test.conftest import synthetic_log

SCORED = np.r_[0:6, 9:11, 12:15]
"""Columns of the multi-step groups (positions, velocities, roll, pitch, rates); yaw is compared modulo 2 pi."""


class ConstantVelocity:
    """A streaming-only test model: the anchor state, position advanced by the anchor velocity each push
    (p(s + h) = p(s) + h dt v(s)), everything else held. It has no predict_horizons."""

    name = "constant_velocity"

    def start_window(self, warm):
        measured = measured_variables(warm)
        return measured, _Advancing(measured[-1].copy(), 1.0 / warm.sample_rate)


class _Advancing:
    def __init__(self, state, dt):
        self.state, self.dt = state, dt

    def push(self, command):
        self.state[0:3] += self.dt * self.state[3:6]
        return self.state.copy()


def straight_line_flight(n=1200, rate=100.0, velocity=(0.8, -0.6, 0.0)):
    """Level flight at constant NED velocity [m/s]: position v t, hover specific force, no rotation."""
    t = np.arange(n) / rate
    v = np.array(velocity)
    zeros = np.zeros((n, 3))
    acc_b = zeros.copy()
    acc_b[:, 2] = -GRAVITY
    return FlightLog(t=t, u=np.full((n, 4), 40000.0), acc_b=acc_b, gyro_b=zeros.copy(), pos_n=t[:, None] * v + [0, 0, -1.0],
                     vel_n=np.tile(v, (n, 1)), euler=zeros.copy(), meta=FlightMeta("crazyflie21", "straight line"))


def test_the_table_lists_a_streaming_only_model_with_its_known_errors():
    vehicle = load_vehicle("crazyflie21")
    log = straight_line_flight()
    config = EvaluationConfig(drop_start=0, drop_end=0, train="0:1", eval="1:12", horizons=(1, 10, 50))
    out = multistep_evaluation([log], [GreyboxPredictor(vehicle), ConstantVelocity(), DummyPredictor()], vehicle, config)
    assert list(out["models"]) == ["naive", "greybox", "constant_velocity"]
    assert out["forms"] == {"naive": "predict_horizons", "greybox": "predict_horizons", "constant_velocity": "streaming"}
    assert list(out["not_multistep"]) == ["dummy"]
    # eval span 1:12 s of a flight ending at 11.99 s: rows 100..1198 (1099 rows); starts 19 .. 1099 - 1 - 50
    assert out["starts"] == 1099 - 50 - 19
    speed = 1.0  # |(0.8, -0.6, 0)| m/s
    naive = out["models"]["naive"]["position"]
    for h in (1, 10, 50):  # naive holds the position: error |v| h dt
        assert naive["mae"][str(h)] == pytest.approx(speed * h * 0.01, rel=1e-9)
    assert naive["sim_err"] == pytest.approx(speed * 0.01 * 50 * 51 / 2, rel=1e-9)
    cv = out["models"]["constant_velocity"]
    assert cv["position"]["sim_err"] == pytest.approx(0.0, abs=1e-9)  # exact on a straight line
    assert cv["position"]["ratio_sim_err"] == pytest.approx(0.0, abs=1e-9)
    assert cv["velocity"]["sim_err"] == pytest.approx(0.0, abs=1e-12)  # nor any other group moves
    assert cv["angular_velocity"]["sim_err"] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("make", [lambda v: ConstantStatePredictor(v)], ids=["naive"])
def test_the_generic_form_equals_the_vectorised_predict_horizons(make):
    """A model with both forms scores the same numbers either way: the generic (live) form from each start
    equals its vectorised predict_horizons. (greybox joins this list when its predict_horizons anchors causally
    on the warm rows ending at each start, as its live form does.)"""
    vehicle = load_vehicle("crazyflie21")
    log, warm, horizon = synthetic_log(400), 20, 50
    model = make(vehicle)
    starts = np.arange(warm - 1, len(log) - horizon)
    generic = predict_horizons_by_stream(model, log, starts, horizon, warm)
    vectorised = model.predict_horizons(log, starts, horizon)
    np.testing.assert_allclose(generic[..., SCORED], vectorised[..., SCORED], atol=1e-12)
    yaw_turns = (generic[..., 11] - vectorised[..., 11]) / (2 * np.pi)
    np.testing.assert_allclose(yaw_turns, np.round(yaw_turns), atol=1e-12)


@pytest.mark.parametrize("spec", ["greybox", "greybox:euler", "naive"])
def test_the_generic_form_is_the_live_window_from_each_start(spec):
    """Row h from start s is what a live node publishes h samples after the anchor of a window whose warm rows
    end at s (predict_window_by_stream on rows s - W + 1 .. s + H)."""
    from quad_modelling.core.models.registry import make_model

    vehicle = load_vehicle("crazyflie21")
    log, warm, horizon = synthetic_log(300), 20, 40
    model = make_model(spec, vehicle)
    starts = np.array([19, 57, 200, 259])
    generic = StreamingHorizons(model, warm).predict_horizons(log, starts, horizon)
    for i, s in enumerate(starts):
        window = predict_window_by_stream(model, log.slice(s - warm + 1, s + horizon + 1), warm)
        np.testing.assert_array_equal(generic[i], window[warm - 1:])


@pytest.mark.parametrize("spec", ["greybox", "greybox:euler", "naive"])
def test_the_generic_form_is_causal(spec):
    """Altering measurements after the anchor and commands after the horizon leaves every prediction unchanged."""
    from quad_modelling.core.models.registry import make_model

    vehicle = load_vehicle("crazyflie21")
    log, warm, horizon, s = synthetic_log(300), 20, 30, 120
    model = StreamingHorizons(make_model(spec, vehicle), warm)
    before = model.predict_horizons(log, np.array([s]), horizon)
    altered = log.slice(0, len(log))
    for name in ("acc_b", "gyro_b", "pos_n", "vel_n", "euler"):
        getattr(altered, name)[s + 1:] += 0.7
    altered.u[s + horizon + 1:] *= 1.3
    after = model.predict_horizons(altered, np.array([s]), horizon)
    np.testing.assert_array_equal(before, after)
    altered.u[s + horizon] *= 1.3  # the last command the horizon uses does change a model's prediction (not naive's)
    if spec != "naive":
        assert not np.array_equal(model.predict_horizons(altered, np.array([s]), horizon)[0, -1], before[0, -1])


def test_multistep_form_chooses_vectorised_then_streaming_then_none():
    vehicle = load_vehicle("crazyflie21")
    naive = ConstantStatePredictor(vehicle)
    assert multistep_form(naive, 20) is naive
    form = multistep_form(ConstantVelocity(), 20)
    assert isinstance(form, StreamingHorizons) and form.name == "constant_velocity" and form.warm_samples == 20
    assert multistep_form(DummyPredictor(), 20) is None


def test_starts_without_room_for_the_warm_rows_are_refused():
    log = synthetic_log(200)
    with pytest.raises(DataError, match="20 warm rows and horizon 50 leave the segment"):
        predict_horizons_by_stream(ConstantVelocity(), log, np.array([10]), 50, 20)
    with pytest.raises(DataError, match="leave the segment"):
        predict_horizons_by_stream(ConstantVelocity(), log, np.array([160]), 50, 20)


def test_a_start_stride_scores_every_kth_start_with_the_same_known_errors():
    vehicle = load_vehicle("crazyflie21")
    config = EvaluationConfig(drop_start=0, drop_end=0, train="0:1", eval="1:12", horizons=(1, 10, 50))
    out = multistep_evaluation([straight_line_flight()], [ConstantVelocity()], vehicle, config, start_stride=4)
    assert out["start_stride"] == 4 and out["starts"] == 258  # starts 19, 23, ..., 1047 of the 1099-row segment
    assert out["models"]["naive"]["position"]["mae"]["10"] == pytest.approx(0.1, rel=1e-9)
    assert out["models"]["constant_velocity"]["position"]["sim_err"] == pytest.approx(0.0, abs=1e-9)


def test_start_errors_average_to_the_tables_sim_err():
    """Per-start SimErr contributions (the diagnosis's and the observer choice's scorer) average to the table's SimErr
    of every group, and the blocks number the starts in 2 s runs."""
    from quad_modelling.core.evaluation.multistep import GROUPS, ratio_to_naive, start_errors
    from quad_modelling.core.models.physics import PhysicsPredictor
    from quad_modelling.io.loader import load_flight
    from test.conftest import REPO

    vehicle = load_vehicle("crazyflie21")
    log = load_flight(REPO / "bags" / "nanobench_B7_oval_medium_rep2", vehicle)
    config = EvaluationConfig.preset("short", horizons=(1, 10, 50))
    model = PhysicsPredictor(vehicle, name="physics")
    naive = ConstantStatePredictor(vehicle, config.trim)
    table = multistep_evaluation([log], [model], vehicle, config)
    groups = tuple(GROUPS)
    (errors, naive_errors), blocks = start_errors([log], [model, naive], vehicle, config, groups)
    assert len(errors) == table["starts"] == len(blocks)
    for i, group in enumerate(groups):
        assert errors[:, i].mean() == pytest.approx(table["models"]["physics"][group]["sim_err"], rel=1e-9)
        assert naive_errors[:, i].mean() == pytest.approx(table["models"]["naive"][group]["sim_err"], rel=1e-9)
    assert ratio_to_naive(errors[:, [1, 3]], naive_errors[:, [1, 3]]) == pytest.approx(
        np.mean([table["models"]["physics"][g]["ratio_sim_err"] for g in ("velocity", "angular_velocity")]), rel=1e-9)
    assert blocks[0] == 0 and np.all(np.diff(blocks) >= 0) and blocks[-1] >= 5


def test_airborne_starts_leave_out_every_horizon_that_touches_the_ground():
    """A level flight set down for 1 s (rows 600-699 at the height it stood at before rows 0-9): ``airborne`` keeps
    exactly the starts whose rows s..s+50 miss the contact rows (and the stand before take-off); the table's starts
    otherwise."""
    from quad_modelling.core.evaluation.multistep import start_errors

    vehicle = load_vehicle("crazyflie21")
    log = straight_line_flight(velocity=(0.8, -0.6, 0.0))
    log.pos_n[:10, 2] = 0.0  # standing before take-off: the lowest point
    log.pos_n[600:700, 2] = -0.001  # within 1 cm of it: contact
    config = EvaluationConfig(drop_start=0, drop_end=0, train="0:1", eval="1:12", horizons=(1, 10, 50))
    naive = ConstantStatePredictor(vehicle, config.trim)
    (every,), _ = start_errors([log], [naive], vehicle, config)
    (kept,), blocks = start_errors([log], [naive], vehicle, config, airborne=True)
    starts = 100 + np.arange(19, 1099 - 50)  # eval rows 100..1198, as the table's
    clear = starts[(starts + 50 < 600) | (starts > 699)]
    assert len(every) == len(starts) and len(kept) == len(clear) == len(blocks)
    assert len(starts) - len(clear) == 150  # starts 550..699


def test_the_table_counts_the_starts_whose_horizon_touches_the_ground_and_merges_the_count():
    """The same flight set down for 1 s: the table scores every start (as before) and says how many of them touch the
    ground -- 150, starts 550..699 -- in results.json (``ground_starts``) and in one line of tables.md; two flights'
    statistics merge to twice the count; a flight that never touches down has no such entry."""
    from quad_modelling.core.evaluation.multistep import flight_multistep_sums, multistep_table
    from quad_modelling.io.reports.evaluation import multistep_lines

    vehicle = load_vehicle("crazyflie21")
    log = straight_line_flight(velocity=(0.8, -0.6, 0.0))
    log.pos_n[:10, 2] = 0.0
    log.pos_n[600:700, 2] = -0.001
    config = EvaluationConfig(drop_start=0, drop_end=0, train="0:1", eval="1:12", horizons=(1, 10, 50))
    table = multistep_evaluation([log], [], vehicle, config)
    assert table["starts"] == 1099 - 19 - 50 and table["ground_starts"] == 150
    assert (f"150 of the {table['starts']} starts' horizons touch the ground (within 1 cm of where the flight stood): scored "
            "as the rest") in " ".join(multistep_lines(table))
    sums = flight_multistep_sums(log, [], vehicle, config)
    sums.merge(flight_multistep_sums(log, [], vehicle, config))
    assert multistep_table(sums, config)["ground_starts"] == 300
    assert type(sums).from_json(sums.to_json(), "stats").ground_starts == 300
    assert "ground_starts" not in multistep_evaluation([straight_line_flight()], [], vehicle, config)
    strided = 100 + np.arange(19, 1099 - 50, 3)  # every 3rd start: those in 550..699 counted
    assert multistep_evaluation([log], [], vehicle, config, start_stride=3)["ground_starts"] == np.count_nonzero((strided >= 550) & (strided <= 699))
