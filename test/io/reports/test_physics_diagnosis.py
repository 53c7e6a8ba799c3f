"""The physics diagnosis report's table cells: why a pair of candidates did not join, an injection's expected and
measured effects."""

from quad_modelling.io.reports.physics_diagnosis import _check_value, _why_not_joined, _why_pair_not_joined, delay_text


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


def test_a_candidate_that_qualified_but_did_not_join_says_which_did():
    """NanoBench: battery on the base +2.7 %, bound +2.1 %, resolved: its cell was empty beside rotor drag's 'joined'."""
    battery = {"shrink": 0.027, "shrink_5pct": 0.021, "main_resolved": True}
    assert _why_not_joined(battery, {"joined": True, "best": "rotor_drag"}) == "qualified; rotor_drag shrinks J more"
    assert _why_not_joined({**battery, "shrink_5pct": 0.004}, {"joined": True, "best": "rotor_drag"}) == "5 % bound < 1%"
    assert _why_not_joined({**battery, "main_resolved": False}, {"joined": False}) == "main component not resolved"


def test_the_newly_found_check_lists_effects_not_a_python_list():
    check = {"check": "nothing else newly found", "newly_found": ["motor_imbalance"], "expected_new": ["motor_imbalance"]}
    assert _check_value(check, "expected") == "nothing (motor_imbalance may: the injected change)"
    assert _check_value(check, "measured") == "motor_imbalance"
    assert _check_value({**check, "newly_found": [], "expected_new": []}, "measured") == "nothing"
    assert _check_value({**check, "expected_new": []}, "expected") == "nothing"


def test_a_delay_on_a_search_bound_says_so_without_a_sigma():
    """Simulated Crazyflie flights, 8 ms input delay (seeds 21-23): the delay fitted 0 on its bound [0, 0.15] read
    "command delay 0.0 +- 0.1 ms", a precise-looking value; on the upper bound the search's bound is said."""
    bounds = {"bounds": [0.0, 0.15], "held": None}
    lower = delay_text({"value": 0.0, "sigma": 1.4e-4, "at_bound": True}, {**bounds, "at_bound": True})
    assert lower == ("0.0 ms (AT BOUND: the search's lower bound 0: the commands act at or before their stamps, or a lag "
                     "of the command path took the delay)")
    assert delay_text({"value": 0.15, "sigma": 2.5e-3}, {**bounds, "at_bound": True}) == "150.0 ms (AT BOUND: the search's; not measured)"
    assert delay_text({"value": 0.0412, "sigma": 2.5e-3, "at_bound": False}, {**bounds, "at_bound": False}) == "41.2 +- 2.5 ms"
    assert delay_text({"value": 0.0, "sigma": float("nan")}, {"held": "held at 0 (switched off)"}) == "0.0 ms (held at 0 (switched off))"
