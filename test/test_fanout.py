"""quad_modelling.fanout: per-flight work serially or on Dask, results in input order, project errors as they are."""

from __future__ import annotations

import io
import time

import pytest

from quad_modelling import fanout
from quad_modelling.errors import ConfigError, DataError
from quad_modelling.fanout import check_fanout_options, map_flights, tty_progress


def square_or_refuse(value: int, offset: int) -> int:
    """A per-flight task: value**2 + offset; DataError for a negative value (a bad flight). Value 5 takes longer,
    so on a cluster later values finish first."""
    if value == 5:
        time.sleep(0.3)
    if value < 0:
        raise DataError(f"flight{value}.csv: column px: not a number in row 3")
    return value * value + offset


def test_serial_and_running_cluster_give_the_results_in_input_order(dask_scheduler):
    values = [5, 0, 3, 9, 1, 7, 2]
    expected = [v * v + 10 for v in values]
    finished = []
    assert map_flights(square_or_refuse, values, 10, progress=lambda i, v: finished.append(i)) == expected
    assert finished == list(range(len(values)))  # one progress call per flight
    finished.clear()
    assert map_flights(square_or_refuse, values, 10, scheduler=dask_scheduler, progress=lambda i, v: finished.append(i)) == expected
    assert sorted(finished) == list(range(len(values)))


def test_a_worker_error_is_the_project_error_naming_the_flight(dask_scheduler):
    with pytest.raises(DataError, match=r"^flight-4\.csv: column px: not a number in row 3$"):
        map_flights(square_or_refuse, [1, 2, -4, 3], 0, scheduler=dask_scheduler)


@pytest.mark.parametrize(("jobs", "scheduler", "message"), [
    (0, None, "--jobs 0: the number of worker processes must be at least 1"),
    (-3, None, "--jobs -3: the number of worker processes must be at least 1"),
    (2, "tcp://127.0.0.1:8786", "--jobs and --scheduler exclude each other"),
    (None, " ", "--scheduler '': expected a scheduler address"),
])
def test_bad_fanout_options_are_one_config_error(jobs, scheduler, message):
    with pytest.raises(ConfigError, match=message):
        check_fanout_options(jobs, scheduler)
    with pytest.raises(ConfigError, match=message):
        map_flights(square_or_refuse, [1], 0, jobs=jobs, scheduler=scheduler)


@pytest.mark.parametrize(("address", "message"), [
    ("tcp://127.0.0.1:9", "cannot connect to a Dask scheduler there within 1 s"),
    ("no-such-protocol://x", "not a scheduler address such as tcp://127.0.0.1:8786"),
    ("garbage", "not a scheduler address such as tcp://127.0.0.1:8786"),
])
def test_an_unreachable_or_malformed_scheduler_is_one_config_error(address, message, monkeypatch):
    monkeypatch.setattr(fanout, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(ConfigError, match=rf"^--scheduler {address}: {message}"):
        map_flights(square_or_refuse, [1], 0, scheduler=address)


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_is_one_line_per_finished_flight_on_a_terminal_only():
    terminal = Terminal()
    say = tty_progress("evaluate", 3, terminal)
    assert map_flights(square_or_refuse, [2, 3, 4], 0, progress=say) == [4, 9, 16]
    assert terminal.getvalue().splitlines() == [f"evaluate: flight {k}/3 done: {v}" for k, v in ((1, 2), (2, 3), (3, 4))]
    assert tty_progress("evaluate", 3, io.StringIO()) is None  # a pipe or file gets no progress lines
