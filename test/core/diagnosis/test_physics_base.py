"""The physics-base diagnosis with the vehicle file's switches: motor lag and input delay switched off are held at 0
in the base and assessed as candidates -- on simulated flights the one present is found, not the other one its
signature resembles; switched on (the default), they are part of the base and no candidate."""

from __future__ import annotations

import dataclasses

import pytest

from quad_modelling.core.diagnosis.physics_base import diagnose_physics, identified_document, next_effect
from quad_modelling.core.physics.effects import parse_effects
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.core.sim.simulate import simulate
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig

CF = load_vehicle("crazyflie21")
SWITCHED_OFF = parse_effects({"motor_lag": {"enabled": False}, "input_delay": {"enabled": False}}, "cf_off.yaml")


def _diagnosed(effect: str, delay_s: float, vehicle_effects=SWITCHED_OFF):
    """Two 30 s simulated Crazyflie flights with ``effect`` on (the stabiliser at the 100 Hz log rate), diagnosed
    with the simulator's speed map: train on one, score on the other."""
    params = sim_params_for(CF)
    params = params.replace(control=dataclasses.replace(params.control, rate=100.0), input_delay=delay_s)
    train, test = (simulate("crazyflie21", (effect,), seed=seed, duration=30.0, params=params) for seed in (11, 12))
    start = CF.with_values({"rotor_speed_gain": params.esc.speed_gain, "rotor_speed_offset": 0.0}, "simulator speed map")
    vehicle = dataclasses.replace(start, effects=vehicle_effects)
    return diagnose_physics([train], [test], vehicle, EvaluationConfig.preset("short"), ("motor_lag", "input_delay")), params, vehicle


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


def test_without_the_switches_lag_and_delay_are_in_the_base_and_no_candidate():
    result, _, _ = _diagnosed("motor_lag", 0.0, vehicle_effects={})
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
