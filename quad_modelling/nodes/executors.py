"""The rclpy executors the nodes spin on (parameter ``executor``; ``run-bag --executor``).

Importing this module does not import rclpy (the CLI reads :data:`EXECUTORS`).
"""

from __future__ import annotations

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
