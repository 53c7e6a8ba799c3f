"""Measurements checked against each other: what a topic map's order, frame, sign or unit mistake makes of them.

A user's topic map (:mod:`quad_modelling.io.topic_maps`) reads without an error whatever frame it names, and a CSV,
ULog or mapped .mat log whatever unit its columns hold, so every flight of another tool's format is checked against
itself (:func:`consistency_warnings`, from :func:`quad_modelling.io.loader.load_flight` and the topic-map reader):
gravity from attitude and accelerometer, velocity against the position's derivative, the gyro against the attitude's
rates, the commands against the input range, the battery against any pack's voltage. A disagreement is a warning;
thresholds are set with margin against the 18 NanoBench flights (docs/formats.md quotes both).
"""

from __future__ import annotations

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.preprocess import attitude_rates, height_above_ground, nav_acceleration
from quad_modelling.core.physics.rigid_body import GRAVITY

GRAVITY_DISAGREEMENT = 0.3
"""Largest |mean a_N| / g of a flight whose attitude and accelerometer agree (:func:`frame_disagreements`): a flight
averages to Δv / T (under 0.05 g for 1 m/s over 2 s), an accelerometer's bias to well under 0.05 g; an attitude read
in the wrong quaternion order or an accelerometer in the wrong body frame puts gravity 1-2 g off."""

VELOCITY_AGREEMENT = 0.5
"""Smallest correlation, per axis, of a flight's velocity with its position's time derivative (:func:`frame_disagreements`)."""

VELOCITY_GAIN_RANGE = (0.5, 2.0)
"""Range of the position's derivative over the velocity (least squares), per N axis whose velocity or derivative
moves (:func:`frame_disagreements`): 0.997-1.001 on the NanoBench flights; a position in m read as mm gives 0.001."""

MOVING_AXIS_MPS = 0.1
"""RMS of the position's derivative [m/s] above which an axis moves enough for the velocity check."""

RATE_WINDOW_S = 0.3
"""The gyro check compares the body rates summed over this window [s] (the attitude's derivative is noisy per row)."""

RATE_AGREEMENT = 0.2
"""Smallest correlation of the gyro's windowed rates with the attitude's, per axis (:func:`frame_disagreements`); on
the 18 NanoBench flights 0.45 or more (B9 trefoil medium, yaw)."""

RATE_GAIN_RANGE = (0.25, 4.0)
"""Range of the gyro's windowed rates over the attitude's (least squares), per axis: 0.5-1.03 on the NanoBench
flights; deg/s read as rad/s is 57."""

MOVING_RATE_RAD_S = 0.05
"""RMS of the attitude's body rates [rad/s] above which an axis turns enough for the gyro check."""


COMMAND_RANGE_USE = 0.05
"""Least share of the vehicle's input range the commands' 99th percentile reaches above its low end in a flight read
through a map (:func:`unused_command_range`): a hover needs 30-70 % (NanoBench about 60 %); PX4's normalised 0..1
read with a map range [0, 100] reaches under 1 %."""


TAKE_OFF_M = 0.05
"""Height [m] above its lowest point a flight must rise for its commands' range to be judged."""

MAX_PACK_VOLTS = 100.0
"""Highest battery voltage [V] :func:`consistency_warnings` takes for a multirotor's pack (24S is about 100 V; a
Crazyflie's 1S 4.2 V read in mV is 4200)."""


def unused_command_range(log: FlightLog, low: float, high: float) -> str | None:
    """A warning when the commands (or one motor's) stay within :data:`COMMAND_RANGE_USE` of the low end of the input
    range [``low``, ``high``] (a map's commands ``range`` in the wrong unit, one CSV column in 0..1: nothing is refused,
    the models see no thrust), else None."""
    tops = [float(np.nanpercentile(u, 99)) if np.isfinite(u).any() else low for u in np.asarray(log.u, dtype=float).T]
    uses = [(top - low) / (high - low) for top in tops]
    if min(uses) >= COMMAND_RANGE_USE:
        return None
    if max(uses) < COMMAND_RANGE_USE:
        return (f"{log.meta.source}: the commands reach {max(uses):.1%} of the input range [{low:g}, {high:g}] (99th "
                f"percentile); a flying vehicle's commands reach {COMMAND_RANGE_USE:.0%} or more: check the commands' range")
    motor = int(np.argmin(uses))  # one motor in another unit (a CSV column in 0..1 next to PWM ones)
    return (f"{log.meta.source}: motor {motor + 1}'s commands reach {uses[motor]:.1%} of the input range [{low:g}, {high:g}] "
            f"(99th percentile), the others' {min(u for i, u in enumerate(uses) if i != motor):.0%} or more: check that "
            "motor's unit or column")


def consistency_warnings(log: FlightLog, low: float, high: float) -> list[str]:
    """:func:`frame_disagreements` and :func:`unused_command_range` (input range [``low``, ``high``]) of any flight
    read, not only through a map: a CSV's motors in 0..1, a ULog's accelerometer in g or position in mm all read
    without a word. The command range is judged only for a flight that rose :data:`TAKE_OFF_M` (a log on the ground
    idles), nothing for a flight with non-finite values or stamps that do not increase."""
    if len(log) < 3 or not np.all(np.diff(log.t) > 0) or not all(
            np.isfinite(values).all() for values in (log.pos_n, log.vel_n, log.euler, log.acc_b, log.gyro_b) if values is not None):
        return []
    flew = float(np.max(height_above_ground(log))) > TAKE_OFF_M  # idle commands on the ground are no mistake
    unused = unused_command_range(log, low, high) if flew else None
    volts = float(np.nanmedian(log.vbat)) if log.vbat is not None and np.isfinite(log.vbat).any() else 0.0
    battery = (f"{log.meta.source}: the battery reads {volts:.4g} V (median), above the {MAX_PACK_VOLTS:g} V of any "
               "multirotor pack: check its unit (mV read as V?)") if volts > MAX_PACK_VOLTS else None
    return [*frame_disagreements(log), *([unused] if unused else []), *([battery] if battery else [])]


def frame_disagreements(log: FlightLog) -> list[str]:
    r"""Warnings for a flight whose measurements disagree with each other as a mistaken frame, order or sign makes
    them: (1) the mean over the flight of :math:`a_N = R f_B + g e_z` (:func:`nav_acceleration`) is near zero when
    the attitude R and the accelerometer's specific force :math:`f_B` agree on where gravity is; above
    :data:`GRAVITY_DISAGREEMENT` g one of them is misread; (2) per N axis that moves (RMS of :math:`\dot p` above
    :data:`MOVING_AXIS_MPS`), the correlation of the velocity with the position's derivative :math:`\dot p`
    (``numpy.gradient`` over t) is at least :data:`VELOCITY_AGREEMENT`; a flipped or swapped axis gives -1 or
    about 0; and per axis whose velocity or derivative moves, :math:`\dot p` over v (least squares) lies in
    :data:`VELOCITY_GAIN_RANGE` (a unit mistake keeps the correlation). For every reader
    (:func:`consistency_warnings`)."""
    out, where = [], log.meta.source
    if log.acc_b is not None and len(log) > 1:
        mean = nav_acceleration(log).mean(axis=0)
        if np.linalg.norm(mean) > GRAVITY_DISAGREEMENT * GRAVITY:
            out.append(f"{where}: the attitude and the accelerometer disagree on where gravity is: R f_B + g averages "
                       f"({mean[0]:.2f}, {mean[1]:.2f}, {mean[2]:.2f}) m/s² N over the flight, not about 0 "
                       "(check the attitude's quaternion order and the frames of attitude and accelerometer)")
    out += _gyro_disagreements(log)
    if len(log) > 2:
        derivative = np.gradient(log.pos_n, log.t, axis=0)
        for k, axis in enumerate("NED"):
            moving = float(np.sqrt(np.mean(derivative[:, k] ** 2)))
            velocity = log.vel_n[:, k]
            if moving > MOVING_AXIS_MPS and np.std(velocity) > 0:
                correlation = float(np.corrcoef(velocity, derivative[:, k])[0, 1])
                if correlation < VELOCITY_AGREEMENT:
                    out.append(f"{where}: the velocity's {axis} axis does not follow the position's derivative "
                               f"(correlation {correlation:.2f}): check the frames of position and velocity")
                    continue
            if max(moving, float(np.sqrt(np.mean(velocity ** 2)))) > MOVING_AXIS_MPS and velocity @ velocity > 0:
                gain = float(derivative[:, k] @ velocity / (velocity @ velocity))
                if not VELOCITY_GAIN_RANGE[0] <= gain <= VELOCITY_GAIN_RANGE[1]:
                    out.append(f"{where}: on the {axis} axis the position's derivative is {gain:.3g} x the velocity, not "
                               "about 1: check the units of position and velocity")
    return out


def _gyro_disagreements(log: FlightLog) -> list[str]:
    r"""Per body axis that turns (attitude rates' RMS above :data:`MOVING_RATE_RAD_S`): the gyro's rates summed over
    :data:`RATE_WINDOW_S` against the attitude's (:func:`attitude_rates`), correlation at least
    :data:`RATE_AGREEMENT` and least-squares gain in :data:`RATE_GAIN_RANGE`; a flipped axis, an attitude or gyro in
    the wrong frame or a gyro in deg/s read as rad/s fails."""
    rows = int(round(RATE_WINDOW_S * log.sample_rate)) if len(log) > 1 else 0
    if log.gyro_b is None or rows < 2 or len(log) < 4 * rows:
        return []
    derived = attitude_rates(log)

    def windowed(values: np.ndarray) -> np.ndarray:
        total = np.cumsum(np.vstack([np.zeros((1, 3)), values]), axis=0)
        return total[rows:] - total[:-rows]
    gyro, attitude = windowed(log.gyro_b), windowed(derived)
    out = []
    for k, axis in enumerate(("roll", "pitch", "yaw")):
        if np.sqrt(np.mean(derived[:, k] ** 2)) <= MOVING_RATE_RAD_S or np.std(gyro[:, k]) == 0:
            continue
        correlation = float(np.corrcoef(gyro[:, k], attitude[:, k])[0, 1])
        gain = float(gyro[:, k] @ attitude[:, k] / (attitude[:, k] @ attitude[:, k]))
        if correlation < RATE_AGREEMENT or not RATE_GAIN_RANGE[0] <= gain <= RATE_GAIN_RANGE[1]:
            out.append(f"{log.meta.source}: the gyro's {axis} rate does not follow the attitude's (correlation "
                       f"{correlation:.2f}, gain {gain:.2f}): check the frames of attitude and gyro and the gyro's unit")
    return out
