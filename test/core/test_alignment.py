"""core.alignment: the coverage rule's numbers; the one interpolation formula (exact at sample stamps, linear in
time, quaternions along the shorter rotation, never across a gap) many rows at once and in a measurement track;
stamp gates: single bad stamps vs a new time base."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quad_modelling.core.alignment import (
    CONFIRM,
    MeasurementTrack,
    Stamp,
    StampGate,
    coverage_reason,
    interpolate_at,
    lerp,
    stream_coverage,
)

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


def test_commands_stamped_in_pairs_are_judged_by_the_pairs_period():
    """A link delivering (or a stack stamping on receipt) two commands 0.1 ms apart every 20 ms: all 500 of a 5 s
    window there, the median step 0.1 ms or 19.9 ms by chance -- it read '1.0 % of 50000 nominal samples'."""
    pairs = np.sort(np.concatenate([np.arange(250) * 20 * MS, np.arange(250) * 20 * MS + 100_000]))
    both = stream_coverage("motor_input", pairs, -5 * MS, 4995 * MS)
    assert both.received == 500 and both.nominal == pytest.approx(5000 / 19.9, rel=1e-9) and both.ok
    lost = stream_coverage("motor_input", np.delete(pairs, range(200, 260)), -5 * MS, 4995 * MS)  # 0.6 s of them lost
    assert not lost.ok and lost.longest_gap_s == pytest.approx(0.6199, abs=1e-6)
    jitter = np.arange(500) * 10 * MS + np.random.default_rng(0).integers(-2 * MS, 2 * MS, 500)  # +-2 ms: as before
    assert stream_coverage("motor_input", jitter, -5 * MS, 4995 * MS).nominal == pytest.approx(
        5000 / (np.median(np.diff(jitter)) / MS), rel=1e-9)


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


def test_quaternions_interpolate_along_the_shorter_rotation_and_stay_unit():
    a = Rotation.from_euler("z", 10, degrees=True).as_quat()
    b = -Rotation.from_euler("z", 30, degrees=True).as_quat()  # the same attitude, the other sign
    for q in (lerp(a, b, 0.5, quaternion=(0, 4)), lerp(np.array([a, b]), np.array([b, a]), np.array([[0.5], [0.5]]), (0, 4))[1]):
        assert abs(np.linalg.norm(q) - 1.0) < 1e-12
        assert abs(Rotation.from_quat(q).as_euler("zyx", degrees=True)[0] - 20.0) < 1e-9  # half-way: 20 deg, not via 200 deg
    assert np.array_equal(b, -Rotation.from_euler("z", 30, degrees=True).as_quat())  # the inputs are not changed


def test_a_track_reads_the_same_numbers_as_interpolate_at_and_exact_stamps_as_stored():
    """One formula: a measurement track at a time equals the rows interpolated there, bit for bit; at a sample's own
    stamp both give the stored sample (an aligned replay gives the offline numbers)."""
    rng = np.random.default_rng(4)
    stamps = np.cumsum(rng.integers(7 * MS, 9 * MS, 40))
    values = rng.normal(size=(40, 7))
    values[:, 3:7] /= np.linalg.norm(values[:, 3:7], axis=1, keepdims=True)
    values[::3, 3:7] *= -1.0  # neighbours on opposite signs
    track = MeasurementTrack(7, max_gap_ns=50 * MS, quaternion=(3, 7))
    for ns, row in zip(stamps, values):
        track.add(int(ns), row)
    at = np.sort(rng.integers(stamps[0], stamps[-1], 200))
    rows = interpolate_at(stamps, values, at, quaternion=(3, 7))
    assert np.array_equal(np.array([track.at(int(ns), 0) for ns in at]), rows)
    assert track.at(int(stamps[5]), 0) is track.values[5]  # interpolate_at's exact rows: the test above
    line = MeasurementTrack(2, max_gap_ns=50 * MS)
    line.add(100 * MS, [1.0, -2.0])
    line.add(108 * MS, [3.0, 2.0])
    assert np.allclose(line.at(102 * MS, 0), [1.5, -1.0]) and np.allclose(line.at(106 * MS, 0), [2.5, 1.0])  # 2/8, 6/8
    assert line.covers(108 * MS) and not line.covers(108 * MS + 1)


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


def test_a_stream_too_short_to_tell_its_rate_is_described_so():
    """A window mark read 'motor_input: 0.0 % of 0 nominal samples (1 received)'."""
    from quad_modelling.core.alignment import StreamCoverage

    coverage = StreamCoverage("motor_input", received=1, nominal=0.0, longest_gap_s=0.0, gap_at_s=0.0)
    assert coverage.describe() == "motor_input: 1 sample received, too few to tell its rate" and not coverage.ok


@pytest.mark.parametrize("kept, coverage", [((0, 1), 0.4), ((0, 2, 3), 0.6), ((0, 1, 2, 3), 0.8)])
def test_a_stream_that_loses_samples_between_regular_ones_is_judged_by_its_own_period(kept, coverage):
    """A 250 Hz IMU keeping the samples ``kept`` of every 5 (steps of 4 ms and longer): the period is the short steps',
    not the long ones' (2 of 5 read '160 % of 125 nominal samples' and was scored)."""
    stamps = np.array([k for k in range(2500) if k % 5 in kept], dtype=np.int64) * 4 * MS
    lossy = stream_coverage("imu", stamps, -2 * MS, 9998 * MS)
    assert lossy.nominal == pytest.approx(2500.0) and lossy.coverage == pytest.approx(coverage) and not lossy.ok
