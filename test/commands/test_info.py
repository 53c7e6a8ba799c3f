import json

from quad_modelling.cli import main
from quad_modelling.io.bag_io import write_bag
from test.conftest import REPO, synthetic_log


def test_info_table_lists_topics_counts_and_rates(tmp_path, capsys):
    write_bag(synthetic_log(n=300), tmp_path / "bag")
    assert main(["info", str(tmp_path / "bag")]) == 0
    out = capsys.readouterr().out
    assert "vehicle:   crazyflie21" in out and "duration:  2.990 s" in out
    line = next(l for l in out.splitlines() if l.startswith("/quad/imu"))
    assert line.split()[1:4] == ["sensor_msgs/msg/Imu", "300", "100.00"]


def test_info_json(tmp_path, capsys):
    write_bag(synthetic_log(n=300), tmp_path / "bag")
    assert main(["info", str(tmp_path / "bag"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["message_count"] == 1200
    assert {t["name"]: t["count"] for t in doc["topics"]}["/quad/motor_input"] == 300


def test_bundled_bag_is_a_nanobench_flight(capsys):
    bag = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
    assert main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "4227" in out and "source:    B7_oval_medium_rep2.csv.gz" in out
    assert (REPO / "bags" / "LICENSE.nanobench").read_text().startswith("BSD 3-Clause License")
