import numpy as np
import pytest

from quad_modelling.core.identification.identify import (
    identified_vehicle_document,
    identify,
    windows_text,
)
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from test.core.flightgen import linear_flight


def test_identification_recovers_motor_constants_used_to_simulate():
    truth = load_vehicle("crazyflie21").with_greybox({"motor_a_m": -25.0, "motor_b_m": 0.5}, "test truth")
    flights = [linear_flight(truth, duration=60.0, seed=s, source=f"f{s}.csv") for s in range(2)]
    start = load_vehicle("crazyflie21")  # A_m -20, B_m 0.815 (derived): 20 % and 60 % off
    config = EvaluationConfig(drop_start=5, drop_end=5, train="5:45", eval="45:55")
    result = identify(flights, start, config)
    assert abs(result.values["motor_a_m"] / -25.0 - 1) < 0.03
    assert abs(result.values["motor_b_m"] / 0.5 - 1) < 0.03
    # only training windows are used
    assert all(span["end_s"] <= 45.0 + 1e-6 for span in result.spans) and len(result.spans) == 8
    doc = identified_vehicle_document(start, result, config.train)
    loaded = VehicleConfig.from_dict(doc, "identified.yaml")
    assert np.isclose(loaded.greybox_value("motor_a_m"), result.values["motor_a_m"])
    assert "greybox fit identified on f0.csv, f1.csv spans 5:45 (8 training windows)" in loaded.greybox["motor_b_m"].source
    assert doc["greybox"]["motor_b_m"]["sigma"] > 0 and loaded.greybox["motor_b_m"].status == "effective"
    assert loaded.greybox["thrust_constant"].value == start.value("rotor_thrust_constant")  # a held at k_f
    airframe = ("mass", "arm_length", "ixx", "iyy", "izz", "prop_inertia")  # never written by identify
    assert [loaded.constants[k] for k in airframe] == [start.constants[k] for k in airframe]


def test_the_window_count_reads_as_english():
    assert [windows_text(n) for n in (1, 2, 8)] == ["1 training window", "2 training windows", "8 training windows"]


def _differential_flight(vehicle, seed, duration=40.0, rate=100.0):
    """The linear model's own flight with independent band-limited commands per motor (0.5-2 Hz, so
    rates and angles stay bounded): excites roll, pitch and yaw, unlike the collective-only flights."""
    from scipy import signal

    from quad_modelling.core import frames
    from quad_modelling.core.flight_log import FlightLog, FlightMeta
    from quad_modelling.core.models.greybox import GreyboxModel
    from quad_modelling.core.physics.rigid_body import GRAVITY

    rng = np.random.default_rng(seed)
    n, dt = int(duration * rate), 1.0 / rate
    b, a = signal.butter(2, [0.5 / (rate / 2), 2.0 / (rate / 2)], btype="band")
    du = signal.lfilter(b, a, rng.standard_normal((n, 4)), axis=0) * 150.0
    states, outputs = GreyboxModel(vehicle).discretise(dt).simulate(np.zeros(16), du)
    euler = states[:, 6:9]
    acc_b = frames.nav_to_body(outputs[:, 6:9] - np.array([0.0, 0.0, GRAVITY]), euler)
    return FlightLog(t=np.arange(n) * dt, u=40000.0 + du, acc_b=acc_b, gyro_b=states[:, 9:12],
                     pos_n=states[:, 0:3], vel_n=states[:, 3:6], euler=euler,
                     meta=FlightMeta(vehicle.name, f"diff{seed}"), vbat=np.full(n, 3.9))


@pytest.mark.slow
def test_identification_recovers_the_drag_constant_and_flags_reversed_spins():
    truth = load_vehicle("crazyflie21").with_greybox({"torque_constant": 7.45e-10}, "test truth")
    flights = [_differential_flight(truth, seed=s) for s in range(2)]
    config = EvaluationConfig(drop_start=5, drop_end=5, train="5:30", eval="30:35")
    result = identify(flights, load_vehicle("crazyflie21"), config)  # starts from the derived k_m 1.07e-10 (d/a 0.006)
    assert abs(result.values["torque_constant"] / 7.45e-10 - 1) < 0.05  # d/a 0.042
    assert result.motor_check["consistent"] and not result.motor_check["yaw_reversed"]

    # the same flights read with every spin direction reversed: the check must say so
    doc = identified_vehicle_document(load_vehicle("crazyflie21"), result, config.train)
    for motor in doc["motors"]:
        motor["spin"] = "cw" if motor["spin"] == "ccw" else "ccw"
    reversed_config = VehicleConfig.from_dict(doc, "reversed.yaml")
    check = identify(flights, reversed_config, config).motor_check
    assert check["yaw_reversed"] and not check["consistent"]


def test_identify_searches_the_motor_time_constants_of_the_diagnosis_base_fit():
    from quad_modelling.core.identification.greybox_fit import (
        MOTOR_POLE_RANGE,
        MOTOR_TIME_CONSTANT_RANGE,
    )

    assert MOTOR_TIME_CONSTANT_RANGE == (0.002, 2.0)
    assert MOTOR_POLE_RANGE == (0.5, 500.0)  # -A_m [1/s] = 1 / tau_m


@pytest.mark.slow
def test_identify_and_the_diagnosis_base_give_the_same_constants_on_the_same_windows():
    """One identification: ``identify`` on a training span and the diagnosis base on the same windows."""
    from quad_modelling.core.diagnosis.catalogue import CATALOGUE
    from quad_modelling.core.diagnosis.diagnose import diagnose

    truth = load_vehicle("crazyflie21").with_greybox({"torque_constant": 7.45e-10}, "test truth")
    flights = [_differential_flight(truth, seed=s, duration=25.0) for s in range(2)]
    config = EvaluationConfig(drop_start=5, drop_end=5, train="0%:100%", eval="0%:100%")
    start = load_vehicle("crazyflie21")
    identified = identify(flights, start, config)
    base = diagnose(flights, flights, start, [CATALOGUE["rotor_drag"]], config).base
    assert len(identified.spans) == 2
    for key in ("motor_a_m", "motor_b_m", "torque_constant"):
        assert identified.values[key] == base.values[key]
    assert identified.input_gain == base.values["thrust_gain_K"]
    assert identified.fit["arm_scale"] == base.values["arm_scale"]
    assert identified.fit["rotor_reaction_scale"] == base.values["rotor_reaction_scale"]


@pytest.mark.slow
def test_a_negligible_rotor_reaction_term_is_held_not_run_to_its_bound():
    """The Crazyflie's configured I_prop (3.4e-11 kg m²) moves yaw acceleration by far less than 1 %: k_R is held at 1
    and says so; with a 1e4 times heavier propeller the term matters and k_R is fitted (truth 1)."""
    from quad_modelling.core.identification.greybox_fit import ROTOR_REACTION_FLOOR

    config = EvaluationConfig(drop_start=5, drop_end=5, train="5:30", eval="30:35")
    light = load_vehicle("crazyflie21")
    result = identify([_differential_flight(light, seed=3)], light, config)
    assert "rotor_reaction_scale" in result.fit["held"] and result.fit["rotor_reaction_scale"] == 1.0
    k_r = next(e for e in result.constants if e.name == "rotor_reaction_scale")
    assert k_r.held == f"its term is below {ROTOR_REACTION_FLOOR:.0%} of the yaw acceleration" and k_r.poorly_determined

    heavy = light.with_values({"prop_inertia": 3.4e-7}, "test: heavy propellers")
    result = identify([_differential_flight(heavy, seed=3)], heavy, config)
    assert "rotor_reaction_scale" not in result.fit["held"]
    assert 0.5 < result.fit["rotor_reaction_scale"] < 2.0 and not result.fit["at_bound"]["rotor_reaction_scale"]


@pytest.mark.parametrize("name", ["linkquad", "crazyflie21", "px4_iris"])
def test_every_greybox_search_bound_is_a_value_the_vehicle_file_accepts(name):
    """identify searches d = a (d/a) within YAW_DRAG_RATIO_RANGE; a fit on its bound must still write a loadable file
    (a negative d was refused when the file was written: 5 of the 18 NanoBench flights alone)."""
    from quad_modelling.core.identification.greybox_fit import YAW_DRAG_RATIO_RANGE
    from quad_modelling.core.models.greybox import GreyboxParameters
    from quad_modelling.core.vehicle import CONSTANT_RANGES

    thrust_constant = GreyboxParameters.from_vehicle(load_vehicle(name)).thrust_constant
    low, high, _ = CONSTANT_RANGES["torque_constant"]
    assert all(low < ratio * thrust_constant < high for ratio in YAW_DRAG_RATIO_RANGE)
