import gzip
import warnings

import numpy as np
import pytest

from quad_modelling.core import frames
from quad_modelling.errors import DataError
from quad_modelling.io.nanobench import read_nanobench
from test.conftest import FIXTURES

FLIGHT = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"
QUIRK = FIXTURES / "nanobench" / "B9_trefoil_fast_rep2_rows1199-1399.csv.gz"


def _edit(tmp_path, row: int, column: str, value: str):
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    header = lines[0].split(",")
    cells = lines[row].split(",")
    cells[header.index(column)] = value
    lines[row] = ",".join(cells)
    path = tmp_path / "edited.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_real_flight_in_internal_frames():
    log = read_nanobench(FLIGHT)
    assert len(log) == 1000 and log.sample_rate == pytest.approx(100.0, rel=1e-3)
    assert log.meta.vehicle == "crazyflie21"
    # On the ground at the start: specific force points up, i.e. -g along FRD z.
    np.testing.assert_allclose(log.acc_b[:20].mean(axis=0), [0, 0, -frames.STANDARD_GRAVITY], atol=0.2)
    # Vicon z up -> NED z down: the take-off height becomes negative z.
    assert log.pos_n[:, 2].min() < -0.5
    # roll/pitch/yaw columns agree with the quaternion in radians (the column doc says degrees).
    assert log.meta.notes["euler_columns_unit"] == "rad"
    assert np.all(np.diff(log.t) > 0) and log.vbat.min() > 3.0


def test_extrapolated_motor_tail_is_cut_with_a_warning():
    # B9_trefoil_fast_rep2: the onboard log stops, the CSV extrapolates the motors linearly past 65535 (issue 18:
    # once refused outright). The 148 collinear rows are cut; what remains is recorded and in range.
    log = read_nanobench(QUIRK)
    assert len(log) == 53 and log.u.max() == 65535.0
    assert log.meta.notes["extrapolated_tail"] == {"from_row": 54, "t_s": pytest.approx(0.53, abs=1e-3), "rows": 148}
    assert "saturated_commands" not in log.meta.notes
    [warning] = log.meta.notes["warnings"]
    assert warning == (f"{QUIRK}: motor columns continue as one straight line from data row 54 (t=0.53 s) to the end "
                       "(148 rows, up to 294574): the onboard log stopped and the CSV extrapolated it; the flight is cut at t=0.53 s")


def test_motor_values_just_beyond_the_range_are_clipped_and_counted(tmp_path):
    path = _edit(tmp_path, 300, "motor_motor_m2", "66254")
    lines = path.read_text().splitlines()
    cells = lines[301].split(",")
    cells[lines[0].split(",").index("motor_motor_m2")] = "65600"
    lines[301] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    log = read_nanobench(path)
    assert log.u[299, 1] == 65535.0 and log.u[300, 1] == 65535.0 and log.u.max() == 65535.0
    assert log.meta.notes["saturated_commands"] == {"motor_motor_m2": 2}
    t = log.t[299] - log.t[0]
    assert log.meta.notes["warnings"] == [
        f"{path}: column motor_motor_m2: 2 values above the crazyflie21 input range [0, 65535] PWM clipped "
        f"(max 66254 at row 300, t={t:.2f} s)"
    ]


@pytest.mark.parametrize("value", ["-1", "68900"])
def test_negative_or_far_beyond_motor_values_are_refused_with_column_and_row(tmp_path, value):
    path = _edit(tmp_path, 300, "motor_motor_m3", value)
    t = read_nanobench(FLIGHT).t
    with pytest.raises(DataError) as info:
        read_nanobench(path)
    assert str(info.value) == (
        f"{path}: column motor_motor_m3 data row 300 (t={t[299] - t[0]:.2f} s into the flight) is {value}, outside the crazyflie21 "
        "input range [0, 65535] PWM (1 values outside; up to 5% of the range beyond it is clipped as saturation)"
    )


def test_flight_without_imu_and_battery_columns_has_no_such_sensors(tmp_path):
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    header = lines[0].split(",")
    drop = [header.index(c) for c in header if c.startswith("imu_") or c == "pwr_pm_vbat"]
    path = tmp_path / "pose_only.csv"
    path.write_text("\n".join(",".join(c for i, c in enumerate(line.split(",")) if i not in drop) for line in lines) + "\n")
    log = read_nanobench(path)
    assert log.acc_b is None and log.gyro_b is None and log.vbat is None and len(log) == 1000
    np.testing.assert_allclose(log.pos_n, read_nanobench(FLIGHT).pos_n)


def _with_battery(lines, volts) -> str:
    column = lines[0].split(",").index("pwr_pm_vbat")
    rows = [line.split(",") for line in lines[1:]]
    for row, value in zip(rows, volts):
        row[column] = f"{value:g}"
    return "\n".join([lines[0], *(",".join(row) for row in rows)]) + "\n"


def test_battery_readings_at_or_below_0_v_are_skipped_as_the_bag_readers_do(tmp_path):
    """A battery column of zeros (a monitor not logging) was read as 0 V: identify --effects battery then blamed the
    shipped vehicle file (reference voltage 0 V). Readings at or below 0 V are skipped and said, as in bags and ULogs;
    identify names the flight with the reason."""
    from quad_modelling.core.identification.physics_fit import identify_physics
    from quad_modelling.core.vehicle import load_vehicle
    from quad_modelling.core.windows import EvaluationConfig

    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    volts = np.full(len(lines) - 1, 3.9)
    volts[100:110] = 0.0
    (tmp_path / "some.csv").write_text(_with_battery(lines, volts))
    log = read_nanobench(tmp_path / "some.csv")
    assert np.all(log.vbat == 3.9) and log.meta.notes["battery"] == (
        "pwr_pm_vbat: 10 of 1000 readings at or below 0 V or not finite skipped (a battery not connected)")
    (tmp_path / "none.csv").write_text(_with_battery(lines, np.full(len(lines) - 1, -3.7)))
    assert read_nanobench(tmp_path / "none.csv").vbat is None
    with pytest.raises(DataError) as info:
        identify_physics([log, read_nanobench(tmp_path / "none.csv")], load_vehicle("crazyflie21"), EvaluationConfig(),
                         terms=("battery",))
    assert str(info.value).startswith(f"{tmp_path / 'none.csv'}: identify --effects battery needs the battery voltage, "
                                      "and this flight has none (pwr_pm_vbat: 1000 of 1000 readings at or below 0 V")


def test_nan_row_is_named(tmp_path):
    t = read_nanobench(FLIGHT).t
    with pytest.raises(DataError, match=rf"edited.csv: column vx is not finite at data row 17 \(line 18 of the file, "
                                        rf"t={t[16] - t[0]:.2f} s into the flight\)"):
        read_nanobench(_edit(tmp_path, 17, "vx", "nan"))
    with warnings.catch_warnings():  # a non-finite first stamp: no time into the flight (numpy warned: 3 lines)
        warnings.simplefilter("error")
        with pytest.raises(DataError, match=r"edited.csv: column t is not finite at data row 1 \(line 2 of the file\)$"):
            read_nanobench(_edit(tmp_path, 1, "t", "inf"))


def test_text_in_a_number_column_names_the_column_and_the_data_row_as_a_nan_does(tmp_path):
    path = _edit(tmp_path, 17, "vx", "xyz")
    with pytest.raises(DataError) as info:
        read_nanobench(path)
    assert str(info.value) == f"{path}: unparsable value 'xyz' in column vx at data row 17 (line 18 of the file)"


def test_non_monotonic_time_is_named(tmp_path):
    previous = gzip.open(FLIGHT, "rt").read().splitlines()[9].split(",")[0]
    with pytest.raises(DataError, match="time is not strictly increasing at sample 10 of 1000"):
        read_nanobench(_edit(tmp_path, 10, "t", previous))


def test_a_quaternion_in_another_order_than_its_header_is_warned_about(tmp_path):
    """w, x, y, z under the header qx, qy, qz, qw read 180 deg off with no word (the reader measured it into the
    notes only): a warning now, the shipped order none."""
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    header = lines[0].split(",")
    q = [header.index(c) for c in ("qx", "qy", "qz", "qw")]
    for i in range(1, len(lines)):
        cells = lines[i].split(",")
        x, y, z, w = (cells[k] for k in q)
        for k, value in zip(q, (w, x, y, z)):
            cells[k] = value
        lines[i] = ",".join(cells)
    path = tmp_path / "wxyz.csv"
    path.write_text("\n".join(lines) + "\n")
    warned = [w for w in read_nanobench(path).meta.notes.get("warnings", []) if "disagree" in w]
    assert len(warned) == 1 and warned[0].startswith(f"{path}: the quaternion qx..qw and the roll/pitch/yaw columns disagree by up to")
    assert warned[0].endswith("check its column order (x, y, z, w) and its frame (ENU/FLU)")
    assert not [w for w in read_nanobench(FLIGHT).meta.notes.get("warnings", []) if "disagree" in w]


def test_a_header_with_a_byte_order_mark_or_quotes_reads(tmp_path):
    """A spreadsheet's UTF-8 BOM made the header's first name '\\ufefft' ("missing column(s) ['t']"); a quoted header
    made every column missing."""
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    bom, quoted = tmp_path / "bom.csv", tmp_path / "quoted.csv"
    bom.write_text("\ufeff" + "\n".join(lines) + "\n", encoding="utf-8")
    quoted.write_text(",".join(f'"{c}"' for c in lines[0].split(",")) + "\n" + "\n".join(lines[1:]) + "\n")
    for path in (bom, quoted):
        np.testing.assert_array_equal(read_nanobench(path).pos_n, read_nanobench(FLIGHT).pos_n)


def test_missing_column_is_named(tmp_path):
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    lines[0] = lines[0].replace("imu_gyro_y", "imu_gyro_q")
    path = tmp_path / "renamed.csv"
    path.write_text("\n".join(lines))
    with pytest.raises(DataError, match=r"missing NanoBench column\(s\) \['imu_gyro_y'\]"):
        read_nanobench(path)


def test_truncated_gzip_is_a_data_error(tmp_path):
    data = FLIGHT.read_bytes()
    path = tmp_path / "cut.csv.gz"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="cut.csv.gz"):
        read_nanobench(path)


def test_a_line_no_csv_row_can_be_is_refused_before_it_is_held(tmp_path, monkeypatch):
    """A gzip of 1.5 MB inflated to one 1.5 GiB line (3.3 GB of memory, then a MemoryError traceback under a limit):
    lines are read at most MAX_LINE_CHARS at a time, a whole file at most MAX_TEXT_CHARS (both made small here)."""
    from quad_modelling.io import nanobench

    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    path = tmp_path / "bomb.csv.gz"
    with gzip.open(path, "wt") as out:
        out.write("\n".join([*lines[:5], "1" * (nanobench.MAX_LINE_CHARS + 1), *lines[5:10]]) + "\n")
    with pytest.raises(DataError) as info:
        read_nanobench(path)
    assert str(info.value) == (f"{path}: line 6 is longer than {nanobench.MAX_LINE_CHARS} characters (a NanoBench row "
                               "holds about 600): not a NanoBench CSV")
    monkeypatch.setattr(nanobench, "MAX_TEXT_CHARS", 1 << 20)
    (tmp_path / "long.csv").write_text("\n".join(lines[:1] + lines[1:] * 20) + "\n")
    with pytest.raises(DataError, match=r"long.csv: more than 1 MiB of text \(line \d+\): too large for one NanoBench flight$"):
        read_nanobench(tmp_path / "long.csv")


def test_a_truncated_file_names_its_short_last_row(tmp_path):
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    path = tmp_path / "truncated.csv"
    path.write_text("\n".join(lines[:300]) + "\n" + lines[300][: len(lines[300]) // 2])
    with pytest.raises(DataError) as info:
        read_nanobench(path)
    assert str(info.value).startswith(f"{path}: data row 300 (line 301 of the file) has ")
    assert str(info.value).endswith(f"values, the header {len(lines[0].split(','))} columns: a short or truncated row")


@pytest.mark.parametrize("damage, what", [
    (lambda cells: cells[:30] + ["9.9"] + cells[30:], "a cell more than the header: the columns after it shift"),
    (lambda cells: cells + ["1.0"], "a cell more than the header: the columns after it shift"),
    (lambda cells: cells[:5] + cells[6:], "a short or truncated row"),
])
def test_a_row_with_a_cell_more_or_less_than_the_header_is_refused_by_its_row(tmp_path, damage, what):
    """numpy's ``usecols`` read a longer row's first cells and dropped the rest: a stray cell in rows 1201-1300 shifted
    Vbat to ~61 kV with no word (a review, session 44); a row missing a cell in the middle was read shifted too."""
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    width = len(lines[0].split(","))
    lines[101] = ",".join(damage(lines[101].split(",")))  # data row 101
    path = tmp_path / "uneven.csv"
    path.write_text("\n".join(lines) + "\n\n")
    with pytest.raises(DataError) as info:
        read_nanobench(path)
    cells = width + (1 if "more" in what else -1)
    assert str(info.value) == f"{path}: data row 101 (line 102 of the file) has {cells} values, the header {width} columns: {what}"


def test_comments_blank_lines_and_trailing_commas_are_no_cells(tmp_path):
    """As numpy's parser reads them (they loaded before the row check): a ``#`` comment line or an inline comment
    with a comma, blank lines, a trailing comma on the rows or on the header (a review, session 44)."""
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    reference = read_nanobench(FLIGHT)
    variants = {
        "comments": [lines[0], "# logger restarted, twice", *lines[1:50], "", lines[50] + "  # a note, with a comma", *lines[51:]],
        "row_commas": [lines[0], *(line + "," for line in lines[1:])],
        "header_comma": [lines[0] + ",", *lines[1:]],
    }
    for name, text in variants.items():
        path = tmp_path / f"{name}.csv"
        path.write_text("\n".join(text) + "\n")
        np.testing.assert_array_equal(read_nanobench(path).pos_n, reference.pos_n)


def test_an_unparsable_value_names_its_line_in_the_file_past_blank_and_comment_lines(tmp_path):
    lines = gzip.open(FLIGHT, "rt").read().splitlines()
    cells = lines[40].split(",")
    cells[3] = "abc"
    text = [lines[0], "", "# a comment", *lines[1:40], ",".join(cells), *lines[41:]]
    path = tmp_path / "bad_value.csv"
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(DataError) as info:
        read_nanobench(path)
    name = lines[0].split(",")[3]
    assert str(info.value) == f"{path}: unparsable value 'abc' in column {name} at data row 40 (line 43 of the file)"


def test_a_gzipped_csv_is_read_whatever_its_name(tmp_path):
    renamed = tmp_path / "flight.txt"
    renamed.write_bytes(FLIGHT.read_bytes())
    np.testing.assert_array_equal(read_nanobench(renamed).pos_n, read_nanobench(FLIGHT).pos_n)
