"""Issue 18: a pose-only Vicon .mat (t, pos, euler, u; no accelerometer or gyro) converts, evaluates, and refuses identify."""

import json

import numpy as np
import pytest
import scipy.io

from quad_modelling.cli import main
from quad_modelling.core import frames
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.bag_io import read_bag
from test.core.flightgen import linear_flight

MAPPING = """\
time:  {variable: T, unit: s}
u:     {variable: motors, unit: us}
pos_n: {variable: pos, unit: mm, frame: ENU}
vel_n: {variable: vel, unit: m/s, frame: ENU}
euler: {variable: att, unit: deg, frame: NED}
"""


def _vicon_mat(directory):
    log = linear_flight(load_vehicle("linkquad"), duration=42.0, seed=0)
    scipy.io.savemat(directory / "vicon.mat", {"T": log.t, "motors": log.u * 1e6, "pos": frames.ned_to_enu(log.pos_n) * 1e3,
                                               "vel": frames.ned_to_enu(log.vel_n), "att": np.rad2deg(log.euler), "vehicle": "linkquad"})
    (directory / "vicon.yaml").write_text(MAPPING)
    return log


def test_pose_only_vicon_mat_converts_and_evaluates_pose_and_velocity(tmp_path, capsys):
    log = _vicon_mat(tmp_path)
    assert main(["convert", str(tmp_path / "vicon.mat"), "--mapping", str(tmp_path / "vicon.yaml"), "-o", str(tmp_path / "bag")]) == 0
    bag = read_bag(tmp_path / "bag")
    assert bag.acc_b is None and bag.gyro_b is None
    np.testing.assert_allclose(bag.pos_n, log.pos_n, atol=1e-9)
    assert main(["info", str(tmp_path / "bag")]) == 0
    assert "/quad/imu" not in capsys.readouterr().out

    out = tmp_path / "eval"
    assert main(["evaluate", str(tmp_path / "bag"), "--model", "naive", "--model", "greybox", "--preset", "short", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "greybox: TIC acc_z needs accelerometer, roll_rate needs gyro, vel_z 0.95" in printed
    results = json.loads((out / "results.json").read_text())
    greybox = results["models"]["greybox"]["eval"]
    assert greybox["vel_z"]["tic"] == pytest.approx(0.9503, abs=1e-4)  # as on the same flight with its IMU (test_fewer_sensors)
    assert greybox["acc_x"] == {"rms": None, "tic": None, "needs": "accelerometer"}
    assert greybox["roll_rate"] == {"rms": None, "tic": None, "needs": "gyro"}
    horizons = results["horizons"]["models"]["greybox"]
    # causal multi-step trim (the second before each start): 0.015 position, 0.70 velocity (test_evaluation says why)
    assert horizons["position"]["ratio_sim_err"] < 0.02 and horizons["velocity"]["ratio_sim_err"] < 0.75
    assert horizons["angular_velocity"] == {"needs": "gyro"}
    tables = (out / "tables.md").read_text()
    assert "| Z acceleration | - | needs accelerometer | needs accelerometer |" in tables
    assert "| greybox | angular_velocity | needs gyro |" in tables


def test_identify_on_a_pose_only_flight_names_the_missing_sensors(tmp_path, capsys):
    _vicon_mat(tmp_path)
    assert main(["convert", str(tmp_path / "vicon.mat"), "--mapping", str(tmp_path / "vicon.yaml"), "-o", str(tmp_path / "bag")]) == 0
    capsys.readouterr()
    assert main(["identify", str(tmp_path / "bag"), "--preset", "short", "-o", str(tmp_path / "id.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"quad-modelling identify: error: {tmp_path / 'bag'}: identify (it fits the measured Z and angular accelerations) "
                   "needs the accelerometer (acc_b) and the gyro (gyro_b), which this flight does not have"]
    assert not (tmp_path / "id.yaml").exists()
