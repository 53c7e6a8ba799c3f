"""FlightLog: one flight on one monotonic time base, in the internal convention.

Frames and units (see :mod:`quad_modelling.core.frames`): N = NED, B = FRD,
Euler ZYX, SI units. Every array has one row per sample time ``t``.

=========  =======  ==========================================================
field      shape    content
=========  =======  ==========================================================
t          (N,)     sample time [s], strictly increasing
u          (N, 4)   raw engine commands as logged (PWM counts, pulse seconds...)
acc_b      (N, 3)   optional onboard accelerometer specific force, B frame [m/s²]
gyro_b     (N, 3)   optional onboard gyro rates p, q, r about B axes [rad/s]
pos_n      (N, 3)   motion-capture position in N [m]
vel_n      (N, 3)   motion-capture velocity in N [m/s]
euler      (N, 3)   motion-capture attitude φ, θ, ψ [rad]
vbat       (N,)     optional battery voltage [V]
omega      (N, 4)   optional rotor speeds [rad/s]
=========  =======  ==========================================================

Optional fields are None when the flight has no such sensor (a motion-capture
log without an onboard IMU, a log without battery or rotor speed): a variable
or model that needs a missing sensor says so by name (:data:`SENSORS`,
:meth:`FlightLog.require`) instead of refusing the flight.

Construction validates shapes, strictly increasing time and finite values
(a NaN is rejected with the channel and sample time named; readers that can
fill gaps say so in ``meta.notes``), the sensor full-scale limits below,
which catch data in the wrong unit (e.g. accelerations in g, angles in deg),
and plausibility bounds on position and velocity (:data:`POSITION_LIMIT`,
:data:`VELOCITY_LIMIT`), which catch corrupt values (a position of 1e30 m).

Engine commands beyond the vehicle's input range (:func:`saturate_commands`):
the actuator saturates, so a command up to :data:`SATURATION_MARGIN` of the
range beyond it is clipped to the range with a warning (kept in
``meta.notes['warnings']`` and counted in ``meta.notes['saturated_commands']``);
a negative command (range starting at 0 or above) or one further out is refused.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field

import numpy as np

from quad_modelling.core.frames import STANDARD_GRAVITY
from quad_modelling.errors import DataError

GYRO_FULL_SCALE = np.deg2rad(2000.0)
"""Largest rate a MEMS gyro reports [rad/s] (±2000 deg/s: BMI088, MPU-6050 ranges)."""

ACCEL_FULL_SCALE = 24.0 * STANDARD_GRAVITY
"""Largest specific force a MEMS accelerometer reports [m/s²] (±24 g: BMI088)."""

POSITION_LIMIT = 1.0e5
"""Largest |position| component [m] a flight may hold: 100 km, beyond any local frame a multirotor flight is logged
in (motion-capture volumes, a PX4 local NED frame whose origin is set at arming). A judgement, not a measurement:
it catches a corrupt or wrongly scaled position (1e30 m, a mm log read as km), not a long flight."""

VELOCITY_LIMIT = 200.0
"""Largest |velocity| component [m/s] a flight may hold: above any multirotor's (racing quadrotors reach about
50 m/s) and below the speed of sound; a judgement that catches corrupt or wrongly scaled velocities."""

MAX_TIME_S = (2**63 - 1) / 1e9
"""Largest |t| [s] a flight may hold: what a ROS stamp of int64 nanoseconds reaches (year 2262 in Unix time)."""

VECTOR_FIELDS = ("acc_b", "gyro_b", "pos_n", "vel_n", "euler")
"""The (N, 3) fields, in the order used by writers."""

FIELD_WIDTHS = {"u": 4, **{name: 3 for name in VECTOR_FIELDS}, "vbat": 0, "omega": 4}
"""Every field but t -> its columns (0: a vector of one number per row)."""

COLUMN_NAMES = {"u": ("motor 1", "motor 2", "motor 3", "motor 4"), "acc_b": ("x", "y", "z"), "gyro_b": ("roll rate", "pitch rate", "yaw rate"),
                "pos_n": ("north", "east", "down"), "vel_n": ("north", "east", "down"), "euler": ("roll", "pitch", "yaw"),
                "omega": ("rotor 1", "rotor 2", "rotor 3", "rotor 4")}
"""What each column of a field is, for an error message a user reads (NED/FRD, whatever the file's own columns)."""

FINGERPRINT_FIELDS = ("u", "pos_n", "acc_b", "gyro_b")
"""The recorded fields :meth:`FlightLog.fingerprint` digests (a missing sensor's left out)."""

RANGES = {
    "gyro_b": (GYRO_FULL_SCALE, "rad/s (gyro full scale)"),
    "acc_b": (ACCEL_FULL_SCALE, "m/s² (accelerometer full scale)"),
    "euler": (np.pi + 1e-6, "rad for roll/pitch"),
    "pos_n": (POSITION_LIMIT, "m (no local frame is that large)"),
    "vel_n": (VELOCITY_LIMIT, "m/s (faster than any multirotor)"),
}
"""Field -> (largest |value|, what it is): checked in this order on construction."""

RANGE_COLUMNS = {"euler": 2}
"""Fields whose first columns only :data:`RANGES` limits (the yaw is continuous: any size)."""

SCREEN_LIMITS = {
    "t": np.array([MAX_TIME_S]),
    "u": np.full(4, np.finfo(float).max),
    **{name: np.array([RANGES[name][0]] * RANGE_COLUMNS.get(name, 3) + [np.finfo(float).max] * (3 - RANGE_COLUMNS.get(name, 3)))
       for name in VECTOR_FIELDS},
    "vbat": np.array([np.finfo(float).max]),
    "omega": np.full(4, np.finfo(float).max),
}
"""Field -> the largest |value| of each column a valid log holds (the float maximum: finite only): the one-pass
screen of a short log (:data:`SCREENED_ROWS`); |x| <= limit is false for NaN and ±inf too."""

SCREENED_ROWS = 16
"""A log of up to this many rows is screened in one pass (:data:`SCREEN_LIMITS`) before the per-field checks, which
run only when it fails (they name the field and the row): the live predictor builds a 2-row log per input, where the
per-field checks cost ~100 µs here and the screen ~20 µs."""

_SCREENS: dict[tuple[str, ...], np.ndarray] = {}
"""Present fields -> their columns' screen limits, concatenated once."""

SENSORS = {"acc_b": "accelerometer", "gyro_b": "gyro", "vbat": "battery voltage", "omega": "rotor speed"}
"""The optional fields and the sensor each comes from (None in a flight without that sensor)."""

SATURATION_MARGIN = 0.05
"""Largest excess beyond the input range, as a fraction of the range width, that is clipped as
actuator saturation (:func:`saturate_commands`); further out is refused as impossible. A judgement,
not a measurement: ESC/servo PWM endpoints are calibrated to a few per cent of their 1000 µs span,
so a command a few per cent past an endpoint is a request the actuator saturates. The NanoBench
values beyond 65535 (B9_trefoil_fast_rep2, up to 4.78e6) are no evidence either way: they lie in a
linearly extrapolated tail (:mod:`quad_modelling.io.nanobench`), no recorded sample exceeds 65535."""


def first_outside(values: np.ndarray, low: float, high: float) -> tuple[int, int, int] | None:
    """(row, column, count) of the first value of an (N, k) array outside [low, high], or None."""
    outside = (values < low) | (values > high)
    if not outside.any():
        return None
    row = int(np.argmax(outside.any(axis=1)))
    return row, int(np.argmax(outside[row])), int(outside.sum())


@dataclass
class FlightMeta:
    """What a flight log is about.

    vehicle: name of the vehicle config (``config/vehicles/<name>.yaml``).
    source: the file it was read from (or ``simulated``).
    notes: free-form facts kept with the log (effects, seed, fill rules...).
    """

    vehicle: str
    source: str
    notes: dict = field(default_factory=dict)


@dataclass
class FlightLog:
    """One flight on one time base; validated on construction (see module doc)."""

    t: np.ndarray
    u: np.ndarray
    acc_b: np.ndarray | None
    gyro_b: np.ndarray | None
    pos_n: np.ndarray
    vel_n: np.ndarray
    euler: np.ndarray
    meta: FlightMeta
    vbat: np.ndarray | None = None
    omega: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = self.meta.source
        self.t = np.ascontiguousarray(self.t, dtype=float)
        if self.t.ndim != 1 or self.t.size < 2:
            raise DataError(f"{where}: time must be a vector of at least 2 samples, got shape {self.t.shape}")
        n = self.t.size
        for name, width in FIELD_WIDTHS.items():
            value = getattr(self, name)
            if value is None and name in SENSORS:
                continue
            value, shape = np.ascontiguousarray(value, dtype=float), (n, width) if width else (n,)
            if value.shape != shape:
                raise DataError(f"{where}: field {name} has shape {value.shape}, expected {shape}")
            setattr(self, name, value)
        if n <= SCREENED_ROWS and self._within_limits():
            self._check_time_order(where)
            return
        self._check_finite(where)
        beyond = np.abs(self.t) > MAX_TIME_S
        if beyond.any():
            row = int(np.argmax(beyond))
            raise DataError(f"{where}: time at sample {row + 1} of {n} is {self.t[row]:.4g} s, beyond ±{MAX_TIME_S:.4g} s (int64 "
                            "nanosecond stamps): corrupt time base")
        self._check_time_order(where)
        for name, (limit, what) in RANGES.items():
            self._check_range(where, name, limit, what)

    def _within_limits(self) -> bool:
        """Every value finite and within its field's limit (:data:`SCREEN_LIMITS`): the checks of a valid log in one
        pass over its fields stacked; which check failed, and where, the full checks say."""
        names = tuple(name for name in SCREEN_LIMITS if getattr(self, name) is not None)
        limits = _SCREENS.get(names)
        if limits is None:
            limits = _SCREENS[names] = np.concatenate([SCREEN_LIMITS[name] for name in names])
        stacked = np.concatenate([getattr(self, name).reshape(len(self.t), -1) for name in names], axis=1)
        return bool((np.abs(stacked) <= limits).all())

    def _check_time_order(self, where: str) -> None:
        if (self.t[1:] > self.t[:-1]).all():
            return
        steps = np.diff(self.t)
        if np.any(~(steps > 0)):
            row = int(np.argmax(~(steps > 0))) + 1
            raise DataError(
                f"{where}: time is not strictly increasing at sample {row + 1} of {len(self.t)} "
                f"(t={self.t[row]:.6f} s after {self.t[row - 1]:.6f} s)"
            )

    def _check_finite(self, where: str) -> None:
        for name in ("t", "u", *VECTOR_FIELDS, "vbat", "omega"):
            value = getattr(self, name)
            if value is None or np.isfinite(value).all():
                continue
            bad = ~np.isfinite(value)
            if bad.any():
                row = int(np.argmax(bad.reshape(len(value), -1).any(axis=1)))
                column = None if value.ndim == 1 else int(np.argmax(bad[row]))
                raise DataError(f"{where}: {self._field_text(name, column)} is not finite at {self._sample_text(row, name != 't')}")

    def _field_text(self, name: str, column: int | None) -> str:
        """``field pos_n column 1 (east)``: the internal name, and what the column is in words."""
        if column is None:
            return f"field {name}"
        return f"field {name} column {column} ({COLUMN_NAMES[name][column]})" if name in COLUMN_NAMES else f"field {name} column {column}"

    def _sample_text(self, row: int, timed: bool = True) -> str:
        """``sample 500 of 1000 (t=4.990 s into the flight)``: 1-based, as a file's data rows are counted."""
        time = f" (t={self.t[row] - self.t[0]:.3f} s into the flight)" if timed and np.isfinite(self.t[[0, row]]).all() else ""
        return f"sample {row + 1} of {len(self.t)}{time}"

    def _check_range(self, where: str, name: str, limit: float, what: str) -> None:
        """|value| <= ``limit`` in the columns :data:`RANGES` limits of field ``name`` (DataError naming the first beyond)."""
        if getattr(self, name) is None:
            return
        values = np.abs(getattr(self, name)[:, :RANGE_COLUMNS.get(name, 3)])
        if values.max() > limit:
            row, col = np.unravel_index(int(np.argmax(values)), values.shape)
            raise DataError(
                f"{where}: {self._field_text(name, int(col))} at {self._sample_text(int(row))} is "
                f"{getattr(self, name)[row, col]:.4g}, beyond ±{limit:.4g} {what}: wrong unit or corrupt data"
            )

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def duration(self) -> float:
        """Time span t[-1] - t[0] [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def sample_rate(self) -> float:
        """Median sample rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.t)))

    def fingerprint(self) -> str:
        """A digest of the flight's recorded numbers (its row count, commands, positions, accelerometer and gyro;
        SHA-256, 16 hex digits): the same flight under any path, name or format has the same, two flights differ
        (``merge``, and every command's one-flight-once check, :func:`~quad_modelling.io.loader.check_distinct_flights`).
        Stamps, battery voltage and the derived velocity and attitude are left out: a flight and the bag converted from
        it differ there in their last bits (the bundled B7 bag and its NanoBench CSV: 2.4e-7 s, 2.4e-7 V, 7e-16)."""
        digest = hashlib.sha256(str(len(self.t)).encode())
        for name in (n for n in FINGERPRINT_FIELDS if getattr(self, n) is not None):
            digest.update(name.encode())
            digest.update(np.ascontiguousarray(getattr(self, name), dtype=np.float64).tobytes())
        return digest.hexdigest()[:16]

    def slice(self, start: int, stop: int) -> FlightLog:
        """Rows [start, stop) as a new FlightLog (copied arrays) with the same metadata."""
        changes = {
            name: getattr(self, name)[start:stop].copy()
            for name in ("t", "u", *VECTOR_FIELDS, "vbat", "omega")
            if getattr(self, name) is not None
        }
        return dataclasses.replace(self, **changes)

    def missing_sensors(self, fields=tuple(SENSORS)) -> list[str]:
        """The optional ``fields`` this flight lacks (None)."""
        return [name for name in fields if getattr(self, name) is None]

    def require(self, fields, purpose: str) -> None:
        """Raise DataError naming the first of ``fields`` this flight lacks: ``FILE: identify needs the gyro (gyro_b), ...``."""
        missing = self.missing_sensors(fields)
        if missing:
            names = " and ".join(f"the {SENSORS[name]} ({name})" for name in missing)
            raise DataError(f"{self.meta.source}: {purpose} needs {names}, which this flight does not have")

    def warn(self, message: str) -> None:
        """Record a warning about this flight in ``meta.notes['warnings']`` (printed by ``convert``, kept in the bag)."""
        self.meta.notes.setdefault("warnings", []).append(message)

    def check_input_range(self, low: float, high: float, unit: str) -> None:
        """Raise DataError naming column, row and time of the first command outside [low, high]."""
        found = first_outside(self.u, low, high)
        if found:
            row, col, _ = found
            raise DataError(
                f"{self.meta.source}: engine command u{col + 1} row {row} (t={self.t[row]:.3f} s) is "
                f"{self.u[row, col]:.6g} {unit}, outside the configured range [{low:g}, {high:g}] "
                f"of vehicle {self.meta.vehicle}"
            )

    def saturate_inputs(self, low: float, high: float, unit: str, names=("u1", "u2", "u3", "u4")) -> None:
        """Clip the commands to [low, high] in place (:func:`saturate_commands`): warnings and counts go to the notes."""
        self.u, warnings, counts = saturate_commands(self.u, self.t, low, high, self.meta.source, self.meta.vehicle, unit, names)
        for message in warnings:
            self.warn(message)
        if counts:
            self.meta.notes["saturated_commands"] = {**self.meta.notes.get("saturated_commands", {}), **counts}

    def allclose(self, other: FlightLog, rtol: float = 1e-9, atol: float = 1e-9) -> bool:
        """True when every array of both logs is equal within tolerance (metadata ignored)."""
        for name in ("t", "u", *VECTOR_FIELDS, "vbat", "omega"):
            a, b = getattr(self, name), getattr(other, name)
            if (a is None) != (b is None):
                return False
            if a is not None and (a.shape != b.shape or not np.allclose(a, b, rtol=rtol, atol=atol)):
                return False
        return True


def saturate_commands(u: np.ndarray, t: np.ndarray, low: float, high: float, where: str, vehicle: str, unit: str,
                      names=("u1", "u2", "u3", "u4"), margin: float = SATURATION_MARGIN) -> tuple[np.ndarray, list[str], dict]:
    """Clip engine commands to [low, high] as the actuator does; refuse the physically impossible.

    Returns (clipped commands, one warning per column clipped, counts per column name). A value
    more than ``margin`` x (high - low) beyond the range, or negative when ``low`` >= 0, raises
    DataError naming file, column, row and time (``t`` relative to its first sample). Warnings read
    ``FILE: column C: N values above the V input range [lo, hi] UNIT clipped (max M at row R, t=T s)``.
    """
    u = np.asarray(u, dtype=float)
    slack = margin * (high - low)
    floor = max(low - slack, 0.0) if low >= 0 else low - slack
    found = first_outside(u, floor, high + slack)
    if found:
        row, col, count = found
        raise DataError(
            f"{where}: column {names[col]} data row {row + 1} (t={t[row] - t[0]:.2f} s into the flight) is {u[row, col]:.6g}, "
            f"outside the {vehicle} input range [{low:g}, {high:g}] {unit} ({count} values outside; up to "
            f"{margin:.0%} of the range beyond it is clipped as saturation)"
        )
    warnings, counts = [], {}
    for col, name in enumerate(names):
        for side, outside, extreme in (("above", u[:, col] > high, np.argmax), ("below", u[:, col] < low, np.argmin)):
            if outside.any():
                row = int(extreme(np.where(outside, u[:, col], high if side == "above" else low)))
                counts[name] = counts.get(name, 0) + int(outside.sum())
                warnings.append(
                    f"{where}: column {name}: {int(outside.sum())} values {side} the {vehicle} input range [{low:g}, {high:g}] {unit} "
                    f"clipped ({'max' if side == 'above' else 'min'} {u[row, col]:.6g} at row {row + 1}, t={t[row] - t[0]:.2f} s)"
                )
    return np.clip(u, low, high), warnings, counts


def chosen_vehicle(given: str | None, named: str | None, where: str) -> str | None:
    """The vehicle name a flight is read with: ``given`` (``--vehicle``: a name, or the ``name`` of a file a command
    loaded) or else the one the file ``named``; DataError (one line) when both names are there and differ -- a LinkQuad
    log read as a Crazyflie would have its commands taken in the other's unit, every constant fitted to its bound. A
    YAML path given as such (not loaded yet) may name any vehicle."""
    if given and named and str(given) != str(named) and not str(given).endswith((".yaml", ".yml")):  # a FILE: any name
        raise DataError(f"{where}: the flight names vehicle {named!r}, --vehicle gives {given!r}: pass a vehicle file of "
                        f"{named!r} (name: {named} in the YAML, as identify writes it) or none")
    return given or named
