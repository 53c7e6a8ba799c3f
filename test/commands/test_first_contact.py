"""First contact: what a new user's own flight meets first. A flight too slow for any window is refused for its rate
(naming it and the rate needed), on every verb that scores, never blamed on the spans and never a traceback; a hybrid
loaded without the vehicle it was trained with names the ``--vehicle`` to pass."""

from __future__ import annotations

import numpy as np
import pytest

from quad_modelling.cli import main
from quad_modelling.core.preprocess import causal_derivative, differentiate
from quad_modelling.core.windows import MIN_SAMPLE_RATE_HZ, check_window_rate
from quad_modelling.errors import DataError
from test.conftest import REPO, synthetic_log

ULOG = REPO / "test" / "data" / "px4" / "sample_px4_events.ulg"
"""PX4 SITL take-off and landing logged at PX4's default rates: 152 samples at 10 Hz on the actuator_motors base."""

BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"

RATE_LINE = "sampled at 10 Hz (median step 100 ms); scoring needs 20 Hz or faster (a window allows no step over 50 ms), " \
            "whatever the spans: record the flight at 20 Hz or more"


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def px4_bag(tmp_path_factory):
    """The 10 Hz ULog converted to a bag (convert takes any rate: it is the scoring that cannot)."""
    bag = tmp_path_factory.mktemp("px4") / "events"
    assert main(["convert", str(ULOG), "-o", str(bag)]) == 0
    return bag


@pytest.mark.parametrize("argv", [
    ["evaluate", "{ulog}", "-o", "{out}/e"],  # the thesis's spans: too long for 15 s too, but the rate comes first
    ["evaluate", "{ulog}", "--preset", "short", "-o", "{out}/e"],
    ["evaluate", "{ulog}", "--drop", "1:1", "--train", "0%:50%", "--eval", "50%:100%", "--window", "5", "-o", "{out}/e"],  # was the polyorder traceback
    ["identify", "{ulog}", "--drop", "1:1", "--train", "0%:50%", "--eval", "50%:100%", "--window", "5", "-o", "{out}/v.yaml"],
    ["train", "{ulog}", "--drop", "1:1", "--train", "0%:60%", "--quiet", "-o", "{out}/m.npz"],
    ["diagnose", "--base", "greybox", "--train", "{ulog}", "--test", "{ulog}", "--drop", "1:1", "--window", "5", "-o", "{out}/d"],
    ["run-bag", "{bag}", "--models", "naive", "--window", "5", "-o", "{out}/live"],
], ids=["evaluate-thesis", "evaluate-short", "evaluate-window-5", "identify", "train", "diagnose", "run-bag"])
def test_a_10_hz_flight_is_refused_for_its_rate_on_every_verb_that_scores(argv, px4_bag, tmp_path, capsys):
    args = [a.format(ulog=ULOG, bag=px4_bag, out=tmp_path) for a in argv]
    assert main(args) == 2
    line = one_error_line(capsys)
    source = str(px4_bag) if argv[0] == "run-bag" else str(ULOG)
    assert line.startswith(f"quad-modelling {argv[0]}: error: {source}: {RATE_LINE}")
    assert line.endswith("add `actuator_motors 10` (interval ms) and the position and attitude topics to "
                         "etc/logging/logger_topics.txt on the SD card (docs/px4.md)")  # a PX4 log, converted or not: how
    assert "--preset" not in line and "window fits" not in line  # the spans are not blamed
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_info_reads_a_10_hz_log_and_says_no_verb_can_score_it(capsys):
    assert main(["info", str(ULOG)]) == 0
    captured = capsys.readouterr()
    assert "samples:   152 at 10.00 Hz" in captured.out
    assert captured.err.startswith(f"note: {ULOG}: {RATE_LINE}; PX4 logs actuator_motors at 10 Hz by default")


def test_skip_bad_leaves_a_too_slow_flight_out_like_an_unreadable_one(tmp_path, capsys):
    nanobench = REPO / "test" / "fixtures" / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"  # 10 s at 100 Hz
    assert main(["evaluate", str(ULOG), str(nanobench), "--skip-bad", "--drop", "0:0", "--train", "0:4", "--eval", "4:8",
                 "--window", "4", "--no-multistep", "-o", str(tmp_path / "e")]) == 1  # done, one left out
    captured = capsys.readouterr()
    assert f"skipped: {ULOG}: {RATE_LINE}" in captured.err
    assert captured.out.startswith("1 flight(s), windows train 1, eval 1")


def test_the_rate_rule_is_the_coverage_rule():
    assert MIN_SAMPLE_RATE_HZ == 20.0  # 1 / MAX_GAP_S: a window allows no step over 50 ms
    check_window_rate(synthetic_log(n=200, rate=20.0))  # 20 Hz: every step exactly 50 ms, scoreable
    with pytest.raises(DataError, match="synthetic: sampled at 19.9 Hz .* scoring needs 20 Hz or faster"):
        check_window_rate(synthetic_log(n=200, rate=19.9))


def test_the_causal_derivative_of_a_slow_log_is_a_backward_difference_not_a_traceback():
    values = np.column_stack([np.arange(8.0) ** 2, -np.arange(8.0)])
    dt = 0.1  # 10 Hz: the 0.11 s derivative window holds one sample
    causal = causal_derivative(values, dt)
    assert np.array_equal(causal[0], [0.0, 0.0])
    assert np.allclose(causal[1:], np.diff(values, axis=0) / dt)
    assert np.allclose(differentiate(values, dt)[1:-1, 1], -10.0)  # the centred form: numpy.gradient, as before


def test_run_bag_with_a_hybrid_trained_on_another_vehicle_file_says_which_vehicle_to_pass(tmp_path, capsys, monkeypatch):
    from quad_modelling.core.training.hybrid import HybridTrainingConfig, train_hybrid_on_flights
    from quad_modelling.core.training.rollout import RolloutConfig
    from quad_modelling.core.vehicle import load_vehicle
    from quad_modelling.io.loader import load_flight

    identified = tmp_path / "crazyflie21_identified.yaml"  # as identify writes: the bag's vehicle, other constants
    text = (REPO / "config" / "vehicles" / "crazyflie21.yaml").read_text()
    identified.write_text(text.replace("rotor_thrust_constant: {value: 1.788e-8,", "rotor_thrust_constant: {value: 1.9e-8,"))
    monkeypatch.chdir(tmp_path)
    vehicle = load_vehicle(identified.name)  # given relative, as a user types it: the file records the absolute path
    tiny = HybridTrainingConfig(hidden=(4,), rollout=RolloutConfig(horizon=5, batch_size=64, max_epochs=1, patience=1,
                                                                   learning_rate=3e-3, windows_per_epoch=64))
    flight = load_flight(BAG, vehicle)
    model = train_hybrid_on_flights([flight.slice(1000, 1600)], [None], vehicle, tiny, seed=0).save(tmp_path / "hybrid.npz")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the hint works from another directory
    assert main(["run-bag", str(BAG), "--models", f"hybrid:{model}", "-o", str(tmp_path / "live")]) == 2
    line = one_error_line(capsys)
    assert f"{model}: the hybrid model was trained with other physics constants of vehicle 'crazyflie21' than " in line
    assert f"(rotor_thrust_constant); pass the vehicle it was trained with: --vehicle {identified.resolve()} " in line
    assert "retrain it with" not in line and not (tmp_path / "live").exists()
