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


def test_info_on_a_mat_log_shows_samples_and_simulation_notes(tmp_path, capsys):
    from quad_modelling.io.matlog import write_matlog

    log = synthetic_log(n=300, vehicle="linkquad")
    log.meta.notes.update({"effects": ["battery"], "seed": 7})
    write_matlog(log, tmp_path / "f.mat")
    assert main(["info", str(tmp_path / "f.mat")]) == 0
    out = capsys.readouterr().out
    assert "samples:   300 at 100.00 Hz, duration 2.990 s" in out
    assert "effects:   ['battery']" in out and "seed:      7" in out
    assert main(["info", str(tmp_path / "f.mat"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["fields"] == ["u", "acc_b", "gyro_b", "pos_n", "vel_n", "euler", "vbat", "omega"]


def test_info_into_a_closed_pipe_exits_quietly(tmp_path):
    """``quad-modelling info BAG | head -1``: the reader leaves early; no traceback, exit 141 (SIGPIPE)."""
    import subprocess
    import sys

    reader = subprocess.Popen([sys.executable, "-m", "quad_modelling.cli", "info", str(REPO / "bags" / "nanobench_B7_oval_medium_rep2")],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    reader.stdout.close()  # the pipe's reader is gone before the first line is written
    _, err = reader.communicate(timeout=60)
    assert reader.returncode == 141 and b"Traceback" not in err and err == b""


def test_info_says_why_no_flight_is_read_from_a_bag_no_map_matches(tmp_path, capsys):
    """A bag of topics no built-in map reads: the topic table, and one note line saying which maps were tried."""
    from test.stack_bags import px4_messages, write_stack_bag
    from quad_modelling.core.vehicle import load_vehicle
    from quad_modelling.io.loader import load_flight
    from test.conftest import REPO

    flight = load_flight(REPO / "test" / "fixtures" / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz")
    cf = load_vehicle("crazyflie21")

    def renamed(writer):  # a bridge configured with other topic names
        for topic, ns, msg in px4_messages(writer, log=flight, input_range=(cf.input_min, cf.input_max)):
            yield topic.replace("/fmu/out/", "/fmu/renamed/"), ns, msg

    bag = write_stack_bag(tmp_path / "px4_renamed", renamed)
    assert main(["info", str(bag)]) == 0
    captured = capsys.readouterr()
    assert "/fmu/renamed/vehicle_odometry" in captured.out
    notes = [line for line in captured.err.splitlines() if line.startswith("note: ")]
    assert len(notes) == 1 and notes[0].startswith(f"note: {bag}: no topic map matches the bag's topics")
