"""Identified constants as printed and written: unit, sigma, bounds, at-bound flag, change from the vehicle."""

import math

from quad_modelling.core.identification.constants_report import ConstantEstimate, constant_lines
from quad_modelling.core.identification.least_squares import bound_side


def test_entry_line_states_value_unit_sigma_and_change():
    e = ConstantEstimate("motor_b_m", 0.253, "1/s", 0.01, (0.001, 380.0), 0.76)
    assert e.change_percent == (0.253 - 0.76) / 0.76 * 100.0
    assert e.lines() == ["  motor_b_m 0.253 1/s (sigma 0.01), vehicle 0.76: -67 %, bounds [0.001, 380]"]
    assert not e.poorly_determined and e.reason() == ""
    assert e.as_dict()["change_percent"] == -66.7 and e.as_dict()["at_bound"] is False


def test_poorly_determined_when_sigma_above_half_the_value_or_at_a_bound():
    assert not ConstantEstimate("motor_a_m", -31.0, "1/s", 15.0, (-500.0, -0.5), -20.0).poorly_determined  # 48 %
    wide = ConstantEstimate("motor_a_m", -31.0, "1/s", 25.0, (-500.0, -0.5), -20.0)  # the demo's A_m
    assert wide.poorly_determined and wide.reason() == "sigma 81 % of the value"
    bound = ConstantEstimate("arm_scale", 0.3, "1", 0.01, (0.3, 3.0), 1.0, at_bound=bound_side(0.3, 0.3, 3.0) is not None)
    assert bound.poorly_determined and "search bound [0.3, 3]" in bound.reason()
    assert bound.lines()[0].endswith("AT BOUND")
    assert ConstantEstimate("x", 1.0, "1", math.nan).poorly_determined
    lines = constant_lines([bound, ConstantEstimate("k", 2.0, "N", 0.1, None, None)], "title")
    assert lines[0] == "title" and lines[2] == "  k 2 N (sigma 0.1)"
    assert lines[-2:] == ["  poorly determined: arm_scale: ended on its search bound [0.3, 3];",
                          "    would help: more excitation of the variables it drives"]  # wrapped: one entry each
    assert all(len(line) <= 100 for line in lines)


def test_long_entries_wrap_at_100_characters():
    e = ConstantEstimate("rotor_reaction_scale", 0.001, "rad/s2 per PWM count", 1700.0, (0.001, 1000.0), 1.0, at_bound=True)
    lines = e.lines()
    assert len(lines) == 2 and all(len(line) <= 100 for line in lines) and lines[1].strip() == "bounds [0.001, 1e+03] AT BOUND"


def test_a_zero_estimate_with_a_sigma_is_poorly_determined_without_dividing_by_zero():
    estimate = ConstantEstimate("rotor_drag_arm", 0.0, "m", 0.01, (-0.1, 0.1), 0.0)
    assert estimate.poorly_determined
    assert estimate.reason() == "sigma 0.01 m about a value of 0"
    assert estimate.change_percent is None


def test_a_term_the_vehicle_file_did_not_have_says_new_not_nan():
    line = ConstantEstimate("ground_effect.coefficient", 0.00118, "m2", 0.00011, vehicle=float("nan")).lines()[0]
    assert line == "  ground_effect.coefficient 0.00118 m2 (sigma 0.00011), new (not in the vehicle file)"
