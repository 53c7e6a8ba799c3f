"""Per-flight work fanned out over Dask: the one place that starts or joins a cluster.

A command that works flight by flight calls :func:`map_flights` (or :func:`iter_flights`) with a
module-level function ``func(path, *args)``: each call receives one flight's path (and a small
configuration), loads the flight itself and returns something small (per-flight statistics), so the
driver never holds every flight of a fleet.

* Neither ``jobs`` nor ``scheduler`` (the default): the calls run here, one after the other, and Dask is
  not even imported (no start-up cost).
* ``jobs`` = N >= 1: a local Dask cluster of N worker processes with one thread each, bound to
  127.0.0.1, dashboard off; closed when the work is done.
* ``scheduler`` = ADDRESS (``tcp://127.0.0.1:8786``): the workers of a running ``dask scheduler`` /
  ``dask worker``; they must be able to import ``quad_modelling`` and read the flight paths.

Results come back in the order of ``paths`` whatever the order the flights finish in, so a merge
over them (``core/evaluation/statistics``) gives the same numbers, bit for bit, as the serial run.
A project error raised in a worker (:class:`~quad_modelling.errors.QuadModellingError`) is raised
here as it is (the CLI prints its one line and exits 2): the first failing flight in the order of ``paths``, the one a
serial run stops at, whichever finishes first. The cluster failing under the work is one
:class:`~quad_modelling.errors.ClusterError` line too: a flight whose workers all died running it
(distributed's ``KilledWorker``: out of memory, killed by a signal, a crash in native code) names the flight;
a scheduler that stops or whose connection is lost mid-run names the scheduler and how many flights were done.
Distributed's own log lines about it are held back while the work runs (the one line says it). Docs: ``docs/scale.md``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from quad_modelling.errors import ClusterError, ConfigError, reason

CONNECT_TIMEOUT_S = 10.0
"""How long [s] ``--scheduler ADDRESS`` may take to answer before the command gives up with one line."""

ANSWER_GRACE_S = 5.0
"""Beyond :data:`CONNECT_TIMEOUT_S`, how long [s] a scheduler address that accepts the connection may take to answer
(distributed's timeout bounds the connection, not a peer that accepts and stays silent: it waited without end)."""

JOBS_PER_CORE = 4
"""``--jobs`` at most this many worker processes per core: one-thread workers beyond the cores only cost memory and
start-up (``--jobs 1000000`` grew the driver to 0.9 GB without a worker)."""

WORKER_WAIT_S = 20.0
"""How long [s] a running scheduler may take to have at least one worker before the command gives up."""

WORKER_PRELOAD = "quad_modelling.worker_setup"
"""The module a local cluster's workers import at their start (dask's ``distributed.worker.preload``): SIGINT ignored."""

LOCAL_HOST = "127.0.0.1"
"""The only interface a local cluster (``--jobs``) listens on: nothing leaves the machine."""

DROPPED_WORKER_ENVIRON = ("MALLOC_TRIM_THRESHOLD_",)
"""Of distributed's environment for new worker processes (``distributed.nanny.pre-spawn-environ``), what a local
cluster leaves out: glibc's trim threshold at 64 KiB also fixes its mmap threshold, so every array above 128 KiB
is mapped and unmapped and its pages faulted in again at each allocation. On a physics-base diagnosis case that
is +32 % wall time (8.8 s of system time in 36 s; ``diagnose --validate``: 5 min of system time in 11 min); the
one-thread BLAS settings stay. A fleet's workers hold one flight at a time, so glibc's default trimming suffices."""


def check_fanout_options(jobs: int | None, scheduler: str | None) -> None:
    """ConfigError for ``--jobs`` below 1 or given together with ``--scheduler``, or an empty ``--scheduler``."""
    if jobs is not None and scheduler is not None:
        raise ConfigError("--jobs and --scheduler exclude each other: --jobs starts a local cluster, --scheduler uses a running one")
    if jobs is not None and jobs < 1:
        raise ConfigError(f"--jobs {jobs}: the number of worker processes must be at least 1")
    most = JOBS_PER_CORE * (os.cpu_count() or 1)
    if jobs is not None and jobs > most:
        raise ConfigError(f"--jobs {jobs}: at most {most} worker processes on this machine's {os.cpu_count() or 1} core(s) "
                          f"({JOBS_PER_CORE} per core; one-thread workers beyond the cores only cost memory)")
    if scheduler is not None and not scheduler.strip():
        raise ConfigError("--scheduler '': expected a scheduler address such as tcp://127.0.0.1:8786")
    port = re.search(r":(\d+)/?$", scheduler or "")
    if port and not 0 < int(port.group(1)) <= 65535:
        raise ConfigError(f"--scheduler {scheduler}: not a scheduler address such as tcp://127.0.0.1:8786 (port "
                          f"{port.group(1)} is not in 1..65535)")


def add_fanout_arguments(parser) -> None:
    """``--jobs N`` and ``--scheduler ADDRESS`` of every command that fans out over flights."""
    parser.add_argument("--jobs", type=int, metavar="N",
                        help="per-flight work on a local Dask cluster of N worker processes (default: serial, in this process)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="per-flight work on the workers of a running Dask scheduler, e.g. tcp://127.0.0.1:8786")


@contextlib.contextmanager
def local_cluster(jobs: int) -> Iterator[Any]:
    """A ``distributed.LocalCluster`` of ``jobs`` worker processes with one thread each, listening on 127.0.0.1 only,
    dashboard off (``dashboard_address=None``); the scheduler's remaining HTTP endpoint (health, metrics) on a free
    loopback port rather than 8787, which another cluster may hold; the workers' environment without
    :data:`DROPPED_WORKER_ENVIRON`. Closed on exit."""
    import dask
    from distributed import LocalCluster

    environ = {key: value for key, value in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
               if key not in DROPPED_WORKER_ENVIRON}
    # A Ctrl-C of the process group reaches the workers too (each printed a KeyboardInterrupt traceback, 55 lines for
    # two): each ignores SIGINT from its start (WORKER_PRELOAD), and leaves it to this process, which closes the
    # cluster. While the workers start, this process notes a Ctrl-C and raises it once the cluster is under ``with``
    # (with SIGINT ignored here meanwhile, as before session 31, it was lost: the command ran on to exit 0 and wrote
    # its output). A worker still importing when it comes may print its traceback. SIGTERM stays as it is: the
    # nannies stop their workers with it.
    main = threading.current_thread() is threading.main_thread()
    held: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum)) if main else None
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ, "distributed.worker.preload": [WORKER_PRELOAD]}):
            cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, host=LOCAL_HOST, dashboard_address=None,
                                   scheduler_kwargs={"dashboard": False, "dashboard_address": f"{LOCAL_HOST}:0"},
                                   silence_logs=logging.CRITICAL)  # a task's error is raised here, not logged there
    except BaseException:
        if main:
            signal.signal(signal.SIGINT, previous)
        if held:  # a worker the Ctrl-C reached before it ignored SIGINT may have failed the start: the Ctrl-C it is
            raise KeyboardInterrupt from None
        raise
    with cluster:
        if main:
            signal.signal(signal.SIGINT, previous)
            if held:  # the cluster closes on it
                raise KeyboardInterrupt
        yield cluster


@contextlib.contextmanager
def dask_client(jobs: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A ``distributed.Client`` of a new local cluster (``jobs`` processes x 1 thread on 127.0.0.1, no
    dashboard) or of the running scheduler at ``scheduler``; ConfigError (one line) when the scheduler
    cannot be reached within :data:`CONNECT_TIMEOUT_S` or has no worker within :data:`WORKER_WAIT_S`."""
    check_fanout_options(jobs, scheduler)
    from distributed import Client

    if scheduler is None:
        with local_cluster(jobs) as cluster, Client(cluster) as client:
            yield client
        return
    try:
        client = _answering_client(Client, scheduler)
    except ConfigError:
        raise
    except (ValueError, TypeError) as err:
        raise ConfigError(f"--scheduler {scheduler}: not a scheduler address such as tcp://127.0.0.1:8786 ({reason(err)})") from err
    except (OSError, TimeoutError) as err:
        raise ConfigError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler there within {CONNECT_TIMEOUT_S:g} s "
                          f"({reason(err)})") from err
    except MemoryError as err:  # another service's first bytes (an ssh banner) read as a frame length of exabytes
        raise ConfigError(f"--scheduler {scheduler}: what answers there is no Dask scheduler (its first bytes are no Dask "
                          "message)") from err
    try:
        try:
            client.wait_for_workers(1, timeout=WORKER_WAIT_S)
        except (TimeoutError, OSError) as err:
            raise ConfigError(f"--scheduler {scheduler}: no Dask worker joined the scheduler within {WORKER_WAIT_S:g} s "
                              f"(start one with: dask worker {scheduler})") from err
        yield client
    finally:
        client.close()


def _answering_client(client_class, scheduler: str):
    """``Client(scheduler)`` made in a thread of its own, given :data:`CONNECT_TIMEOUT_S` + :data:`ANSWER_GRACE_S`:
    ConfigError (one line) when the address accepts the connection and never answers (the thread is left to the
    process's end)."""
    made: dict[str, Any] = {}

    def connect() -> None:
        try:
            made["client"] = client_class(scheduler, timeout=CONNECT_TIMEOUT_S)
        except BaseException as err:  # re-raised in the caller's thread
            made["error"] = err

    thread = threading.Thread(target=connect, name="dask-scheduler-connect", daemon=True)
    thread.start()
    thread.join(CONNECT_TIMEOUT_S + ANSWER_GRACE_S)
    if thread.is_alive():
        raise ConfigError(f"--scheduler {scheduler}: something accepted the connection there but no Dask scheduler "
                          f"answered within {CONNECT_TIMEOUT_S + ANSWER_GRACE_S:g} s")
    if "error" in made:
        raise made["error"]
    return made["client"]


@contextlib.contextmanager
def distributed_logs_held() -> Iterator[None]:
    """distributed's loggers at CRITICAL while the work runs: a lost scheduler or dead worker is reported as one
    :class:`~quad_modelling.errors.ClusterError` line, not as the client's reconnection tracebacks."""
    names = ["distributed", *(n for n in list(logging.root.manager.loggerDict) if n.startswith("distributed."))]
    levels = {name: logging.getLogger(name).level for name in names}
    for name in names:
        logging.getLogger(name).setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def lost(where: str, finished: int, total: int, err: BaseException) -> str:
    """The one line of a scheduler lost mid-run (``where``: which cluster), with the first line of distributed's text."""
    first = (str(err).strip().splitlines() or ["no details"])[0][:200]
    return (f"lost {where} after {finished} of {total} flight(s): it stopped or its connection failed "
            f"({type(err).__name__}: {first}); nothing was written, run the command again")


def iter_flights(func: Callable[..., Any], paths: Sequence, *args: Any, jobs: int | None = None, scheduler: str | None = None,
                 progress: Callable[[int, Any, Any], None] | None = None) -> Iterator[Any]:
    """``func(path, *args)`` for every path, yielded in the order of ``paths`` (module docstring).

    ``progress(index, path, result)`` is called once per finished flight, in the order they finish. A worker's
    result is released from the cluster as soon as it is yielded, so a consumer that keeps only a
    running merge holds one flight's result at a time (plus those that finished ahead of their turn).
    """
    check_fanout_options(jobs, scheduler)
    if jobs is None and scheduler is None:
        for index, path in enumerate(paths):
            result = func(path, *args)
            if progress:
                progress(index, path, result)
            yield result
        return
    from concurrent.futures import CancelledError

    from distributed import KilledWorker, as_completed
    from distributed.comm.core import CommClosedError

    where = f"the Dask scheduler at {scheduler}" if scheduler else f"the local Dask cluster (--jobs {jobs})"
    finished = 0
    with distributed_logs_held(), dask_client(jobs, scheduler) as client:
        run = uuid.uuid4().hex  # task keys unique on a scheduler other commands may share
        futures = []
        try:
            futures = [client.submit(func, path, *args, pure=False, key=f"{getattr(func, '__name__', 'task')}-{run}-{index}")
                       for index, path in enumerate(paths)]
            order = {future.key: index for index, future in enumerate(futures)}
            done: dict[int, Any] = {}
            completed: set[int] = set()
            next_index = 0
            for future in as_completed(futures):
                index = order[future.key]
                failing = index  # the flight an error is named after
                try:
                    try:
                        done[index] = future.result()  # re-raises a worker's exception as it is (BagError, an OSError, too)
                    except (KilledWorker, CancelledError):
                        raise
                    except Exception:  # the serial run's error: an earlier flight's own, if one fails too
                        for failing in (earlier for earlier in range(index) if earlier not in completed):
                            futures[failing].result()
                        failing = index
                        raise
                    completed.add(index)
                except KilledWorker as err:
                    raise ClusterError(f"flight {paths[failing]}: every Dask worker that ran it died ({type(err).__name__}: "
                                       "killed for memory, by a signal, or a crash in native code) on "
                                       f"{where}; run it alone without --jobs/--scheduler to see why") from err
                except CancelledError as err:  # distributed cancels every future when the scheduler is lost
                    raise ClusterError(lost(where, finished, len(paths), err)) from err
                finished += 1
                future.release()
                if progress:
                    progress(index, paths[index], done[index])
                while next_index in done:
                    yield done.pop(next_index)
                    next_index += 1
        except (CancelledError, CommClosedError) as err:  # submitting or waiting when the scheduler is gone
            raise ClusterError(lost(where, finished, len(paths), err)) from err
        finally:
            for future in futures:
                future.cancel()


def map_flights(func: Callable[..., Any], paths: Sequence, *args: Any, jobs: int | None = None, scheduler: str | None = None,
                progress: Callable[[int, Any, Any], None] | None = None) -> list:
    """The list of :func:`iter_flights`: ``[func(path, *args) for path in paths]``, serially or on Dask."""
    return list(iter_flights(func, paths, *args, jobs=jobs, scheduler=scheduler, progress=progress))


def tty_progress(verb: str, total: int, stream=None) -> Callable[[int, Any, Any], None] | None:
    """A ``progress(index, path, result)`` printing ``VERB: flight k/N done: PATH`` on stderr when it is a terminal, else
    None; ``skipped`` for ``done`` when the result says the flight was left out (its ``skipped`` message, --skip-bad)."""
    import sys

    stream = stream or sys.stderr
    if not stream.isatty():
        return None
    finished = [0]

    def say(index: int, path, result=None) -> None:
        finished[0] += 1
        outcome = "skipped" if getattr(result, "skipped", None) else "done"
        print(f"{verb}: flight {finished[0]}/{total} {outcome}: {path}", file=stream, flush=True)

    return say
