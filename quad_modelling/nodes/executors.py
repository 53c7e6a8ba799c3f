"""How a node process runs: the rclpy executor it spins on (parameter ``executor``; ``run-bag --executor``), its
scheduling (parameter ``realtime_priority``: :func:`set_realtime_priority`) and its math libraries' thread pools
(parameter ``math_threads``: :func:`limit_math_threads`).

Importing this module does not import rclpy (the CLI reads :data:`EXECUTORS`).
"""

from __future__ import annotations

import os
import sys

SPIN_TIMEOUT_S = 0.2
"""Longest single wait of a node's spin loop [s]: a node ends at most this long after Ctrl-C or SIGTERM (the
signal's handler runs in Python when the wait returns; ``run_node``)."""

EXECUTORS = ("events", "single")
"""rclpy executors a node can spin on (parameter ``executor``):

* ``events``: ``rclpy.experimental.EventsExecutor`` (rclpy 7.1, Jazzy). Its queue of ready
  events is kept in C++, so a message costs no Python wait-set rebuild: on this 2-core
  machine the whole graph plays the bundled bag at 9.9-10.7x real time with it and
  5.9-6.0x with ``single`` (bench/bench_nodes.py). Its ``spin()`` busy-loops after Ctrl-C
  here, so nodes spin it with ``spin_once`` in a loop (:func:`spin`), which ends cleanly.
* ``single``: rclpy's ``SingleThreadedExecutor``, the reference implementation.
"""


def executor_kind(value) -> str | None:
    return None if value in EXECUTORS else f"must be one of {', '.join(EXECUTORS)}"


def make_executor(kind: str, node):
    """An executor of ``kind`` (:data:`EXECUTORS`) with ``node`` added."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        executor = EventsExecutor(context=node.context)
    else:
        from rclpy.executors import SingleThreadedExecutor

        executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    return executor


class _SignalState:
    """Whether this process is inside an executor's ``spin_once`` (where a node's callbacks run), and a signal that
    arrived there: the handler (``common.run_node``) defers it, so that Ctrl-C or SIGTERM never raises inside a
    callback (the events executor logged that as FATAL with a traceback) but right after the spin returns."""

    spinning = False
    pending: str | None = None


def interrupt(name: str) -> None:
    """A SIGINT or SIGTERM (``name``) arrived: KeyboardInterrupt now, or after the running ``spin_once`` returns."""
    if _SignalState.spinning:
        _SignalState.pending = name
        return
    raise KeyboardInterrupt(name)


def spin_once(executor, timeout_s: float) -> None:
    """``executor.spin_once`` with a signal that arrives during it raised as KeyboardInterrupt when it returns."""
    _SignalState.spinning = True
    try:
        executor.spin_once(timeout_sec=timeout_s)
    finally:
        _SignalState.spinning = False
    if _SignalState.pending is not None:
        name, _SignalState.pending = _SignalState.pending, None
        raise KeyboardInterrupt(name)


def spin(node, executor) -> None:
    """Spin ``executor`` until ``node``'s context shuts down (Ctrl-C raises KeyboardInterrupt out of it, between callbacks)."""
    while node.context.ok():
        spin_once(executor, SPIN_TIMEOUT_S)


def set_realtime_priority(priority: int) -> str | None:
    """Put every thread of this process under SCHED_FIFO at ``priority`` (1-99), or back under normal
    scheduling (SCHED_OTHER) for 0; None, or why not.

    Every thread, not just the caller: Fast DDS delivers samples on its own
    threads, which wake the executor; one of them preempted by an ordinary
    process delays the answer as much as the executor itself being preempted.
    Call it once the node and its executor exist (threads created later inherit
    the policy). Needs CAP_SYS_NICE or an RLIMIT_RTPRIO of at least
    ``priority`` (``ulimit -r``; ``rtprio`` in /etc/security/limits.conf).
    """
    policy, param = (os.SCHED_FIFO if priority else os.SCHED_OTHER), os.sched_param(priority)
    try:
        for tid in sorted(int(t) for t in os.listdir("/proc/self/task")):
            os.sched_setscheduler(tid, policy, param)
    except PermissionError:
        return (f"SCHED_FIFO priority {priority} not permitted (needs CAP_SYS_NICE or rtprio >= {priority} in "
                "/etc/security/limits.conf); running with normal scheduling")
    except (ProcessLookupError, FileNotFoundError):  # a thread ended meanwhile / no /proc: best effort
        return None
    return None


MATH_THREADS = 1
"""Default threads of the math libraries' pools in a node process (parameter ``math_threads``)."""


def limit_math_threads(threads: int) -> str:
    """Run the thread pools of the math libraries this process has loaded (numpy's and scipy's OpenBLAS, an OpenMP
    runtime, torch's intra-op pool when torch is loaded) on ``threads`` threads; 0 leaves them as the libraries
    started them (one thread per core). Returns what it set, for the log.

    Why one: a node's arrays are tiny (a batch of one state, a window of rows), where a pool's extra threads never
    pay, and an idle OpenBLAS worker spins before it sleeps: under SCHED_FIFO (``realtime_priority``, which moves
    every thread of the process) it holds the second core of a two-core flight computer against the flight stack."""
    if threads <= 0:
        return "math libraries' thread pools as they start (one thread per core)"
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=threads)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(threads)
    return f"math libraries' thread pools (BLAS, OpenMP{', torch' if torch is not None else ''}) on {threads} thread(s)"
