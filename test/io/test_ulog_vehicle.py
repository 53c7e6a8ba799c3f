"""A vehicle started from a PX4 log's parameters (io/ulog_vehicle.py vehicle_from_ulog): the two SITL samples,
logs rewritten with other CA_ROTORn parameters, and the refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from pyulog import ULog

from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import DataError
from quad_modelling.io.ulog_vehicle import (
    _inputs,
    rotor_frame,
    symmetric_frame,
    vehicle_document,
    vehicle_from_ulog,
    vehicle_yaml,
)

PX4 = Path(__file__).resolve().parents[1] / "data" / "px4"
EVENTS = PX4 / "sample_px4_events.ulg"
GROUND = PX4 / "sample_logging_tagged_and_default_params.ulg"


def rewritten(source: Path, target: Path, params: dict) -> Path:
    """``source`` with only its motor topics, and ``params`` set among its initial parameters."""
    ulog = ULog(str(source), message_name_filter_list=["actuator_motors", "actuator_outputs"])
    ulog.initial_parameters.update(params)
    ulog.write_ulog(str(target))
    return target


def test_events_sample_frame_spins_and_range_are_the_logs():
    params = ULog(str(EVENTS), message_name_filter_list=["actuator_motors"]).initial_parameters
    vehicle = vehicle_from_ulog(EVENTS, "iris_from_log")
    config = VehicleConfig.from_dict(vehicle.document, "iris_from_log.yaml")
    px = np.array([params[f"CA_ROTOR{n}_PX"] for n in range(4)])
    py = np.array([params[f"CA_ROTOR{n}_PY"] for n in range(4)])
    km = np.array([params[f"CA_ROTOR{n}_KM"] for n in range(4)])
    # Logged: front rotors at (0.1515, ±0.245), back at (-0.1515, ∓0.1875); KM +0.05, +0.05, -0.05, -0.05.
    np.testing.assert_allclose(px, [0.1515, -0.1515, 0.1515, -0.1515], atol=1e-7)
    np.testing.assert_allclose(py, [0.245, -0.1875, -0.245, 0.1875], atol=1e-7)
    # Symmetrised: (sign PX * mean |PX|, sign PY * mean |PY|) = (±0.1515, ±0.21625), radius 0.264038.
    np.testing.assert_allclose(config.motor_positions, np.column_stack([np.sign(px) * 0.1515, np.sign(py) * 0.21625]), atol=1e-6)
    assert config.value("arm_length") == pytest.approx(np.hypot(0.1515, 0.21625), abs=1e-6) == pytest.approx(0.264038, abs=1e-6)
    assert config.yaw_signs.tolist() == np.sign(km).tolist() == [1, 1, -1, -1]  # KM > 0: counter-clockwise
    assert [m.name for m in config.motors] == ["m1_front_right", "m2_back_left", "m3_front_left", "m4_back_right"]
    assert (config.geometry, config.input_min, config.input_max, config.input_unit) == ("x", 0.0, 1.0, "normalised")
    assert config.constants["arm_length"].source == (
        "log parameters CA_ROTOR0..3_PX/PY, x frame symmetrised (logged radii 0.2881, 0.2411, 0.2881, 0.2411 m, mean 0.2646 m)")
    mass = config.constants["mass"]
    assert (mass.value, mass.source, mass.status) == (1.5, "guess: px4_iris.yaml (not in the log)", "identified")
    assert config.value("rotor_speed_gain") == 1000.0 and vehicle.warnings == []
    assert config.greybox_value("motor_b_m") == 40000.0  # the greybox's B_m = k_u / tau_m


def test_pwm_sample_range_from_its_parameters_and_frame_guessed_with_a_warning():
    vehicle = vehicle_from_ulog(GROUND, "pwm_from_log")
    config = VehicleConfig.from_dict(vehicle.document, "pwm_from_log.yaml")
    # PWM_MAIN_MIN/MAX 1075/1950 are logged; the disarmed pulse (900, what the outputs hold) is PX4's default.
    assert (config.input_min, config.input_max, config.input_unit) == (900.0, 1950.0, "us")
    assert vehicle.comments[2] == ("inputs: PWM outputs [0, 1, 2, 3]: disarmed 900 us (PX4's default PWM_MAIN_DISARM 900 us, "
                                   "not in the log) .. max 1950 us; armed range 1075..1950 us (PWM_MAIN_MIN/MAX)")
    assert vehicle.warnings == [f"{GROUND}: no CA_ROTORn_PX/PY/KM parameters (PX4 before the control allocator): "
                                "motor positions and spins copied from px4_iris_pwm.yaml"]
    np.testing.assert_allclose(config.motor_positions, [[0.1515, 0.21625], [-0.1515, -0.21625], [0.1515, -0.21625], [-0.1515, 0.21625]])
    assert config.constants["arm_length"].source == "guess: px4_iris_pwm.yaml (no CA_ROTORn_PX/PY in the log)"
    assert config.constants["rotor_speed_gain"].unit == "rad/s per us"


def test_the_yaml_text_reads_back_to_the_same_document():
    vehicle = vehicle_from_ulog(EVENTS, "iris_from_log")
    text = vehicle_yaml(vehicle)
    assert text.startswith("# Vehicle started from sample_px4_events.ulg by quad-modelling convert --vehicle-from-log.\n")
    assert yaml.safe_load(text) == vehicle.document


def test_another_frame_in_the_parameters_is_read_as_logged(tmp_path):
    """A plus frame with uneven arms and the opposite spins: the vehicle follows the parameters, not px4_iris."""
    plus = {"CA_ROTOR0_PX": 0.2, "CA_ROTOR0_PY": 0.0, "CA_ROTOR0_KM": -0.05, "CA_ROTOR1_PX": -0.2, "CA_ROTOR1_PY": 0.0,
            "CA_ROTOR1_KM": -0.05, "CA_ROTOR2_PX": 0.0, "CA_ROTOR2_PY": 0.21, "CA_ROTOR2_KM": 0.05,
            "CA_ROTOR3_PX": 0.0, "CA_ROTOR3_PY": -0.19, "CA_ROTOR3_KM": 0.05}
    config = VehicleConfig.from_dict(vehicle_from_ulog(rewritten(EVENTS, tmp_path / "plus.ulg", plus), "plus").document, "plus")
    assert config.geometry == "plus" and config.value("arm_length") == pytest.approx(0.2)
    np.testing.assert_allclose(config.motor_positions, [[0.2, 0.0], [-0.2, 0.0], [0.0, 0.2], [0.0, -0.2]], atol=1e-7)
    assert config.yaw_signs.tolist() == [-1, -1, 1, 1]
    assert [m.name for m in config.motors] == ["m1_front", "m2_back", "m3_right", "m4_left"]


def test_a_hexacopter_log_is_refused_in_one_line(tmp_path):
    path = rewritten(EVENTS, tmp_path / "hexa.ulg", {"CA_ROTOR_COUNT": 6})
    with pytest.raises(DataError) as caught:
        vehicle_from_ulog(path, "hexa")
    assert str(caught.value) == f"{path}: 6 rotors (CA_ROTOR_COUNT); only 4-rotor vehicles are read"


def _params(**changes) -> dict:
    params = {}
    for n, (x, y, km) in enumerate([(0.15, 0.2, 0.05), (-0.15, -0.2, 0.05), (0.15, -0.2, -0.05), (-0.15, 0.2, -0.05)]):
        params.update({f"CA_ROTOR{n}_PX": x, f"CA_ROTOR{n}_PY": y, f"CA_ROTOR{n}_KM": km})
    return {**params, **changes}


def test_rotor_parameters_that_cannot_make_a_vehicle_are_refused():
    assert rotor_frame({"CA_ROTOR0_PX": 0.1}, "f.ulg") is None  # incomplete: the caller guesses and warns
    with pytest.raises(DataError) as caught:
        vehicle_document({}, _params(CA_ROTOR_COUNT=float("nan")), "f.ulg", "v")
    assert str(caught.value) == "f.ulg: parameter CA_ROTOR_COUNT is nan, not a rotor count"
    with pytest.raises(DataError) as caught:
        rotor_frame(_params(CA_ROTOR2_KM=0.0), "f.ulg")
    assert str(caught.value) == "f.ulg: parameter CA_ROTOR2_KM is 0: its sign gives the rotor's spin (positive = counter-clockwise seen from above)"
    with pytest.raises(DataError) as caught:
        rotor_frame(_params(CA_ROTOR1_AX=1.0, CA_ROTOR1_AZ=-1.0), "f.ulg")
    assert str(caught.value) == ("f.ulg: rotor CA_ROTOR1 thrust axis (AX, AY, AZ) = [1.0, 0.0, -1.0] is 45 deg from straight up "
                                 "(0, 0, -1); a vehicle config holds vertical rotors only")
    with pytest.raises(DataError) as caught:
        rotor_frame(_params(CA_ROTOR0_PY=float("nan")), "f.ulg")
    assert str(caught.value) == "f.ulg: parameters CA_ROTOR0_PX/PY/KM are not finite: 0.15, nan, 0.05"
    positions = np.array([[0.15, 0.2], [0.15, 0.1], [0.15, -0.2], [-0.15, 0.2]])  # two rotors in one quadrant
    with pytest.raises(DataError) as caught:
        symmetric_frame(positions, "f.ulg")
    assert str(caught.value) == ("f.ulg: rotors CA_ROTOR0..3 at (PX, PY) = [[0.15, 0.2], [0.15, 0.1], [0.15, -0.2], [-0.15, 0.2]] m "
                                 "form neither an x frame (one rotor per quadrant) nor a plus frame (two on each body axis)")


def test_pwm_range_and_disarmed_pulse_follow_the_motor_channels():
    params = {**{f"PWM_MAIN_FUNC{c}": 100 + m for c, m in zip((5, 6, 7, 8), (1, 2, 3, 4))},
              **{f"PWM_MAIN_MIN{c}": 1100 for c in range(5, 9)}, **{f"PWM_MAIN_MAX{c}": 1900 + c for c in range(5, 9)},
              **{f"PWM_MAIN_DIS{c}": 1000 for c in range(5, 9)}, "PWM_MAIN_MIN1": 1500}
    inputs, comment = _inputs("actuator_outputs", params, "f.ulg")
    assert inputs == {"min": 1000.0, "max": 1908.0, "unit": "us"}
    assert comment == "inputs: PWM outputs [4, 5, 6, 7]: disarmed 1000 us (PWM_MAIN_DISn) .. max 1908 us; armed range 1100..1908 us (PWM_MAIN_MINn/MAXn)"
    with pytest.raises(DataError) as caught:
        _inputs("actuator_outputs", {}, "f.ulg")
    assert str(caught.value) == ("f.ulg: motor commands are PWM (actuator_outputs) but the log has no PWM_MAIN_MIN/MAX or "
                                 "PWM_MAIN_MINn/MAXn parameters: the input range cannot be read; copy config/vehicles/px4_iris_pwm.yaml")
