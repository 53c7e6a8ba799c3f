"""The physics model's optional terms: the vehicle file's effects section (validation, one line per fault, round
trip) and what each switched-on term does to the model's predictions (signs and sizes, live = offline, causal)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.physics import PhysicsPredictor
from quad_modelling.core.physics import rigid_body, rotors
from quad_modelling.core.physics.effects import BASE_SWITCHES, effects_document, parse_effects, parse_term_names
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle, vehicle_file
from quad_modelling.errors import ConfigError
from quad_modelling.io.loader import load_flight
from test.conftest import FIXTURES

CF = load_vehicle("crazyflie21")

GROUND = {"enabled": True,
          "coefficient": {"value": 3.3e-5, "sigma": 4e-6, "unit": "m2", "bounds": [0.0, 2e-3], "source": "test", "status": "identified"},
          "offset": {"value": 0.02, "unit": "m", "bounds": [0.0, 0.2], "source": "test", "status": "measured"}}
BATTERY = {"enabled": True,
           "kappa": {"value": 0.2, "unit": "1/V", "bounds": [-1.0, 1.0], "source": "test", "status": "identified"},
           "reference_voltage": {"value": 3.9, "unit": "V", "bounds": [0.0, 100.0], "source": "test", "status": "measured"}}


def _vehicle(effects: dict) -> VehicleConfig:
    doc = yaml.safe_load(vehicle_file("crazyflie21").read_text())
    doc["effects"] = copy.deepcopy(effects)
    return VehicleConfig.from_dict(doc, "cf_terms.yaml")


def test_a_valid_section_round_trips_and_switches_the_terms_on():
    vehicle = _vehicle({"ground_effect": GROUND, "battery": BATTERY})
    p = PhysicsParameters.from_vehicle(vehicle)
    assert p.ground_effect == (3.3e-5, 0.02) and p.battery == (0.2, 3.9) and p.terms_on == ("ground_effect", "battery", "gyroscopic")  # the body gyroscopic term acts without an entry
    again = parse_effects(yaml.safe_load(yaml.safe_dump(effects_document(vehicle.effects))), "again.yaml")
    assert yaml.safe_dump(effects_document(again)) == yaml.safe_dump(effects_document(vehicle.effects))  # sigma NaN != NaN
    assert again["ground_effect"].values() == (3.3e-5, 0.02) and again["ground_effect"].parameters["coefficient"].sigma == 4e-6
    assert PhysicsParameters.from_vehicle(_vehicle({"ground_effect": {**GROUND, "enabled": False}})).ground_effect is None


def test_a_gyroscopic_entry_switched_off_keeps_the_bodys_own_term_as_no_entry_does():
    """Off drops the rotors' part only: -ω × Iω is Euler's equations (the simulator keeps it too). At ω = (1, 2, 3)
    rad/s and no torque, dω/dt = -I⁻¹ (ω × Iω) for no entry, the entry off, and the entry on at (1, 0)."""
    rates = np.array([[1.0, 2.0, 3.0]])
    def scale(value: float) -> dict:
        return {"value": value, "unit": "1", "bounds": [0.0, 10.0], "source": "test", "status": "identified"}

    off = {"enabled": False, "body_scale": scale(1.0), "rotor_scale": scale(1.0)}
    for effects in ({}, {"gyroscopic": off}, {"gyroscopic": {**off, "enabled": True, "rotor_scale": scale(0.0)}}):
        p = PhysicsParameters.from_vehicle(_vehicle(effects))
        assert p.gyroscopic == (1.0, 0.0), effects
        inertia = np.asarray(p.inertia)
        torque = rigid_body.gyroscopic_torque(rates, inertia)
        _, angular = rigid_body.accelerations(p, np.zeros((1, 3)), np.eye(3)[None], rates, np.zeros((1, 4)), np.zeros((1, 4)))
        assert np.allclose(angular, torque / inertia, rtol=1e-12) and np.allclose(torque, -np.cross(rates, rates * inertia))
        assert np.abs(angular).max() > 0.1  # the Crazyflie's ixx != izz: a term the test can see


@pytest.mark.parametrize("change, message", [
    (lambda e: e.update(drag_wind=GROUND), "cf_terms.yaml: effects.drag_wind: unknown physics-model term; known: ground_effect"),
    (lambda e: e["ground_effect"]["coefficient"].pop("unit"), "cf_terms.yaml: effects.ground_effect.coefficient: missing unit"),
    (lambda e: e["ground_effect"]["coefficient"].update(unit="m"), "effects.ground_effect.coefficient.unit must be 'm2', got 'm'"),
    (lambda e: e["ground_effect"]["coefficient"].update(value=0.5), "effects.ground_effect.coefficient.value 0.5 m2 lies outside its bounds [0, 0.002]"),
    (lambda e: e["ground_effect"].pop("offset"), "effects.ground_effect.offset: ground_effect is switched on but its parameter offset was never identified"),
    (lambda e: e["ground_effect"]["offset"].update(status="not identified"), "effects.ground_effect.offset: ground_effect is switched on but this parameter was never identified"),
    (lambda e: e["ground_effect"].update(gain=1.0), "effects.ground_effect.gain: unknown parameter; ground_effect has coefficient, offset"),
    (lambda e: e["ground_effect"].update(enabled="yes"), "effects.ground_effect.enabled must be true or false"),
    (lambda e: e["ground_effect"]["coefficient"].update(bounds=[False, 0.002]),  # read as 0 before
     "effects.ground_effect.coefficient: value, bounds [low, high] and sigma must be numbers"),
    # values the file's own bounds allow but the physics does not (a -0.5 s observer history was a traceback)
    (lambda e: e["ground_effect"]["coefficient"].update(value=-1e-4, bounds=[-1.0, 1.0]),
     "effects.ground_effect.coefficient.value -0.0001 m2: must be in [0, inf], whatever the bounds"),
    (lambda e: e["ground_effect"]["coefficient"].update(sigma=-1e-5), "effects.ground_effect.coefficient.sigma -1e-05: must be a finite number >= 0"),
    (lambda e: e.update(disturbance_observer={"enabled": True, **{key: {"value": value, "unit": unit, "bounds": [-1.0, 1e9],
                                                                       "source": "test", "status": "identified"}
                                                                 for key, value, unit in (("linear_history", -0.5, "s"),
                                                                                          ("angular_history", 0.5, "s"),
                                                                                          ("angular_trim", 1.0, "1"))}}),
     "effects.disturbance_observer.linear_history.value -0.5 s: must be in [0, 999], whatever the bounds"),
    (lambda e: e.update(disturbance_observer={"enabled": True, **{key: {"value": value, "unit": unit, "bounds": [0.0, 10.0],
                                                                       "source": "test", "status": "identified"}
                                                                 for key, value, unit in (("linear_history", 0.5, "s"),
                                                                                          ("angular_history", 0.5, "s"),
                                                                                          ("angular_trim", 0.5, "1"))}}),
     "effects.disturbance_observer.angular_trim.value 0.5 1: must be 0 or 1"),
    (lambda e: e.update(motor_imbalance={"enabled": True, **{f"gain_{i}": {"value": 0.0 if i == 2 else 1.0, "unit": "1",
                                                                          "bounds": [-1.0, 2.0], "source": "test", "status": "identified"}
                                                            for i in range(1, 5)}}),
     "effects.motor_imbalance.gain_2.value 0 1: must be above 0"),
])
def test_each_fault_is_one_line_naming_the_file_the_term_and_the_key(change, message):
    effects = {"ground_effect": copy.deepcopy(GROUND)}
    change(effects)
    with pytest.raises(ConfigError) as err:
        _vehicle(effects)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_switched_off_drag_lag_and_delay_hold_their_constants_at_zero_and_need_none():
    """rotor_drag, motor_lag, input_delay switch base constants: off, the model has no drag, each rotor at its
    steady speed at once, no delay; no entry or ``enabled: true``, the file's constants; off, the file need not
    have the drag constants."""
    as_filed = PhysicsParameters.from_vehicle(_vehicle({}))
    assert as_filed.time_constant > 0 and as_filed.delay > 0 and as_filed.drag[0] > 0
    on = PhysicsParameters.from_vehicle(_vehicle({name: {"enabled": True} for name in BASE_SWITCHES}))
    assert (on.time_constant, on.delay, on.drag, on.drag_arm) == (as_filed.time_constant, as_filed.delay, as_filed.drag, as_filed.drag_arm)
    vehicle = _vehicle({name: {"enabled": False} for name in BASE_SWITCHES})
    off = PhysicsParameters.from_vehicle(vehicle)
    assert (off.time_constant, off.delay, off.drag, off.drag_arm) == (0.0, 0.0, (0.0, 0.0, 0.0), 0.0)
    assert off.thrust_constant == as_filed.thrust_constant and off.inertia == as_filed.inertia
    u = np.full(4, 0.6 * CF.input_max)
    start = np.zeros(4)
    assert np.allclose(rotors.interval_rotor_speed(off, start, u, 0.01), rotors.steady_rotor_speed(off, u))  # no lag
    assert not np.allclose(rotors.interval_rotor_speed(as_filed, start, u, 0.01), rotors.steady_rotor_speed(as_filed, u))
    again = parse_effects(yaml.safe_load(yaml.safe_dump(effects_document(vehicle.effects))), "again.yaml")
    assert {name: term.on for name, term in again.items()} == {name: False for name in BASE_SWITCHES}
    doc = yaml.safe_load(vehicle_file("crazyflie21").read_text())
    for key in BASE_SWITCHES["rotor_drag"]:
        doc["constants"].pop(key)
    with pytest.raises(ConfigError, match="needs the vehicle constants rotor_drag_xy, rotor_drag_z, rotor_drag_arm"):
        PhysicsParameters.from_vehicle(VehicleConfig.from_dict(doc, "no_drag.yaml"))
    doc["effects"] = {"rotor_drag": {"enabled": False}}
    assert PhysicsParameters.from_vehicle(VehicleConfig.from_dict(doc, "no_drag.yaml")).drag == (0.0, 0.0, 0.0)
    with pytest.raises(ConfigError, match="effects.motor_lag.value: unknown parameter; motor_lag is a switch: its values "
                                          "are the constants rotor_time_constant"):
        _vehicle({"motor_lag": {"enabled": True, "value": 0.03}})


def test_an_effects_list_names_known_terms_once():
    assert parse_term_names(["battery", "ground_effect"]) == ("ground_effect", "battery")
    with pytest.raises(ConfigError, match="ground_effect named more than once"):
        parse_term_names(["ground_effect", "battery", "ground_effect"])
    with pytest.raises(ConfigError, match="unknown physics-model term 'wind'"):
        parse_term_names(["wind"])
    with pytest.raises(ConfigError, match="an empty name in the list"):
        parse_term_names(["battery", ""])
    assert parse_term_names([""]) == ()  # identify's default: no term


def test_identifys_unknown_term_error_lists_only_what_identify_fits():
    from quad_modelling.core.identification.physics_terms import identify_term_names

    with pytest.raises(ConfigError) as err:
        identify_term_names(["wind"])
    assert "disturbance_observer" not in str(err.value) and "motor_imbalance" in str(err.value)


def test_ground_effect_lifts_near_the_ground_and_fades_with_height():
    p = PhysicsParameters.from_vehicle(_vehicle({"ground_effect": GROUND}))
    hover = p.hover_rotor_speed(GRAVITY)
    rotor = np.full((3, 4), hover)
    pos = np.array([[0.0, 0.0, -0.05], [0.0, 0.0, -0.3], [0.0, 0.0, -5.0]])
    acc, _ = rigid_body.accelerations(p, np.zeros((3, 3)), np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 3)), rotor, np.zeros((3, 4)), pos)
    expected = -GRAVITY * 3.3e-5 / (-pos[:, 2] + 0.02) ** 2  # up (NED -z): the weight times the extra thrust factor
    assert np.allclose(acc[:, 2], expected, rtol=1e-9) and acc[0, 2] < acc[1, 2] < acc[2, 2] < 0


def test_battery_scales_the_rotor_speed_by_the_voltage_and_motor_gains_scale_each_command():
    p = PhysicsParameters.from_vehicle(_vehicle({"battery": BATTERY}))
    u = np.full((2, 4), 30000.0)
    speeds = rotors.steady_rotor_speed(p, rotors.effective_commands(p, u, np.array([3.9, 4.1])))
    assert np.allclose(speeds[0], rotors.steady_rotor_speed(p, u[0]))
    assert np.allclose(speeds[1], 1.04 * rotors.steady_rotor_speed(p, u[1]))
    gains = p.with_values(battery=None, motor_gains=(1.25, 1.0, 1.0, 1.0))
    assert np.allclose(rotors.effective_commands(gains, u)[:, 0], 37500.0) and np.allclose(rotors.effective_commands(gains, u)[:, 1:], 30000.0)


def test_with_terms_on_live_equals_multistep_and_nothing_after_the_anchor_is_used():
    vehicle = _vehicle({"ground_effect": GROUND, "battery": BATTERY,
                        "motor_imbalance": {"enabled": True, **{f"gain_{i}": {"value": g, "unit": "1", "bounds": [0.5, 2.0], "source": "test",
                                                                          "status": "identified"} for i, g in enumerate((1.1, 0.95, 1.0, 0.95), 1)}},
                        "gyroscopic": {"enabled": True, **{key: {"value": 1.0, "unit": "1", "bounds": [0.0, 10.0], "source": "test", "status": "measured"}
                                                           for key in ("body_scale", "rotor_scale")}}})
    log = load_flight(FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", CF).slice(300, 420)
    model = PhysicsPredictor(vehicle)
    horizons = model.predict_horizons(log, np.array([40]), 60)[0]
    _, stream = model.start_window(log.slice(0, 41))
    live = np.array([stream.push_at(log.u[k], log.t[k]) for k in range(41, 101)])
    assert np.allclose(live, horizons[1:], rtol=1e-9, atol=1e-9)
    base = PhysicsPredictor(CF).predict_horizons(log, np.array([40]), 60)[0]
    assert np.max(np.abs(horizons[:, 15:18] - base[:, 15:18])) > 1.0  # the terms change the angular accelerations
    altered = FlightLog(**{**log.__dict__, "u": np.where(np.arange(len(log))[:, None] > 40, 1.3 * log.u, log.u),
                           "vbat": np.where(np.arange(len(log)) > 40, log.vbat - 0.3, log.vbat)})
    again = model.predict_horizons(altered, np.array([40]), 60)[0]
    assert np.array_equal(again[0], horizons[0])  # the anchor row: nothing after it moved it


def test_a_battery_term_on_a_flight_without_voltage_is_refused_in_one_line():
    from quad_modelling.errors import DataError

    log = load_flight(FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", CF).slice(300, 420)
    no_voltage = FlightLog(**{**log.__dict__, "vbat": None})
    with pytest.raises(DataError, match="battery term needs the battery voltage, and this flight has none"):
        PhysicsPredictor(_vehicle({"battery": BATTERY})).predict_horizons(no_voltage, np.array([40]), 10)


def _imbalance(gains, offset=None) -> dict:
    """A motor_imbalance entry with ``gains`` and, unless None, the CG offset (c_x, c_y) [m] (an older file has none)."""
    entry = {"enabled": True, **{f"gain_{i}": {"value": g, "unit": "1", "bounds": [0.5, 2.0], "source": "test", "status": "identified"}
                                 for i, g in enumerate(gains, 1)}}
    if offset is not None:
        entry.update({f"cg_offset_{axis}": {"value": c, "sigma": 1e-4, "unit": "m", "bounds": [-0.01, 0.01], "source": "test",
                                            "status": "identified"} for axis, c in zip("xy", offset)})
    return entry


def test_the_motor_imbalance_cg_offset_round_trips_and_an_older_entry_without_it_reads_zero():
    vehicle = _vehicle({"motor_imbalance": _imbalance((1.1, 0.95, 1.0, 0.95), (0.004, -0.003))})
    p = PhysicsParameters.from_vehicle(vehicle)
    assert p.motor_gains == (1.1, 0.95, 1.0, 0.95) and p.cg_offset == (0.004, -0.003) and "motor_imbalance" in p.terms_on
    again = parse_effects(yaml.safe_load(yaml.safe_dump(effects_document(vehicle.effects))), "again.yaml")
    assert again["motor_imbalance"].values() == (1.1, 0.95, 1.0, 0.95, 0.004, -0.003)
    assert again["motor_imbalance"].parameters["cg_offset_y"].sigma == 1e-4
    older = PhysicsParameters.from_vehicle(_vehicle({"motor_imbalance": _imbalance((1.1, 0.95, 1.0, 0.95))}))
    assert older.motor_gains == (1.1, 0.95, 1.0, 0.95) and older.cg_offset == (0.0, 0.0)
    off = PhysicsParameters.from_vehicle(_vehicle({"motor_imbalance": {**_imbalance((1.0,) * 4, (0.004, 0.0)), "enabled": False}}))
    assert off.motor_gains is None and off.cg_offset is None
    wrong = _imbalance((1.0,) * 4, (0.004, 0.0))
    wrong["cg_offset_x"]["unit"] = "mm"
    with pytest.raises(ConfigError, match="effects.motor_imbalance.cg_offset_x.unit must be 'm', got 'mm'"):
        _vehicle({"motor_imbalance": wrong})
