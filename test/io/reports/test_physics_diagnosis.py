"""The physics diagnosis report's table cells: why a pair of candidates did not join, an injection's expected and
measured effects."""

from quad_modelling.io.reports.physics_diagnosis import _check_value, _why_pair_not_joined


def _pair(low: float, resolved: bool = True) -> dict:
    return {"shrink": low + 0.01, "shrink_5pct": low, "J": 0.3, "main_resolved": resolved}


def test_a_pair_row_names_the_rule_it_missed():
    step = {"joined": False}
    assert _why_pair_not_joined(_pair(0.015), "battery + ground_effect", step) == "5 % bound < 2% (a pair's)"
    assert _why_pair_not_joined(_pair(0.03, resolved=False), "battery + ground_effect", step) == "a main component not resolved"
    refused = {"joined": False, "imbalance_roll_pitch": {"supported": False}}
    assert _why_pair_not_joined(_pair(0.03), "battery + motor_imbalance", refused).startswith("a yaw pattern only")
    assert _why_pair_not_joined(_pair(0.03), "battery + ground_effect", refused) == ""  # passed every rule, none joined
    assert _why_pair_not_joined(_pair(0.03), "battery + ground_effect", {"joined": True}) == "another pair shrinks J more"


def test_the_newly_found_check_lists_effects_not_a_python_list():
    check = {"check": "nothing else newly found", "newly_found": ["motor_imbalance"], "expected_new": ["motor_imbalance"]}
    assert _check_value(check, "expected") == "nothing (motor_imbalance may: the injected change)"
    assert _check_value(check, "measured") == "motor_imbalance"
    assert _check_value({**check, "newly_found": [], "expected_new": []}, "measured") == "nothing"
    assert _check_value({**check, "expected_new": []}, "expected") == "nothing"
