"""The one span grammar and the one window clock (core/windows.py): every span form, its errors, and
offline cuts equal to the live stamp assignment on jittered stamps."""

import dataclasses
import math

import numpy as np
import pytest

from quad_modelling.core.evaluation.windowed import (
    SpanScores,
    evaluate_window,
    window_mean,
)
from quad_modelling.core.models.base import ConstantStatePredictor
from quad_modelling.core.training.narx import span_indices
from quad_modelling.core.preprocess import (
    MeasurementGap,
    TrimConfig,
    mark_measurement_gaps,
    resample_uniform,
)
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import (
    EvaluationConfig,
    SpanSpec,
    WindowClock,
    gap_free_runs,
    gap_rows,
    parse_drop,
    plan_windows,
    rows_between,
    seconds_spans,
    span_segments,
    span_windows,
    windows_between,
)
from quad_modelling.errors import ConfigError
from test.conftest import synthetic_log

from .flightgen import linear_flight


@pytest.fixture(scope="module")
def linkquad():
    return load_vehicle("linkquad")


@pytest.mark.parametrize(("text", "expected"), [
    ("30:150", (30.0, 150.0, False)),
    ("0.5:.75", (0.5, 0.75, False)),
    (" 20 : inf ", (20.0, math.inf, False)),
    ("0:INF", (0.0, math.inf, False)),
    ("0%:60%", (0.0, 0.6, True)),
    ("60 %:100%", (0.6, 1.0, True)),
])
def test_every_span_form_parses_to_its_bounds_and_back(text, expected):
    span = SpanSpec.parse("train", text)
    assert (span.start, span.end, span.relative) == expected
    assert SpanSpec.parse("train", span.text()) == span


@pytest.mark.parametrize(("text", "reason"), [
    ("30", "expected START:END"),
    ("1:2:3", "expected START:END"),
    ("a:b", "bound 'a' is not a non-negative number"),
    ("-5:10", "bound '-5' is negative; e.g. 30:150"),
    ("1e1:2e1x", "bound '2e1x' is not a non-negative number"),
    ("10%:20", "both bounds in seconds or both in percent"),
    ("0%:inf", "both bounds in seconds or both in percent"),
    ("inf:inf", "START must be finite"),
    ("50:40", "need 0 <= START < END seconds"),
    ("0%:120%", "0 <= START < END <= 100"),
    ("inf%:1%", "not a non-negative number"),
])
def test_bad_spans_name_the_text_and_what_is_wrong(text, reason):
    with pytest.raises(ConfigError, match="span train") as err:
        SpanSpec.parse("train", text)
    assert repr(text) in str(err.value) and reason in str(err.value)


def test_named_spans_use_the_same_parser_and_live_spans_are_unique_seconds():
    assert SpanSpec.parse_named("eval:150:190") == SpanSpec("eval", 150.0, 190.0, False)
    assert SpanSpec.parse_named("live:0:inf") == SpanSpec("live", 0.0, math.inf, False)
    assert SpanSpec.parse_named("a:0%:50%") == SpanSpec("a", 0.0, 0.5, True)
    for bad in ("eval", ":0:10", "eval:0", "eval:0:1:2"):
        with pytest.raises(ConfigError, match="expected NAME:START:END"):
            SpanSpec.parse_named(bad)
    with pytest.raises(ConfigError, match="span eval '10:5': need 0 <= START < END"):
        SpanSpec.parse_named("eval:10:5")
    assert [s.name for s in seconds_spans(["a:0:10", "b:10:15"])] == ["a", "b"]
    with pytest.raises(ConfigError, match="unique"):
        seconds_spans(["a:0:10", "a:10:15"])
    with pytest.raises(ConfigError, match="live spans are seconds"):
        seconds_spans(["a:0%:50%"])
    with pytest.raises(ConfigError, match="at least one span"):
        seconds_spans([])
    live = SpanSpec.parse_named("b:10:15")
    assert live.covers(10.0, 15.0) and not live.covers(5.0, 10.0) and not live.covers(10.0, 20.0)


def test_drops_are_two_finite_seconds():
    assert parse_drop("30:22") == (30.0, 22.0)
    assert parse_drop("3.5:.5") == (3.5, 0.5)
    for bad, reason in (("30", "expected START:END"), ("5%:5%", "finite seconds"), ("0:inf", "finite seconds"),
                        ("x:1", "not a non-negative number"),
                        ("-5:0", "START -5 is negative; --drop START:END gives the seconds dropped at take-off and at landing, "
                                 "each >= 0, e.g. 30:22 (0:0 drops nothing)"), (" 5:-0.5", "END -0.5 is negative")):
        with pytest.raises(ConfigError, match="--drop") as err:
            parse_drop(bad)
        assert reason in str(err.value)
    config = EvaluationConfig.from_options("short", "2:3", train="10:20")
    assert (config.drop_start, config.drop_end, config.train, config.eval) == (2.0, 3.0, "10:20", "60%:100%")


def _live_windows(stamps: np.ndarray, window_s: float, rows: int) -> dict[int, list[int]]:
    """Rows per window as the live nodes assign them: origin = first stamp, dt from the first steps."""
    clock = WindowClock(window_s, 0.2)
    clock.origin_ns = int(stamps[0])
    for ns in stamps[: WindowClock.PERIOD_SAMPLES + 1]:
        clock.observe(int(ns))
    assigned: dict[int, list[int]] = {}
    for row, ns in enumerate(stamps):
        assigned.setdefault(clock.locate(int(ns))[0], []).append(row)
    return {k: r for k, r in assigned.items() if len(r) == rows}


def test_offline_cut_equals_the_live_assignment_on_jittered_stamps():
    rng = np.random.default_rng(3)
    dt_ns, rows = 10_000_000, 100  # 100 Hz, 1 s windows
    nominal = 5_000_000_000 + dt_ns * np.arange(2050, dtype=np.int64)
    stamps = nominal + rng.integers(-4_000_000, 4_000_001, size=nominal.size)  # jitter up to 4 ms < dt/2
    stamps[0] = nominal[0]
    offline = WindowClock(1.0, 0.2, dt_ns / 1e9, origin_ns=int(stamps[0])).cut(stamps)
    live = _live_windows(stamps, 1.0, rows)
    assert len(offline) == 20  # 20.5 s of stamps: the remainder is not a window
    assert [(r[0], r[-1] + 1) for _, r in sorted(live.items())] == offline
    assert offline[0] == (0, 100) and offline[-1] == (1900, 2000)
    # one dropped stamp keeps its window (99 of 100 rows, longest step <= 28 ms: the coverage rule of
    # core.alignment, as the live evaluator scores it); six in a row (a gap over 50 ms) leave it out, as live marks it
    one = np.delete(stamps, 555)
    cut = WindowClock(1.0, 0.2, dt_ns / 1e9, origin_ns=int(one[0])).cut(one)
    assert len(cut) == 20 and (500, 599) in cut and (599, 699) in cut
    gap = np.delete(stamps, range(550, 556))
    cut = WindowClock(1.0, 0.2, dt_ns / 1e9, origin_ns=int(gap[0])).cut(gap)
    assert len(cut) == 19 and (500, 594) not in cut and (594, 694) in cut


def test_flight_windows_on_jittered_stamps_follow_the_clock(linkquad):
    log = linear_flight(linkquad, duration=30.0)
    jitter = np.random.default_rng(5).uniform(-0.004, 0.004, len(log))
    jitter[0] = 0.0
    log = dataclasses.replace(log, t=log.t + jitter)
    assert windows_between(log, 0.0, math.inf, 10.0) == [(0, 1000), (1000, 2000), (2000, 3000)]
    assert windows_between(log, 2.5, 25.0, 10.0) == [(250, 1250), (1250, 2250)]
    assert windows_between(log, 2.5, 22.49, 10.0) == [(250, 1250)]  # the second ends past the span
    assert rows_between(log, 2.5, 25.0) == (250, 2500)
    config = EvaluationConfig.preset("short", window_s=5.0)
    # flying part 5..25 s: 0%:60% = 5..17 s -> two 5 s windows from 5 s
    assert [(w.start, w.stop) for w in span_windows(log, SpanSpec.parse("train", config.train), config)] == [(500, 1000), (1000, 1500)]


def test_narx_training_rows_follow_the_evaluation_row_rule(linkquad):
    log = linear_flight(linkquad, duration=30.0)
    # 24.384 s lies between samples 2438 and 2439: the half-period rule takes the nearest sample as the
    # boundary, as the evaluation's segments do (before: the first sample at or after the bound)
    assert span_indices(log, (5.0, 24.384)) == rows_between(log, 5.0, 24.384) == (500, 2438)
    assert span_indices(log, (5.0, 24.386)) == (500, 2439)


def test_window_mean_is_the_mean_over_windows():
    rms = [np.array([1.0, 2.0]), np.array([3.0, 6.0]), np.array([2.0, 1.0])]
    np.testing.assert_allclose(window_mean(rms), [2.0, 3.0])
    scores = SpanScores.over_windows(rms, [np.array([0.5, 0.0])] * 3)
    assert scores.windows == 3 and scores.tic.tolist() == [0.5, 0.0] and scores.rms.tolist() == [2.0, 3.0]


def test_a_predictor_trimmed_otherwise_than_the_evaluation_is_refused(linkquad):
    window = linear_flight(linkquad, duration=12.0).slice(0, 1000)
    naive = ConstantStatePredictor(linkquad)
    with pytest.raises(ConfigError, match="model naive trims its prediction with"):
        evaluate_window(naive, window, 20, TrimConfig(trim_s=0.5), linkquad)
    same = evaluate_window(ConstantStatePredictor(linkquad, TrimConfig(trim_s=0.5)), window, 20, TrimConfig(trim_s=0.5), linkquad)
    default = evaluate_window(naive, window, 20, TrimConfig(), linkquad)
    # the measured trim differs, the error does not: the naive prediction is the same absolute signal
    np.testing.assert_allclose(same.rms, default.rms, atol=1e-12)


def gapped_flight(n: int = 3000):
    """A 30 s synthetic flight (100 Hz) whose motion capture is marked missing strictly between rows 400 and 1068."""
    log = synthetic_log(n=n)
    mark_measurement_gaps(log, [MeasurementGap("/quad/mocap/odom", float(log.t[400]), float(log.t[1068]), ("pos_n", "vel_n", "euler"))])
    return log


def test_no_window_overlaps_a_marked_measurement_gap():
    log = gapped_flight()
    assert np.flatnonzero(gap_rows(log)).tolist() == list(range(401, 1068))
    # 2 s windows from t0: [4, 6) s .. [10, 12) s hold rows inside the gap (4.00..10.68 s): left out
    expected = [(0, 200), (200, 400)] + [(a, a + 200) for a in range(1200, 3000, 200)]
    assert windows_between(log, 0.0, math.inf, 2.0) == expected
    assert len(windows_between(synthetic_log(n=3000), 0.0, math.inf, 2.0)) == 15
    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="0:30", eval="0:30", window_s=2.0)
    plan = plan_windows([resample_uniform(log)], config)  # evaluate's path: resampled, cut on the one clock
    assert [(w.start, w.stop) for w in plan["eval"]] == expected[:-1]  # the flight ends at 29.99 s: [28, 30) s is not whole


def test_segments_split_at_a_marked_gap():
    log = gapped_flight()
    assert gap_free_runs(log, 0, 3000) == [(0, 401), (1068, 3000)]
    assert gap_free_runs(log, 500, 1000) == []  # wholly inside
    assert gap_free_runs(log, 1000, 2000) == [(1068, 2000)]
    assert gap_free_runs(synthetic_log(n=300), 10, 200) == [(10, 200)]
    config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train="0:30", eval="2:20", window_s=2.0)
    assert span_segments(log, config.spans()[1], config) == [(200, 401), (1068, 2000)]  # the multi-step segments


def test_span_overlap_is_judged_for_spans_of_one_kind():
    assert EvaluationConfig().span_overlap() is None  # 30:150 and 150:190 meet, share nothing
    assert EvaluationConfig(train="30:160").span_overlap() == (
        "the training span 30:160 and the evaluation span 150:190 share 150:160: what is fitted there is scored partly in-sample")
    assert EvaluationConfig(train="0%:100%", eval="60%:100%").span_overlap().endswith("share 60%:100%: what is fitted there is scored partly in-sample")
    assert EvaluationConfig(train="0%:60%", eval="100:190").span_overlap() is None  # mixed kinds depend on the flight


def test_no_window_error_suggests_what_would_fit():
    """Seconds spans: try the short preset; the short preset already: the window or the drops are what does not fit."""
    from quad_modelling.core.windows import no_window_error

    thesis = str(no_window_error(EvaluationConfig(), [40.0]))
    assert thesis.endswith("for short flights use --preset short or relative spans such as --drop 5:5 --train 0%:60% --eval 60%:100%")
    short = str(no_window_error(EvaluationConfig.preset("short"), [12.0, 9.0]))
    assert short.endswith("the longest flight flies 2.0 s after the drops: use a shorter --window, smaller --drop, or longer flights "
                          "(a window touching a marked measurement gap is left out too: the warnings above name the gaps)")


def test_a_seconds_span_without_a_whole_window_of_the_flight_is_named():
    """run-bag --eval 40:50 on a 42.3 s bag scored nothing and said so only after the replay, as a coverage mark."""
    from quad_modelling.core.windows import spans_without_a_window

    assert spans_without_a_window(["train:0:20", "eval:40:50"], 42.26, 10.0) == [
        "span eval 40:50 holds no 10 s window of this 42.3 s flight (2.3 s of it): nothing will be scored there"]
    assert spans_without_a_window(["live:0:inf"], 42.26, 10.0) == []
    assert spans_without_a_window(["eval:50:60"], 42.26, 10.0)[0].endswith("(0.0 s of it): nothing will be scored there")
