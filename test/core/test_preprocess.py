import numpy as np
import pytest

from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.preprocess import (
    TrimConfig,
    causal_derivative,
    differentiate,
    measured_variables,
    nav_acceleration,
    resample_uniform,
    smooth,
    trailing_means,
    trimmed_inputs,
    trimmed_variables,
    uniform_time_check,
)
from quad_modelling.core.variables import INDEX
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.errors import DataError


def make_log(n=1000, rate=100.0, euler=None, acc_b=None, gyro=None, u=None, t=None):
    t = np.arange(n) / rate if t is None else t
    n = len(t)
    zeros = np.zeros((n, 3))
    return FlightLog(
        t=t, u=np.full((n, 4), 1.5e-3) if u is None else u,
        acc_b=np.tile([0.0, 0.0, -GRAVITY], (n, 1)) if acc_b is None else acc_b,
        gyro_b=zeros if gyro is None else gyro, pos_n=zeros, vel_n=zeros,
        euler=zeros if euler is None else euler, meta=FlightMeta("linkquad", "test"),
    )


def test_accelerometer_at_rest_gives_zero_nav_acceleration_level_and_tilted():
    log = make_log(10)
    np.testing.assert_allclose(nav_acceleration(log), 0.0, atol=1e-12)
    # tilted 30 deg in roll at rest: specific force is -g along the N z axis seen in the body
    phi = np.deg2rad(30.0)
    f_b = np.array([0.0, -GRAVITY * np.sin(phi), -GRAVITY * np.cos(phi)])
    tilted = make_log(10, euler=np.tile([phi, 0.0, 0.3], (10, 1)), acc_b=np.tile(f_b, (10, 1)))
    np.testing.assert_allclose(nav_acceleration(tilted), 0.0, atol=1e-12)


def test_thrust_up_while_level_is_negative_z_acceleration():
    # 2 m/s^2 upwards: specific force (0, 0, -(g + 2))
    log = make_log(10, acc_b=np.tile([0.0, 0.0, -(GRAVITY + 2.0)], (10, 1)))
    np.testing.assert_allclose(nav_acceleration(log)[:, 2], -2.0)


def test_differentiated_gyro_is_angular_acceleration():
    t = np.arange(500) / 100.0
    gyro = np.column_stack([np.sin(2 * t), 0.5 * t, np.zeros_like(t)])
    log = make_log(t=t, gyro=gyro)
    acc = measured_variables(log)[:, INDEX["roll_acc"] : INDEX["yaw_acc"] + 1]
    np.testing.assert_allclose(acc[10:-10, 0], 2 * np.cos(2 * t[10:-10]), atol=5e-3)  # 0.25 % of the amplitude
    np.testing.assert_allclose(acc[:, 1], 0.5, atol=1e-9)
    assert np.allclose(differentiate(np.arange(2.0)[:, None], 0.1), 10.0)


def test_trim_uses_the_first_second_and_detrends_long_windows():
    n = 1000
    u = np.tile(np.arange(n)[:, None] * 1e-7 + 1.5e-3, (1, 4))
    log = make_log(n, u=u)
    trimmed = trimmed_inputs(log, TrimConfig(trim_s=1.0))
    np.testing.assert_allclose(trimmed[:100].mean(axis=0), 0.0, atol=1e-15)
    long = make_log(6000, u=np.tile(np.arange(6000)[:, None] * 1e-7 + 1.5e-3, (1, 4)))
    np.testing.assert_allclose(trimmed_inputs(long), 0.0, atol=1e-12)  # a pure trend is removed entirely
    variables = trimmed_variables(make_log(300, gyro=np.tile([0.1, 0.2, 0.3], (300, 1))))
    np.testing.assert_allclose(variables[:, INDEX["roll_rate"]], 0.0, atol=1e-12)


def test_smoothing_removes_noise_but_keeps_slow_motion():
    rng = np.random.default_rng(0)
    t = np.arange(1000) / 100.0
    slow = np.sin(2 * np.pi * 0.5 * t)
    noisy = slow + 0.3 * rng.standard_normal(t.size)
    smoothed = smooth(noisy, 100.0)
    assert np.std(smoothed - slow) < np.std(noisy - slow) / 3  # 5 Hz of 50 Hz Nyquist: ~sqrt(0.1) of the noise left
    np.testing.assert_allclose(smooth(slow, 100.0)[50:-50], slow[50:-50], atol=0.01)  # 0.5 Hz passes unchanged


def test_resample_fills_a_dropped_sample_and_marks_a_long_hole_as_a_gap():
    """A hole over 50 ms in every column refused the flight (a 110 ms logging dropout of a CSV), while a bag reader
    marks such holes: it is now a marked gap of the time base whose filled rows no window or segment uses."""
    from quad_modelling.core.preprocess import TIME_BASE_HOLE, marked_gaps
    from quad_modelling.core.windows import gap_free_runs, gap_rows

    t = np.delete(np.arange(300) / 100.0, 150)
    log = make_log(t=t, gyro=np.column_stack([t, 2 * t, 0 * t]))
    filled = resample_uniform(log)
    assert len(filled) == 300
    np.testing.assert_allclose(filled.gyro_b[150], [1.5, 3.0, 0.0])
    assert filled.meta.notes["resampled_filled_samples"] == 1 and not marked_gaps(filled)
    hole = make_log(t=np.concatenate([np.arange(100) / 100.0, 1.1 + np.arange(100) / 100.0]))  # rows 0.99 .. 1.10: 110 ms
    resampled = resample_uniform(hole)
    (gap,) = marked_gaps(resampled)
    assert gap.topic == TIME_BASE_HOLE and (gap.start_s, gap.end_s) == pytest.approx((0.99, 1.10))
    assert int(gap_rows(resampled).sum()) == 10 and gap_free_runs(resampled, 0, len(resampled)) == [(0, 100), (110, 210)]
    assert len(resampled.meta.notes["warnings"]) == 1 and "topic time base has no message for 0.11 s" in resampled.meta.notes["warnings"][0]
    assert not marked_gaps(hole) and "warnings" not in hole.meta.notes  # the input log's notes are its own


def test_measurement_gaps_are_found_between_stream_stamps_with_rows_inside():
    from quad_modelling.core.preprocess import interpolation_gaps

    t = np.arange(0.0, 10.0, 0.1)
    stream = np.concatenate([np.arange(0.0, 2.05, 0.1), np.arange(5.0, 10.0, 0.1)])
    assert interpolation_gaps(stream, t) == [(pytest.approx(2.0), 5.0)]
    assert interpolation_gaps(stream, t, max_gap_s=3.5) == []
    assert interpolation_gaps(stream, t[:20]) == []  # no row falls inside the gap: nothing is interpolated through it


def test_marking_gaps_replaces_earlier_gap_notes_and_keeps_other_warnings():
    from quad_modelling.core.preprocess import (
        MeasurementGap,
        gap_warnings,
        mark_measurement_gaps,
        marked_gaps,
    )

    log = make_log()
    log.warn("flight: column u1: 3 values above the range clipped")
    gap = MeasurementGap("/quad/imu", float(log.t[10]), float(log.t[80]), ("acc_b", "gyro_b"))
    mark_measurement_gaps(log, [gap])
    mark_measurement_gaps(log, [gap])  # a re-read finds it again: one warning, not two
    assert marked_gaps(log) == [gap]
    assert len(gap_warnings(log)) == 1 and len(log.meta.notes["warnings"]) == 2
    assert gap_warnings(log)[0].startswith(f"{log.meta.source}: topic /quad/imu has no message for 0.70 s (t=0.100..0.800 s into the flight)")
    mark_measurement_gaps(log, [])
    assert "measurement_gaps" not in log.meta.notes and log.meta.notes["warnings"] == ["flight: column u1: 3 values above the range clipped"]
    log.meta.notes["measurement_gaps"] = [{"topic": "/quad/imu", "start_s": "soon"}]
    with pytest.raises(DataError, match=r"notes measurement_gaps entry 0 is not a \{topic, start_s, end_s\} mapping"):
        marked_gaps(log)
    log.meta.notes["measurement_gaps"] = [{"topic": "/quad/imu", "start_s": 3.0, "end_s": 1.0}]
    with pytest.raises(DataError, match=r"notes measurement_gaps entry 0 spans 3\.\.1 s: not a time interval"):
        marked_gaps(log)
    log.meta.notes = {"warnings": "clipped"}  # notes come from a user's file: not a list is one line
    with pytest.raises(DataError, match="test: notes warnings is str, expected a list"):
        mark_measurement_gaps(log, [])


def test_causal_derivative_is_exact_on_a_quadratic_and_reads_no_later_row():
    dt = 0.01
    t = np.arange(200) * dt
    values = np.column_stack([3.0 * t**2 - t, np.full_like(t, 2.0)])
    slope = causal_derivative(values, dt)
    # rows >= 2 fit a quadratic through >= 3 past rows: exact; row 1 is the backward difference; row 0 is 0
    np.testing.assert_allclose(slope[2:], np.column_stack([6.0 * t[2:] - 1.0, np.zeros(198)]), atol=1e-9)
    np.testing.assert_allclose(slope[1], [(values[1, 0] - values[0, 0]) / dt, 0.0], atol=1e-9)
    np.testing.assert_array_equal(slope[0], [0.0, 0.0])
    noisy = values + np.random.default_rng(0).standard_normal(values.shape)
    changed = noisy.copy()
    changed[120:] += 5.0
    np.testing.assert_array_equal(causal_derivative(changed, dt)[:120], causal_derivative(noisy, dt)[:120])
    # the last row of the centred fit is the same one-sided fit: a warm start's anchor gets one derivative
    np.testing.assert_allclose(causal_derivative(noisy[:40], dt)[-1], differentiate(noisy[:40], dt)[-1], atol=1e-9)
    np.testing.assert_array_equal(differentiate(noisy, dt, causal=True), causal_derivative(noisy, dt))


def test_trailing_means_average_the_rows_up_to_each_end():
    values = 40000.0 + 1000.0 * np.random.default_rng(1).standard_normal((50, 4))
    ends = np.array([0, 3, 9, 10, 49])
    expected = np.array([values[max(0, e - 9): e + 1].mean(axis=0) for e in ends])  # 10 rows, fewer near row 0
    np.testing.assert_allclose(trailing_means(values, ends, 10), expected, rtol=1e-12)
    np.testing.assert_allclose(trailing_means(values[:, 0], ends, 1), values[ends, 0], rtol=1e-12)
    with pytest.raises(DataError, match="at least one sample"):
        trailing_means(values, ends, 0)


def test_stamp_jitter_of_receipt_times_passes_the_uniform_check_and_a_missing_sample_does_not():
    """crazyswarm2 stamps on receipt: 100 Hz with +-2 ms jitter (steps 6-14 ms) is uniform data, scored live; a step of
    twice the median is a missing sample."""
    rng = np.random.default_rng(3)
    t = np.arange(1000) / 100.0 + rng.uniform(-0.002, 0.002, 1000)
    uniform_time_check(make_log(t=np.sort(t)))
    dropped = np.delete(np.arange(1000) / 100.0, 500)
    with pytest.raises(DataError, match=r"test: sample step at row 500 \(5.010 s into the flight\) is 20.00 ms, median 10.00 ms"):
        uniform_time_check(make_log(t=dropped))


def test_a_time_jump_no_uniform_grid_can_hold_is_refused_naming_it():
    """A stamp 1e9 s off asked numpy for a 745 GiB grid (a traceback from info, convert, identify, evaluate; a review,
    session 44); a jump the grid can hold (1e4 s, 1e6 rows) is a marked gap as before."""
    from quad_modelling.core.preprocess import MAX_FILLED_ROWS, mark_time_base_holes, marked_gaps

    t = np.arange(400) / 100.0
    jumped = make_log(t=np.where(t >= 2.0, t + 1e9, t))
    for form in (resample_uniform, mark_time_base_holes):
        with pytest.raises(DataError) as info:
            form(jumped)
        assert str(info.value) == (f"test: the time jumps by {1e9 + 0.01:.6g} s after sample 200 (t = 1.99 s into the flight): a "
                                   f"uniform time base would fill {int(round((1e9 + 3.99) * 100)) + 1 - 400} rows (at most "
                                   f"{MAX_FILLED_ROWS}); a stamp is wrong")
    held = resample_uniform(make_log(t=np.where(t >= 2.0, t + 1e4, t)))
    assert len(held) == 1_000_400 and len(marked_gaps(held)) == 1


def test_each_hole_is_said_once_by_the_rule_that_marked_it():
    """A reader's gap (0.5 s rule) was restated "longer than 0.05 s" once resampling marked a hole beside it, and a
    hole of the time base whose filled rows lie inside a reader's gap of a topic stamped 3 ms later was said twice,
    by both rules: the reader's gaps keep their warnings, resampling adds its own holes only, by its rule."""
    from quad_modelling.core.preprocess import MeasurementGap, gap_warnings, mark_measurement_gaps, marked_gaps
    from quad_modelling.core.windows import gap_rows

    k = np.arange(1000)
    t = np.round(k[~(((k > 100) & (k < 161)) | ((k > 300) & (k < 331)))] / 100.0, 9)  # holes 1.00..1.61 s, 3.00..3.31 s
    log = make_log(t=t)
    reader = MeasurementGap("/quad/motor_input", 1.0, 1.61, ("u",))  # the reader's hole of the time base, over 0.5 s
    mark_measurement_gaps(log, [reader], 0.5)
    resampled = resample_uniform(log)
    (said_by_reader, said_by_resampling) = gap_warnings(resampled)
    assert "no message for 0.61 s (t=1.000..1.610 s into the flight), longer than 0.5 s" in said_by_reader
    assert "topic time base has no message for 0.31 s (t=3.000..3.310 s into the flight), longer than 0.05 s" in said_by_resampling
    assert [g.topic for g in marked_gaps(resampled)] == ["/quad/motor_input", "time base"]
    assert resampled.meta.notes["gap_rule_s"] == 0.05  # a bag written from it re-finds both
    assert gap_warnings(log) == [said_by_reader] and marked_gaps(log) == [reader]  # the input's notes are its own

    t = np.round(k[~((k > 300) & (k < 331))] / 100.0, 9)  # one hole in every column, 3.00..3.31 s
    log = make_log(t=t)
    mocap = MeasurementGap("/quad/mocap/odom", 3.003, 3.553, ("pos_n", "vel_n", "euler"))  # its stamps 3 ms later
    mark_measurement_gaps(log, [mocap], 0.5)
    resampled = resample_uniform(log)
    assert marked_gaps(resampled) == [mocap] and len(gap_warnings(resampled)) == 1
    assert "topic /quad/mocap/odom has no message for 0.55 s (t=3.003..3.553 s into the flight), longer than 0.5 s" \
        in gap_warnings(resampled)[0]
    assert np.flatnonzero(gap_rows(resampled)).tolist() == list(range(301, 356))  # the filled rows 3.01..3.30 among them


def test_the_height_of_a_flight_shorter_than_its_median_kernel_is_read_without_a_warning():
    """scipy warned (two lines on stderr before the one-line error of a 2-row flight) when the 5-row median kernel
    exceeded the flight: such a flight has no median."""
    import warnings

    from quad_modelling.core.preprocess import CONTACT_MEDIAN_SAMPLES, height_above_ground

    log = make_log(n=CONTACT_MEDIAN_SAMPLES - 2)
    log.pos_n[:, 2] = [0.0, -1.0, -0.5]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(height_above_ground(log), [0.0, 1.0, 0.5])  # NED: z down
    assert height_above_ground(make_log(n=CONTACT_MEDIAN_SAMPLES)).shape == (CONTACT_MEDIAN_SAMPLES,)
