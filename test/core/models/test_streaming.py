"""Streaming helpers: the priming window is a hover at rest, and priming leaves a model's answers unchanged."""

import dataclasses

import numpy as np
import pytest

from quad_modelling.core.models.base import ConstantStatePredictor
from quad_modelling.core.models.greybox import GreyboxPredictor
from quad_modelling.core.models.streaming import (
    hover_at_rest,
    predict_window_by_stream,
    prime,
)
from quad_modelling.core.preprocess import measured_variables, trim_prediction
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import DataError
from test.conftest import synthetic_log


def test_hover_at_rest_measures_a_still_vehicle_at_one_metre():
    vehicle = load_vehicle("crazyflie21")
    log = hover_at_rest(vehicle, 0.0025, 80)
    assert len(log) == 80 and np.isclose(log.sample_rate, 400.0)
    measured = measured_variables(log)
    assert np.allclose(measured[:, 2], -1.0)  # Z down (NED): 1 m up
    assert np.allclose(measured[:, 3:9], 0.0, atol=1e-12)  # no velocity, and -g specific force cancels gravity
    assert np.allclose(measured[:, 12:18], 0.0)
    assert np.allclose(log.acc_b[:, 2], -GRAVITY)
    assert np.allclose(log.u, 0.5 * (vehicle.input_min + vehicle.input_max))


def test_greybox_primed_on_a_hover_predicts_the_hover_and_then_the_same_numbers():
    """Priming runs the model once on the hover at rest (trimmed: zero deviation -> it stays put) and changes
    nothing for the windows that follow."""
    vehicle = load_vehicle("crazyflie21")
    rest = hover_at_rest(vehicle, 0.01, 20)
    warm_predictions, stream = GreyboxPredictor(vehicle).start_window(rest)
    pushed = np.array([stream.push(rest.u[-1]) for _ in range(50)])
    assert np.allclose(pushed[:, 0:3], [0.0, 0.0, -1.0], atol=1e-9)  # trimmed inputs are zero: no motion
    assert np.allclose(pushed[:, 3:9], 0.0, atol=1e-9)

    window = synthetic_log(300)
    fresh = predict_window_by_stream(GreyboxPredictor(vehicle), window, 20)
    primed_model = GreyboxPredictor(vehicle)
    prime(primed_model, vehicle, 0.01, 20)
    assert np.array_equal(predict_window_by_stream(primed_model, window, 20), fresh)


def test_a_model_that_rejects_the_priming_window_is_left_unprimed_without_an_error():
    class NeedsMoreRows:
        name = "needs-more-rows"
        calls = 0

        def start_window(self, warm):
            self.calls += 1
            raise DataError(f"{warm.meta.source}: needs 100 warm rows, got {len(warm)}")

    model = NeedsMoreRows()
    prime(model, load_vehicle("crazyflie21"), 0.01, 20)
    assert model.calls == 1


def test_the_naive_model_holds_the_same_measured_state_live_offline_and_multistep():
    """Live (stream), offline window and multi-step forms of the one naive model: the measurement at the
    anchor (row warm - 1), held."""
    vehicle = load_vehicle("crazyflie21")
    window, warm = synthetic_log(300), 20
    naive = ConstantStatePredictor(vehicle)
    anchor_state = measured_variables(window.slice(0, warm), vehicle)[-1]
    live = predict_window_by_stream(naive, window, warm)
    np.testing.assert_array_equal(live[warm:], np.tile(anchor_state, (300 - warm, 1)))
    np.testing.assert_allclose(naive.predict_window(window, warm), trim_prediction(window, live))
    horizons = naive.predict_horizons(window, np.array([warm - 1]), 50)
    assert horizons.shape == (1, 51, 18)
    scored = np.r_[0:6, 9:15]  # the multi-step groups: position, velocity, orientation, angular velocity
    np.testing.assert_allclose(horizons[0][:, scored], np.tile(anchor_state[scored], (51, 1)), atol=1e-12)


def test_flown_receding_horizon_publishes_each_anchor_h_commands_later_with_the_offline_multistep_numbers():
    """Pure logic, no node: commands in one by one; every anchor s comes out when command s + h is in (and its
    measurements are covered), equal to the offline multi-step form from the same start; nothing before."""
    from quad_modelling.core.evaluation.multistep import multistep_form
    from quad_modelling.core.models.physics import PhysicsPredictor
    from quad_modelling.core.models.streaming import RecedingHorizon

    vehicle = load_vehicle("crazyflie21")
    log = synthetic_log(300)
    model = PhysicsPredictor(vehicle)
    t_ns = np.round(log.t * 1e9).astype(np.int64)
    row_of = {int(ns): i for i, ns in enumerate(t_ns)}

    def make_log(stamps, rows, measured):
        return log.slice(row_of[int(stamps[0])], row_of[int(stamps[-1])] + 1)

    horizon = RecedingHorizon(lambda warm: multistep_form(model, warm), make_log, horizon_s=0.05, warm_s=0.2,
                              history_s=2.0, sample_period_s=0.0, wait_s=0.5, inputs="flown")
    covered_until = {"ns": -1}
    out = []
    for i, ns in enumerate(t_ns.tolist()):
        horizon.add(ns, log.u[i], None)
        covered_until["ns"] = ns if i % 7 else covered_until["ns"]  # measurements lag now and then
        out += list(horizon.ready(lambda s: s <= covered_until["ns"], lambda s: ("measured",)))
    assert horizon.steps == 5 and horizon.warm == 20
    assert all(kind == "prediction" for kind, *_ in out)
    starts = np.arange(19, 300 - 5)
    expected = multistep_form(model, 20).predict_horizons(log, starts, 5)
    got = [e for e in out if e[1] in set(t_ns[starts + 5].tolist())]
    assert [e[1] for e in out] == t_ns[starts + 5][:len(out)].tolist() and len(out) >= len(starts) - 1
    assert np.allclose(np.array([e[2] for e in got]), expected[:len(got)], atol=1e-9)
    assert np.allclose([e[3] for e in got], 0.05, atol=1e-6)  # t_{s+h} - t_s


def test_a_burst_of_inputs_microseconds_apart_does_not_become_the_receding_horizons_period():
    """30 inputs 1 us apart at the start made dt 1 us and h 100 000 steps: the predictor answered nothing and ignored
    SIGINT (a review, session 44). Such a dt is said as a fault and measured again over the next steps; a plausible dt
    whose h is over MAX_LIVE_HORIZON_STEPS is said once, and nothing is kept (no predictions on that time base)."""
    from quad_modelling.core.models.streaming import MAX_LIVE_HORIZON_STEPS, RecedingHorizon

    horizon = RecedingHorizon(lambda warm: object(), lambda *a: None, horizon_s=0.1, warm_s=0.2, history_s=2.0,
                              sample_period_s=0.0, wait_s=0.5)
    burst = 1_000_000_000 + np.arange(30, dtype=np.int64) * 1_000  # 1 us apart
    faults = [horizon.add(int(ns), np.zeros(4), None) for ns in burst]
    assert faults[:20] == [None] * 20 and horizon.steps is None
    assert faults[20] == ("horizon_period", "receding horizon: the median of the last 20 motor_input steps is 1e-06 s, under "
                                            "0.0001 s: measured again over the next ones")
    assert len(horizon.rows) <= 10  # the rows before the fault are not kept
    flight = burst[-1] + np.arange(1, 41, dtype=np.int64) * 5_000_000  # then 200 Hz
    faults = [horizon.add(int(ns), np.zeros(4), None) for ns in flight]
    assert all(f is None for f in faults) and horizon.steps == 20 and horizon.period_ns == 5_000_000
    long = RecedingHorizon(lambda warm: object(), lambda *a: None, horizon_s=30.0, warm_s=0.2, history_s=2.0,
                           sample_period_s=0.0, wait_s=0.5)
    faults = [long.add(int(ns), np.zeros(4), None) for ns in np.arange(200, dtype=np.int64) * 2_500_000]
    assert [f for f in faults if f] == [("horizon_period", "receding horizon: horizon_s 30 s at dt 0.0025 s is 12000 steps, "
                                                           f"more than {MAX_LIVE_HORIZON_STEPS}: no horizon predictions")]
    assert long.steps is None and not long.rows  # said once, nothing kept
    long.reset()  # a new time base measures again
    assert not long.too_long


@pytest.mark.parametrize("model_name", ["greybox", "physics"])
def test_held_receding_horizon_forecasts_at_each_input_the_multistep_form_with_the_command_held(model_name):
    """Hold mode, pure logic: every command s is answered as soon as it is in (not h commands later), stamped
    t_s + h dt, with the offline multi-step form run on a copy of the segment whose commands after s are u_s
    (``hold_inputs``), to 1e-9 -- the same prediction path as the flown mode, only the commands after s differ."""
    from quad_modelling.core.evaluation.multistep import multistep_form
    from quad_modelling.core.models.physics import PhysicsPredictor
    from quad_modelling.core.models.streaming import RecedingHorizon, hold_inputs

    vehicle = load_vehicle("crazyflie21")
    base = synthetic_log(300)
    t_ns = 5_000_000_000 + np.arange(300, dtype=np.int64) * 10_000_000  # exact 10 ms steps: the held stamps are the rows'
    log = dataclasses.replace(base, t=t_ns / 1e9)
    model = GreyboxPredictor(vehicle) if model_name == "greybox" else PhysicsPredictor(vehicle)
    row_of = {int(ns): i for i, ns in enumerate(t_ns)}

    def make_log(stamps, rows, measured):  # what the node's _rows_log does with messages: rows' commands, measured rows
        at = np.array(measured)
        return dataclasses.replace(log, t=np.asarray(stamps) / 1e9, u=np.array([r[1] for r in rows]),
                                   omega=np.array([r[2] for r in rows]), acc_b=log.acc_b[at], gyro_b=log.gyro_b[at],
                                   pos_n=log.pos_n[at], vel_n=log.vel_n[at], euler=log.euler[at], vbat=log.vbat[at])

    h, warm = 5, 20
    horizon = RecedingHorizon(lambda w: multistep_form(model, w), make_log, horizon_s=0.05, warm_s=0.2, history_s=2.0,
                              sample_period_s=0.0, wait_s=0.5)
    assert horizon.inputs == "hold"
    out = {}
    for i, ns in enumerate(t_ns.tolist()):
        horizon.add(ns, log.u[i], log.omega[i])
        events = list(horizon.ready(lambda s: s <= ns, lambda s: row_of[s]))
        assert all(kind == "prediction" for kind, *_ in events)
        if i < 20:  # the anchors 19, 20 wait for dt (the median of the first 20 steps): known at input 20
            assert events == []
            continue
        anchors = [19, 20] if i == 20 else [i]  # from then on: input i answers anchor i at once, nothing else
        assert [e[1] for e in events] == [int(t_ns[s]) + h * 10_000_000 for s in anchors]
        out.update({s: e for s, e in zip(anchors, events)})
    assert horizon.steps == h and horizon.period_ns == 10_000_000
    assert np.allclose([e[3] for e in out.values()], h * 0.01, atol=1e-12)  # stamped t_s + h dt
    form = multistep_form(model, warm)
    starts = [s for s in out if s + h < len(log)]
    expected = np.array([form.predict_horizons(hold_inputs(log, s), np.array([s]), h)[0] for s in starts])
    got = np.array([out[s][2] for s in starts])
    flown = form.predict_horizons(log, np.array(starts), h)
    print(f"{model_name}: max |hold - offline on held inputs| = {np.abs(got - expected).max():.2e}, "
          f"max |hold - flown| at h = {np.abs(got[:, h] - flown[:, h]).max():.2e}")
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    assert np.abs(got[:, h] - flown[:, h]).max() > 1e-6  # the held commands matter: not the flown prediction
