import os
import subprocess
import sys
from pathlib import Path

from quad_modelling.cli import build_parser, main
from quad_modelling.io.bag_io import read_bag
from quad_modelling.io.matlog import read_matlog, write_matlog
from test.conftest import FIXTURES, synthetic_log

FLIGHT = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"
QUIRK = FIXTURES / "nanobench" / "B9_trefoil_fast_rep2_rows1199-1399.csv.gz"


def test_every_verb_help_explains_inputs_outputs_with_an_example(capsys):
    parser = build_parser()
    verbs = parser._subparsers._group_actions[0].choices
    assert {"convert", "info"} <= set(verbs)
    for name, sub in verbs.items():
        text = sub.format_help()
        assert "example" in text and f"quad-modelling {name}" in text, name


def test_convert_one_nanobench_flight(tmp_path, capsys):
    assert main(["convert", str(FLIGHT), "-o", str(tmp_path / "bag")]) == 0
    assert "1000 samples" in capsys.readouterr().out
    assert len(read_bag(tmp_path / "bag")) == 1000


def test_convert_bag_back_to_mat(tmp_path):
    write_matlog(synthetic_log(vehicle="linkquad"), tmp_path / "a.mat")
    assert main(["convert", str(tmp_path / "a.mat"), "-o", str(tmp_path / "bag")]) == 0
    assert main(["convert", str(tmp_path / "bag"), "-o", str(tmp_path / "b.mat")]) == 0
    assert read_matlog(tmp_path / "b.mat").meta.vehicle == "linkquad"


def _far_beyond(directory: Path) -> Path:
    """FLIGHT with motor_motor_m2 of data row 500 at 80000: 22 % beyond 65535, refused (not saturation)."""
    import gzip

    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    cells = lines[500].split(",")
    cells[lines[0].split(",").index("motor_motor_m2")] = "80000"
    lines[500] = ",".join(cells)
    directory.mkdir()
    path = directory / "far_beyond.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_several_inputs_go_to_a_directory_and_a_bad_one_is_refused(tmp_path, capsys):
    out = tmp_path / "bags"
    bad = _far_beyond(tmp_path / "in")
    code = main(["convert", str(FLIGHT), str(bad), "-o", str(out)])
    printed = capsys.readouterr()
    err = printed.err
    assert code == 2 and "column motor_motor_m2 data row 500" in err and "outside the crazyflie21 input range" in err
    assert printed.out == ""  # no "FLIGHT -> out/..." for a bag the refusal rolled back
    assert len(err.strip().splitlines()) == 1  # one clear line
    assert not out.exists() and list(tmp_path.iterdir()) == [tmp_path / "in"]  # nothing partial left behind
    assert main(["convert", str(FLIGHT), str(bad), "-o", str(out), "--skip-bad"]) == 1
    assert sorted(p.name for p in out.iterdir()) == ["B7_oval_medium_rep2_first1000"]
    capsys.readouterr()
    none = tmp_path / "none"  # every input refused: exit 2 and no empty directory
    assert main(["convert", str(bad), str(tmp_path / "in" / "nosuch.csv"), "-o", str(none), "--skip-bad"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"quad-modelling convert: error: none of the 2 inputs could be converted (each refused above); nothing written to {none}"
    assert len(err) == 3 and not none.exists()


def test_the_extrapolated_quirk_converts_with_one_warning_kept_in_the_bag(tmp_path, capsys):
    # Issue 18: B9_trefoil_fast_rep2's motor values beyond 65535 lie in an extrapolated tail; it converts, cut, with a warning.
    assert main(["convert", str(QUIRK), "-o", str(tmp_path / "bag")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"warning: {QUIRK}: motor columns continue as one straight line from data row 54 (t=0.53 s) to the end "
                   "(148 rows, up to 294574): the onboard log stopped and the CSV extrapolated it; the flight is cut at t=0.53 s"]
    log = read_bag(tmp_path / "bag")
    assert len(log) == 53 and log.meta.notes["extrapolated_tail"]["rows"] == 148 and len(log.meta.notes["warnings"]) == 1
    assert main(["convert", str(QUIRK), str(FLIGHT), "-o", str(tmp_path / "bags")]) == 0  # with others: once too (was twice)
    assert sum("motor columns continue as one straight line" in line for line in capsys.readouterr().err.splitlines()) == 1


def test_existing_output_is_kept_without_force(tmp_path, capsys):
    assert main(["convert", str(FLIGHT), "-o", str(tmp_path / "bag")]) == 0
    before = sorted((p.name, p.stat().st_size) for p in (tmp_path / "bag").iterdir())
    assert main(["convert", str(FLIGHT), "-o", str(tmp_path / "bag")]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert sorted((p.name, p.stat().st_size) for p in (tmp_path / "bag").iterdir()) == before
    assert main(["convert", str(FLIGHT), "-o", str(tmp_path / "bag"), "--force"]) == 0


def test_force_replaces_an_earlier_bag_only_and_a_bag_named_by_its_mcap_is_an_input(tmp_path, capsys):
    """``convert -o EVAL --force`` deleted an evaluation's results (any verb's marker counted); a bag given by its .mcap
    file was not seen as the input its directory is (``convert BAG/x.mcap -o BAG/sub`` wrote into the input bag), and
    ``info`` refused the .mcap file evaluate and convert take."""
    evaluation = tmp_path / "evaluation"
    evaluation.mkdir()
    (evaluation / "results.json").write_text("{}")
    assert main(["convert", str(FLIGHT), "-o", str(evaluation), "--force"]) == 2
    assert "no earlier output of this command (none of metadata.yaml)" in capsys.readouterr().err
    assert sorted(p.name for p in evaluation.iterdir()) == ["results.json"]
    bag = tmp_path / "bag"
    assert main(["convert", str(FLIGHT), "-o", str(bag)]) == 0
    mcap = next(bag.glob("*.mcap"))
    for output in (bag / "sub", bag / "sub.mat"):
        assert main(["convert", str(mcap), "-o", str(output)]) == 2
        assert f"the output lies inside the input {mcap}" in capsys.readouterr().err
    assert sorted(p.name for p in bag.iterdir()) == ["bag.mcap", "metadata.yaml"]
    capsys.readouterr()
    assert main(["info", str(mcap)]) == 0
    assert capsys.readouterr().out.startswith(f"bag:       {bag}\n")


def test_a_csvs_missing_rows_are_a_marked_gap_in_convert_and_info(tmp_path, capsys):
    """3 s of rows cut from a NanoBench CSV converted to a bag with no word and no gap in its notes (only a scoring verb
    said it), and to a .mat log that a bag of the same flight was refused as: now the hole is marked and warned by
    the reader's rule, as evaluate does, and the .mat output refused alike. The same file twice is said so."""
    import gzip

    rows = gzip.open(FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", "rt").read().splitlines()
    cut = tmp_path / "cut.csv"
    cut.write_text("\n".join(rows[:400] + rows[700:]) + "\n")
    assert main(["convert", str(cut), "-o", str(tmp_path / "bag")]) == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if "time base has no message for 3.01 s" in line]
    assert len(warned) == 1 and "t=3.980..6.990 s into the flight" in warned[0]
    gaps = read_bag(tmp_path / "bag").meta.notes["measurement_gaps"]
    assert [(g["topic"], round(g["end_s"] - g["start_s"], 2)) for g in gaps] == [("/quad/motor_input", 3.01)]  # the bag re-finds it
    # a .mat keeps a hole of the time base as the rows it lacks (no row inside it to be misused), and reads it back so
    assert main(["convert", str(cut), "-o", str(tmp_path / "cut.mat")]) == 0
    capsys.readouterr()
    assert len(read_matlog(tmp_path / "cut.mat")) == 700
    assert main(["info", str(tmp_path / "cut.mat")]) == 0 and "measurement_gaps: [{'topic': 'time base'" in capsys.readouterr().out
    # a 10 Hz log missing one row has one hole, not one per 100 ms step (97 warnings)
    slow = tmp_path / "slow.csv"
    slow.write_text("\n".join(rows[:1] + [r for k, r in enumerate(rows[1:]) if k % 10 == 0 and k != 500]) + "\n")
    assert main(["convert", str(slow), "-o", str(tmp_path / "slow_bag")]) == 0
    assert "has no message" not in capsys.readouterr().err
    slow.write_text("\n".join(rows[:1] + [r for k, r in enumerate(rows[1:]) if k % 10 == 0 and not 500 <= k <= 520]) + "\n")
    assert main(["convert", str(slow), "-o", str(tmp_path / "slow_bag2")]) == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if "has no message" in line]
    assert len(warned) == 1 and "has no message for 0.40 s" in warned[0] and "longer than 0.25 s" in warned[0], warned
    assert main(["info", str(cut)]) == 0 and "measurement_gaps: [{'topic': 'time base'" in capsys.readouterr().out
    assert main(["convert", str(cut), str(tmp_path / "." / "cut.csv"), "-o", str(tmp_path / "two")]) == 2
    assert "given twice" in capsys.readouterr().err


def _make_unwritable(directory):
    """chmod for ordinary users; root ignores modes, so also set the immutable flag."""
    directory.chmod(0o555)
    if os.geteuid() == 0:
        subprocess.run(["chattr", "+i", str(directory)], check=True)


def _undo(directory):
    if os.geteuid() == 0:
        subprocess.run(["chattr", "-i", str(directory)], check=True)
    directory.chmod(0o755)


def test_unwritable_output_directory_is_one_line_and_exit_2(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    _make_unwritable(locked)
    try:
        assert main(["convert", str(FLIGHT), "-o", str(locked / "bag")]) == 2
    finally:
        _undo(locked)
    err = capsys.readouterr().err.strip()
    assert err.startswith("quad-modelling convert: error:") and "locked" in err and "writ" in err
    assert list(locked.iterdir()) == []


def test_missing_parent_directory(tmp_path, capsys):
    assert main(["convert", str(FLIGHT), "-o", str(tmp_path / "no" / "such" / "bag")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_mat_without_vehicle_needs_vehicle_flag(tmp_path, capsys):
    import numpy as np
    import scipy.io

    log = synthetic_log(vehicle="linkquad")
    write_matlog(log, tmp_path / "a.mat")
    contents = {k: v for k, v in scipy.io.loadmat(tmp_path / "a.mat").items() if not k.startswith("__") and k != "vehicle"}
    scipy.io.savemat(tmp_path / "novehicle.mat", contents)
    assert main(["convert", str(tmp_path / "novehicle.mat"), "-o", str(tmp_path / "bag")]) == 2
    assert "pass --vehicle" in capsys.readouterr().err
    assert main(["convert", str(tmp_path / "novehicle.mat"), "--vehicle", "linkquad", "-o", str(tmp_path / "bag")]) == 0
    assert np.allclose(read_bag(tmp_path / "bag").u, log.u)


def test_command_line_entry_point_runs(tmp_path):
    entry_point = Path(sys.executable).parent / "quad-modelling"  # installed by `make` (pip -e .)
    result = subprocess.run([str(entry_point), "info", str(tmp_path / "absent")], capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.strip() == f"quad-modelling info: error: {tmp_path / 'absent'}: no such file or directory"


def test_a_damaged_ulog_converts_with_a_warning_that_it_is_damaged(tmp_path, capsys):
    """400 bytes overwritten in the middle of a ULog: pyulog skips the damaged part; convert says so in a warning
    line (before: exit 0 and nothing said, the lost messages only visible as lower rates in `info`)."""
    source = Path(__file__).resolve().parents[1] / "data" / "px4" / "sample_px4_events.ulg"
    damaged = bytearray(source.read_bytes())
    damaged[500000:500400] = b"\xab" * 400
    ulog = tmp_path / "damaged.ulg"
    ulog.write_bytes(bytes(damaged))
    assert main(["convert", str(ulog), "-o", str(tmp_path / "bag")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: {ulog}: pyulog found the file damaged and skipped the damaged part (its messages are lost; "
                        "notes.pyulog has what it said)"]
