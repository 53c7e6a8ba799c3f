"""The motor order/spin check on the bundled real flight: signs judged by significance."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core.identification.greybox_fit import identify_base
from quad_modelling.core.identification.identify import modelled_thrusts, training_batch
from quad_modelling.core.identification.motor_check import (
    T_THRESHOLD,
    check_lines,
    check_motor_layout,
    likely_layout,
    valid_spins,
)
from quad_modelling.core.identification.uncertainty import hac_covariance
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.io.loader import load_flight

BAG = Path(__file__).resolve().parents[3] / "bags" / "nanobench_B7_oval_medium_rep2"
DEMO = EvaluationConfig(drop_start=0, drop_end=0, train="10:25", eval="25:35", window_s=5)  # what `make demo` runs


@pytest.fixture(scope="module")
def bag_flight():
    return load_flight(BAG, load_vehicle("crazyflie21"))


def _check(log, vehicle):
    batch = training_batch([log], vehicle, DEMO)
    return check_motor_layout(batch, modelled_thrusts(batch, identify_base(batch, vehicle)), vehicle)


def test_no_false_alarm_on_the_bundled_bag(bag_flight):
    check = _check(bag_flight, load_vehicle("crazyflie21"))
    assert check["verdict"] == "consistent" and not check["wrong"] and check["fix"] is None
    statuses = [m[axis]["status"] for m in check["motors"] for axis in ("roll", "pitch", "yaw")]
    assert "wrong" not in statuses and statuses.count("agrees") >= 10
    assert all(len(line) <= 100 for line in check_lines(check))


@pytest.mark.parametrize("columns, swapped", [((1, 0, 2, 3), "m1_front_right <-> m2_back_right"),
                                              ((2, 1, 0, 3), "m1_front_right <-> m3_back_left")])
def test_swapped_command_columns_are_caught_and_named(bag_flight, columns, swapped):
    """Neighbours (m1/m2: pitch and yaw flip) and a diagonal pair (m1/m3: roll and pitch flip, same spin)."""
    log = replace(bag_flight, u=bag_flight.u[:, list(columns)])
    check = _check(log, load_vehicle("crazyflie21"))
    assert check["verdict"] == "inconsistent" and not check["consistent"]
    assert check["fix"]["actions"] == [f"swapped order: {swapped}"] and check["fix"]["unexplained"] == 0
    assert check["data_spins"] is None  # a swap is named, not silently rewritten
    assert any("identify again" in line for line in check_lines(check))


def test_a_reversed_spin_in_the_vehicle_file_is_caught(bag_flight):
    vehicle = load_vehicle("crazyflie21")
    motors = list(vehicle.motors)
    motors[1] = replace(motors[1], yaw_sign=-motors[1].yaw_sign)  # m2 written ccw, it spins cw
    wrong = replace(vehicle, motors=tuple(motors))
    check = _check(bag_flight, wrong)
    assert check["verdict"] == "inconsistent" and check["wrong"] == ["m2_back_right yaw"]
    assert check["fix"]["actions"] == ["reversed spin: m2_back_right"]
    assert check["data_spins"] == [int(s) for s in vehicle.yaw_signs]


def test_insignificant_opposite_signs_are_undetermined_not_wrong():
    vehicle = load_vehicle("crazyflie21")
    from quad_modelling.core.identification.motor_check import sign_status

    assert sign_status(-2.9, +1.0) == "undetermined" and sign_status(-T_THRESHOLD - 0.1, +1.0) == "wrong"
    assert sign_status(3.5, +1.0) == "agrees" and sign_status(np.nan, -1.0) == "undetermined"
    # the layout search explains strong signs first: only m1/m2 yaw is strongly opposite, roll/pitch weak
    t = np.array([[-1.0, +1.0, -5.0], [-1.0, -1.0, +5.0], [+1.0, -1.0, +5.0], [+1.0, +1.0, -5.0]])
    layout = likely_layout(t, vehicle)
    assert layout["unexplained"] == 0 and layout["reversed_spins"] == [] and layout["moved"] == 2


def test_valid_spins_need_balanced_reaction_torques_and_full_rank():
    pos = load_vehicle("crazyflie21").motor_positions
    assert valid_spins(pos, np.array([1, -1, 1, -1]))
    assert not valid_spins(pos, np.array([-1, 1, 1, -1]))  # two neighbours reversed: yaw = -pitch row
    assert not valid_spins(pos, np.array([1, 1, 1, -1]))  # unbalanced at hover


def test_hac_standard_error_grows_with_autocorrelation():
    """AR(1) residuals with rho 0.9 and an AR(1) regressor: the HAC variance exceeds the textbook one by about
    (1 + rho^2)/(1 - rho^2) = 9.5 (both series persistent); with white residuals both agree."""
    rng = np.random.default_rng(7)
    w, n = 40, 500

    def ar1(rho):
        e = rng.standard_normal((w, n))
        out = np.zeros((w, n))
        for k in range(1, n):
            out[:, k] = rho * out[:, k - 1] + e[:, k]
        return out

    x = ar1(0.9)
    for rho, lo, hi in ((0.0, 0.8, 1.25), (0.9, 5.0, 12.0)):
        e = ar1(rho)
        textbook = np.sum(e**2) / (e.size - 1) / np.sum(x**2)
        hac = hac_covariance(x[:, :, None, None], e[:, :, None], lags=100)[0, 0]
        assert lo < hac / textbook < hi
