"""The physics-base diagnosis with the vehicle file's switches: motor lag and input delay switched off are held at 0
in the base and assessed as candidates -- on simulated flights the one present is found, not the other one its
signature resembles; switched on (the default), they are part of the base and no candidate."""

from __future__ import annotations

import dataclasses
import functools

import pytest

from quad_modelling.core.diagnosis.physics_base import (
    diagnose_physics,
    identified_document,
    next_effect,
    pair_candidates,
)
from quad_modelling.core.diagnosis.verdicts import FOUND_MIN_BOUND, unconfirmed_text
from quad_modelling.core.physics.effects import parse_effects
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.core.sim.simulate import simulate
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig

CF = load_vehicle("crazyflie21")
SWITCHED_OFF = parse_effects({"motor_lag": {"enabled": False}, "input_delay": {"enabled": False}}, "cf_off.yaml")


@functools.lru_cache(maxsize=None)
def _diagnosed(effect: str, delay_s: float, switched_off: bool = True):
    """Two 30 s simulated Crazyflie flights with ``effect`` on (the stabiliser at the 100 Hz log rate), diagnosed
    with the simulator's speed map: train on one, score on the other; lag and delay switched off in the vehicle
    (``switched_off``) or not. Once per run for each arguments (tests share it)."""
    vehicle_effects = SWITCHED_OFF if switched_off else {}
    params = sim_params_for(CF)
    params = params.replace(control=dataclasses.replace(params.control, rate=100.0), input_delay=delay_s)
    train, test = (simulate("crazyflie21", (effect,), seed=seed, duration=30.0, params=params) for seed in (11, 12))
    start = CF.with_values({"rotor_speed_gain": params.esc.speed_gain, "rotor_speed_offset": params.esc.speed_offset}, "simulator speed map")
    vehicle = dataclasses.replace(start, effects=vehicle_effects)
    return diagnose_physics([train], [test], vehicle, EvaluationConfig.preset("short"), ("motor_lag", "input_delay")), params, vehicle


@pytest.mark.slow
def test_a_motor_lag_is_found_as_a_lag_and_a_delay_as_a_delay():
    """Truth τ_m 50 ms (found 55: the simulated gyro's Δt/2 period mean adds 5 ms, test_physics_fit) and a 40 ms
    delay (found 45). Each alone shrinks the held-out J by ~20 %; the other, tried on top, adds nothing."""
    lag, params, vehicle = _diagnosed("motor_lag", 0.0)
    assert lag.found == ["motor_lag"] and lag.effects["input_delay"]["verdict"] == "not supported"
    tau = lag.effects["motor_lag"]["components"][0]
    assert tau["resolved"] and tau["value"] == pytest.approx(params.motor_time_constant + 0.5 / params.log_rate, rel=0.1)
    assert lag.dropped["motor_lag"] > 0.1 and lag.summary["delay_s"]["value"] == 0.0
    document = identified_document(vehicle, lag.final, "test")
    assert document["effects"]["motor_lag"] == {"enabled": True} and document["effects"]["input_delay"]["enabled"] is False
    delay, _, _ = _diagnosed("input_delay", 0.04)
    assert delay.found == ["input_delay"] and delay.summary["delay_s"]["value"] == pytest.approx(0.045, abs=0.01)
    assert delay.effects["motor_lag"]["verdict"] == "not supported"
    # its 5 ms time constant is resolved (5 sigma) yet not supported: the report says why, in one sentence
    assert delay.effects["motor_lag"]["components"][0]["resolved"]
    assert "resolved on the training flights (>= 3 sigma, off its bounds; the halves are fitted for found effects), but added to base + input_delay it shrinks the held-out error by -" in \
        delay.effects["motor_lag"]["text"]


@functools.lru_cache(maxsize=None)
def _imbalance_diagnosed(effect: str):
    """Seed 223's first training and its held-out flight of ``diagnose --validate`` (60 s simulated LinkQuad flights,
    a low pass first) with ``effect`` on, diagnosed as there with the motor imbalance the only candidate (6 s)."""
    from quad_modelling.commands.diagnose import PHYSICS_CONFIG
    from quad_modelling.core.diagnosis.physics_validation import (
        PHYSICS_VALIDATION_DURATION_S, CaseSettings, assessing_vehicle, simulated_flight, test_seeds, train_seeds,
        validation_params)

    settings = CaseSettings("linkquad", (), PHYSICS_VALIDATION_DURATION_S, PHYSICS_CONFIG, "effects-on", validation_params("linkquad"))
    train, test = (simulated_flight(settings, (effect,), seeds(223)[0])[0] for seeds in (train_seeds, test_seeds))
    return diagnose_physics([train], [test], assessing_vehicle("linkquad"), PHYSICS_CONFIG, ("motor_imbalance",))


@pytest.mark.slow
@pytest.mark.parametrize("effect, found", [("bent_arm", False), ("motor_imbalance", True)])
def test_an_imbalance_whose_gains_shrink_the_error_only_by_their_yaw_pattern_is_not_found(effect, found):
    """A bent arm (rotor 1 tilted 3 degrees about its arm: a yaw torque in proportion to its thrust, what the gains'
    yaw pattern makes) is not found as a motor imbalance: on top of the gains' yaw pattern alone (YAW_PATTERN_ONLY)
    its roll and pitch part does not shrink the held-out error; the report says why and keeps the gains. The
    simulator's own imbalance (its gains and a 6 mm CG offset) is found: its roll and pitch part shrinks J by far more
    than FOUND_MIN_BOUND."""
    result = _imbalance_diagnosed(effect)
    part = result.steps[0]["imbalance_roll_pitch"]
    assert result.found == (["motor_imbalance"] if found else []) and part["supported"] is found
    text = result.effects["motor_imbalance"]["text"]
    if found:
        assert part["shrink_5pct"] > 5 * FOUND_MIN_BOUND and "tilted" not in text
    else:
        assert result.steps[0]["trials"]["motor_imbalance"]["shrink_5pct"] >= FOUND_MIN_BOUND  # it passed alone
        assert part["shrink_5pct"] < FOUND_MIN_BOUND and "a rotor tilted about its arm (a bent arm)" in text
        assert result.steps[0]["trials"]["motor_imbalance"]["yaw_pattern_only"]  # the selection table's reason
        assert f"it shrinks the held-out error by {part['imbalance_shrink']:+.1%}" in text and part["imbalance_shrink"] > 0.02
        assert result.summary["motor_command_gains"]["fitted"] and result.final.effects == ()


def test_an_effect_resolved_but_not_supported_says_which_holds():
    text = unconfirmed_text({"shrink": -0.0004, "shrink_5pct": -0.003}, ["rotor_drag", "battery"])
    assert text == ("resolved on the training flights (>= 3 sigma, off its bounds; the halves are fitted for found effects), but added to base + rotor_drag + battery it shrinks the held-out "
                    "error by +0.0% (5 % bound -0.3%; found needs a 5 % bound >= 1%): the held-out flights do not "
                    "confirm it")


@pytest.mark.slow
def test_without_the_switches_lag_and_delay_are_in_the_base_and_no_candidate():
    result, _, _ = _diagnosed("motor_lag", 0.0, switched_off=False)
    assert result.candidates == [] and result.found == []
    assert set(result.to_json()["in_base"]) >= {"motor_lag", "input_delay", "thrust_nonlinearity", "trim_drift"}


def test_a_larger_shrink_at_its_bound_does_not_block_a_resolved_effect():
    """The all-seven case of seeds 6301-6303 (bench/results/diagnose_sim_physics_switched_before_fix.md): the delay at
    its 150 ms bound shrank J most, the resolved lag next; the lag joins. Nothing may join: the largest, not joining."""
    resolved, at_bound = [{"resolved": True}], [{"resolved": False}]
    scored = {"rotor_drag": (0.165, 0.029, resolved), "motor_lag": (0.342, 0.250, resolved),
              "input_delay": (0.347, 0.267, at_bound), "battery": (-0.004, -0.005, at_bound)}
    assert next_effect(scored) == ("motor_lag", True)
    assert next_effect({"input_delay": (0.347, 0.267, at_bound), "gyroscopic": (0.03, -0.01, resolved),
                        "ground_effect": (0.01, 0.005, resolved)}) == ("input_delay", False)


def test_an_effect_joins_on_the_evidence_of_its_bootstrap_bound_not_on_its_point_estimate():
    """Seed 132, all seven on (bench/results/diagnose_validate_131.md, session 21): on top of drag, imbalance, lag and
    battery the input delay shrank J by 1.95 % with a 5 % bound of 1.2 %: it joins. Seed 131's bent arm: the motor
    imbalance shrank J by 3.2 % with a bound of 0.4 %: it does not (a disturbance outside the catalogue)."""
    resolved = [{"resolved": True}]
    assert next_effect({"input_delay": (0.0195, 0.0121, resolved), "ground_effect": (0.0166, 0.0103, resolved),
                        "gyroscopic": (0.0005, -0.0002, resolved)}) == ("input_delay", True)
    assert next_effect({"motor_imbalance": (0.032, 0.004, resolved), "battery": (0.001, -0.003, resolved)}) == ("motor_imbalance", False)
    assert next_effect({"motor_imbalance": (0.032, FOUND_MIN_BOUND, resolved)}) == ("motor_imbalance", True)


def test_the_pair_step_tries_every_two_resolved_candidates_but_the_lag_and_the_delay():
    """Seed 72, all seven on (bench/results/diagnose_validate_71.md): on top of motor lag and rotor drag no candidate
    joined alone; the battery and the motor imbalance, resolved, are tried together, the delay (its own twin check)
    and the unresolved ground effect are not."""
    resolved, unresolved = [{"resolved": True}], [{"resolved": False}]
    scored = {"input_delay": (0.006, -0.004, resolved), "ground_effect": (0.0, -0.001, unresolved),
              "battery": (-0.006, -0.010, resolved), "gyroscopic": (-0.01, -0.02, unresolved),
              "motor_imbalance": (0.016, -0.055, resolved)}
    assert pair_candidates(scored) == [("battery", "motor_imbalance")]
    scored["rotor_drag"] = (0.01, -0.002, resolved)
    assert pair_candidates(scored) == [("battery", "motor_imbalance"), ("battery", "rotor_drag"), ("motor_imbalance", "rotor_drag")]
    assert pair_candidates({"battery": (0.0, -0.01, resolved), "motor_lag": (0.01, 0.0, resolved)}) == []


@pytest.mark.slow
def test_lag_and_delay_are_said_apart_or_not_by_their_held_out_difference():
    """A 50 ms lag: the delay fitted in its place shrinks J by less, outside the bootstrap interval (told apart); an
    8 ms delay, under one 10 ms log period, shrinks J as a lag does (2.5 % each, session-12 note): not told apart,
    said in both entries and in the summary."""
    lag, _, _ = _diagnosed("motor_lag", 0.0)
    check = lag.effects["motor_lag"]["twin"]
    assert check["told_apart"] and check["difference_90"][0] > 0 and lag.summary["not_told_apart"] == []
    assert "the held-out flights fit it better than an input delay in its place" in lag.effects["motor_lag"]["text"]
    assert "the held-out flights fit the motor lag found better than it in its place" in lag.effects["input_delay"]["text"]
    short, _, _ = _diagnosed("input_delay", 0.008)
    (found,) = short.found
    check = short.effects[found]["twin"]
    low, high = check["difference_90"]
    assert not check["told_apart"] and low <= 0 <= high
    assert check["shrink"] - check["other_shrink"] == pytest.approx(0.0, abs=0.01)
    assert short.summary["not_told_apart"] == [[found, check["other"]]]
    assert "do not tell" in short.effects[check["other"]]["text"]


def test_the_twin_check_reads_the_paired_bootstrap():
    """Three scores on the same starts: an 'other' twin exactly as good as the found one is not told apart; one
    10 % worse on every start is."""
    import numpy as np

    from quad_modelling.core.diagnosis.physics_base import HeldOutScore, twin_check
    from quad_modelling.core.diagnosis.verdicts import twin_text

    rng = np.random.default_rng(0)
    naive = np.ones((400, 2))
    blocks = np.repeat(np.arange(20), 20)
    before = HeldOutScore(1.0 + 0.1 * rng.random((400, 2)), naive, blocks)
    chosen = HeldOutScore(before.model * 0.8, naive, blocks)
    assert not twin_check("motor_lag", before, chosen, HeldOutScore(chosen.model.copy(), naive, blocks))["told_apart"]
    worse = twin_check("motor_lag", before, chosen, HeldOutScore(chosen.model * 1.1, naive, blocks))
    assert worse["told_apart"] and worse["other"] == "input_delay" and not worse["other_better"]
    assert worse["shrink"] - worse["other_shrink"] == pytest.approx(0.08, abs=1e-9)
    # seed 91, all seven on: the lag joined at 20.8 % while the delay in its place, at its search bound, shrank 26.7 %
    better = twin_check("motor_lag", before, chosen, HeldOutScore(chosen.model * 0.9, naive, blocks))
    assert better["other_better"] and not better["told_apart"]
    text = twin_text(better, "motor_lag")
    assert "an input delay fitted in its place shrank the held-out error more" in text and "do not tell" not in text
    narrow = {**worse, "shrink": 0.064, "other_shrink": 0.063, "difference_90": [2.8e-05, 0.0024]}  # told apart, barely
    assert "difference +0.003% .. +0.240% (90 %)" in twin_text(narrow, "motor_lag")  # it read +0.0 % .. +0.2 %
    # told apart says what was compared, each twin alone on the rung, not that the other is absent: a 50 ms lag with an
    # 8 ms delay was found as one 55.0 ms delay "told from a motor lag by the held-out flights" (seeds 31-33)
    delay = twin_check("input_delay", before, chosen, HeldOutScore(chosen.model * 1.1, naive, blocks))
    found, other = twin_text(delay, "input_delay"), twin_text(delay, "motor_lag")
    assert found.startswith("the held-out flights fit it better than a motor lag in its place (shrink 20.0% against 12.0%")
    assert other.startswith("the held-out flights fit the input delay found better than it in its place (")
    assert all("a lag and a delay together are one lag of the command path, not separated here" in t for t in (found, other))
    assert "told from" not in found + other


@pytest.mark.slow
def test_a_lag_searched_to_its_bound_with_the_base_observer_is_refitted_with_the_others():
    """Simulated LinkQuad, all seven effects on, the validation's seed-142 flights as the pilot flew them before it
    led with a low pass (physics_validation.LEADING; session 21): the base is fitted with the
    default observer, whose angular trim trades with the rotor lag; fitted with it (and with none) the lag went to its
    0.3 s bound and was not resolved, so the lag was never found. Refitted with the measured observer it lands inside
    and is found (0.21 s alone: it also stands for the 20 ms delay and the rotor drag's damping; truth 0.105 s)."""
    from quad_modelling.commands.diagnose import PHYSICS_CONFIG
    from quad_modelling.core.diagnosis.physics_validation import assessing_vehicle
    from quad_modelling.core.diagnosis.validation import CaseSettings, simulated_flight, test_seeds, train_seeds
    from quad_modelling.core.effect_names import SWITCHED_EFFECTS

    everything = ("rotor_drag", "battery", "motor_lag", "input_delay", "ground_effect", "gyroscopic", "motor_imbalance")
    assert set(everything) <= set(SWITCHED_EFFECTS)
    settings = CaseSettings("linkquad", (), 60.0, PHYSICS_CONFIG, "effects-on", None)
    train = [simulated_flight(settings, everything, s)[0] for s in train_seeds(142)]
    test = [simulated_flight(settings, everything, s)[0] for s in test_seeds(142)]
    result = diagnose_physics(train, test, assessing_vehicle("linkquad"), PHYSICS_CONFIG, ("motor_lag",))
    tau = result.effects["motor_lag"]["components"][0]
    assert result.found == ["motor_lag"] and tau["resolved"] and not tau["at_bound"]
    assert 0.1 < tau["value"] < 0.25
    choice = result.final.fit.diagnostics["fit_observer_choice"]
    assert choice["chosen"] == "measured" and choice["errors"]["default"] > 1.3 * choice["errors"]["measured"]


@pytest.mark.slow
def test_the_reports_multistep_table_is_evaluates_and_the_verdicts_starts_apart():
    """The report's multi-step table scores every start, as `evaluate` does, and the verdict the starts whose 50 steps
    stay off the ground, every second one. On simulated Crazyflie flights (battery on, 60 s; the held-out flight,
    seed 13, set down on a low pass from 21 to 27 s: here asked below where it stands, as the simulator's low passes
    touched down before session 34) the two differed far more than the note's "third digit":
    the final's velocity 0.52 -> 0.66, angular velocity 0.12 -> 0.34 over 622 of 4930 starts that touch the ground (no
    model here has ground contact; velocity 0.52 -> 0.62 on this flight). Leaving out the ground-touching starts gives the verdict's ratios but for its
    sampling of every second start; the report gives both, with the count of starts of each."""
    from quad_modelling.commands.diagnose import PHYSICS_CONFIG as config
    from quad_modelling.core.evaluation.multistep import start_errors
    from quad_modelling.core.models.base import ConstantStatePredictor
    from quad_modelling.core.models.physics import PhysicsPredictor
    from quad_modelling.io.reports.physics_diagnosis import report_markdown
    from test.conftest import simulated

    from quad_modelling.core.sim.simulate import simulate

    params = sim_params_for(CF)
    params = params.replace(pilot=dataclasses.replace(params.pilot, low_hover=(0.0, 0.01)))  # rests at 0.015 m
    train, test = simulated("crazyflie21", ("battery",), 11, 60.0), simulate("crazyflie21", ("battery",), seed=13, duration=60.0, params=params)
    result = diagnose_physics([train], [test], CF, config, ("battery",))
    data, final = result.to_json(), result.final
    table, verdict = data["multistep"], data["held_out"]["final"]
    model = PhysicsPredictor(final.vehicle, observer=final.fit.observer, trim=config.trim)
    naive = ConstantStatePredictor(final.vehicle, config.trim)
    ratios = {}
    for airborne in (False, True):
        (e, n), _ = start_errors([test], [model, naive], final.vehicle, config, airborne=airborne)
        ratios[airborne] = (len(e), e.mean(axis=0) / n.mean(axis=0))
    groups = ("velocity", "angular_velocity")
    assert ratios[False][0] == table["starts"] and ratios[True][0] == table["airborne_starts"]  # the counts the report gives
    assert list(ratios[False][1]) == pytest.approx([table["models"]["final"][g]["ratio_sim_err"] for g in groups], rel=1e-9)
    assert 0.1 * table["starts"] < table["starts"] - table["airborne_starts"]  # the ground is in the span
    assert verdict["starts"] == pytest.approx(table["airborne_starts"] / 2, abs=1)  # every second airborne start
    every, off = ratios[False][1], ratios[True][1]
    for g, group in enumerate(groups):
        assert off[g] == pytest.approx(verdict["ratio_to_naive"][group], rel=0.03)  # the sampling alone
        assert every[g] > 1.1 * off[g]  # the ground-touching starts (velocity 0.62 against 0.52)
    text = " ".join(report_markdown(data).split())
    assert (f"every second start whose 50 steps stay off the ground, {verdict['starts']} here. Every start: what "
            f"`evaluate --model physics` gives, {table['starts']} starts, {table['starts'] - table['airborne_starts']} "
            "of them touching the ground") in text and "third digit" not in text
    row = [f"{verdict['ratio_to_naive'][g]:.3f}" for g in groups] + [f"{table['models']['final'][g]['ratio_sim_err']:.3f}" for g in groups]
    assert "| final | " + " | ".join(row) + " |" in text
