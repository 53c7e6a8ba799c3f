"""Model specs -> streaming predictors for the predictor node and run-bag; the predictor node's parameters.

Every spec (``naive``, ``greybox``, ``greybox:euler``, ``narx:PATH``, ...) is built
by the core registry through :func:`quad_modelling.core.models.streaming.streaming_predictor`,
the same objects ``quad-modelling evaluate`` uses.
"""

from __future__ import annotations

from quad_modelling.core.models.registry import streaming_predictor
from quad_modelling.core.models.streaming import HORIZON_INPUTS, StreamingPredictor
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.io import topics
from quad_modelling.nodes.common import (
    model_name_check,
    sample_period,
    topic_name,
    Param,
    executor_param,
    math_threads_param,
    non_empty,
    non_negative,
    positive,
    time_span,
    qos_param,
    realtime_param,
    stamp_step_param,
    vehicle_param,
)
from quad_modelling.nodes.mapping.streams import topic_map_param


def model_name(spec: str) -> str:
    """Default topic prefix of a spec: its kind (``narx:model.npz`` -> ``narx``)."""
    return spec.partition(":")[0].strip()


def make_streaming_predictor(spec: str, vehicle: VehicleConfig) -> StreamingPredictor:
    """Build the live form of ``spec``; ConfigError naming the spec when unknown or not streamable."""
    return streaming_predictor(spec, vehicle)


def check_spec_without_vehicle(spec: str) -> None:
    """Refuse, before the vehicle is known, a spec that is wrong whatever the vehicle: an unknown kind, a
    bad argument, a missing or unreadable model file (ConfigError/DataError from the registry).

    The registry is asked with no vehicle: what it checks before using the vehicle is reported; a
    factory that needs the vehicle to go further fails with AttributeError/TypeError, which only says
    the rest is checked once the vehicle is known (:func:`make_streaming_predictor`).
    """
    try:
        streaming_predictor(spec, None)
    except (AttributeError, TypeError):
        pass


def horizon_inputs_kind(value) -> str | None:
    return None if value in HORIZON_INPUTS else f"must be one of {', '.join(HORIZON_INPUTS)}"


def predictor_parameters(default_model: str) -> list[Param]:
    return [
        Param("model", default_model, "model spec: naive, greybox, greybox:euler, narx:PATH, hybrid:PATH", non_empty),
        Param("model_file", "", "model file appended to the spec as MODEL:FILE (e.g. the NARX .npz); empty = none"),
        Param("model_name", "", "topic prefix and name of the predictions (<model_name>/odom); empty = the spec's kind",
              model_name_check),
        vehicle_param(),
        Param("window_s", EvaluationConfig.window_s, "window length W [s]; windows [t0 + kW, t0 + (k+1)W) from the first motor input",
              time_span),
        Param("warm_s", EvaluationConfig.warm_s, "warm start at each window start [s] (thesis 0.2 s)", time_span),
        Param("sample_period_s", 0.0, "nominal sample period [s]; 0 = median of the first motor-input steps", sample_period),
        Param("measurement_tolerance_s", 0.02, "a command stamp with no measurement sample on both sides uses the nearest "
                                              "one within this [s], else the row has no measurement", non_negative),
        Param("measurement_gap_s", 0.1, "longest gap between two samples of a measurement stream interpolated through [s]",
              positive),
        stamp_step_param(),
        Param("horizon_s", 0.0, "receding-horizon mode: publish <model>/horizon/odom, the state horizon_s [s] ahead of "
                                "each anchor; 0 = window mode (the thesis's)", non_negative),
        Param("horizon_inputs", "hold", "receding-horizon mode: commands after each anchor: hold (the last one held, "
                                        "published at once: the forecast) or flown (the recorded ones, published h "
                                        "commands later: equals the offline multi-step MAE@h)", horizon_inputs_kind),
        Param("horizon_history_s", 2.5, "receding-horizon mode, a model without a carried-state forecast (naive, truth) "
                                        "or a flight without a gyro: rows [s] up to each anchor its multi-step form is "
                                        "re-run over (trims and filters settle within 2 s)", positive),
        Param("motor_input_topic", "motor_input", "engine inputs (sensor_msgs/JointState)", topic_name),
        Param("odom_topic", "mocap/odom", "motion capture (nav_msgs/Odometry)", topic_name),
        Param("imu_topic", "imu", "IMU (sensor_msgs/Imu)", topic_name),
        Param("battery_topic", "", "battery voltage (sensor_msgs/BatteryState) for models that use it; empty = not subscribed"),
        Param("world_frame", topics.WORLD_FRAME, "frame_id of the predicted pose", non_empty),
        topic_map_param(),
        qos_param(),
        Param("qos_depth", 1000, "depth of the keep-last subscriptions and publishers", positive),
        executor_param(),
        realtime_param(),
        math_threads_param(),
    ]
