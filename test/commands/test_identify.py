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
