from pathlib import Path

import numpy as np
import pytest
import yaml

from quad_modelling.cli import main
from quad_modelling.core.models.greybox import GreyboxParameters
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.vehicle import (
    CONSTANT_KEYS,
    GRAVITY,
    GREYBOX_KEYS,
    MOVED_TO_GREYBOX,
    RENAMED_KEYS,
    VehicleConfig,
    check_unit,
    load_vehicle,
    vehicle_dir,
)
from quad_modelling.errors import ConfigError, VehicleKeyWarning

REPO_VEHICLES = vehicle_dir()


def test_linkquad_matches_thesis_table_3_1():
    cfg = load_vehicle("linkquad")
    assert cfg.geometry == "plus"
    assert cfg.mass == 1.2 and cfg.value("arm_length") == 0.215
    np.testing.assert_allclose(cfg.inertia, [9.56e-3, 9.85e-3, 15.2e-3])
    # the physical hover speed Omega_0 = sqrt(m g / 4 k_f), k_f = 1.0e-5: 542 rad/s
    assert cfg.hover_rotor_speed == pytest.approx(np.sqrt(1.2 * GRAVITY / (4 * 1.0e-5)))
    # the thesis greybox keeps Table 3-1's a = 1.59e-7 (its greybox section): Omega_0 = 4302 rad/s
    assert GreyboxParameters.from_vehicle(cfg).hover_rotor_speed == pytest.approx(np.sqrt(1.2 * GRAVITY / (4 * 1.59e-7)))
    # thesis yaw sum (-1)^i T_i: rotors 1 and 3 negative, 2 and 4 positive
    np.testing.assert_array_equal(cfg.yaw_signs, [-1, 1, -1, 1])
    np.testing.assert_allclose(cfg.motor_positions, [[0.215, 0], [0, 0.215], [-0.215, 0], [0, -0.215]])


def test_crazyflie_is_an_x_frame_with_every_constant_sourced():
    cfg = load_vehicle("crazyflie21")
    assert cfg.geometry == "x" and cfg.input_max == 65535
    np.testing.assert_allclose(np.hypot(*cfg.motor_positions.T), 0.046, rtol=1e-3)
    assert all(c.source for c in cfg.constants.values())
    assert {"rotor_time_constant", "rotor_thrust_constant", "rotor_torque_constant"} <= set(cfg.identified())


@pytest.mark.parametrize("name", ["crazyflie21", "linkquad", "px4_iris", "px4_iris_pwm"])
def test_a_shipped_vehicle_gives_one_value_per_physical_constant(name, recwarn):
    cfg = load_vehicle(name)
    assert not [w for w in recwarn if issubclass(w.category, VehicleKeyWarning)]
    assert set(CONSTANT_KEYS) <= set(cfg.constants)
    assert not set(cfg.constants) & (set(GREYBOX_KEYS) | set(RENAMED_KEYS) | set(MOVED_TO_GREYBOX))
    assert all(c.unit and c.source and c.status in ("measured", "identified") for c in cfg.constants.values())
    # only the thesis reproduction carries the greybox's own identified values, named as such
    assert bool(cfg.greybox) == (name == "linkquad")


def _old_crazyflie(tmp_path, drop=()):
    """The Crazyflie file as it was before one value per constant: the greybox's A_m, B_m, a, d next to the
    physical rotor constants, and the physics fit's inertias as physics_ixx/iyy."""
    doc = yaml.safe_load((vehicle_dir() / "crazyflie21.yaml").read_text())
    old = {"motor_a_m": -20.0, "motor_b_m": 0.76, "thrust_constant": 2.88e-8, "drag_constant": 7.24e-10,
           "physics_ixx": 8.4e-5, "physics_iyy": 7.4e-5}
    units = {"motor_a_m": "1/s", "motor_b_m": "rad/s2 per PWM", "thrust_constant": "N s2/rad2", "drag_constant": "N m s2/rad2",
             "physics_ixx": "kg m2", "physics_iyy": "kg m2"}
    for key, value in old.items():
        doc["constants"][key] = {"value": value, "unit": units[key], "source": "old file", "status": "identified"}
    for key in drop:
        del doc["constants"][key]
    path = tmp_path / "old_crazyflie.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_an_old_vehicle_file_loads_with_one_warning_line_naming_each_old_and_new_key(tmp_path):
    path = _old_crazyflie(tmp_path)
    with pytest.warns(VehicleKeyWarning) as caught:
        cfg = load_vehicle(path)
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    assert str(caught[0].message) == (
        f"{path}: old vehicle keys read as the new ones (rename them, docs/formats.md): constants.motor_a_m -> greybox.motor_a_m, "
        "constants.motor_b_m -> greybox.motor_b_m, constants.thrust_constant -> greybox.thrust_constant, "
        "constants.drag_constant -> greybox.torque_constant, constants.physics_ixx -> constants.effective_ixx, "
        "constants.physics_iyy -> constants.effective_iyy")
    # the greybox keeps the old file's values exactly; the physical constants are the file's rotor_* ones
    g = GreyboxParameters.from_vehicle(cfg)
    assert (g.motor_a_m, g.motor_b_m, g.thrust_constant, g.torque_constant) == (-20.0, 0.76, 2.88e-8, 7.24e-10)
    assert cfg.value("rotor_thrust_constant") == 1.788e-8
    assert PhysicsParameters.from_vehicle(cfg).inertia[:2] == (8.4e-5, 7.4e-5)
    assert cfg.value("ixx") == 1.657171e-5  # the airframe's


def test_an_old_vehicle_file_without_the_physical_rotor_constants_is_one_error_naming_the_key(tmp_path):
    path = _old_crazyflie(tmp_path, drop=("rotor_speed_gain",))
    with pytest.warns(VehicleKeyWarning), pytest.raises(ConfigError) as err:
        load_vehicle(path)
    assert str(err.value).startswith(f"{path}: missing required key constants.rotor_speed_gain (an old vehicle file: its "
                                     "motor_a_m, motor_b_m, thrust_constant, drag_constant, physics_ixx, physics_iyy are")


def test_an_old_key_next_to_its_replacement_is_an_error():
    doc = _doc()
    doc["constants"]["thrust_constant"] = doc["greybox"]["thrust_constant"]
    with pytest.raises(ConfigError, match=r"doc: constants.thrust_constant is the old name of greybox.thrust_constant, and the file gives both"):
        VehicleConfig.from_dict(doc, "doc")


def test_the_cli_prints_an_old_vehicle_files_warning_as_one_line(tmp_path, capsys):
    path = _old_crazyflie(tmp_path)
    # the vehicle is read before the flights: one warning line, then the missing flight's one error line (exit 2)
    assert main(["evaluate", str(tmp_path / "missing.csv"), "--vehicle", str(path), "--model", "greybox",
                 "-o", str(tmp_path / "out")]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2 and lines[1].startswith("quad-modelling evaluate: error: ") and "missing.csv" in lines[1]
    assert lines[0].startswith(f"quad-modelling evaluate: warning: {path}: old vehicle keys read as the new ones (rename "
                               "them, docs/formats.md): constants.motor_a_m -> greybox.motor_a_m, ")


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
    doc["greybox"]["motor_a_m"]["value"] = 9.56
    with pytest.raises(ConfigError, match="greybox.motor_a_m.value must be negative"):
        VehicleConfig.from_dict(doc, "doc")


def test_names_yaml_reads_as_numbers_are_text_and_any_off_axis_frame_is_an_x():
    """``name: 2021`` and motors named 1..4 are what the user wrote (YAML reads them as numbers); a stretched x frame
    (rotors 17 deg off the axes, as convert --vehicle-from-log labels it) is an x frame."""
    document = yaml.safe_load((REPO_VEHICLES / "crazyflie21.yaml").read_text())
    document["name"] = 2021
    for i, motor in enumerate(document["motors"]):
        motor["name"] = i + 1
    arm = document["constants"]["arm_length"]["value"]
    for motor, (x, y) in zip(document["motors"], ((1, 1), (-1, 1), (-1, -1), (1, -1))):  # 73 deg from x, 17 from y
        motor["position"] = [x * arm * np.sin(np.radians(17)), y * arm * np.cos(np.radians(17))]
    vehicle = VehicleConfig.from_dict(document, "doc")
    assert vehicle.name == "2021" and [m.name for m in vehicle.motors] == ["1", "2", "3", "4"] and vehicle.geometry == "x"


def test_a_path_without_yaml_is_not_read_as_the_shipped_vehicle():
    with pytest.raises(ConfigError, match=r"^vehicle './crazyflie21': a path to a vehicle file ends in .yaml"):
        load_vehicle("./crazyflie21")


def test_unknown_vehicle_lists_the_shipped_ones():
    with pytest.raises(ConfigError, match="crazyflie21, linkquad"):
        load_vehicle("hexacopter")


def test_with_values_replaces_and_records_source():
    cfg = load_vehicle("crazyflie21").with_values({"rotor_speed_gain": 0.05}, "identified from test")
    assert cfg.value("rotor_speed_gain") == 0.05
    assert cfg.constants["rotor_speed_gain"].source == "identified from test"
    with pytest.raises(ConfigError):
        cfg.with_values({"nope": 1.0}, "x")
    with pytest.raises(ConfigError, match="unknown constant 'motor_b_m'"):
        cfg.with_values({"motor_b_m": 1.0}, "x")  # a greybox constant: with_greybox
    greybox = cfg.with_greybox({"motor_b_m": 1.5}, "identified from test")
    assert greybox.greybox_value("motor_b_m") == 1.5 and greybox.greybox["motor_b_m"].status == "effective"
    assert greybox.greybox_value("motor_a_m") == -1.0 / 0.05  # the others as derived


def test_load_by_path(tmp_path):
    path = Path(tmp_path / "mine.yaml")
    path.write_text((vehicle_dir() / "crazyflie21.yaml").read_text())
    assert load_vehicle(path).name == "crazyflie21"


def test_a_constant_may_carry_its_sigma_and_a_bad_one_is_named():
    doc = _doc()
    doc["constants"]["mass"]["sigma"] = 0.005
    doc["constants"]["izz"]["sigma"] = float("nan")  # not determined
    cfg = VehicleConfig.from_dict(doc, "doc")
    assert cfg.constants["mass"].sigma == 0.005 and np.isnan(cfg.constants["izz"].sigma)
    assert cfg.constants["ixx"].sigma is None
    doc["constants"]["mass"]["sigma"] = -1.0
    with pytest.raises(ConfigError, match=r"^doc: constants.mass.sigma must be a finite number >= 0 \(or .nan: not determined\), got -1$"):
        VehicleConfig.from_dict(doc, "doc")
    doc["constants"]["mass"]["sigma"] = "big"
    with pytest.raises(ConfigError, match=r"^doc: constants.mass.sigma is not a number: 'big'$"):
        VehicleConfig.from_dict(doc, "doc")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["constants"]["mass"].update(unit="g", value=27), "constants.mass.unit is 'g'; mass is read in kg"),
    (lambda d: d["constants"]["ixx"].update(unit="g cm2"), "constants.ixx.unit is 'g cm2'; ixx is read in kg m2"),
    (lambda d: d["constants"]["rotor_speed_gain"].update(unit="rad per PWM"), "rotor_speed_gain is read in rad/s per input unit"),
    (lambda d: d["constants"]["mass"].update(vlaue=1.0), "constants.mass.vlaue is not a field of a constant"),
    (lambda d: d.update(geomtery="x"), "geomtery is not a key of a vehicle file"),
    # an identified effective inertia under a typo flew on the airframe's (orientation SimErr ratio 0.94 -> 1.64)
    (lambda d: d["constants"].update(effective_ixx_=d["constants"]["ixx"]), "constants.effective_ixx_ is not a vehicle constant"),
    (lambda d: d["constants"].update(masss=d["constants"]["mass"]), "constants.masss is not a vehicle constant"),
    (lambda d: d["motors"][0].update(tilt_deg=3), "motors[0].tilt_deg is not a key of a motor (known: name, position, spin)"),
    (lambda d: d["inputs"].update(offset=100), "inputs.offset is not a key of inputs (known: min, max, unit)"),
    (lambda d: d["motors"][1].update(name=d["motors"][0]["name"]), "motors name 'm1_front_right' twice"),
    # four rotors at one point passed the radius check: a traceback in identify and diagnose, a singular export
    (lambda d: [m.update(position=d["motors"][0]["position"]) for m in d["motors"]],
     "with their spins cannot set thrust, roll, pitch and yaw apart (rotors coincide or pair up)"),
    (lambda d: d.update(geometry="plus"), "geometry plus but rotor(s) [1, 2, 3, 4] lie off a body axis ('plus': every rotor on one"),
    (lambda d: d["motors"][1].update(position=[0.0, 0.046]), "geometry x but rotor(s) [2] lie on a body axis"),
    (lambda d: d.update(effects={"disturbance_observer": {"enabled": False, 1: "x", "foo": "y"}}),  # a TypeError sorting them
     "effects.disturbance_observer.1: unknown parameter"),
    (lambda d: d.update(effects={"disturbance_observer": {"enabled": True, "linear_history": {
        "value": 0.5, "unit": "s", "bounds": [0.0, 10.0], "status": "identified", "source": "test", "sigma": float("inf")}}}),
     "effects.disturbance_observer.linear_history.sigma inf: must be a finite number >= 0"),
    # read as text or as absent before: a vehicle named "None", a section of 0
    (lambda d: d.update(name=None), "name must be text, got 'None'"),
    (lambda d: d["motors"][2].update(name={"a": 1}), "motors[2].name must be text, got \"{'a': 1}\""),
    (lambda d: d["inputs"].update(unit=None), "inputs.unit must be text, got 'None'"),
    (lambda d: d.update(greybox=0), "greybox must be a mapping of motor_a_m"),
    # a gain of 1e300 overflowed every prediction (18 warning lines), a denormal lag its inverse
    (lambda d: d["constants"]["rotor_speed_gain"].update(value=1e300), "constants.rotor_speed_gain.value 1e+300 turns the rotors at"),
    (lambda d: d["constants"]["rotor_time_constant"].update(value=5e-324),
     "constants.rotor_time_constant.value 4.94066e-324 s: 0 (no motor lag) or at least 1e-06 s"),
    # a name without the fit's record made a starting value "identified": exported as one
    (lambda d: d.update(identification={"constants": {"rotor_time_constant": None}}),
     "identification.constants.rotor_time_constant must be the fit's record with a finite value (as identify writes it), got 'None'"),
])
def test_a_wrong_unit_or_a_mistyped_key_is_one_error_not_read_silently(edit, message, tmp_path):
    """A mass in g was read as 27 kg, and a typo'd key ignored: now one line naming the key."""
    document = yaml.safe_load((REPO_VEHICLES / "crazyflie21.yaml").read_text())
    edit(document)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    assert message in str(info.value) and str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_a_unit_per_command_accepts_the_vehicles_own_command_unit():
    check_unit("rotor_speed_gain", "rad/s per PWM", "x")
    check_unit("rotor_speed_gain", "rad/s per us", "x")
    check_unit("mass", "kg", "x")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["constants"]["mass"].update(value=True), r"constants.mass.value is not a number: 'True'"),
    (lambda d: d["constants"]["mass"].update(sigma=True), r"constants.mass.sigma is not a number: 'True'"),
    (lambda d: d["inputs"].update(min=False), r"inputs.min and inputs.max must be numbers"),
    (lambda d: d["motors"][0].update(position=[True, 0.03]), r"motors\[0\].position is not two numbers"),
])
def test_a_yaml_boolean_is_not_a_number(edit, message):
    """`mass: {value: true}` flew as 1.0 kg (float(True)); every number of a vehicle file refuses a boolean."""
    doc = _doc()
    edit(doc)
    with pytest.raises(ConfigError, match=message):
        VehicleConfig.from_dict(doc, "doc")


def test_the_speed_map_identify_holds_is_never_a_starting_value_left_behind():
    """identify never fits the speed map (its thrust constant absorbs the scale); a file marking it `identified` (both
    shipped PX4 vehicles) was refused by export after identify had run on it: "never identified: rotor_speed_gain"."""
    import yaml

    from quad_modelling.core.physics.parameters import PHYSICS_KEYS
    from quad_modelling.core.vehicle import HELD_BY_IDENTIFY, VehicleConfig, vehicle_dir

    doc = yaml.safe_load((vehicle_dir() / "crazyflie21.yaml").read_text())
    for key in HELD_BY_IDENTIFY:
        doc["constants"][key]["status"] = "identified"
    fitted = [k for k in PHYSICS_KEYS if k not in HELD_BY_IDENTIFY]
    doc["identification"] = {"files": ["test"], "constants": {key: {"value": doc["constants"][key]["value"]} for key in fitted}}
    assert VehicleConfig.from_dict(doc, "test").never_identified(PHYSICS_KEYS) == []
    doc["identification"]["constants"].pop("rotor_delay")
    assert VehicleConfig.from_dict(doc, "test").never_identified(PHYSICS_KEYS) == ["rotor_delay"]
