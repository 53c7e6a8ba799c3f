"""NanoBench Crazyflie 2.1 flights (``*.csv`` / ``*.csv.gz``, BSD-3, Ullah & Baca 2026).

Columns used (DESIGN section 5), all on the CSV's single 100 Hz time base ``t``
[s, Unix epoch]:

=====================================  ===============================================
columns                                meaning
=====================================  ===============================================
px, py, pz                             Vicon position, world ENU (z up) [m]
qx, qy, qz, qw                         Vicon attitude, quaternion of R_world<-body(FLU)
vx, vy, vz                             Vicon velocity, world ENU [m/s]
imu_acc_x, imu_acc_y, imu_acc_z        specific force, body FLU [g]
imu_gyro_x, imu_gyro_y, imu_gyro_z     body rates, FLU [rad/s]
motor_motor_m1 .. motor_motor_m4       motor PWM ratio 0..65535 (u1..u4)
pwr_pm_vbat                            battery voltage [V]
roll, pitch, yaw                       Vicon Euler angles, FLU/ENU
=====================================  ===============================================

The attitude is taken from the quaternion (converted by the frames module);
roll/pitch/yaw are only checked against it: the data holds them in radians,
not degrees as the column reference says. The IMU and battery columns are
optional (a flight without them has no acc_b/gyro_b/vbat).

Extrapolated tail: the CSV puts every onboard stream on the Vicon clock; when
the onboard log stops before the Vicon recording, the motor columns continue
as one straight line to the end (``B9_trefoil_fast_rep2``: from t = 12.5 s on,
rising to 4.78e6 by t = 42.3 s; its IMU and battery columns go flat or linear
with them). Recorded motor values are never collinear with all four motors
moving for more than 11 rows in the 18 NanoBench flights, so a final run of at
least :data:`EXTRAPOLATED_MIN_S` is cut off with a warning and recorded in
``meta.notes['extrapolated_tail']``.

Motor values beyond the vehicle's input range are clipped to it with a warning
and a count (:func:`quad_modelling.core.flight_log.saturate_commands`); negative
or far beyond (more than the saturation margin) are refused with file, column
and row named.
"""

from __future__ import annotations

import gzip
import warnings
import zlib
from pathlib import Path

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.alignment import battery_on_rows
from quad_modelling.core.flight_log import FlightLog, FlightMeta, saturate_commands
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle
from quad_modelling.errors import DataError, reason

POSITION = ("px", "py", "pz")
QUATERNION = ("qx", "qy", "qz", "qw")
VELOCITY = ("vx", "vy", "vz")
ACCEL = ("imu_acc_x", "imu_acc_y", "imu_acc_z")
GYRO = ("imu_gyro_x", "imu_gyro_y", "imu_gyro_z")
MOTORS = ("motor_motor_m1", "motor_motor_m2", "motor_motor_m3", "motor_motor_m4")
VBAT = "pwr_pm_vbat"
EULER_COLUMNS = ("roll", "pitch", "yaw")
REQUIRED = ("t", *POSITION, *QUATERNION, *VELOCITY, *MOTORS)
OPTIONAL = {"acc_b": ACCEL, "gyro_b": GYRO, "vbat": (VBAT,)}
"""Column groups a flight may lack as a whole (FlightLog field -> columns)."""

EXTRAPOLATED_MIN_S = 1.0
"""Shortest final run [s] of exactly collinear, moving motor values cut off as extrapolated (module docstring)."""

COLLINEAR_TOLERANCE = 1.0
"""Largest second difference [command counts] of a motor column counted as exactly linear (the
extrapolated tail: < 0.3; recorded flight: median 240)."""

EULER_COLUMN_TOLERANCE = 0.01
"""Largest rotation [rad] between the roll/pitch/yaw columns and the quaternion for the columns to
count as radians agreeing with it (recorded in ``meta.notes``; the attitude always comes from the
quaternion)."""


def _uneven_row(lines: list[str], header: list[str]) -> str | None:
    """The first data line (after the header) whose cells are not the header's, said as the reader says a row; None
    when every line has them. As the parser reads them: a ``#`` starts a comment, blank lines are skipped, and empty
    cells at the end of a line (a trailing comma) are no cells. A row with one cell more or less shifts the columns
    after it: numpy's ``usecols`` read a longer row's first cells silently (a stray cell made Vbat 60 971 V)."""
    width = len(header)
    while width and not header[width - 1]:
        width -= 1
    row = 0
    for number, line in enumerate(lines, start=2):  # the file's line number (the header is line 1)
        content = line.split("#", 1)[0]
        if not content.strip():
            continue
        row += 1
        cells = content.split(",")
        while len(cells) > width and not cells[-1].strip():
            cells.pop()
        if len(cells) != width:
            what = "a short or truncated row" if len(cells) < width else "a cell more than the header: the columns after it shift"
            return f"data row {row} (line {number} of the file) has {len(cells)} values, the header {width} columns: {what}"
    return None


def _unparsable(err: ValueError, columns: list[str], lines: list[str]) -> str:
    """The message of numpy.loadtxt's ValueError in the reader's terms: the column by its ``columns`` (header) name and
    the data row counted from 1 after the header (numpy counts the data rows from 0, blank and comment lines not
    among them, and the file's column from 1) with its line in the file (``lines``: the file's after the header);
    rows of another length are refused before (:func:`_uneven_row`)."""
    import re

    text = reason(err)
    found = re.search(r"could not convert string (.*) to \w+ at row (\d+), column (\d+)", text)
    if not found:
        return f"unparsable value ({text})"
    value, row, col = found.group(1), int(found.group(2)), int(found.group(3))
    name = columns[col - 1] if 0 < col <= len(columns) else f"number {col}"
    data_lines = [number for number, line in enumerate(lines, start=2) if line.split("#", 1)[0].strip()]
    line = data_lines[row] if row < len(data_lines) else row + 2
    return f"unparsable value {value} in column {name} at data row {row + 1} (line {line} of the file)"


GZIP_MAGIC = b"\x1f\x8b"
"""The first two bytes of a gzip file (RFC 1952): a compressed CSV is read as one whatever its name."""


MAX_LINE_CHARS = 1 << 16
"""Longest line read [characters]: a NanoBench row of 52 columns holds about 600. A longer one is damage, and a
gzip of 1.5 MB inflated to one line of 1.5 GiB (3.3 GB of memory before any check)."""

MAX_TEXT_CHARS = 1 << 30
"""Most text read from one flight file [characters]: a 100 Hz NanoBench flight holds about 60 kB a second."""


def _bounded_lines(stream, where: str) -> list[str]:
    """The lines left in ``stream`` without their ends, each at most :data:`MAX_LINE_CHARS` and all at most
    :data:`MAX_TEXT_CHARS`; DataError naming the line (the header is line 1) otherwise."""
    lines: list[str] = []
    total = 0
    while line := stream.readline(MAX_LINE_CHARS + 1):
        if len(line) > MAX_LINE_CHARS:
            raise DataError(f"{where}: line {len(lines) + 2} is longer than {MAX_LINE_CHARS} characters (a NanoBench row "
                            "holds about 600): not a NanoBench CSV")
        total += len(line)
        if total > MAX_TEXT_CHARS:
            raise DataError(f"{where}: more than {MAX_TEXT_CHARS >> 20} MiB of text (line {len(lines) + 2}): too large "
                            "for one NanoBench flight")
        lines.append(line.rstrip("\n"))
    return lines


def _open_text(path: Path):
    with open(path, "rb") as head:
        compressed = head.read(2) == GZIP_MAGIC
    return gzip.open(path, "rt", encoding="utf-8-sig") if compressed else open(path, encoding="utf-8-sig")  # a BOM dropped


def read_nanobench(path: str | Path, vehicle: str | VehicleConfig = "crazyflie21") -> FlightLog:
    """Read one NanoBench CSV flight into a FlightLog (NED/FRD, SI).

    ``vehicle``: config name, YAML path or an already loaded config (not loaded again).

    Raises DataError naming the file and the column/row at fault: missing
    columns, unparsable or non-finite values, non-monotonic time, motor values
    outside the vehicle's input range.
    """
    path = Path(path)
    where = str(path)
    lines: list[str] = []  # the file's lines after the header, once read
    try:
        with _open_text(path) as stream:
            first = stream.readline(MAX_LINE_CHARS + 1)
            if len(first) > MAX_LINE_CHARS:
                raise DataError(f"{where}: the header line is longer than {MAX_LINE_CHARS} characters: not a NanoBench CSV")
            header = [name.strip().strip('"').strip("'").strip() for name in first.strip().split(",")]  # "t" too
            missing = [c for c in REQUIRED if c not in header]
            missing += [c for group in OPTIONAL.values() if any(c in header for c in group) for c in group if c not in header]
            if missing:
                raise DataError(f"{where}: missing NanoBench column(s) {missing}")
            twice = sorted({c for c in (*REQUIRED, *EULER_COLUMNS) if header.count(c) > 1})
            if twice:
                raise DataError(f"{where}: NanoBench column(s) {twice} appear more than once in the header")
            optional = [c for group in OPTIONAL.values() for c in group]
            index = {name: header.index(name) for name in (*REQUIRED, *optional, *EULER_COLUMNS) if name in header}
            lines = _bounded_lines(stream, where)
            uneven = _uneven_row(lines, header)
            if uneven:
                raise DataError(f"{where}: {uneven}")
            with warnings.catch_warnings():  # a header-only file is refused below, not warned about
                warnings.simplefilter("ignore", UserWarning)
                rows = np.loadtxt(lines, delimiter=",", usecols=list(index.values()), ndmin=2)
    except DataError:
        raise  # a ValueError too, already naming the file
    except FileNotFoundError as err:
        raise DataError(f"{where}: no such file") from err
    except (OSError, EOFError, gzip.BadGzipFile, zlib.error) as err:
        raise DataError(f"{where}: cannot read ({reason(err)})") from err
    except UnicodeDecodeError as err:
        raise DataError(f"{where}: not UTF-8 text (byte {err.start} of a line: {err.object[err.start:err.start + 1]!r})") from err
    except ValueError as err:
        raise DataError(f"{where}: {_unparsable(err, header, lines)}") from err
    if len(rows) == 0:
        raise DataError(f"{where}: no data rows after the header")
    column = {name: rows[:, i] for i, name in enumerate(index)}
    for name, values in column.items():
        bad = ~np.isfinite(values)
        if bad.any():
            row = int(np.argmax(bad))
            at = f", t={column['t'][row] - column['t'][0]:.2f} s into the flight" if np.isfinite(column["t"][[0, row]]).all() else ""
            raise DataError(f"{where}: column {name} is not finite at data row {row + 1} (line {row + 2} of the file{at})")

    def stack(names: tuple[str, ...]) -> np.ndarray:
        return np.column_stack([column[n] for n in names])

    quat = stack(QUATERNION)
    bad_quaternion = frames.non_unit_quaternion(quat)
    if bad_quaternion:
        row, norm = bad_quaternion
        raise DataError(f"{where}: quaternion qx..qw at data row {row + 1} has norm {norm:.3f}, not 1")
    euler = frames.quat_enu_to_euler_ned(quat)
    euler[:, 2] = frames.unwrap_angles(euler[:, 2])
    notes = {"format": "nanobench", "euler_from": "quaternion qx..qw"}
    if all(c in column for c in EULER_COLUMNS):
        # The columns are the same attitude as roll/pitch/yaw about the fixed ENU axes x, y, z
        # (scipy's extrinsic "xyz"): compare the two rotations, no frame conversion involved.
        from scipy.spatial.transform import Rotation

        from_columns = Rotation.from_euler("xyz", stack(EULER_COLUMNS))
        deviation = (from_columns.inv() * Rotation.from_quat(quat)).magnitude()
        row = int(np.argmax(deviation))
        notes["euler_columns_max_deviation_rad"] = float(deviation[row])
        notes["euler_columns_unit"] = (
            "rad" if deviation[row] < EULER_COLUMN_TOLERANCE
            else f"inconsistent with the quaternion (largest deviation {deviation[row]:.3g} rad at data row {row + 1})"
        )
    config = vehicle if isinstance(vehicle, VehicleConfig) else load_vehicle(vehicle)
    notes_warnings = []
    if notes.get("euler_columns_unit", "rad") != "rad":  # measured, and said (a wxyz quaternion under qx..qw: 180 deg off)
        notes_warnings.append(f"{where}: the quaternion qx..qw and the roll/pitch/yaw columns disagree by up to "
                              f"{notes['euler_columns_max_deviation_rad']:.3g} rad (data row {row + 1}); the attitude is read "
                              "from the quaternion: check its column order (x, y, z, w) and its frame (ENU/FLU)")
    keep = _recorded_rows(stack(MOTORS), column["t"])
    if keep < len(column["t"]):
        t, motors = column["t"], stack(MOTORS)
        notes["extrapolated_tail"] = {"from_row": keep + 1, "t_s": float(t[keep] - t[0]), "rows": len(t) - keep}
        notes_warnings.append(
            f"{where}: motor columns continue as one straight line from data row {keep + 1} (t={t[keep] - t[0]:.2f} s) to the end "
            f"({len(t) - keep} rows, up to {motors[keep:].max():.6g}): the onboard log stopped and the CSV extrapolated it; "
            f"the flight is cut at t={t[keep] - t[0]:.2f} s"
        )
        column = {name: values[:keep] for name, values in column.items()}
        quat, euler = quat[:keep], euler[:keep]
    motors, clipped, counts = saturate_commands(stack(MOTORS), column["t"], config.input_min, config.input_max, where, config.name,
                                                config.input_unit, MOTORS)
    notes_warnings += clipped
    if counts:
        notes["saturated_commands"] = counts
    has = {field: all(c in column for c in columns) for field, columns in OPTIONAL.items()}
    vbat = None
    if has["vbat"]:  # readings at 0 V or below skipped, as the bag readers do (a monitor not logging)
        vbat, battery_note = battery_on_rows(column["t"], column[VBAT], column["t"])
        if battery_note:
            notes["battery"] = f"{VBAT}: {battery_note}"
    log = FlightLog(
        t=column["t"],
        u=motors,
        acc_b=frames.flu_to_frd(frames.to_si(stack(ACCEL), "g")) if has["acc_b"] else None,
        gyro_b=frames.flu_to_frd(stack(GYRO)) if has["gyro_b"] else None,
        pos_n=frames.enu_to_ned(stack(POSITION)),
        vel_n=frames.enu_to_ned(stack(VELOCITY)),
        euler=euler,
        vbat=vbat,
        meta=FlightMeta(vehicle=config.name, source=where, notes=notes),
    )
    for message in notes_warnings:
        log.warn(message)
    return log


def _recorded_rows(motors: np.ndarray, t: np.ndarray) -> int:
    """Rows before an extrapolated tail (module docstring): len(motors) when there is none.

    The tail is the final run of rows whose motor values are collinear (every second difference
    within :data:`COLLINEAR_TOLERANCE`) while moving; the two rows that define the line are kept.
    """
    if len(motors) < 3:
        return len(motors)
    linear = (np.abs(np.diff(motors, 2, axis=0)) <= COLLINEAR_TOLERANCE).all(axis=1)
    moving = (np.diff(motors, axis=0)[1:] != 0).any(axis=1)
    run = linear & moving
    start = len(run)
    while start > 0 and run[start - 1]:
        start -= 1
    rate = (len(t) - 1) / (t[-1] - t[0]) if t[-1] > t[0] else 0.0
    if len(run) - start < max(EXTRAPOLATED_MIN_S * rate, 3):
        return len(motors)
    return start + 2
