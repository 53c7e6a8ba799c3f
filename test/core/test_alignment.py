"""core.alignment: the coverage rule's numbers, interpolation to other stamps (exact at sample stamps, nlerp,
never across a gap), outlier stamps vs clock jumps."""

import numpy as np
import pytest

from quad_modelling.core.alignment import StampGuard, coverage_reason, interpolate_at, stream_coverage

MS = 1_000_000


def test_coverage_of_a_uniform_stream_a_dropped_sample_and_a_burst_loss():
    stamps = np.arange(500, dtype=np.int64) * 10 * MS  # 100 Hz over [-5 ms, 4995 ms)
    full = stream_coverage("motor_input", stamps, -5 * MS, 4995 * MS)
    assert (full.received, full.nominal, full.coverage, full.longest_gap_s, full.ok) == (500, 500.0, 1.0, 0.010, True)
    one = stream_coverage("motor_input", np.delete(stamps, 250), -5 * MS, 4995 * MS)
    assert one.received == 499 and one.longest_gap_s == pytest.approx(0.020) and one.gap_at_s == pytest.approx(2.495) and one.ok
    burst = stream_coverage("imu", np.delete(stamps, range(100, 130)), -5 * MS, 4995 * MS)
    assert burst.coverage == pytest.approx(0.94) and burst.longest_gap_s == pytest.approx(0.310) and not burst.ok
    late = stream_coverage("mocap_odom", stamps[10:], -5 * MS, 4995 * MS)  # a late start: the edge is a gap
    assert late.longest_gap_s == pytest.approx(0.105) and late.gap_at_s == 0.0 and not late.ok
    assert stream_coverage("imu", stamps[:1], -5 * MS, 4995 * MS).coverage == 0.0
    reason = coverage_reason([full, burst])
    assert reason == ("coverage below the rule (>= 95 % of nominal samples, gaps <= 50 ms): imu: 94.0 % of 500 nominal "
                      "samples (470 received), longest gap 310 ms at 0.995 s into the window")
    assert coverage_reason([full, one]) == ""


def test_interpolation_is_exact_at_sample_stamps_linear_between_and_never_crosses_a_gap():
    stamps = np.array([0, 10, 20, 100, 110], dtype=np.int64) * MS
    values = np.array([[0.0], [1.0], [2.0], [3.0], [4.0]]) * np.pi
    at = np.array([10, 15, 60, 105, 170, 111, -40, -60], dtype=np.int64) * MS
    out = interpolate_at(stamps, values, at)[:, 0] / np.pi
    assert out[0] == 1.0 and out[1] == pytest.approx(1.5) and np.isnan(out[2]) and out[3] == pytest.approx(3.5)
    assert np.isnan(out[4]) and out[5] == 4.0 and out[6] == 0.0 and np.isnan(out[7])  # holds within 50 ms of the ends
    assert np.isnan(interpolate_at(stamps, values, np.array([111 * MS, -1 * MS]), hold=False)).all()  # a truth must be bracketed
    exact = interpolate_at(stamps, values, stamps)
    assert np.array_equal(exact, values)  # bit for bit: the aligned replay scores the recorded rows


def test_quaternions_are_interpolated_normalised_and_sign_aligned():
    half = np.pi / 8  # rotations of 0 and 45 deg about z; the second sample given with the opposite sign
    q = np.array([[0, 0, 0, 1.0], [0, 0, -np.sin(half), -np.cos(half)]])
    mid = interpolate_at(np.array([0, 10 * MS]), q, np.array([5 * MS]), quaternion=(0, 4))[0]
    assert np.linalg.norm(mid) == pytest.approx(1.0)
    angle = 2 * np.arctan2(mid[2], mid[3])
    assert angle == pytest.approx(np.pi / 8, abs=1e-3)  # nlerp half-way: 22.5 deg


def test_a_single_outlier_stamp_is_dropped_and_five_agreeing_ones_are_a_jump():
    guard = StampGuard(max_jump_s=5.0, confirm=5)
    s = 10**9
    assert [guard.check(ns) for ns in (100 * s, 101 * s, 5000 * s, 102 * s, -7 * s)] == ["accept", "accept", "outlier", "accept", "outlier"]
    assert guard.last == 102 * s
    verdicts = [guard.check(ns * s // 100) for ns in range(0, 5)]  # the publisher restarted at 0 s
    assert verdicts == ["outlier"] * 4 + ["jump"] and guard.last == 4 * s // 100
    assert guard.check(5 * s // 100) == "accept"
