"""Measurements checked against each other (core/consistency.py)."""

import numpy as np

from quad_modelling.core.consistency import frame_disagreements
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.physics.rigid_body import GRAVITY
from test.core.test_preprocess import make_log


def test_frame_disagreements_name_gravity_off_and_a_flipped_velocity_axis():
    """At rest the accelerometer's -g up (FRD) agrees with a level attitude; read in FLU (+g) it puts gravity 2 g off.
    A circle at 0.5 m/s whose velocity E axis is flipped: correlation -1 on E, the N axis agrees."""
    assert frame_disagreements(make_log()) == []
    flipped = make_log(acc_b=np.tile([0.0, 0.0, GRAVITY], (1000, 1)))
    assert frame_disagreements(flipped) == [
        "test: the attitude and the accelerometer disagree on where gravity is: R f_B + g averages (0.00, 0.00, 19.62) m/s² N "
        "over the flight, not about 0 (check the attitude's quaternion order and the frames of attitude and accelerometer)"]
    level = make_log()
    t = level.t
    circle = FlightLog(t=t, u=level.u, acc_b=level.acc_b, gyro_b=level.gyro_b, euler=level.euler, meta=level.meta,
                       pos_n=np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)]) * 0.5,
                       vel_n=np.column_stack([-np.sin(t), -np.cos(t), np.zeros_like(t)]) * 0.5)  # E flipped
    assert frame_disagreements(circle) == [
        "test: the velocity's E axis does not follow the position's derivative (correlation -1.00): check the frames of "
        "position and velocity"]


def test_every_reader_is_checked_one_motor_in_another_unit_and_a_battery_in_millivolts_are_said():
    """consistency_warnings runs on every flight read (it ran on topic-map bags only: a CSV motor column in 0..1 next
    to PWM ones, a battery in mV, a ULog's position in mm read without a word); a log that never took off idles, its
    commands are no mistake; a flight with non-finite values is not judged."""
    from quad_modelling.core.consistency import consistency_warnings

    log = make_log(u=np.tile([30000.0, 31000.0, 32000.0, 33000.0], (1000, 1)))
    log.pos_n = np.zeros((len(log), 3))  # make_log's arrays share one zeros array
    log.pos_n[500:, 2] = -1.0  # it takes off (NED: z down)
    assert consistency_warnings(log, 0.0, 65535.0) == []
    log.u[:, 0] = 0.5
    log.vbat = np.full(len(log), 3900.0)
    assert consistency_warnings(log, 0.0, 65535.0) == [
        "test: motor 1's commands reach 0.0% of the input range [0, 65535] (99th percentile), the others' 47% or more: "
        "check that motor's unit or column",
        "test: the battery reads 3900 V (median), above the 100 V of any multirotor pack: check its unit (mV read as V?)"]
    log.pos_n[:, 2] = 0.0  # on the ground all along: its idle commands are no mistake
    log.vbat = None
    assert consistency_warnings(log, 0.0, 65535.0) == []
    flipped = make_log(acc_b=np.tile([0.0, 0.0, GRAVITY], (1000, 1)))  # gravity 2 g off
    assert len(consistency_warnings(flipped, 0.0, 3e-3)) == 1
    flipped.acc_b[10] = np.nan  # a marked gap's row: not judged
    assert consistency_warnings(flipped, 0.0, 3e-3) == []
