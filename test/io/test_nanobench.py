import gzip

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


def test_motor_values_beyond_pwm_range_are_refused_with_column_and_row():
    with pytest.raises(DataError, match=r"B9_trefoil_fast_rep2_rows1199-1399.csv.gz: column motor_motor_m\d data row \d+ .* outside the crazyflie21 input range \[0, 65535\] PWM"):
        read_nanobench(QUIRK)


def test_nan_row_is_named(tmp_path):
    with pytest.raises(DataError, match=r"edited.csv: column vx is not finite at data row 17"):
        read_nanobench(_edit(tmp_path, 17, "vx", "nan"))


def test_non_monotonic_time_is_named(tmp_path):
    previous = gzip.open(FLIGHT, "rt").read().splitlines()[9].split(",")[0]
    with pytest.raises(DataError, match="time is not strictly increasing at row 9"):
        read_nanobench(_edit(tmp_path, 10, "t", previous))


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
