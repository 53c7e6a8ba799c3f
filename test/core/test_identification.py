import numpy as np

from quad_modelling.core.evaluation import EvaluationConfig
from quad_modelling.core.identification import identified_vehicle_document, identify
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle

from .flightgen import linear_flight


def test_identification_recovers_motor_constants_used_to_simulate():
    truth = load_vehicle("crazyflie21").with_values({"motor_a_m": -25.0, "motor_b_m": 0.5}, "test truth")
    flights = [linear_flight(truth, duration=60.0, seed=s, source=f"f{s}.csv") for s in range(2)]
    start = load_vehicle("crazyflie21")  # A_m -20, B_m 0.76: 20 % and 50 % off
    config = EvaluationConfig(drop_start=5, drop_end=5, train="5:45", eval="45:55")
    result = identify(flights, start, config)
    assert abs(result.values["motor_a_m"] / -25.0 - 1) < 0.03
    assert abs(result.values["motor_b_m"] / 0.5 - 1) < 0.03
    # only training windows are used
    assert all(span["end_s"] <= 45.0 + 1e-6 for span in result.spans) and len(result.spans) == 8
    doc = identified_vehicle_document(start, result, config.train)
    loaded = VehicleConfig.from_dict(doc, "identified.yaml")
    assert np.isclose(loaded.value("motor_a_m"), result.values["motor_a_m"])
    assert "identified from f0.csv, f1.csv spans 5:45" in loaded.constants["motor_b_m"].source
    assert doc["constants"]["motor_b_m"]["sigma"] > 0
