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


def spin(node, executor) -> None:
    """Spin ``executor`` until ``node``'s context shuts down (Ctrl-C raises KeyboardInterrupt out of it)."""
    while node.context.ok():
        executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
