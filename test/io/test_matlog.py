import numpy as np
import pytest
import scipy.io
import yaml

from quad_modelling.core import frames
from quad_modelling.errors import ConfigError, DataError, OutputExistsError
from quad_modelling.io.matlog import (
    THESIS_VARIABLES,
    load_mapping,
    read_matlog,
    write_matlog,
)
from test.conftest import REPO, synthetic_log


def test_round_trip_keeps_every_field_and_the_notes(tmp_path):
    log = synthetic_log(vehicle="linkquad")
    log.meta.notes["effects"] = ["battery", "rotor_drag"]
    path = write_matlog(log, tmp_path / "flight.mat")
    back = read_matlog(path)
    assert back.allclose(log, rtol=0, atol=0)
    assert back.meta.vehicle == "linkquad"
    assert back.meta.notes == {"seed": 0, "effects": ["battery", "rotor_drag"]}
    stored = scipy.io.loadmat(path)
    assert set(THESIS_VARIABLES["u"]) <= set(stored)  # default names are what docs/formats.md documents


def test_existing_output_needs_force(tmp_path):
    log = synthetic_log(vehicle="linkquad")
    write_matlog(log, tmp_path / "f.mat")
    with pytest.raises(OutputExistsError, match="exists; pass --force"):
        write_matlog(log, tmp_path / "f.mat")
    write_matlog(log, tmp_path / "f.mat", force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.mat"]  # no temporary left behind


def test_foreign_log_through_a_mapping_file(tmp_path):
    """A lab log in ENU/FLU, g, deg, deg/s, microseconds and one matrix for the motors,
    read with the shipped example mapping (config/mappings/example_lab.yaml)."""
    n = 50
    t = np.arange(n) * 0.004
    acc_flu_g = np.column_stack([np.full(n, 0.1), np.full(n, -0.2), np.full(n, 1.0)])
    gyro_flu_dps = np.column_stack([np.full(n, 10.0), np.full(n, 20.0), np.full(n, -30.0)])
    scipy.io.savemat(tmp_path / "lab.mat", {
        "T": t, "PWM": np.full((n, 6), 1500.0), "ax": acc_flu_g[:, 0], "ay": acc_flu_g[:, 1], "az": acc_flu_g[:, 2],
        "gyro": gyro_flu_dps, "pos": np.tile([1.0, 2.0, 3.0], (n, 1)), "vel": np.tile([0.5, 0.0, -0.1], (n, 1)),
        "att": np.tile([5.0, 10.0, 90.0], (n, 1)), "battery_voltage": np.full(n, 12.1),
    })
    log = read_matlog(tmp_path / "lab.mat", vehicle="linkquad", mapping=load_mapping(REPO / "config" / "mappings" / "example_lab.yaml"))
    np.testing.assert_allclose(log.u[0], [1.5e-3] * 4)
    np.testing.assert_allclose(log.acc_b[0], [0.1 * frames.STANDARD_GRAVITY, 0.2 * frames.STANDARD_GRAVITY, -frames.STANDARD_GRAVITY])
    np.testing.assert_allclose(log.gyro_b[0], np.deg2rad([10.0, -20.0, 30.0]))
    np.testing.assert_allclose(log.pos_n[0], [2.0, 1.0, -3.0])
    np.testing.assert_allclose(log.euler[0], np.deg2rad([5.0, 10.0, 90.0]))
    np.testing.assert_allclose(log.vbat, 12.1)


def test_file_without_the_mapped_variables_lists_what_it_found(tmp_path):
    scipy.io.savemat(tmp_path / "other.mat", {"time": np.arange(10.0), "motors": np.ones((10, 4))})
    with pytest.raises(DataError, match=r"other.mat: field u needs variable\(s\) \['u1', 'u2', 'u3', 'u4'\].*found: \['motors', 'time'\]"):
        read_matlog(tmp_path / "other.mat", vehicle="linkquad")


@pytest.mark.parametrize("dropped, field", [(("ddZB",), "acc_b"), (("dPsi",), "gyro_b"), (("Omega3", "Omega4"), "omega")])
def test_part_of_an_optional_sensor_is_refused_not_dropped(tmp_path, dropped, field):
    """A .mat without ddZB read as a flight with no accelerometer (ddXB and ddYB thrown away, no word): the sensor's
    variables come all or none."""
    contents = scipy.io.loadmat(write_matlog(synthetic_log(vehicle="linkquad", with_optional=True), tmp_path / "f.mat"))
    if field == "omega":
        contents.update({f"Omega{i}": np.full(len(contents["time"].ravel()), 500.0) for i in range(1, 5)})
    scipy.io.savemat(tmp_path / "part.mat", {k: v for k, v in contents.items() if not k.startswith("__") and k not in dropped})
    with pytest.raises(DataError) as err:
        read_matlog(tmp_path / "part.mat")
    assert f"part.mat: field {field} has variable(s)" in str(err.value) and f"but not {list(dropped)}: give all of" in str(err.value)


def test_an_empty_vehicle_variable_says_so(tmp_path):
    """vehicle = '' in a .mat read as "got a ndarray"."""
    contents = scipy.io.loadmat(write_matlog(synthetic_log(vehicle="linkquad"), tmp_path / "f.mat"))
    contents["vehicle"] = ""
    scipy.io.savemat(tmp_path / "empty.mat", {k: v for k, v in contents.items() if not k.startswith("__")})
    with pytest.raises(DataError, match="empty.mat: variable vehicle is empty; store the vehicle config name in it or pass --vehicle NAME"):
        read_matlog(tmp_path / "empty.mat")
    assert read_matlog(tmp_path / "empty.mat", vehicle="linkquad").meta.vehicle == "linkquad"


def test_mapping_without_a_unit_is_a_config_error(tmp_path):
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({"time": {"variable": "t"}}))
    with pytest.raises(ConfigError, match="field 'time' needs a 'unit'"):
        load_mapping(tmp_path / "m.yaml")


def test_corrupt_and_missing_files_are_data_errors(tmp_path):
    (tmp_path / "bad.mat").write_bytes(b"MATLAB 5.0 MAT-file garbage" + bytes(200))
    with pytest.raises(DataError, match="bad.mat: not a readable MATLAB file"):
        read_matlog(tmp_path / "bad.mat")
    with pytest.raises(DataError, match="no such file"):
        read_matlog(tmp_path / "absent.mat")


def test_nan_row_in_a_mat_log_is_named(tmp_path):
    log = synthetic_log(vehicle="linkquad")
    path = write_matlog(log, tmp_path / "f.mat")
    contents = scipy.io.loadmat(path)
    contents["dTheta"][42] = np.nan
    scipy.io.savemat(tmp_path / "nan.mat", {k: v for k, v in contents.items() if not k.startswith("__")})
    with pytest.raises(DataError, match=r"field gyro_b column 1 \(pitch rate\) is not finite at sample 43 of 400 \(t=0.420 s into the flight\)"):
        read_matlog(tmp_path / "nan.mat")


def test_a_pose_only_vicon_log_reads_through_a_mapping_without_imu(tmp_path):
    log = synthetic_log()
    scipy.io.savemat(tmp_path / "vicon.mat", {"T": log.t, "motors": log.u, "pos": frames.ned_to_enu(log.pos_n) * 1e3,
                                              "vel": frames.ned_to_enu(log.vel_n), "att": np.rad2deg(log.euler)})
    (tmp_path / "map.yaml").write_text(yaml.safe_dump({
        "time": {"variable": "T", "unit": "s"}, "u": {"variable": "motors", "unit": "PWM"},
        "pos_n": {"variable": "pos", "unit": "mm", "frame": "ENU"}, "vel_n": {"variable": "vel", "unit": "m/s", "frame": "ENU"},
        "euler": {"variable": "att", "unit": "deg", "frame": "NED"}}))
    back = read_matlog(tmp_path / "vicon.mat", vehicle="crazyflie21", mapping=load_mapping(tmp_path / "map.yaml"))
    assert back.acc_b is None and back.gyro_b is None and back.vbat is None
    np.testing.assert_allclose(back.pos_n, log.pos_n, atol=1e-12)
    np.testing.assert_allclose(back.euler[:, :2], log.euler[:, :2], atol=1e-12)


def test_mapped_command_unit_is_checked_against_the_vehicle_input_unit(tmp_path, capsys):
    from quad_modelling.cli import main
    from quad_modelling.io.loader import load_flight

    log = synthetic_log(vehicle="linkquad")
    pulse_us = np.full_like(log.u, 1500.0)
    scipy.io.savemat(tmp_path / "lab.mat", {"T": log.t, "pwm": pulse_us, "pos": log.pos_n, "vel": log.vel_n, "att": log.euler,
                                            "acc": log.acc_b, "gyro": log.gyro_b})
    (tmp_path / "map.yaml").write_text(yaml.safe_dump({
        "time": {"variable": "T", "unit": "s"}, "u": {"variable": "pwm", "unit": "us"},
        "acc_b": {"variable": "acc", "unit": "m/s2", "frame": "FRD"}, "gyro_b": {"variable": "gyro", "unit": "rad/s", "frame": "FRD"},
        "pos_n": {"variable": "pos", "unit": "m", "frame": "NED"}, "vel_n": {"variable": "vel", "unit": "m/s", "frame": "NED"},
        "euler": {"variable": "att", "unit": "rad", "frame": "NED"}}))
    mat, mapping = tmp_path / "lab.mat", tmp_path / "map.yaml"
    assert np.allclose(load_flight(mat, "linkquad", mapping_file=mapping).u, 1.5e-3)  # linkquad takes seconds: 1500 us = 1.5 ms
    assert np.allclose(load_flight(mat, "px4_iris_pwm", mapping_file=mapping).u, 1500.0)  # px4_iris_pwm takes us: as logged
    with pytest.raises(ConfigError) as err:
        load_flight(mat, "crazyflie21", mapping_file=mapping)  # PWM counts, not a pulse length
    assert "mapping field 'u' unit 'us' does not fit vehicle crazyflie21's input unit 'PWM'" in str(err.value)
    assert main(["convert", str(mat), "--mapping", str(mapping), "--vehicle", "px4_iris", "-o", str(tmp_path / "bag")]) == 2
    message = capsys.readouterr().err.strip()
    assert "\n" not in message and "input unit 'normalised'" in message and not (tmp_path / "bag").exists()
