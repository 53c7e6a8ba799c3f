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
    assert identified.value("motor_a_m") == pytest.approx(truth.value("motor_a_m"), rel=0.05)
    assert identified.value("motor_b_m") == pytest.approx(truth.value("motor_b_m"), rel=0.05)
    assert "identified on flight0.mat, flight1.mat spans 0%:60%" in identified.constants["motor_a_m"].source
    doc = yaml.safe_load(out.read_text())
    assert len(doc["identification"]["spans"]) == 2 and np.isfinite(doc["constants"]["motor_a_m"]["sigma"])
    assert "motor order/spin check" in capsys.readouterr().out


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
    assert "  motor_b_m " in printed and "rad/s2 per PWM count (sigma " in printed and "vehicle 0.76: " in printed
    doc = yaml.safe_load(out.read_text())
    b_m = doc["constants"]["motor_b_m"]
    assert b_m["vehicle_value"] == 0.76 and b_m["sigma"] > 0 and len(b_m["bounds"]) == 2
    assert b_m["change_percent"] == pytest.approx(100 * (b_m["value"] - 0.76) / 0.76, abs=0.05)
    assert b_m["source"].startswith("identified on nanobench_B7_oval_medium_rep2 spans 10:25") and "sigma" in b_m["source"]
    fitted = doc["identification"]["constants"]
    assert fitted["arm_scale"]["at_bound"] == (fitted["arm_scale"]["value"] <= 0.3 * 1.001)
    for name, entry in fitted.items():  # every poorly determined constant has its one line (a held one says so in its entry)
        flagged = f"poorly determined: {name}:" in printed or f"  {name} {entry['value']:.3g} 1 (held: " in printed
        assert flagged == (entry["poorly_determined"] is not None)
    assert fitted["rotor_reaction_scale"]["held"] and fitted["rotor_reaction_scale"]["value"] == 1.0
    assert doc["identification"]["motor_check"]["verdict"] == "consistent"
