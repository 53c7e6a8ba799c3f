"""Streams on their own clocks (core.stream_alignment): values at an anchor time, stamps a real link delivers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quad_modelling.core.stream_alignment import CONFIRM, MeasurementTrack, Stamp, StampGate

MS = 1_000_000


def test_exact_stamps_are_returned_as_stored_and_between_them_the_value_is_linear_in_time():
    track = MeasurementTrack(2, max_gap_ns=50 * MS)
    track.add(100 * MS, [1.0, -2.0])
    track.add(108 * MS, [3.0, 2.0])
    assert track.at(100 * MS, 0) is track.values[0]  # bit-equal: an aligned replay gives the offline numbers
    assert np.allclose(track.at(102 * MS, 0), [1.5, -1.0])  # 2/8 of the way
    assert np.allclose(track.at(106 * MS, 0), [2.5, 1.0])
    assert track.covers(108 * MS) and not track.covers(108 * MS + 1)


def test_quaternions_interpolate_along_the_shorter_rotation_and_stay_unit():
    track = MeasurementTrack(4, max_gap_ns=50 * MS, quaternion=(0, 4))
    a = Rotation.from_euler("z", 10, degrees=True).as_quat()
    b = -Rotation.from_euler("z", 30, degrees=True).as_quat()  # the same attitude, the other sign
    track.add(0, a)
    track.add(10 * MS, b)
    q = track.at(5 * MS, 0)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    assert abs(Rotation.from_quat(q).as_euler("zyx", degrees=True)[0] - 20.0) < 1e-9  # half-way: 20°, not via 200°


def test_a_gap_is_never_interpolated_through_only_the_nearest_sample_within_tolerance_is_used():
    track = MeasurementTrack(1, max_gap_ns=50 * MS)
    track.add(0, [0.0])
    track.add(200 * MS, [10.0])  # a 200 ms motion-capture dropout
    assert track.at(100 * MS, tolerance_ns=20 * MS) is None
    assert track.at(15 * MS, tolerance_ns=20 * MS)[0] == 0.0
    assert track.at(190 * MS, tolerance_ns=20 * MS)[0] == 10.0
    assert track.at(230 * MS, tolerance_ns=20 * MS) is None  # newer than anything held, beyond tolerance
    assert track.at(215 * MS, tolerance_ns=20 * MS)[0] == 10.0


def test_track_keeps_order_refuses_duplicates_and_is_bounded():
    track = MeasurementTrack(1, max_gap_ns=50 * MS, capacity=3)
    for ns in (30, 10, 20):
        assert track.add(ns * MS, [ns])
    assert not track.add(20 * MS, [99])
    assert track.stamps == [10 * MS, 20 * MS, 30 * MS] and track.at(20 * MS, 0)[0] == 20
    track.add(40 * MS, [40])
    assert track.stamps == [20 * MS, 30 * MS, 40 * MS] and len(track) == 3


def admit_all(gate, stamps):
    return [gate.admit(ns) for ns in stamps]


def test_single_stamps_from_the_future_or_the_past_are_dropped_and_the_stream_goes_on():
    gate = StampGate(max_step_ns=1000 * MS)
    regular = [k * 10 * MS for k in range(10)]
    verdicts = admit_all(gate, regular[:5])
    assert gate.admit(10 ** 6 * 10 ** 9) is Stamp.SUSPECT  # one stamp 1e6 s ahead
    verdicts += admit_all(gate, regular[5:7])
    assert gate.dropped == [] and verdicts.count(Stamp.ACCEPTED) == 7
    gate.admit(70 * MS)
    assert gate.admit(5 * MS) is Stamp.SUSPECT  # one from the past
    assert gate.admit(80 * MS) is Stamp.ACCEPTED and gate.dropped == [5 * MS]
    assert gate.admit(80 * MS) is Stamp.SUSPECT  # a duplicate
    assert gate.admit(90 * MS) is Stamp.ACCEPTED and gate.dropped == [80 * MS] and gate.last == 90 * MS


def test_a_restarted_publisher_or_a_clock_jump_is_a_new_time_base_after_three_consistent_stamps():
    gate = StampGate(max_step_ns=1000 * MS)
    admit_all(gate, [5000 * MS + k * 10 * MS for k in range(20)])
    back = [k * 10 * MS for k in range(CONFIRM)]  # the publisher restarted: stamps from an earlier flight time
    verdicts = [gate.admit(ns, payload=ns) for ns in back]
    assert verdicts == [Stamp.SUSPECT] * (CONFIRM - 1) + [Stamp.JUMPED]
    assert gate.confirmed == back and gate.last == back[-1]
    assert gate.admit(back[-1] + 10 * MS) is Stamp.ACCEPTED
    forward = [10 ** 12 + k * 10 * MS for k in range(CONFIRM)]  # a wall/sim clock jump 1000 s ahead
    assert admit_all(gate, forward)[-1] is Stamp.JUMPED


def test_inconsistent_suspects_never_make_a_time_base():
    gate = StampGate(max_step_ns=1000 * MS)
    admit_all(gate, [0, 10 * MS])
    wild = [10 ** 15, 5 * 10 ** 15, 2 * 10 ** 15, 9 * 10 ** 15]  # scattered garbage, each far from the previous
    assert all(v is Stamp.SUSPECT for v in admit_all(gate, wild))
    assert gate.admit(20 * MS) is Stamp.ACCEPTED and gate.last == 20 * MS


def test_gate_refuses_a_non_positive_step():
    with pytest.raises(ValueError, match="max_step_ns"):
        StampGate(0)
