"""How `make test` spreads the suite over two pytest-xdist workers (``-n 2``): a test file is one unit of work, so
its module- and session-scoped fixtures (simulations, identifications, diagnoses) are built once, on one worker;
the units known to be long are handed out first, so that no long unit starts last while the other worker idles.

Two groups span several files:

* ``test/ros``: every ROS test runs on one worker, one after the other, as in a serial run: no two DDS graphs
  (or real-time publishers) compete with each other; the other worker runs the rest of the suite meanwhile. Each
  worker process holds a ROS domain of its own anyway (``test/ros/conftest.py``, ``quad_modelling.nodes.domains``).
* ``dask``: the two files that use the session-scoped local Dask cluster (``test/conftest.py::dask_scheduler``)
  share one cluster instead of starting one per worker.

Used through ``pytest_xdist_make_scheduler`` in ``test/conftest.py`` for ``-n N`` with the default ``--dist load``;
any other ``--dist`` given on the command line is xdist's own.

A test marked ``exclusive`` (a real-time DDS graph whose assertions count what arrived in time) runs alone: it waits
for the other workers' current tests to end, and they start nothing until it has ended (:func:`cpu_turn`), so it
has the machine as in a serial run.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from pathlib import Path

from xdist.scheduler import LoadScopeScheduling

GROUPS = {
    "test/ros/": "test/ros",
    "test/test_fanout.py": "dask",
    "test/commands/test_fanout.py": "dask",
}
"""Path prefix of a test file -> the unit of work it joins (files not listed are a unit each)."""

UNIT_SECONDS = {
    "test/ros": 250,
    "test/test_readme_tour.py": 85,
    "test/core/diagnosis/test_diagnosis_validation.py": 60,
    "test/commands/test_diagnose_physics.py": 65,
    "dask": 37,
    "test/core/diagnosis/test_diagnosis.py": 36,
    "test/core/sim/test_sim.py": 23,
    "test/core/sim/test_dynamics.py": 1,
    "test/core/sim/test_disturbances.py": 21,
    "test/core/models/test_hybrid.py": 10,
    "test/fuzz/test_fuzz_binary_readers.py": 9,
    "test/commands/test_identify.py": 9,
    "test/commands/test_bad_inputs.py": 9,
    "test/core/identification/test_physics_fit.py": 14,
    "test/core/diagnosis/test_effects.py": 8,
    "test/core/diagnosis/test_physics_base.py": 35,
    "test/core/diagnosis/test_physics_validation.py": 18,
    "test/io/test_topic_maps.py": 7,
    "test/core/models/test_causality.py": 7,
    "test/core/identification/test_identification.py": 7,
    "test/commands/test_evaluate.py": 6,
    "test/commands/test_diagnose.py": 6,
    "test/test_colcon_build.py": 5,
    "test/commands/test_merge.py": 5,
    "test/core/identification/test_motor_check.py": 5,
}
"""Seconds of the longest units, to order the queue: longest first; units not listed follow in xdist's order. The ROS
group by its wall time on a quiet machine (mostly waiting on DDS graphs and node start-ups: about 160 s of CPU), the
others by their CPU seconds (user + system, subprocesses included) in a ``make test`` run (bench/results/test_time.md):
the part of their cost that does not depend on the machine's load. Rough numbers suffice: only their order matters."""


def unit_of(nodeid: str) -> str:
    """The unit of work of a test id (``test/core/test_x.py::test_y[p]`` -> its file or its group)."""
    path = nodeid.split("::", 1)[0]
    return next((group for prefix, group in GROUPS.items() if path.startswith(prefix)), path)


class LongestFileFirstScheduling(LoadScopeScheduling):
    """xdist's scope scheduling with a file (or a :data:`GROUPS` group) as the scope, longest unit first."""

    def _split_scope(self, nodeid: str) -> str:
        return unit_of(nodeid)

    def _assign_work_unit(self, node) -> None:
        longest = max(self.workqueue, key=lambda unit: UNIT_SECONDS.get(unit, 0))  # the first of equals: queue order
        self.workqueue.move_to_end(longest, last=False)
        super()._assign_work_unit(node)


@contextlib.contextmanager
def _flock(path: Path, mode: int) -> Iterator[None]:
    with open(path, "a") as handle:
        fcntl.flock(handle, mode)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


@contextlib.contextmanager
def cpu_turn(item) -> Iterator[None]:
    """Around one test's setup, call and teardown on an xdist worker: an ``exclusive`` test alone, any other test
    beside the others (a readers-writer lock of two ``flock`` files in the run's base temporary directory, shared by
    its workers; the gate lets a waiting exclusive test in before the next shared one). Nothing outside xdist."""
    basetemp = item.config.option.basetemp
    if not os.environ.get("PYTEST_XDIST_WORKER") or not basetemp:
        yield
        return
    run_dir = Path(basetemp).parent
    gate, turn = run_dir / "cpu_turn.gate", run_dir / "cpu_turn.lock"
    if item.get_closest_marker("exclusive") is not None:
        with _flock(gate, fcntl.LOCK_EX), _flock(turn, fcntl.LOCK_EX):
            yield
        return
    with contextlib.ExitStack() as held:
        with _flock(gate, fcntl.LOCK_EX):
            held.enter_context(_flock(turn, fcntl.LOCK_SH))
        yield
