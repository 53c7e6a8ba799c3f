"""The ``truth`` model (issue #25 item 7): the simulator's own physics from a log's notes, in every form.

Its multi-step error sits far below the physics model's and the naive prediction's on a simulated flight, its
window (live) form equals its multi-step form, its batch derivative is the simulator's bit for bit, its notes
rebuild the simulator's parameters, and a flight without simulator notes is refused in one line.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from quad_modelling.cli import main
from quad_modelling.core.effect_names import SIM_DEFAULT_EFFECTS
from quad_modelling.core.evaluation.multistep import multistep_evaluation
from quad_modelling.core.flight_log import FlightMeta
from quad_modelling.core.models.physics import Observer
from quad_modelling.core.models.registry import make_model, streaming_predictor
from quad_modelling.core.models.streaming import predict_window_by_stream, push_sample
from quad_modelling.core.preprocess import resample_uniform
from quad_modelling.core.sim.dynamics import QuadDynamics
from quad_modelling.core.sim.params import TRUTH_NOTES_KEY, sim_params_from_notes
from quad_modelling.core.sim.simulate import run_simulation
from quad_modelling.core.sim.truth_model import NO_OBSERVER, TruthPredictor
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import ConfigError, DataError
from test.conftest import FIXTURES

NANOBENCH = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"
"""A real (not simulated) Crazyflie flight."""


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("linkquad")


@pytest.fixture(scope="module")
def plain():
    """30 s effect-free LinkQuad flight (seed 3): manoeuvres from 9 s, landing from 22 s."""
    return run_simulation("linkquad", (), seed=3, duration=30.0)


@pytest.fixture(scope="module")
def with_effects():
    """12 s LinkQuad flight with the default effects: motor lag, input delay, battery, ground effect, rotor drag..."""
    return run_simulation("linkquad", SIM_DEFAULT_EFFECTS, seed=4, duration=12.0)


def test_truth_multistep_error_is_far_below_the_physics_model_and_naive(plain, vehicle):
    """Held-out manoeuvres (9-21 s), horizons 1..50: the truth's SimErr ratio to naive is a fraction of the physics
    model's (the vehicle file's constants). Measured: truth 0.63 velocity / 0.42 angular velocity, physics 0.82 / 1.13."""
    from quad_modelling.core.windows import EvaluationConfig

    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="0:9", eval="9:21", window_s=5.0, warm_s=0.2)
    table = multistep_evaluation([resample_uniform(plain.log)], [make_model("truth", vehicle), make_model("physics", vehicle)],
                                 vehicle, config)
    ratio = {name: {g: entry[g]["ratio_sim_err"] for g in ("velocity", "angular_velocity")} for name, entry in table["models"].items()}
    assert table["starts"] > 1000
    assert ratio["truth"]["angular_velocity"] < 0.5 and ratio["truth"]["velocity"] < 0.7
    assert ratio["physics"]["angular_velocity"] > 2.0 * ratio["truth"]["angular_velocity"]
    assert ratio["physics"]["velocity"] > 1.2 * ratio["truth"]["velocity"]
    assert table["forms"]["truth"] == "predict_horizons"


@pytest.mark.parametrize("flight", ["plain", "with_effects"])
def test_window_live_and_multistep_forms_agree(request, flight, vehicle):
    """predict_window (the stream with real stamps), a hand-driven live loop and the multi-step form from the last
    warm row give the same numbers to 1e-9 (the scalar and the batch derivative are the same code)."""
    log = request.getfixturevalue(flight).log
    window, warm = log.slice(700, 780), 20
    model = make_model("truth", vehicle)
    offline = predict_window_by_stream(model, window, warm)
    predictions, stream = streaming_predictor("truth", vehicle).start_window(window.slice(0, warm))
    live = [push_sample(stream, window.u[k], float(window.t[k])) for k in range(warm, len(window))]
    assert np.allclose(np.vstack([predictions, live]), offline, rtol=0, atol=1e-9)
    multistep = model.predict_horizons(window, np.array([warm - 1]), len(window) - warm)[0]
    assert np.allclose(multistep[1:], offline[warm:], rtol=0, atol=1e-9)
    assert np.abs(offline[warm:, 12:15] - window.gyro_b[warm:]).max() < 0.05  # 0.6 s open loop, still on the gyro


def test_batch_derivative_and_step_are_the_simulators_bit_for_bit(with_effects):
    """The truth model's batch form of the simulator's derivative (every state entry an array) gives exactly the
    scalar derivative and RK4 step the simulator runs, ground contact included."""
    dynamics = QuadDynamics(with_effects.params, ("motor_lag", "rotor_drag", "ground_effect", "gyroscopic", "wind",
                                                  "motor_imbalance", "bent_arm", "com_offset"))
    rng = np.random.default_rng(0)
    states = [dynamics.hover_state(h) for h in (0.08, 0.3, 1.0)] + [dynamics.state_at_rest()]
    for s in states:
        s[3:6] = rng.normal(size=3).tolist()
        s[10:13] = (0.5 * rng.normal(size=3)).tolist()
    targets, wind = [500.0, 510.0, 520.0, 530.0], (0.4, -0.2, 0.1)
    batch = [np.array([s[i] for s in states]) for i in range(17)]
    scalar = np.array([dynamics.derivative(s, targets, wind) for s in states])
    vector = dynamics.batch_derivative(batch, [np.full(4, w) for w in targets], wind)
    assert np.array_equal(np.column_stack([np.broadcast_to(v, (4,)) for v in vector]), scalar)
    stepped = dynamics.step(batch, [np.full(4, w) for w in targets], wind, 0.001, dynamics.batch_derivative)[0]
    assert np.array_equal(np.column_stack(stepped), np.array([dynamics.step(s, targets, wind, 0.001)[0] for s in states]))


def test_notes_rebuild_the_simulator_parameters(with_effects):
    notes = json.loads(json.dumps(with_effects.log.meta.notes))  # as a .mat or bag keeps them
    params = sim_params_from_notes(notes, "flight.mat")
    for field in ("esc", "geometry", "ground", "battery", "rotor_drag", "wind", "imbalance", "com_offset", "bent_arm",
                  "input_delay", "ground_effect_min_height", "physics_rate", "log_rate"):
        assert getattr(params, field) == getattr(with_effects.params, field), field
    assert params.vehicle.motors == with_effects.params.vehicle.motors
    assert {k: c.value for k, c in params.vehicle.constants.items()} == {k: c.value for k, c in with_effects.params.vehicle.constants.items()}


def test_flights_without_the_truth_notes_are_refused_in_one_line(with_effects, tmp_path, capsys):
    old = dict(with_effects.log.meta.notes)
    del old[TRUTH_NOTES_KEY]
    with pytest.raises(DataError, match=r"^old\.mat: simulated \(sim_version \d+\) before the logs kept"):
        sim_params_from_notes(old, "old.mat")
    assert main(["evaluate", str(NANOBENCH), "--model", "truth", "--preset", "short", "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{NANOBENCH}: not a simulated flight (no simulator notes)" in err
    assert not (tmp_path / "out").exists()


def test_registry_specs(with_effects, vehicle, tmp_path):
    assert make_model("truth", vehicle).observer == NO_OBSERVER
    observed = make_model("truth:0.5,0.25", vehicle)
    assert observed.name == "truth:0.5,0.25" and observed.observer == Observer(0.5, 0.25)
    notes = tmp_path / "notes.json"
    notes.write_text(json.dumps(with_effects.log.meta.notes))
    from_file = make_model(f"truth:{notes}", vehicle)
    assert from_file.name == "truth" and isinstance(from_file, TruthPredictor)
    window = with_effects.log.slice(600, 700)
    window = dataclasses.replace(window, meta=FlightMeta(window.meta.vehicle, "live window", notes={}))  # no notes, as live
    assert np.array_equal(predict_window_by_stream(from_file, window, 20),
                          predict_window_by_stream(make_model("truth", vehicle), with_effects.log.slice(600, 700), 20))
    with pytest.raises(ConfigError, match="model spec truth:x"):
        make_model("truth:x", vehicle)
    (tmp_path / "real.json").write_text("{}")
    with pytest.raises(DataError, match="real.json: not a simulated flight"):
        make_model(f"truth:{tmp_path / 'real.json'}", vehicle)
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match="deep.json nests deeper than JSON can be read$"):
        make_model(f"truth:{tmp_path / 'deep.json'}", vehicle)


def test_the_physics_model_with_the_simulated_crazyflies_constants_is_its_truth():
    """The simulated Crazyflie shares its vehicle file's measured speed map (only k_f and k_m are the world's own) and
    its low passes stay off the ground: effect-free, the physics model given the world's k_f and k_m, its lag, delay
    and rotor drag switched off -- nothing else changed in crazyflie21.yaml -- predicts as the truth does over every
    start (session 33's review measured 1.48x on angular velocity: the world's own speed map, and a low pass sitting
    on its feet). 40 s, a low pass flown first."""
    from quad_modelling.core.physics.effects import parse_effects
    from quad_modelling.core.sim.params import sim_params_for
    from quad_modelling.core.sim.simulate import simulate
    from quad_modelling.core.windows import EvaluationConfig

    params = sim_params_for("crazyflie21")
    params = params.replace(pilot=dataclasses.replace(params.pilot, leading=("low_hover",)))
    log = simulate("crazyflie21", (), seed=21, duration=40.0, params=params)
    low = next(m for m in log.meta.notes["pilot"]["manoeuvres"] if m["channel"] == "low_hover")
    assert low["shape"] == "smooth_step"
    during = (log.t > low["start"]) & (log.t < low["start"] + low["duration"])
    reference = params.pilot.hover_height + low["amplitude"]
    assert np.all(-log.pos_n[during, 2] > reference - 0.01)  # holds its height within 1 cm: 2.5 cm over its feet or more
    world = {k: params.adjustments[k]["used"] for k in ("rotor_thrust_constant", "rotor_torque_constant")}
    off = parse_effects({name: {"enabled": False} for name in ("motor_lag", "input_delay", "rotor_drag")}, "effect-free")
    vehicle = dataclasses.replace(load_vehicle("crazyflie21").with_values(world, "the simulator's world"), effects=off)
    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="0:6", eval="6:32", window_s=5.0, warm_s=0.2)
    table = multistep_evaluation([resample_uniform(log)], [make_model("truth", vehicle), make_model("physics:0,0", vehicle)],
                                 vehicle, config)
    assert table["starts"] > 2000
    for group in ("velocity", "angular_velocity"):
        truth, physics = (table["models"][m][group]["sim_err"] for m in ("truth", "physics:0,0"))
        assert physics == pytest.approx(truth, rel=0.03)
