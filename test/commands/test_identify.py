import numpy as np
import pytest
import yaml

from quad_modelling.cli import main
from quad_modelling.core.vehicle import load_vehicle


def test_identify_writes_loadable_vehicle(flights, tmp_path, capsys):
    out = tmp_path / "lq.yaml"
    assert main(["identify", *flights, "--vehicle", "linkquad", "--preset", "short", "-o", str(out)]) == 0
    from quad_modelling.core.vehicle import load_vehicle as load

    identified = load(out)
    truth = load_vehicle("linkquad")
    assert identified.greybox_value("motor_a_m") == pytest.approx(truth.greybox_value("motor_a_m"), rel=0.05)
    assert identified.greybox_value("motor_b_m") == pytest.approx(truth.greybox_value("motor_b_m"), rel=0.05)
    assert "greybox fit identified on flight0.mat, flight1.mat spans 0%:60%" in identified.greybox["motor_a_m"].source
    doc = yaml.safe_load(out.read_text())
    assert len(doc["identification"]["spans"]) == 2 and np.isfinite(doc["greybox"]["motor_a_m"]["sigma"])
    assert "motor order/spin check" in capsys.readouterr().out


@pytest.mark.slow
def test_identify_on_the_bundled_bag_reports_constants_and_no_false_alarm(tmp_path, capsys):
    """What `make demo` runs: every constant with unit, sigma, bounds and change; the motor check consistent."""
    from pathlib import Path

    bag = Path(__file__).resolve().parents[2] / "bags" / "nanobench_B7_oval_medium_rep2"
    out = tmp_path / "cf.yaml"
    assert main(["identify", str(bag), "--vehicle", "crazyflie21", "--drop", "0:0", "--train", "10:25", "--window", "5",
                 "--eval", "25:35", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert all(len(line) <= 100 for line in printed.splitlines())
    assert "motor order/spin check: consistent with the config" in printed and "INCONSISTENT" not in printed
    derived = 0.04076521 / 0.05  # B_m = k_u / tau_m: the greybox's constant derived from the physical ones
    assert "  motor_b_m " in printed and "rad/s2 per PWM (sigma " in printed and f"vehicle {derived:.3g}: " in printed
    doc = yaml.safe_load(out.read_text())
    b_m = doc["greybox"]["motor_b_m"]
    assert b_m["vehicle_value"] == pytest.approx(derived, rel=1e-12) and b_m["sigma"] > 0 and len(b_m["bounds"]) == 2
    assert b_m["change_percent"] == pytest.approx(100 * (b_m["value"] - derived) / derived, abs=0.05)
    assert b_m["source"].startswith("greybox fit identified on nanobench_B7_oval_medium_rep2 spans 10:25") and "sigma" in b_m["source"]
    assert b_m["status"] == "effective" and "motor_b_m" not in doc["constants"]
    # the physics fit's roll/pitch inertias: effective values compared with the airframe's, which stay as they were
    assert doc["constants"]["ixx"]["value"] == 1.657171e-5 and doc["constants"]["effective_ixx"]["status"] == "effective"
    assert "effective_ixx " in printed and " x the airframe's ixx 1.66e-05 (effective value)" in printed
    fitted = doc["identification"]["constants"]
    assert fitted["arm_scale"]["at_bound"] == (fitted["arm_scale"]["value"] <= 0.3 * 1.001)
    for name, entry in fitted.items():  # every poorly determined constant has its one line (a held one says so in its entry)
        flagged = f"poorly determined: {name}:" in printed or f"  {name} {entry['value']:.3g} (held: " in printed  # a ratio: no unit 1
        assert flagged == (entry["poorly_determined"] is not None)
    assert fitted["rotor_reaction_scale"]["held"] and fitted["rotor_reaction_scale"]["value"] == 1.0
    # an identified physics constant's entry has the fields the greybox's have (formats.md), equal to identification's
    delay = doc["constants"]["rotor_delay"]
    assert {k: delay[k] for k in ("value", "sigma", "bounds", "at_bound", "vehicle_value", "change_percent")} == \
        {k: fitted["rotor_delay"][k] for k in ("value", "sigma", "bounds", "at_bound", "vehicle_value", "change_percent")}
    assert delay["vehicle_value"] == load_vehicle("crazyflie21").value("rotor_delay")
    held_a = doc["greybox"]["thrust_constant"]  # the greybox's a: the file's rotor constant before identification, said so
    assert held_a["value"] == load_vehicle("crazyflie21").value("rotor_thrust_constant") != doc["constants"]["rotor_thrust_constant"]["value"]
    assert held_a["source"].startswith("derived from the vehicle file's rotor_thrust_constant before identification (1.788e-08 N s2/rad2;")
    assert doc["identification"]["motor_check"]["verdict"] == "consistent"
    # what identify wrote is an identified vehicle: export takes it (the shipped file's starting values it refuses)
    assert main(["export", str(out), "--format", "casadi", "-o", str(tmp_path / "cf_model")]) == 0
    assert (tmp_path / "cf_model" / "F.casadi").is_file()


@pytest.mark.slow
def test_identify_effects_fits_ground_effect_on_a_simulated_flight_and_switches_it_on(tmp_path, capsys):
    """The simulator's ground effect is Cheeseman-Bennett's 1/(1 - (R/4h)²) at each hub (its own, richer form); the
    model's 1 + c/(h + h_off)² fitted on one 45 s flight must give a thrust gain near the truth's where the flight has
    data (take-off and landing, 0.1-0.3 m), fade with height, and be written switched on with its sigma and bounds."""
    from quad_modelling.core.physics.aero import ground_effect_factor
    from quad_modelling.core.physics.parameters import PhysicsParameters
    from quad_modelling.core.sim.params import sim_params_for
    from quad_modelling.core.sim.simulate import simulate
    from quad_modelling.io.matlog import write_matlog

    flight = tmp_path / "ground.mat"
    write_matlog(simulate("linkquad", ("ground_effect", "motor_lag"), seed=21, duration=45.0), flight)
    out = tmp_path / "lq_ground.yaml"
    assert main(["identify", str(flight), "--vehicle", "linkquad", "--drop", "3:2", "--train", "3:40", "--eval", "40:43",
                 "--effects", "ground_effect", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "  ground_effect.coefficient " in printed and max(len(line) for line in printed.splitlines() if not line.startswith("->")) <= 100
    # its offset is the best of a grid, not a fit: said so, not "poorly determined ... would help: more excitation"
    assert "  ground_effect.offset 0.0537 m (held: the best of a grid, not fitted)" in printed
    assert "poorly determined: ground_effect.offset" not in printed
    # no command delay in these flights: the delay ends on 0, and the advice is the switch, not more excitation
    assert "  poorly determined: rotor_delay: ended on its search bound [0, 0.15];\n    would help: none in the flights? switch " \
           "input_delay off in the vehicle file\n      (effects.input_delay: {enabled: false})" in printed
    term = load_vehicle(out).effects["ground_effect"]
    assert term.on and term.parameters["coefficient"].status == "identified" and term.parameters["coefficient"].sigma > 0
    params = sim_params_for("linkquad")
    radius, hub_above_cg = params.geometry.rotor_radius, -params.geometry.rotor_plane_z
    height = 0.15
    truth_gain = 1.0 / (1.0 - (radius / (4.0 * (height + hub_above_cg))) ** 2) - 1.0
    fitted_gain = float(ground_effect_factor(height, *term.values())) - 1.0
    assert 0.5 * truth_gain < fitted_gain < 2.0 * truth_gain, (fitted_gain, truth_gain)
    assert float(ground_effect_factor(2.0, *term.values())) - 1.0 < 0.3 * fitted_gain
    assert PhysicsParameters.from_vehicle(load_vehicle(out)).ground_effect == term.values()


@pytest.mark.slow
def test_a_rotor_drag_switched_off_in_the_vehicle_file_stays_off_until_effects_names_it(tmp_path):
    """The vehicle file switches rotor drag off: identify holds its constants at 0 and writes the switch off (the
    file's values kept); ``--effects rotor_drag`` fits them and switches it on. The bundled real flight has drag."""
    from pathlib import Path

    from quad_modelling.core.physics.parameters import PhysicsParameters
    from quad_modelling.core.vehicle import vehicle_file

    bag = Path(__file__).resolve().parents[2] / "bags" / "nanobench_B7_oval_medium_rep2"
    doc = yaml.safe_load(vehicle_file("crazyflie21").read_text())
    doc["effects"] = {"rotor_drag": {"enabled": False}}
    start = tmp_path / "cf_no_drag.yaml"
    start.write_text(yaml.safe_dump(doc))
    span = ["--drop", "0:0", "--train", "10:25", "--window", "5"]
    kept, fitted = tmp_path / "kept.yaml", tmp_path / "fitted.yaml"
    assert main(["identify", str(bag), "--vehicle", str(start), *span, "-o", str(kept)]) == 0
    assert main(["identify", str(bag), "--vehicle", str(start), *span, "--effects", "rotor_drag", "-o", str(fitted)]) == 0
    off, on = yaml.safe_load(kept.read_text()), yaml.safe_load(fitted.read_text())
    assert off["effects"]["rotor_drag"] == {"enabled": False} and on["effects"]["rotor_drag"] == {"enabled": True}
    assert off["constants"]["rotor_drag_xy"]["value"] == doc["constants"]["rotor_drag_xy"]["value"]  # the file's, kept
    assert "held at 0: effects.rotor_drag is switched off" in off["constants"]["rotor_drag_xy"]["source"]
    assert PhysicsParameters.from_vehicle(load_vehicle(kept)).drag == (0.0, 0.0, 0.0)
    assert on["constants"]["rotor_drag_xy"]["sigma"] > 0 and PhysicsParameters.from_vehicle(load_vehicle(fitted)).drag[0] > 0


def test_flights_of_two_vehicles_are_refused_naming_one_of_each(tmp_path, capsys):
    from quad_modelling.io.matlog import write_matlog
    from test.conftest import FIXTURES, synthetic_log

    linkquad = tmp_path / "lq.mat"
    write_matlog(synthetic_log(vehicle="linkquad"), linkquad)
    crazyflie = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"
    assert main(["identify", str(crazyflie), str(linkquad), "-o", str(tmp_path / "v.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "the flights are of different vehicles ['crazyflie21', 'linkquad']" in err and "identify one vehicle at a time" in err
    assert f"{crazyflie} of 'crazyflie21', {linkquad} of 'linkquad'" in err and len(err.splitlines()) == 1


@pytest.mark.slow
def test_skipped_input_and_overlapping_spans_are_said(flights, tmp_path, capsys):
    """--skip-bad: the vehicle is identified from the readable flights, and a line says how many were left out of
    identification.files; a training span that overlaps the evaluation span is one warning line."""
    bad = tmp_path / "broken.mat"
    bad.write_bytes(b"not a MAT file")
    out = tmp_path / "lq.yaml"
    assert main(["identify", *flights, str(bad), "--vehicle", "linkquad", "--preset", "short", "--train", "0%:70%",
                 "--skip-bad", "-o", str(out)]) == 1  # written, with an input left out: exit 1, as convert
    err = capsys.readouterr().err
    assert f"skipped: {bad}: " in err
    assert "identified from 2 of 3 inputs: 1 skipped (above), not in identification.files" in err
    assert ("warning: the training span 0%:70% and the evaluation span 60%:100% share 60%:70%: "
            "what is fitted there is scored partly in-sample") in err
    assert len(yaml.safe_load(out.read_text())["identification"]["files"]) == 2
    assert main(["identify", *flights, "--vehicle", "linkquad", "--preset", "short", "-o", str(tmp_path / "b.yaml")]) == 0
    assert "warning" not in capsys.readouterr().err  # the preset's spans meet at 60 % and do not overlap


def test_a_flight_without_a_training_window_is_said(flights, tmp_path, capsys):
    """A flight too short for one training window adds nothing to the greybox fit: one warning line names it."""
    from quad_modelling.io.matlog import read_matlog, write_matlog

    short = read_matlog(flights[1], vehicle="linkquad")
    short = short.slice(0, int(8 * short.sample_rate))  # 8 s: no 10 s window
    write_matlog(short, tmp_path / "short.mat")
    assert main(["identify", flights[0], str(tmp_path / "short.mat"), "--vehicle", "linkquad", "--preset", "short",
                 "--drop", "0:0", "-o", str(tmp_path / "v.yaml")]) == 0
    err = capsys.readouterr().err
    assert (f"warning: {tmp_path / 'short.mat'}: no 10 s training window in span 0%:60% (too short, or every window "
            "touches the ground or a gap): the greybox fit did not use it") in err
    assert f"warning: {flights[0]}" not in err


def test_a_flight_simulated_with_another_speed_map_than_the_vehicle_file_is_said(capsys):
    """identify holds the speed map; a Crazyflie simulated with another one (offset 0 against crazyflie21.yaml's
    381 rad/s, as the simulator flew until session 34) biased every constant with sigmas far below the error: one
    warning names both maps. The shipped vehicles' simulators answer their files' maps: no warning."""
    from quad_modelling.commands.identify import warn_held_speed_map
    from quad_modelling.core.sim.params import EscParams, sim_params_for
    from quad_modelling.core.sim.simulate import simulate

    params = sim_params_for("crazyflie21")
    params = params.replace(esc=EscParams(zero_speed_input=0.0, speed_gain=0.038, idle_speed_fraction=0.3))
    warn_held_speed_map([simulate("crazyflie21", (), seed=3, duration=6.0, params=params)], load_vehicle("crazyflie21"))
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "was simulated with the speed map rotor_speed_gain 0.038, rotor_speed_offset 0;" in err
    assert "holds rotor_speed_gain 0.0407652, rotor_speed_offset 380.836, which identify keeps" in err
    for name in ("crazyflie21", "linkquad"):
        warn_held_speed_map([simulate(name, (), seed=3, duration=6.0)], load_vehicle(name))
        assert capsys.readouterr().err == ""  # the simulator answers its file's map
