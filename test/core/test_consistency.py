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
