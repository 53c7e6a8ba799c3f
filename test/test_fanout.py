"""quad_modelling.fanout: per-flight work serially or on Dask, results in input order, project errors as they are."""

from __future__ import annotations

import io
import os
import signal
import socket
import subprocess
import sys
import time

import dask
import pytest

from quad_modelling import fanout
from quad_modelling.errors import BagError, ClusterError, ConfigError, DataError, QuadModellingError
from quad_modelling.fanout import check_fanout_options, map_flights, tty_progress
from quad_modelling.io.loader import load_flights
from quad_modelling.io.matlog import write_matlog
from test.conftest import REPO, synthetic_log


def square_or_refuse(value: int, offset: int) -> int:
    """A per-flight task: value**2 + offset; DataError for a negative value (a bad flight). Values 5 and -5 take
    longer, so on a cluster later values finish first."""
    if abs(value) == 5:
        time.sleep(0.3)
    if value <= -100:
        raise BagError(f"bag{value}: not a readable rosbag2 bag")
    if value < 0:
        raise DataError(f"flight{value}.csv: column px: not a number in row 3")
    return value * value + offset


def kill_own_worker_on_negative(value: int) -> int:
    """A per-flight task whose process dies on a negative value (as a worker killed for memory or by a crash in native
    code would); value otherwise, after a moment (so a scheduler can go away while others run)."""
    if value < 0:
        os._exit(9)
    time.sleep(0.5)
    return value


def worker_environment(_value: int) -> dict:
    """A per-flight task reporting the allocator and BLAS settings of the process it runs in."""
    return {key: os.environ.get(key) for key in ("MALLOC_TRIM_THRESHOLD_", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}


def test_local_workers_run_one_blas_thread_and_glibcs_default_trimming(dask_scheduler):
    """The shared cluster is :func:`fanout.local_cluster`'s: its workers keep distributed's one-thread BLAS settings
    but not its 64 KiB malloc trim threshold (every large array mapped afresh: +32 % wall time on a diagnosis)."""
    for environment in map_flights(worker_environment, [0, 1, 2, 3], scheduler=dask_scheduler):
        assert environment == {"MALLOC_TRIM_THRESHOLD_": None, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def worker_sigint(_value: int) -> str:
    """A per-flight task reporting how the process it runs in takes SIGINT."""
    return {signal.SIG_IGN: "ignored", signal.SIG_DFL: "default"}.get(signal.getsignal(signal.SIGINT), "handled")


def test_local_workers_leave_a_ctrl_c_to_the_process_that_started_them():
    """A Ctrl-C of the process group reached every worker too: a KeyboardInterrupt traceback each (55 lines for two)
    under the command's one line; the command closes the cluster. This process's own handler is back after."""
    def own(signum, frame):
        raise KeyboardInterrupt

    before = signal.signal(signal.SIGINT, own)
    try:
        with fanout.local_cluster(1) as cluster:
            assert signal.getsignal(signal.SIGINT) is own
            assert map_flights(worker_sigint, [0, 1], scheduler=cluster.scheduler_address) == ["ignored"] * 2
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_ctrl_c_while_the_workers_start_is_raised_once_they_run_and_closes_the_cluster():
    """A Ctrl-C while the local cluster starts its workers was lost (SIGINT ignored then, so that the workers start
    ignoring it), and the command ran on to exit 0 with its output written. Now noted, it is raised as soon as the
    cluster is under ``with``, which closes it: no worker process is left. Sent to the process (any of its threads
    may take it), as a terminal's Ctrl-C is."""
    import multiprocessing
    import threading

    def own(signum, frame):
        raise KeyboardInterrupt

    others = set(multiprocessing.active_children())  # a shared cluster's workers (the dask_scheduler fixture)
    before = signal.signal(signal.SIGINT, own)
    poke = threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT))  # a Ctrl-C while the workers start
    try:
        poke.start()
        with pytest.raises(KeyboardInterrupt):
            with fanout.local_cluster(1):
                time.sleep(5)  # not reached: the held Ctrl-C is raised on entry
                pytest.fail("the Ctrl-C during the start-up was lost")
        assert signal.getsignal(signal.SIGINT) is own
        deadline = time.monotonic() + 10
        while set(multiprocessing.active_children()) - others and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not set(multiprocessing.active_children()) - others
    finally:
        poke.cancel()
        signal.signal(signal.SIGINT, before)


def test_serial_and_running_cluster_give_the_results_in_input_order(dask_scheduler):
    values = [5, 0, 3, 9, 1, 7, 2]
    expected = [v * v + 10 for v in values]
    finished = []
    assert map_flights(square_or_refuse, values, 10, progress=lambda i, v, r: finished.append(i)) == expected
    assert finished == list(range(len(values)))  # one progress call per flight
    finished.clear()
    assert map_flights(square_or_refuse, values, 10, scheduler=dask_scheduler, progress=lambda i, v, r: finished.append(i)) == expected
    assert sorted(finished) == list(range(len(values)))


def test_a_worker_error_is_the_project_error_naming_the_flight(dask_scheduler):
    with pytest.raises(DataError, match=r"^flight-4\.csv: column px: not a number in row 3$"):
        map_flights(square_or_refuse, [1, 2, -4, 3], 0, scheduler=dask_scheduler)
    # two bad flights: the first in input order is named, as the serial run names it, though the second fails first
    with pytest.raises(DataError, match=r"^flight-5\.csv: "):
        map_flights(square_or_refuse, [1, -5, -4, 3], 0, scheduler=dask_scheduler)
    with pytest.raises(BagError, match=r"^bag-100: not a readable rosbag2 bag$"):  # an OSError too: not a lost scheduler
        map_flights(square_or_refuse, [1, -100], 0, scheduler=dask_scheduler)


@pytest.mark.parametrize(("jobs", "scheduler", "message"), [
    (0, None, "--jobs 0: the number of worker processes must be at least 1"),
    (-3, None, "--jobs -3: the number of worker processes must be at least 1"),
    (2, "tcp://127.0.0.1:8786", "--jobs and --scheduler exclude each other"),
    (None, " ", "--scheduler '': expected a scheduler address"),
    (10**6, None, "--jobs 1000000: at most .* worker processes on this machine's"),
    (None, "tcp://127.0.0.1:99999", "not a scheduler address such as tcp://127.0.0.1:8786 \\(port 99999 is not in 1..65535\\)"),
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


def test_a_scheduler_address_that_accepts_and_never_answers_is_one_config_error(monkeypatch):
    """A listener that accepts the connection and stays silent: distributed's connect timeout does not bound it (a
    review waited 200 s); the command gives up after CONNECT_TIMEOUT_S + ANSWER_GRACE_S with one line."""
    monkeypatch.setattr(fanout, "CONNECT_TIMEOUT_S", 1.0)
    monkeypatch.setattr(fanout, "ANSWER_GRACE_S", 1.0)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        started = time.monotonic()
        with pytest.raises(ConfigError, match=rf"^--scheduler {address}: something accepted the connection there but no Dask scheduler answered within 2 s$"):
            map_flights(square_or_refuse, [1], 0, scheduler=address)
        assert time.monotonic() - started < 30


def test_a_service_that_greets_first_is_no_scheduler_in_one_line():
    """An ssh server's banner read as a Dask frame length asked numpy for 2.82 EiB: a 60-line traceback."""
    import threading

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()

        def greet():
            connection, _ = server.accept()
            connection.sendall(b"SSH-2.0-OpenSSH_9.6p1 Ubuntu-3ubuntu13\r\n")
            time.sleep(5)
            connection.close()
        threading.Thread(target=greet, daemon=True).start()
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        with pytest.raises(ConfigError, match=rf"^--scheduler {address}: what answers there is no Dask scheduler"):
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


def test_progress_says_skipped_for_a_flight_left_out(tmp_path):
    good = write_matlog(synthetic_log(n=300, vehicle="linkquad"), tmp_path / "good.mat")
    bad = tmp_path / "bad.mat"  # missing
    terminal = Terminal()
    flights, skipped = load_flights([good, bad], skip_bad=True, progress=tty_progress("evaluate: read", 2, terminal))
    assert len(flights) == 1 and len(skipped) == 1
    assert terminal.getvalue().splitlines() == [f"evaluate: read: flight 1/2 done: {good}",
                                                f"evaluate: read: flight 2/2 skipped: {bad}"]


def test_a_flight_that_kills_its_worker_is_one_cluster_error_naming_it():
    # The local cluster's scheduler runs in this process: with no failure allowed, the first death is final
    # (distributed's default retries the flight on 3 more workers first: the same error, seconds later).
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with pytest.raises(ClusterError) as err:
            map_flights(kill_own_worker_on_negative, [-7], jobs=1)
    message = str(err.value)
    assert isinstance(err.value, QuadModellingError) and "\n" not in message  # the CLI's one line, exit 2
    assert message.startswith("flight -7: every Dask worker that ran it died (KilledWorker: ")
    assert "on the local Dask cluster (--jobs 1); run it alone without --jobs/--scheduler to see why" in message


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def crash_first_refuse_second(value: int) -> int:
    """A per-flight task: value 1's worker dies after a moment, value 2 is a bad flight at once."""
    if value == 1:
        time.sleep(0.5)
        os._exit(9)
    raise DataError(f"flight{value}.csv: column px: not a number in row 3")


@pytest.mark.slow
def test_a_worker_that_dies_on_an_earlier_flight_is_named_after_that_flight():
    """The first bad flight in input order is named; when that earlier one killed its worker, the cluster error names
    it, not the later flight whose own error came first."""
    with pytest.raises(ClusterError, match=r"^flight 1: every Dask worker that ran it died"):
        map_flights(crash_first_refuse_second, [1, 2], jobs=2)


@pytest.mark.slow
def test_a_scheduler_shut_down_mid_run_is_one_cluster_error_naming_it():
    address = f"tcp://127.0.0.1:{_free_port()}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port",
                                  address.rsplit(":", 1)[1], "--no-dashboard"], **quiet)
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                               "--no-dashboard", "--host", "127.0.0.1", "--no-nanny"], cwd=REPO, **quiet)
    finished = []

    def shut_down_after_the_first(index, value, result):  # progress: the scheduler stops once one flight is done
        finished.append(value)
        if len(finished) == 1:
            scheduler.send_signal(signal.SIGTERM)
            scheduler.wait(timeout=30)

    try:
        with pytest.raises(ClusterError) as err:
            map_flights(kill_own_worker_on_negative, [1, 2, 3, 4], scheduler=address, progress=shut_down_after_the_first)
    finally:
        for process in (worker, scheduler):
            process.kill()
            process.wait(timeout=30)
    message = str(err.value)
    assert "\n" not in message and finished == [1]
    assert message.startswith(f"lost the Dask scheduler at {address} after 1 of 4 flight(s): it stopped or its connection failed (")
    assert message.endswith("nothing was written, run the command again")

