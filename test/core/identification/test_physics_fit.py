"""Identification of the physics model: known constants recovered from a simulator flight; on the bundled bag
finite sigmas, at-bound flags, and the identified vehicle file round trip through ``identify``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quad_modelling.core.diagnosis.physics_validation import assessing_vehicle
from quad_modelling.core.identification.constants_report import add_physics_constants
from quad_modelling.core.identification.identify import identified_vehicle_document, identify
from quad_modelling.core.identification.physics_fit import FITTED, identify_physics
from quad_modelling.core.identification.physics_terms import effects_section
from quad_modelling.core.identification.uncertainty import subsample_delay
from quad_modelling.core.models.physics import Observer, PhysicsPredictor
from quad_modelling.core.physics.effects import parse_effects
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.core.sim.simulate import simulate
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle, vehicle_document
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.io.loader import load_flight
from test.conftest import REPO

CF = load_vehicle("crazyflie21")
BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
SHORT = EvaluationConfig.preset("short")


@pytest.fixture(scope="module")
def sim_flight():
    """A 40 s simulated Crazyflie flight with known constants: motor lag, rotor drag and gyroscopic torques on;
    the stabiliser at the 100 Hz log rate (the logged command is the applied one) and noise-free sensors, so
    the only differences from the physics model are the simulator's full nonlinear forms."""
    params = sim_params_for(CF)
    quiet = dataclasses.replace(params.sensors, gyro_noise=0.0, gyro_bias=0.0, gyro_drift=0.0, acc_noise=0.0, acc_bias=0.0,
                                acc_drift=0.0, mocap_position_noise=0.0, mocap_attitude_noise=0.0)
    params = params.replace(control=dataclasses.replace(params.control, rate=100.0), sensors=quiet)
    log = simulate("crazyflie21", ("motor_lag", "rotor_drag", "gyroscopic"), seed=3, duration=40.0, params=params)
    return log, params


@pytest.fixture(scope="module")
def bag():
    return load_flight(BAG, CF)


def test_identification_recovers_the_simulator_constants(sim_flight):
    """Speed map held at the simulator's (k_u = -B_m/A_m, no offset), the rest started from the literature values
    and fitted with the measuring observer (angular_trim off, the structure the simulator has). Tolerances: the
    time constant and thrust/torque constants, inertias 3 % (the fit found < 2 %). The time constant found is the
    motor's plus half a log period: the simulated gyro reports each period's mean rate (a lag of Δt/2 = 5 ms), which
    the model, without a sensor filter, takes into the lag between command and measured rate (with the model's
    step integrating each interval's mean thrust; until 2026-11-26 its start-of-step thrust lagged by as much and
    the two cancelled here, not at the simulator's 250 Hz stabiliser); the rotor drag and its arm
    25 % (the simulator applies drag per rotor at its hub with each rotor's speed, the model the summed speed at
    one arm: a different form)."""
    log, params = sim_flight
    start = CF.with_values({"rotor_speed_gain": params.esc.speed_gain, "rotor_speed_offset": params.esc.speed_offset}, "simulator speed map")
    fit = identify_physics([log], start, EvaluationConfig.preset("short", train="0%:100%"), Observer(0.5, 0.5, angular_trim=False))
    truth = {
        "rotor_time_constant": params.motor_time_constant + 0.5 / params.log_rate, "rotor_thrust_constant": params.vehicle.value("rotor_thrust_constant"),
        "rotor_torque_constant": params.vehicle.value("rotor_torque_constant"), "effective_ixx": CF.value("ixx"), "effective_iyy": CF.value("iyy"),
    }
    for key, value in truth.items():
        assert fit.values[key] == pytest.approx(value, rel=0.03), key
    assert fit.values["rotor_delay"] == 0.0 and fit.at_bound["rotor_delay"]  # no delay simulated: on its lower bound 0
    assert fit.values["rotor_drag_xy"] == pytest.approx(params.rotor_drag.horizontal, rel=0.25)
    assert fit.values["rotor_drag_z"] == pytest.approx(params.rotor_drag.vertical, rel=0.25)
    assert fit.values["rotor_drag_arm"] == pytest.approx(params.geometry.rotor_plane_z, rel=0.25)
    assert not any(on for key, on in fit.at_bound.items() if key != "rotor_delay")  # (flagged too, until a review said)
    assert all(np.isfinite(fit.sigma[key]) and fit.sigma[key] > 0 for key in FITTED)
    delay = next(e for e in fit.estimates() if e.name == "rotor_delay")
    assert delay.at_bound and "AT BOUND" in " ".join(delay.lines())  # every listing reads this one record


def test_a_switched_off_lag_is_held_at_zero_and_identify_effects_motor_lag_fits_it_again(sim_flight):
    """The vehicle file switches motor lag and input delay off: the fit holds τ_m = δ = 0 (no sigma, not at a bound,
    the reason given), and the identified vehicle keeps them off; ``--effects motor_lag`` fits τ_m again (the
    simulator's + Δt/2, as above) and switches it on, δ still held."""
    log, params = sim_flight
    start = CF.with_values({"rotor_speed_gain": params.esc.speed_gain, "rotor_speed_offset": params.esc.speed_offset}, "simulator speed map")
    start = dataclasses.replace(start, effects=parse_effects({"motor_lag": {"enabled": False}, "input_delay": {"enabled": False}}, "t.yaml"))
    config, observer = EvaluationConfig.preset("short", train="0%:100%"), Observer(0.5, 0.5, angular_trim=False)
    held = identify_physics([log], start, config, observer)
    for key in ("rotor_time_constant", "rotor_delay"):
        assert held.values[key] == 0.0 and np.isnan(held.sigma[key]) and not held.at_bound[key]
        assert "effects." in held.held[key] and "switched off" in held.held[key]
    assert held.switches == {"motor_lag": False, "input_delay": False}
    fitted = identify_physics([log], start, config, observer, terms=["motor_lag"])
    assert fitted.values["rotor_time_constant"] == pytest.approx(params.motor_time_constant + 0.5 / params.log_rate, rel=0.03)
    assert fitted.values["rotor_delay"] == 0.0 and fitted.switches == {"motor_lag": True, "input_delay": False}
    assert sum(fitted.diagnostics["error_ratio"].values()) < sum(held.diagnostics["error_ratio"].values())  # the lag helps
    document = vehicle_document(start, "lag and delay off")
    add_physics_constants(document, held, "", "test")
    assert document["effects"]["motor_lag"] == {"enabled": False} and "kept: held at 0" in document["constants"]["rotor_delay"]["source"]
    assert document["constants"]["rotor_time_constant"]["value"] == start.value("rotor_time_constant")  # the file's, not 0


def test_identification_on_the_bundled_bag_has_finite_sigmas_and_flags_values_at_their_bounds(bag):
    fit = identify_physics([bag], CF, SHORT)
    assert all(np.isfinite(fit.sigma[key]) and fit.sigma[key] > 0 for key in FITTED)
    for key in FITTED:
        low, high = fit.bounds[key]
        assert low <= fit.values[key] <= high
    # a starting torque constant 1000x too large puts the estimate below start / 10: clipped there and flagged
    far = CF.with_values({"rotor_torque_constant": CF.value("rotor_torque_constant") * 1000}, "test: far start")
    flagged = identify_physics([bag], far, SHORT)
    assert flagged.at_bound["rotor_torque_constant"]
    assert flagged.values["rotor_torque_constant"] == pytest.approx(far.value("rotor_torque_constant") / 10)
    assert flagged.values["rotor_thrust_constant"] == pytest.approx(fit.values["rotor_thrust_constant"], rel=1e-9)


@pytest.mark.slow
def test_identify_writes_the_physics_constants_into_a_loadable_vehicle(bag, tmp_path):
    result = identify([bag], CF, SHORT)
    assert result.physics is not None
    document = identified_vehicle_document(CF, result, SHORT.train)
    for key in FITTED:
        entry = document["constants"][key]
        assert entry["value"] == result.physics.values[key] and entry["sigma"] == result.physics.sigma[key]
        assert entry["source"].startswith("effective value of the physics fit, " if key.startswith("effective_") else "identified on")
    # the fitted roll/pitch inertias are effective values next to the airframe's, which identify never overwrites
    for key, airframe in (("effective_ixx", "ixx"), ("effective_iyy", "iyy")):
        ratio = result.physics.values[key] / CF.value(airframe)
        assert document["constants"][airframe] == {"value": CF.value(airframe), "unit": "kg m2", "source": CF.constants[airframe].source,
                                                   "status": "measured"}
        assert document["constants"][key]["status"] == "effective" and ratio > 2
        assert f"{ratio:.2f} x the airframe's {airframe} " in document["constants"][key]["source"]
        assert f"  {key} {result.physics.values[key]:.3g} kg m2 = {ratio:.2f} x the airframe's {airframe} " in result.summary()
    assert document["identification"]["physics"]["rotor_delay"]["unit"] == "s"
    path = tmp_path / "cf.yaml"
    from quad_modelling.core.identification.identify import write_vehicle_yaml

    write_vehicle_yaml(document, path)
    vehicle = VehicleConfig.from_yaml(path)
    model = PhysicsPredictor(vehicle)
    assert model.params.thrust_constant == result.physics.values["rotor_thrust_constant"]
    assert "physics model constants" in result.summary()


def test_identify_without_physics_constants_says_so_and_still_identifies_the_greybox(bag):
    doc_vehicle = VehicleConfig(**{**CF.__dict__, "constants": {k: c for k, c in CF.constants.items() if not k.startswith(("rotor_d",))}})
    result = identify([bag], doc_vehicle, SHORT)
    assert result.physics is None and "rotor_delay, rotor_drag_xy" in result.physics_note
    assert "not identified" in result.summary()


def test_constants_the_flights_do_not_excite_are_kept_and_flagged():
    """Collective-only flights of the linear model (no roll, pitch or yaw commands): the roll/pitch inertias, the
    drag arm and the torque constant are not identifiable -- kept at the file's values with a NaN sigma and
    ``identifiable`` False -- while the thrust constant is fitted (the flights are flown by the thesis's linear
    model, so only near the LinkQuad's value: within 10 %)."""
    from test.core.flightgen import linear_flight

    linkquad = load_vehicle("linkquad")
    logs = [linear_flight(linkquad, duration=42.0, seed=seed) for seed in range(2)]
    fit = identify_physics(logs, linkquad, SHORT)
    for key in ("effective_ixx", "effective_iyy", "rotor_drag_arm", "rotor_torque_constant"):
        assert not fit.identifiable[key] and fit.values[key] == linkquad.effective_value(key) and np.isnan(fit.sigma[key])
        assert not fit.at_bound[key]
    assert fit.identifiable["rotor_thrust_constant"]
    assert fit.values["rotor_thrust_constant"] == pytest.approx(linkquad.value("rotor_thrust_constant"), rel=0.1)
    assert "(held: not identifiable from these flights)" in "\n".join(fit.summary())


def test_imbalance_patterns_span_every_gain_spread_of_x_and_plus_frames():
    """The roll, pitch and yaw gain patterns are zero-mean, scaled to 1, and with the common mode span every per-motor
    gain vector (so any motor's gain can be identified relative to the others') on both the x and the + frame."""
    from quad_modelling.core.identification.physics_terms import imbalance_patterns

    for name in ("crazyflie21", "linkquad"):
        v = load_vehicle(name)
        patterns = imbalance_patterns(v.motor_positions, v.yaw_signs)
        np.testing.assert_allclose(patterns.sum(axis=1), 0.0, atol=1e-12)
        np.testing.assert_allclose(np.abs(patterns).max(axis=1), 1.0)
        assert np.linalg.matrix_rank(np.vstack([np.ones(4), patterns])) == 4, name


def test_battery_kappa_is_resolved_from_the_pack_sag():
    """A simulated LinkQuad flight with the battery on (its rotor speed proportional to the pack voltage V, so the
    model's κ = 1/V at the mean voltage, 0.084 1/V): fitted with the default observer, κ comes within 15 % of it and
    at least 3 sigma from 0, because the regression's linear observer is lengthened to BATTERY_FIT_LINEAR_S (with
    the 0.5 s observer: 0.066 +- 0.029 on these flights); the fit's own observer is kept for predicting."""
    from quad_modelling.core.identification.physics_fit import BATTERY_FIT_LINEAR_S
    from test.conftest import simulated

    linkquad = load_vehicle("linkquad")
    flights = [simulated("linkquad", ("battery",), seed, 60.0) for seed in (5101, 5102)]
    fit = identify_physics(flights, linkquad, SHORT, Observer(), terms=["battery"])
    kappa = next(e for e in fit.estimates() if e.name == "battery.kappa")
    truth = 1.0 / np.mean(np.concatenate([f.vbat for f in flights]))
    assert kappa.value == pytest.approx(truth, rel=0.15)
    assert kappa.value >= 3.0 * kappa.sigma
    assert fit.diagnostics["observer"]["linear_s"] == BATTERY_FIT_LINEAR_S
    assert fit.observer == Observer()


def test_identify_recovers_the_simulators_cg_offset_with_the_motor_imbalance():
    """A short simulated LinkQuad flight with only the motor imbalance on (the simulator's own ESC gains and CG
    offset, not set from the model): identify --effects motor_imbalance, the observer chosen by the data as the
    command runs it, fits the CG offset within 1 mm of the simulator's (6, -4) mm and many sigma from 0 (the rotors
    sit at r_i - c about its CG: the moment -c x F of the one physics), and the fitted parameters carry it."""
    from quad_modelling.core.identification.physics_terms import CG_HELD
    from test.conftest import simulated

    linkquad = load_vehicle("linkquad")
    truth = sim_params_for("linkquad").imbalance.cg_offset  # the simulator's, read only
    flight = simulated("linkquad", ("motor_imbalance",), 5101, 40.0)
    fit = identify_physics([flight], linkquad, SHORT, terms=["motor_imbalance"])
    estimates = {e.name: e for e in fit.estimates()}
    for axis, true_value in zip("xy", truth):
        e = estimates[f"motor_imbalance.cg_offset_{axis}"]
        assert e.value == pytest.approx(true_value, abs=1e-3) and abs(e.value) > 5.0 * e.sigma and not e.at_bound
        assert e.held != CG_HELD and e.unit == "m"
    p = fit.parameters(PhysicsParameters.from_vehicle(linkquad))
    assert p.cg_offset == pytest.approx((estimates["motor_imbalance.cg_offset_x"].value, estimates["motor_imbalance.cg_offset_y"].value))


def test_the_imbalance_fitted_on_its_yaw_pattern_alone_holds_the_rest():
    """``imbalance_axes=("yaw",)`` (the diagnosis's reference for the rest of an imbalance): on the flight above the
    gains move along the yaw pattern only (their roll and pitch coordinates 0) and the CG offset is held at 0, where
    the full fit has both, many sigma from 0."""
    from quad_modelling.core.identification.physics_terms import imbalance_patterns
    from test.conftest import simulated

    linkquad = load_vehicle("linkquad")
    patterns = imbalance_patterns(linkquad.motor_positions, linkquad.yaw_signs)
    flight = simulated("linkquad", ("motor_imbalance",), 5101, 40.0)
    coordinates, cg = {}, {}
    for axes in (("roll", "pitch", "yaw"), ("yaw",)):
        fit = identify_physics([flight], linkquad, SHORT, terms=["motor_imbalance"], imbalance_axes=axes)
        gains = np.array([fit.terms["motor_imbalance"][f"gain_{i}"]["value"] for i in range(1, 5)])
        coordinates[axes] = np.linalg.lstsq(patterns.T, gains - 1.0, rcond=None)[0]  # roll, pitch, yaw coordinates
        cg[axes] = [fit.terms["motor_imbalance"][f"cg_offset_{axis}"]["value"] for axis in "xy"]
    np.testing.assert_allclose(coordinates[("yaw",)][:2], 0.0, atol=1e-12)
    assert abs(coordinates[("yaw",)][2]) > 0.003 and cg[("yaw",)] == [0.0, 0.0]
    assert cg[("roll", "pitch", "yaw")] == pytest.approx(sim_params_for("linkquad").imbalance.cg_offset, abs=1e-3)


@pytest.mark.slow
def test_fitted_without_an_observer_the_hover_pins_the_thrust_constant():
    """Effect-free simulated LinkQuad flights: without an observer, gravity in the velocity channel's known part pins
    k_f to the hover (the regression had no g there until 2026-11-26, and k_f went to its lower bound, 1e-6); the
    observer choice then fits and scores with none as well."""
    from test.conftest import simulated

    linkquad = load_vehicle("linkquad")
    truth = sim_params_for(linkquad).vehicle.value("rotor_thrust_constant")
    flights = [simulated("linkquad", (), seed, 60.0) for seed in (5101, 5102)]
    fit = identify_physics(flights, linkquad, SHORT, Observer(0.0, 0.0))
    assert fit.values["rotor_thrust_constant"] == pytest.approx(truth, rel=2e-3)
    assert fit.sigma["rotor_thrust_constant"] < 1e-3 * truth
    assert not fit.at_bound["rotor_thrust_constant"]
    chosen = identify_physics(flights, linkquad, SHORT)
    assert set(chosen.diagnostics["observer_choice"]["errors"]) == {"default", "measured", "linear only", "none"}


def test_the_delay_between_samples_is_the_vertex_of_the_whole_sample_profile():
    """J sampled at whole samples of a parabola with its minimum at 66.1 ms (10 ms samples) gives 66.1 ms; a
    symmetric profile gives the best sample; a neighbour as good as the best puts it half-way between them."""
    def j(delay):
        return 2.1 + 40.0 * (delay - 0.0661) ** 2

    assert subsample_delay(0.07, j(0.06), j(0.07), j(0.08), 0.01) == pytest.approx(0.0661, abs=1e-12)
    assert subsample_delay(0.05, 2.2, 2.1, 2.2, 0.01) == pytest.approx(0.05, abs=1e-15)
    assert subsample_delay(0.05, 2.10, 2.10, 2.2, 0.01) == pytest.approx(0.045, abs=1e-15)


def test_a_time_constant_the_search_leaves_at_its_lower_bound_is_flagged():
    """A simulated LinkQuad flight without motor lag (its rotors jump to their targets), the lag searched as the
    diagnosis's motor_lag candidate searches it (the vehicle switches it off), without an observer (the one its
    rungs keep there): τ ends within the search's tolerance of its 2 ms bound (2.13 ms on --validate's null cases,
    then read as resolved: 6 sigma from 0) and is flagged."""
    vehicle = assessing_vehicle("linkquad")
    log = simulate("linkquad", (), seed=5, duration=60.0)
    config = EvaluationConfig.preset("short", train="0%:100%", eval="0%:100%")
    fit = identify_physics([log], vehicle, config, observer=Observer(0.0, 0.0), terms=["motor_lag"])
    assert fit.values["rotor_time_constant"] < 0.0022 and fit.at_bound["rotor_time_constant"]
    # ... and the advice is the switch, as for a delay on 0 (it said "more excitation": the bound is 2 ms, not 0)
    lag = next(e for e in fit.estimates() if e.name == "rotor_time_constant")
    assert lag.helps.startswith("none in the flights? switch motor_lag off in the vehicle file")


def test_a_delay_fitted_as_a_lag_of_about_a_sample_is_said_to_look_alike_not_to_be_absent():
    """A simulated Crazyflie with its 8 ms command delay and no rotor lag, identified with the shipped file (both
    searched): the lag takes the delay (8.5 ms) and the delay ends on 0. The advice said "none in the flights? switch
    input_delay off" -- backwards (review); it now names the look-alike and the switch that finds the delay. A lag
    of more than two samples beside a delay of 0 keeps the old advice (test_identify's LinkQuad, 105 ms)."""
    log = simulate("crazyflie21", ("input_delay",), seed=4521, duration=40.0)
    fit = identify_physics([log], CF, EvaluationConfig.preset("short", train="0%:100%"), observer=Observer(0.0, 0.0))
    lag, delay = fit.values["rotor_time_constant"], fit.values["rotor_delay"]
    assert 0.006 < lag < 0.011 and delay == 0.0 and fit.at_bound["rotor_delay"]
    helps = next(e for e in fit.estimates() if e.name == "rotor_delay").helps
    assert helps.startswith(f"a lag and a delay look alike at this log rate: the rotor lag ({1000 * lag:.1f} ms) may hold a "
                            "command delay; with no rotor lag in the vehicle, switch motor_lag off")
    off = dataclasses.replace(CF, effects=parse_effects({"motor_lag": {"enabled": False}}, "no lag"))
    found = identify_physics([log], off, EvaluationConfig.preset("short", train="0%:100%"), observer=Observer(0.0, 0.0))
    assert found.values["rotor_delay"] == pytest.approx(0.008, abs=0.003)  # the switch finds it


def test_a_later_pass_searches_the_lag_near_the_previous_one_and_the_whole_range_when_it_ends_at_that_edge(sim_flight, monkeypatch):
    """The imbalance's later Gauss-Newton passes start the rotor-dynamics search at the previous pass's (τ, δ): the
    same τ and δ as the full search (τ within its 10 % tolerance) with fewer objective evaluations; started 4x off
    (log 4 = 1.39 > the 0.5 window), τ's minimum lies at the window's edge and the whole range is searched again."""
    from quad_modelling.core.identification import physics_fit
    from quad_modelling.core.identification.physics_terms import TermDesign

    log, params = sim_flight
    start = CF.with_values({"rotor_speed_gain": params.esc.speed_gain, "rotor_speed_offset": params.esc.speed_offset}, "simulator speed map")
    config = EvaluationConfig.preset("short", train="0%:100%")
    observer = Observer(0.5, 0.5, angular_trim=False)
    segments = physics_fit.training_segments([log], config, observer)
    p = PhysicsParameters.from_vehicle(start)
    calls = []
    counted = physics_fit._normal_equations
    monkeypatch.setattr(physics_fit, "_normal_equations", lambda *a, **k: calls.append(1) or counted(*a, **k))

    def search(near):
        calls.clear()
        tau, delay, *_ = physics_fit._search_dynamics(p, segments, observer, TermDesign(), log.sample_rate, start, None, near)
        return tau, delay, len(calls)

    tau, delay, full = search(None)
    assert tau == pytest.approx(params.motor_time_constant + 0.5 / params.log_rate, rel=0.1)
    near_tau, near_delay, near_calls = search((tau, delay))
    assert near_tau == pytest.approx(tau, rel=0.1) and near_delay == delay
    assert near_calls < 0.7 * full
    far_tau, far_delay, far_calls = search((4.0 * tau, delay))
    assert far_tau == pytest.approx(tau, rel=0.1) and far_delay == delay
    assert far_calls > near_calls


def test_the_fit_leaves_out_anchors_by_the_shared_ground_contact_test(bag):
    """The physics fit's anchors use preprocess.ground_contact, the test of the scores and the window drop: one
    motion-capture sample at the ground mid-flight (a glitch) leaves every anchor in (the 5-sample median), a 0.5 s
    touchdown keeps every anchor whose history and horizon stay clear of it and drops anchors that meet it."""
    from quad_modelling.core.identification.physics_fit import training_segments
    from quad_modelling.core.preprocess import ground_contact

    config = EvaluationConfig.preset("short", train="0%:100%")

    def anchor_times(log):
        return np.concatenate([s.t[s.anchors] for s in training_segments([log], config)])

    before = anchor_times(bag)
    floor = float(np.max(bag.pos_n[:, 2]))  # NED z of the lowest point
    middle = int(np.searchsorted(bag.t, before[len(before) // 2]))
    glitch = bag.pos_n.copy()
    glitch[middle, 2] = floor
    assert np.array_equal(anchor_times(dataclasses.replace(bag, pos_n=glitch)), before)
    down = bag.pos_n.copy()
    rows = (bag.t >= bag.t[middle]) & (bag.t < bag.t[middle] + 0.5)
    down[rows, 2] = floor
    touched = dataclasses.replace(bag, pos_n=down)
    assert ground_contact(touched)[rows][2:-2].all()
    after = anchor_times(touched)
    longest = 0.5  # FIT_HORIZONS_S[-1]: an anchor at t sees t + 0.5 s; its observer history 0.5 s back
    kept = before[(before + longest < bag.t[middle] - 0.03) | (before - longest > bag.t[middle] + 0.5 + 0.03)]
    assert set(kept) <= set(after) and len(after) < len(before)


def test_a_ground_effect_the_bag_pushes_below_zero_vanishes_and_leaves_the_fit_without_it(bag):
    """On the bundled bag the ground-effect coefficient comes out negative (no ground effect there: it flies at
    0.5-1.5 m): held at its bound 0, the term is no term, and every other constant equals the fit without it
    (clipping it alone kept constants that made up for its impossible sign)."""
    observer = Observer()
    without = identify_physics([bag], CF, SHORT, observer=observer)
    with_term = identify_physics([bag], CF, SHORT, observer=observer, terms=("ground_effect",))
    coefficient = with_term.terms["ground_effect"]["coefficient"]
    assert coefficient["value"] == 0.0 and coefficient["at_bound"] and "vanishes" in coefficient["held"]
    assert np.isnan(coefficient["sigma"]) and "ground_effect" in with_term.diagnostics["vanished_terms"]
    assert with_term.values == without.values
    p_with, p_without = with_term.parameters(PhysicsParameters.from_vehicle(CF)), without.parameters(PhysicsParameters.from_vehicle(CF))
    assert p_with.ground_effect[0] == 0.0 and p_without.ground_effect is None
    for name in (f.name for f in dataclasses.fields(p_with) if f.name != "ground_effect"):
        assert np.array_equal(np.asarray(getattr(p_with, name), dtype=object), np.asarray(getattr(p_without, name), dtype=object)), name
    assert effects_section(with_term.terms, "test")["ground_effect"]["enabled"] is False  # written off: no term
    # a vehicle that already has the term on: the refit is without it too, not with the file's coefficient
    document = vehicle_document(CF, "with a ground effect")
    document["effects"] = {"ground_effect": {"enabled": True, **{key: {"value": value, "unit": unit, "bounds": [0.0, 1.0],
                                                                         "source": "test", "status": "identified"}
                                                                   for key, value, unit in (("coefficient", 0.0021, "m2"),
                                                                                            ("offset", 0.05, "m"))}}}
    on = VehicleConfig.from_dict(document, "ge_on.yaml")
    refitted = identify_physics([bag], on, SHORT, observer=observer, terms=("ground_effect",))
    assert refitted.terms["ground_effect"]["coefficient"]["value"] == 0.0 and refitted.values == without.values
