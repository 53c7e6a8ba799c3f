"""Reading flights: an unreadable one raises, or with skip_bad is left out and named; the vehicle config is read
once per flight, and not at all when given a loaded one."""

import pytest

from quad_modelling.errors import ConfigError, DataError
from quad_modelling.io.loader import load_flights
from quad_modelling.io.matlog import write_matlog
from test.conftest import synthetic_log


def test_load_flights_skips_and_names_a_bad_file_only_when_asked(tmp_path):
    good = write_matlog(synthetic_log(n=300, vehicle="linkquad"), tmp_path / "good.mat")
    bad = tmp_path / "bad.mat"  # missing
    with pytest.raises(DataError, match="bad.mat"):
        load_flights([good, bad])
    flights, skipped = load_flights([good, bad], skip_bad=True)
    assert [len(f) for f in flights] == [300] and flights[0].meta.vehicle == "linkquad"
    assert len(skipped) == 1 and "bad.mat" in skipped[0]


import argparse

from quad_modelling.commands.evaluate import load_evaluation_flights
from quad_modelling.core import vehicle as vehicle_module
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.loader import load_flight
from test.conftest import FIXTURES

NANOBENCH = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"


@pytest.fixture
def yaml_loads(monkeypatch):
    """Counts vehicle YAML files read (VehicleConfig.from_yaml calls)."""
    calls = []
    original = vehicle_module.VehicleConfig.from_yaml.__func__

    def counting(cls, path):
        calls.append(str(path))
        return original(cls, path)

    monkeypatch.setattr(vehicle_module.VehicleConfig, "from_yaml", classmethod(counting))
    return calls


def test_a_nanobench_flight_reads_its_vehicle_once(yaml_loads):
    log = load_flight(NANOBENCH)
    assert log.meta.vehicle == "crazyflie21" and len(yaml_loads) == 1  # read_nanobench and load_flight each read it before


def test_a_loaded_vehicle_is_not_read_again(yaml_loads):
    config = load_vehicle("crazyflie21")
    log = load_flight(NANOBENCH, vehicle=config)
    assert log.meta.vehicle == "crazyflie21" and len(yaml_loads) == 1


def test_evaluate_reads_the_given_vehicle_once_for_all_flights(yaml_loads):
    from test.conftest import REPO

    bag = REPO / "bags" / "nanobench_B7_oval_medium_rep2"  # the whole flight: other numbers than its first 1000 rows
    args = argparse.Namespace(inputs=[str(NANOBENCH), str(bag)], vehicle="crazyflie21", skip_bad=False, jobs=None, scheduler=None)
    flights, config, skipped = load_evaluation_flights(args)
    assert len(flights) == 2 and config.name == "crazyflie21" and skipped == []
    assert len(yaml_loads) == 1  # before: 2 per flight + 1 = 5
    args.inputs = [str(NANOBENCH)] * 2  # one flight twice (the command's path check bypassed): its numbers tell
    with pytest.raises(ConfigError, match="the same flight as"):
        load_evaluation_flights(args)


def test_a_bag_named_by_its_file_reads_that_file_or_is_refused(tmp_path):
    """A bag may be named by its .mcap file; the reader reads the files its metadata.yaml lists, so another .mcap file
    in the directory was read as the listed one (another flight, silently): it is refused, naming the listed file."""
    import shutil

    from quad_modelling.errors import BagError
    from quad_modelling.io.bag_io import write_bag

    bag = write_bag(synthetic_log(n=50, seed=1), tmp_path / "bag")
    other = write_bag(synthetic_log(n=80, seed=2), tmp_path / "other")
    (listed,) = bag.glob("*.mcap")
    assert len(load_flight(listed)) == 50
    shutil.copy(next(other.glob("*.mcap")), bag / "stray.mcap")
    with pytest.raises(BagError) as err:
        load_flight(bag / "stray.mcap")
    assert str(err.value) == (f"{bag / 'stray.mcap'}: not a file of the bag {bag} (its metadata.yaml lists {listed.name}); "
                              "give the bag directory or the file it lists")
    (bag / "metadata.yaml").unlink()
    with pytest.raises(BagError, match="stray.mcap: no metadata.yaml beside it"):
        load_flight(bag / "stray.mcap")


def test_a_flight_of_any_reader_is_checked_for_unit_and_frame_mistakes(tmp_path):
    """A NanoBench CSV whose motor 1 is logged in 0..1 next to PWM columns read without a word (only flights read
    through a topic map were checked); the shipped flight reads without such a warning."""
    import gzip

    flight = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"
    lines = gzip.open(flight, "rt").read().splitlines()
    column = lines[0].split(",").index("motor_motor_m1")
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:
        row[column] = f"{float(row[column]) / 65535:.6f}"
    (tmp_path / "fraction.csv").write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    warnings = load_flight(tmp_path / "fraction.csv").meta.notes.get("warnings", [])
    assert [w for w in warnings if "motor 1's commands reach 0.0% of the input range [0, 65535]" in w]
    assert not [w for w in load_flight(flight).meta.notes.get("warnings", []) if "reach" in w]


def test_a_file_named_with_a_line_break_is_named_once(tmp_path):
    """The error's one line turns the name's line break into a space, so the loader did not find the name in it and
    named the file a second time."""
    from quad_modelling.errors import DataError

    path = tmp_path / "bad\nname.mat"
    path.write_text("not a MATLAB file")
    with pytest.raises(DataError) as err:
        load_flight(path)
    assert str(err.value).count("bad name.mat") == 1
