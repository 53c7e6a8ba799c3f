"""run-bag --record: one MCAP (zstd chunks) of measurements, predictions and evaluation, read by the mcap library
and by rosbags; the Foxglove layout plots topics and fields the recording has."""

import json
from collections import Counter

import numpy as np
import pytest
from mcap.reader import make_reader

from quad_modelling.cli import main
from quad_modelling.io.bag_io import TYPESTORE, read_bag, read_recorded
from test.conftest import REPO

BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
MEASURED = ("motor_input", "mocap/odom", "imu")


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "live"
    assert main(["run-bag", str(BAG), "--models", "naive", "--record", "--no-figures", "-o", str(out)]) == 0
    return out


@pytest.mark.slow
def test_recording_holds_every_measurement_prediction_and_evaluation(recorded_run):
    record = recorded_run / "record"
    with open(next(record.glob("*.mcap")), "rb") as handle:  # the mcap library, as Foxglove reads it
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
        counts = Counter(channel.topic for _, channel, _ in reader.iter_messages())
    in_bag = Counter(f"/quad/{m.topic}" for m in read_recorded(BAG) if m.topic in MEASURED)
    assert {t: counts[t] for t in in_bag} == dict(in_bag)  # every measurement the replay played
    assert counts["/quad/naive/odom"] == counts["/quad/naive/accel"] == in_bag["/quad/motor_input"]  # one answer per input
    results = json.loads((recorded_run / "results.json").read_text())
    windows = results["live"]["windows"]
    assert counts["/quad/evaluation"] == len({w["window"] for w in windows})  # one DiagnosticArray per closed window

    # rosbags: the measurements come back byte for byte as the bag holds them, and as the same FlightLog
    original = [m for m in read_recorded(BAG) if m.topic in MEASURED]
    assert read_recorded(record) == original
    flight, again = read_bag(BAG), read_bag(record)
    assert again.meta.vehicle == "crazyflie21"  # custom data, as converted bags
    for field in ("t", "u", "acc_b", "gyro_b", "pos_n", "vel_n", "euler"):
        assert np.array_equal(getattr(again, field), getattr(flight, field)), field

    # the evaluation messages carry the numbers of results.json
    with open(next(record.glob("*.mcap")), "rb") as handle:
        arrays = [TYPESTORE.deserialize_cdr(raw.data, "diagnostic_msgs/msg/DiagnosticArray")
                  for _, channel, raw in make_reader(handle).iter_messages(topics=["/quad/evaluation"])]
    statuses = {s.name: s for a in arrays for s in a.status}
    scored = [w for w in windows if w["scored"]]
    assert scored
    for w in scored:
        values = {kv.key: kv.value for kv in statuses[f"evaluation/{w['model']}/{w['span']}/window_{w['window']}"].values}
        for var, score in w["scores"].items():
            assert float(values[f"{var}.rms"]) == score["rms"] and float(values[f"{var}.tic"]) == score["tic"]
        assert int(values["time_base"]) == w["time_base"] == 0  # one replay, no clock jump


def _field_type(msgtype: str, path: str) -> str:
    """The ROS type at ``path`` (``pose.pose.position.x``, ``effort[2]``) inside ``msgtype``; KeyError if absent."""
    for part in path.split("."):
        name, _, index = part.partition("[")
        fields = dict(TYPESTORE.fielddefs[msgtype][1])
        kind, detail = fields[name]
        if index:
            kind, detail = detail[0]
        msgtype = detail if kind.name == "NAME" else detail[0]
    return msgtype


@pytest.mark.slow
def test_foxglove_layout_plots_recorded_topics_and_existing_fields(recorded_run):
    layout = json.loads((REPO / "config" / "foxglove_layout.json").read_text())
    types = {"/quad/motor_input": "sensor_msgs/msg/JointState", "/quad/mocap/odom": "nav_msgs/msg/Odometry",
             "/quad/imu": "sensor_msgs/msg/Imu", "/quad/evaluation": "diagnostic_msgs/msg/DiagnosticArray"}
    types.update({f"/quad/{m}/odom": "nav_msgs/msg/Odometry" for m in ("naive", "greybox", "narx")})
    types.update({f"/quad/{m}/accel": "geometry_msgs/msg/AccelStamped" for m in ("naive", "greybox", "narx")})

    def panels(node):
        return [node] if isinstance(node, str) else panels(node["first"]) + panels(node["second"])

    assert sorted(panels(layout["layout"])) == sorted(layout["configById"])  # every panel placed once
    plotted = set()
    for panel, config in layout["configById"].items():
        for path in config.get("paths", []):
            topic, _, field = path["value"].partition(".")
            assert _field_type(types[topic], field) == "float64", path["value"]
            assert path["timestampMethod"] == "headerStamp"  # measured and predicted of one instant line up
            plotted.add(topic)
    assert layout["configById"]["DiagnosticSummary!evaluation"]["topicToRender"] == "/quad/evaluation"
    with open(next((recorded_run / "record").glob("*.mcap")), "rb") as handle:
        recorded = {channel.topic for channel in make_reader(handle).get_summary().channels.values()}
    assert {"/quad/mocap/odom", "/quad/imu", "/quad/motor_input"} <= plotted & recorded
    assert {"/quad/greybox/odom", "/quad/greybox/accel", "/quad/narx/odom"} <= plotted  # the models run-bag names so
