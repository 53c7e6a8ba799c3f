"""``convert FLIGHT.ulg --vehicle-from-log VEHICLE.yaml -o BAG``: the vehicle file, the bag, the refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pyulog import ULog

from quad_modelling.cli import main
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.bag_io import read_bag
from quad_modelling.io.loader import load_flight

PX4 = Path(__file__).resolve().parents[1] / "data" / "px4"
EVENTS = PX4 / "sample_px4_events.ulg"
GROUND = PX4 / "sample_logging_tagged_and_default_params.ulg"


def test_events_log_writes_a_vehicle_that_loads_and_converts_the_log(tmp_path, capsys):
    vehicle, bag = tmp_path / "iris_log.yaml", tmp_path / "bag"
    assert main(["convert", str(EVENTS), "--vehicle-from-log", str(vehicle), "-o", str(bag)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == [f"{EVENTS} -> {vehicle} (vehicle iris_log: x frame, arm 0.264 m, inputs 0..1 normalised)",
                   f"{EVENTS} -> {bag} (152 samples, 15.1 s, vehicle iris_log)"]
    config = load_vehicle(vehicle)
    assert config.name == "iris_log" and config.yaw_signs.tolist() == [1, 1, -1, -1]
    np.testing.assert_allclose(config.motor_positions, [[0.1515, 0.21625], [-0.1515, -0.21625], [0.1515, -0.21625], [-0.1515, 0.21625]])
    written = read_bag(bag)
    assert written.meta.vehicle == "iris_log" and len(written) == 152
    # The same log converts with --vehicle VEHICLE.yaml, to the same rows.
    assert main(["convert", str(EVENTS), "--vehicle", str(vehicle), "-o", str(tmp_path / "again")]) == 0
    assert read_bag(tmp_path / "again").allclose(written, rtol=1e-9, atol=1e-9)
    assert load_flight(EVENTS, vehicle=str(vehicle)).meta.vehicle == "iris_log"


def test_a_second_run_without_force_is_refused_in_one_line_and_changes_nothing(tmp_path, capsys):
    vehicle = tmp_path / "v.yaml"
    assert main(["convert", str(EVENTS), "--vehicle-from-log", str(vehicle), "-o", str(tmp_path / "bag")]) == 0
    before = vehicle.read_bytes()
    capsys.readouterr()
    assert main(["convert", str(EVENTS), "--vehicle-from-log", str(vehicle), "-o", str(tmp_path / "other")]) == 2
    assert capsys.readouterr().err == f"quad-modelling convert: error: {vehicle}: exists; pass --force to overwrite\n"
    assert vehicle.read_bytes() == before and not (tmp_path / "other").exists()
    assert main(["convert", str(EVENTS), "--vehicle-from-log", str(vehicle), "-o", str(tmp_path / "other"), "--force"]) == 0


def test_pwm_log_gets_its_pwm_range_and_a_warning_for_the_guessed_frame(tmp_path, capsys):
    vehicle = tmp_path / "pwm.yaml"
    assert main(["convert", str(GROUND), "--vehicle-from-log", str(vehicle), "-o", str(tmp_path / "bag")]) == 0
    err = capsys.readouterr().err
    assert err == (f"warning: {GROUND}: no CA_ROTORn_PX/PY/KM parameters (PX4 before the control allocator): "
                   "motor positions and spins copied from px4_iris_pwm.yaml\n")
    config = load_vehicle(vehicle)
    assert (config.input_min, config.input_max, config.input_unit) == (900.0, 1950.0, "us")
    assert len(read_bag(tmp_path / "bag")) == 98  # the battery bounds nothing: the 0.1 s its stream lacked at the end kept


def test_refusals_leave_nothing_behind(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    hexa = tmp_path / "hexa.ulg"
    ulog = ULog(str(EVENTS), message_name_filter_list=["actuator_motors"])
    ulog.initial_parameters["CA_ROTOR_COUNT"] = 6
    ulog.write_ulog(str(hexa))
    cases = [
        ([str(hexa), "--vehicle-from-log", "v.yaml", "-o", "bag"], f"{hexa}: 6 rotors (CA_ROTOR_COUNT); only 4-rotor vehicles are read"),
        ([str(EVENTS), "--vehicle-from-log", "v.yaml", "--vehicle", "px4_iris", "-o", "bag"],
         "--vehicle-from-log takes one PX4 .ulg input and no --vehicle (got 1 input(s): sample_px4_events.ulg, --vehicle)"),
        ([str(EVENTS), str(GROUND), "--vehicle-from-log", "v.yaml", "-o", "bag"],
         "--vehicle-from-log takes one PX4 .ulg input and no --vehicle "
         "(got 2 input(s): sample_px4_events.ulg, sample_logging_tagged_and_default_params.ulg)"),
        ([str(EVENTS), "--vehicle-from-log", "v.txt", "-o", "bag"], "--vehicle-from-log 'v.txt': the vehicle file must end in .yaml or .yml"),
        ([str(EVENTS), "--vehicle-from-log", "bag/v.yaml", "-o", "bag"],
         "--vehicle-from-log bag/v.yaml and -o bag overlap; give the vehicle file and the output different places"),
        # the bag names its vehicle crazyflie21: a later read without --vehicle took the shipped Crazyflie's file
        ([str(EVENTS), "--vehicle-from-log", "crazyflie21.yaml", "-o", "bag"],
         "--vehicle-from-log crazyflie21.yaml: crazyflie21 is a shipped vehicle's name, which the bag would name (a later "
         "read without --vehicle takes the shipped crazyflie21); choose another file name"),
    ]
    for args, message in cases:
        capsys.readouterr()
        assert main(["convert", *args]) == 2, args
        assert capsys.readouterr().err == f"quad-modelling convert: error: {message}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hexa.ulg"]
