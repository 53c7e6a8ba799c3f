"""The nodes' console entry points (``replay``, ``predictor``, ``greybox_predictor``, ``narx_predictor``, ``evaluator``).

A node's module imports rclpy, numpy and its model's libraries before its ``main`` installs the signal handlers
(:func:`quad_modelling.nodes.common.run_node`); a Ctrl-C in that second ended with a KeyboardInterrupt traceback.
Here the module is imported inside a guard: interrupted, the node says so in one line and exits 130 (128 + SIGINT,
as a shell reports it), as it does once started. This module imports nothing heavy itself.
"""

from __future__ import annotations

import importlib
import signal
import sys
import threading

EXIT_INTERRUPTED = 130
"""Exit code of a node interrupted while starting or stopped by a signal before it was built (128 + SIGINT, as a
shell reports it)."""


def run(module: str, name: str) -> int:
    """``quad_modelling.nodes.<module>.main()``; exit 130 with one line when interrupted while importing it (SIGINT
    is taken first even when the process started with it ignored, as a background job does)."""
    if threading.current_thread() is threading.main_thread():  # only the main thread may set signal handlers
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:
        main = importlib.import_module(f"quad_modelling.nodes.{module}").main
    except KeyboardInterrupt:
        print(f"{name}: interrupted while starting", file=sys.stderr)
        return EXIT_INTERRUPTED
    return main()


def replay() -> int:
    return run("replay_node", "replay")


def predictor() -> int:
    return run("predictor_node", "predictor")


def greybox_predictor() -> int:
    return run("greybox_predictor_node", "greybox_predictor")


def narx_predictor() -> int:
    return run("narx_predictor_node", "narx_predictor")


def evaluator() -> int:
    return run("evaluator_node", "evaluator")
