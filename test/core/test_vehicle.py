from pathlib import Path

import numpy as np
import pytest
import yaml

from quad_modelling.core.vehicle import (
    GRAVITY,
    VehicleConfig,
    load_vehicle,
    vehicle_dir,
)
from quad_modelling.errors import ConfigError


def test_linkquad_matches_thesis_table_3_1():
    cfg = load_vehicle("linkquad")
    assert cfg.geometry == "plus"
    assert cfg.mass == 1.2 and cfg.value("arm_length") == 0.215
    np.testing.assert_allclose(cfg.inertia, [9.56e-3, 9.85e-3, 15.2e-3])
    # Omega_0 = sqrt(m g / 4a) with a = 1.59e-7
    assert cfg.hover_rotor_speed == pytest.approx(np.sqrt(1.2 * GRAVITY / (4 * 1.59e-7)))
    # thesis yaw sum (-1)^i T_i: rotors 1 and 3 negative, 2 and 4 positive
    np.testing.assert_array_equal(cfg.yaw_signs, [-1, 1, -1, 1])
    np.testing.assert_allclose(cfg.motor_positions, [[0.215, 0], [0, 0.215], [-0.215, 0], [0, -0.215]])


def test_crazyflie_is_an_x_frame_with_every_constant_sourced():
    cfg = load_vehicle("crazyflie21")
    assert cfg.geometry == "x" and cfg.input_max == 65535
    np.testing.assert_allclose(np.hypot(*cfg.motor_positions.T), 0.046, rtol=1e-3)
    assert all(c.source for c in cfg.constants.values())
    assert {"motor_a_m", "motor_b_m", "thrust_constant", "drag_constant"} <= set(cfg.identified())


def _doc():
    return yaml.safe_load((vehicle_dir() / "linkquad.yaml").read_text())


def test_missing_constant_is_named(tmp_path):
    doc = _doc()
    del doc["constants"]["izz"]
    path = tmp_path / "v.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=r"v.yaml: missing required key constants\.izz"):
        VehicleConfig.from_yaml(path)


def test_missing_source_is_an_error_not_a_default():
    doc = _doc()
    del doc["constants"]["mass"]["source"]
    with pytest.raises(ConfigError, match=r"constants\.mass\.source"):
        VehicleConfig.from_dict(doc, "doc")


def test_motor_positions_must_sit_on_the_arm():
    doc = _doc()
    doc["motors"][0]["position"] = [0.3, 0.0]
    with pytest.raises(ConfigError, match="not arm_length 0.215"):
        VehicleConfig.from_dict(doc, "doc")


def test_unstable_motor_pole_is_rejected():
    doc = _doc()
    doc["constants"]["motor_a_m"]["value"] = 9.56
    with pytest.raises(ConfigError, match="motor_a_m.value must be negative"):
        VehicleConfig.from_dict(doc, "doc")


def test_unknown_vehicle_lists_the_shipped_ones():
    with pytest.raises(ConfigError, match="crazyflie21, linkquad"):
        load_vehicle("hexacopter")


def test_with_values_replaces_and_records_source():
    cfg = load_vehicle("crazyflie21").with_values({"motor_b_m": 1.5}, "identified from test")
    assert cfg.value("motor_b_m") == 1.5
    assert cfg.constants["motor_b_m"].source == "identified from test"
    with pytest.raises(ConfigError):
        cfg.with_values({"nope": 1.0}, "x")


def test_load_by_path(tmp_path):
    path = Path(tmp_path / "mine.yaml")
    path.write_text((vehicle_dir() / "crazyflie21.yaml").read_text())
    assert load_vehicle(path).name == "crazyflie21"
