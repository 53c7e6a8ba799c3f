"""Parameters and QoS as ROS users expect them, tested without spinning a node (nodes/common.py, nodes/domains.py)."""

import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

from quad_modelling.errors import ConfigError
from quad_modelling.nodes import domains
from quad_modelling.nodes.common import (
    BadParameter,
    Param,
    VehicleSource,
    integers_as_floats,
    history_qos,
    prediction_subscription_qos,
    subscription_qos,
    unknown_parameters,
)
from quad_modelling.nodes.evaluator_node import EVALUATOR_PARAMETERS
from quad_modelling.nodes.predictor_node import predictor_parameters
from quad_modelling.nodes.replay_node import REPLAY_PARAMETERS
from test.conftest import REPO


def test_a_misspelt_parameter_names_the_closest_declared_one():
    declared = [p.name for p in predictor_parameters("greybox")]
    warnings = unknown_parameters(["windw_s", "window_s", "use_sim_time", "qos_overrides./quad/imu.subscription.depth",
                                   "colour"], declared)
    assert warnings[0] == "unknown parameter 'colour' ignored; declared: " + ", ".join(sorted(declared))
    assert warnings[1] == "unknown parameter 'windw_s' ignored; did you mean 'window_s'?"
    assert len(warnings) == 2  # rclpy's own parameters and the declared one are not reported
    assert unknown_parameters(["modles"], [p.name for p in EVALUATOR_PARAMETERS]) == \
        ["unknown parameter 'modles' ignored; did you mean 'models'?"]


def test_an_integer_for_a_float_parameter_becomes_that_float_and_other_types_stay():
    params = [p for p in REPLAY_PARAMETERS if p.name in ("rate", "max_in_flight", "bag")]
    overrides = {"rate": Parameter("rate", value=2), "max_in_flight": Parameter("max_in_flight", value=7),
                 "bag": Parameter("bag", value="b")}
    assert integers_as_floats(overrides, params) == ["rate"]
    assert overrides["rate"].type_ == Parameter.Type.DOUBLE and overrides["rate"].value == 2.0
    assert overrides["max_in_flight"].type_ == Parameter.Type.INTEGER and overrides["max_in_flight"].value == 7
    assert overrides["bag"].value == "b"
    assert integers_as_floats({"x": Parameter("x", value=3)}, [Param("x", 1, "an integer parameter")]) == []


def test_subscription_qos_kinds():
    best = subscription_qos("best_effort", 1000)
    assert (best.reliability, best.durability, best.depth) == (ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE, 1000)
    reliable = subscription_qos("reliable", 50)
    assert (reliable.reliability, reliable.depth) == (ReliabilityPolicy.RELIABLE, 50)
    sensor = subscription_qos("sensor_data", 1000)
    assert (sensor.reliability, sensor.depth) == (ReliabilityPolicy.BEST_EFFORT, 5)  # rclpy's qos_profile_sensor_data
    with pytest.raises(BadParameter, match="qos='fast': must be one of best_effort, reliable, sensor_data, replay"):
        subscription_qos("fast")
    for params in (predictor_parameters("naive"), EVALUATOR_PARAMETERS):  # every subscribing node has the parameter
        qos = next(p for p in params if p.name == "qos")
        assert qos.default == "best_effort" and qos.check("sensor_data") is None and qos.check("x")


def test_vehicle_is_learned_from_the_replay_or_a_mismatch_refused_in_one_line():
    learner = VehicleSource("predictor", "")
    assert learner.vehicle is None
    assert learner.announce("linkquad").name == "linkquad"
    assert learner.announce("linkquad") is None  # the same announcement again (late joiner, repeat): nothing new
    assert learner.vehicle.mass == pytest.approx(1.2)  # the thesis's LinkQuad (Table 3-1)
    set_one = VehicleSource("evaluator", "crazyflie21")
    assert set_one.announce("crazyflie21") is None and set_one.vehicle.name == "crazyflie21"
    assert set_one.announce(str(REPO / "config" / "vehicles" / "crazyflie21.yaml")) is None  # the same vehicle by path
    with pytest.raises(BadParameter) as err:
        set_one.announce("linkquad")
    message = str(err.value)
    assert "\n" not in message and "vehicle='crazyflie21'" in message and "vehicle 'linkquad'" in message
    with pytest.raises(BadParameter, match="cannot load"):
        VehicleSource("predictor", "").announce("/nowhere/custom_quad.yaml")
    assert VehicleSource("p", "crazyflie21").announce("/elsewhere/crazyflie21.yaml") is None  # same name, file on another host
    with pytest.raises(BadParameter) as err:  # with the parameter set, it is the mismatch (it said "set parameter vehicle")
        VehicleSource("evaluator", "crazyflie21").announce("not_a_vehicle_xyz")
    assert "vehicle='crazyflie21'" in str(err.value) and "cannot load either" in str(err.value)
    assert "set parameter vehicle" not in str(err.value)
    with pytest.raises(BadParameter, match="parameter vehicle='warp': unknown vehicle"):
        VehicleSource("predictor", "warp")


def test_each_claim_gets_a_domain_no_other_holder_has(tmp_path, monkeypatch):
    monkeypatch.setattr(domains, "DOMAIN_IDS", range(40, 43))
    monkeypatch.setattr(domains, "_held", [])
    got = [domains.claim_domain(tmp_path) for _ in range(3)]
    assert sorted(got) == [40, 41, 42]  # flock is per open file: a second claim in one process gets another domain
    with pytest.raises(ConfigError, match="every ROS domain 40-42 is held"):
        domains.claim_domain(tmp_path)
    domains._held.pop(got.index(41)).close()  # a holder that ends releases its domain
    assert domains.claim_domain(tmp_path) == 41


def test_our_data_keeps_its_history_for_a_late_reader_that_asks():
    offered = history_qos(400)
    assert (offered.reliability, offered.durability, offered.depth) == (ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL, 400)
    assert prediction_subscription_qos("reliable", 400) == offered  # asks for the history the predictor offers
    assert prediction_subscription_qos("replay", 400) == offered
    for kind in ("best_effort", "sensor_data"):  # a best-effort reader stays volatile, as for measurements
        assert prediction_subscription_qos(kind) == subscription_qos(kind)
    # qos:=replay asks our replay's measurements for their history too; reliable stays volatile (matches any stack)
    assert subscription_qos("replay", 400) == offered
    assert subscription_qos("reliable", 400).durability == DurabilityPolicy.VOLATILE


def test_time_parameters_shorter_than_a_microsecond_are_refused_at_start():
    """``max_stamp_step_s:=1e-12`` passed ``> 0`` and rounded to 0 ns: a traceback at the predictor's start and an
    evaluator that dropped every message; ``window_s:=1e-12`` divided by zero at the first message (a review,
    session 44). Every node's window, warm start and stamp step is at least 1 us, said in its one line."""
    for params in (predictor_parameters("naive"), EVALUATOR_PARAMETERS):
        checks = {p.name: p.check for p in params}
        for name in ("window_s", "warm_s", "max_stamp_step_s"):
            assert checks[name](1e-12) == "must be at least 1e-06 s", name
            assert checks[name](1e-6) is None and checks[name](0.2) is None
            assert checks[name](float("inf")) == "must be finite and at most 1e+06"
