"""Shared test helpers: synthetic flight logs, simulated flights flown once per run, the committed fixtures."""

from __future__ import annotations

import os

# One BLAS/OpenMP thread per test process (set before numpy is imported; subprocesses inherit it). The suite runs on
# two xdist workers on two cores, and its matrices are small: OpenBLAS's extra threads spin-wait for work, and on a
# busy machine a 20x20 scipy.linalg.expm costs 3 ms of CPU with them against 0.02 ms without (a 300x300 product
# 13 ms against 1.1 ms) -- the same results for a tenth of the CPU (bench/results/test_time.md).
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import fcntl  # noqa: E402
import hashlib  # noqa: E402
import pickle  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

from quad_modelling.core.flight_log import FlightLog, FlightMeta  # noqa: E402

FIXTURES = Path(__file__).parent / "fixtures"
REPO = Path(__file__).resolve().parent.parent

# DDS stays on loopback in every test process, whatever started pytest.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MPLBACKEND", "Agg")

# The fuzz suite (test/fuzz/) is reproducible: derandomized (examples follow from each test's source), no
# example database, a deadline per example that turns a hang into a failure. "ci" is the default; a longer
# search: HYPOTHESIS_PROFILE=deep.
settings.register_profile(
    "ci", derandomize=True, database=None, deadline=5000, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.register_profile("deep", parent=settings.get_profile("ci"), derandomize=False, max_examples=1000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def pytest_configure(config):
    global _CONFIG
    _CONFIG = config
    config.addinivalue_line("markers", "exclusive: runs with no other test running beside it under pytest-xdist "
                                       "(a real-time graph that counts what arrived in time; test/parallel.py)")
    config.addinivalue_line("markers", "slow: a slow scenario test, left out of `make test` and run by `make test-slow` "
                                       "(CI runs both): one that took over about 6 s in `make test --durations` "
                                       "on a slow 2-core machine")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not os.environ.get("PYTEST_XDIST_WORKER"):  # one process: nothing beside the test to wait for
        yield
        return
    from test.parallel import cpu_turn

    with cpu_turn(item):
        yield


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``-n N`` (``make test``): a file or group per worker, longest first (test/parallel.py); another --dist as given."""
    if config.getvalue("dist") != "load":
        return None
    from test.parallel import LongestFileFirstScheduling

    return LongestFileFirstScheduling(config, log)


def synthetic_log(n: int = 400, vehicle: str = "crazyflie21", seed: int = 0, rate: float = 100.0, with_optional: bool = True) -> FlightLog:
    """A smooth, plausible flight: hover-level commands, gentle attitude and yaw beyond ±π."""
    rng = np.random.default_rng(seed)
    t = 5.0 + np.arange(n) / rate
    phase = 2 * np.pi * 0.3 * (t - t[0])
    euler = np.column_stack([0.1 * np.sin(phase), -0.08 * np.cos(phase), np.linspace(-3.0, 4.0, n)])
    u_max = 65535.0 if vehicle == "crazyflie21" else 0.0021
    u_hover = 0.7 * u_max
    return FlightLog(
        t=t,
        u=u_hover * (1 + 0.02 * rng.standard_normal((n, 4))),
        acc_b=np.column_stack([0.3 * np.sin(phase), 0.2 * np.cos(phase), -9.81 + 0.1 * rng.standard_normal(n)]),
        gyro_b=0.2 * rng.standard_normal((n, 3)),
        pos_n=np.column_stack([np.cos(phase), np.sin(phase), -1.0 + 0.1 * np.sin(phase)]),
        vel_n=np.column_stack([-np.sin(phase), np.cos(phase), 0.1 * np.cos(phase)]),
        euler=euler,
        vbat=np.linspace(4.1, 3.7, n) if with_optional else None,
        omega=1500 + 10 * rng.standard_normal((n, 4)) if with_optional else None,
        meta=FlightMeta(vehicle=vehicle, source="synthetic", notes={"seed": seed}),
    )


@pytest.fixture
def flight() -> FlightLog:
    return synthetic_log()


@pytest.fixture(scope="session")
def dask_scheduler():
    """The address of a running local Dask cluster (2 worker processes, 1 thread each, 127.0.0.1, no dashboard),
    shared by the fan-out tests that use ``--scheduler ADDRESS`` (started once: a cluster takes seconds)."""
    from quad_modelling.fanout import local_cluster

    with local_cluster(2) as cluster:
        yield cluster.scheduler_address


_CONFIG = None
"""This run's pytest config (pytest_configure): where :func:`simulated_run` keeps its flights."""
_SIMULATED: dict[tuple, bytes] = {}


def simulated_run(vehicle: str, effects: tuple[str, ...], seed: int, duration: float):
    """``run_simulation(vehicle, effects, seed=seed, duration=duration)`` (the vehicle's own simulator parameters),
    flown once per test run and shared by every file that needs the same flight: the simulator is deterministic in
    its seed (test/core/sim/test_sim.py), and a 90 s flight costs seconds. Under pytest-xdist the flights are shared
    between the workers through pickles in the run's base temporary directory (a lock per flight: the second
    worker waits for the first); each call returns a fresh copy, so no test sees another's changes."""
    from quad_modelling.core.sim.simulate import run_simulation

    key = (vehicle, tuple(effects), int(seed), float(duration))
    if key not in _SIMULATED:
        basetemp = _CONFIG.option.basetemp if _CONFIG is not None else None
        if not (os.environ.get("PYTEST_XDIST_WORKER") and basetemp):
            _SIMULATED[key] = pickle.dumps(run_simulation(vehicle, effects, seed=seed, duration=duration))
        else:
            folder = Path(basetemp).parent / "simulations"
            folder.mkdir(exist_ok=True)
            path = folder / f"{hashlib.sha256(repr(key).encode()).hexdigest()[:16]}.pickle"
            with open(path.with_suffix(".lock"), "a") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)
                if not path.exists():
                    staged = path.with_suffix(f".tmp-{os.getpid()}")
                    staged.write_bytes(pickle.dumps(run_simulation(vehicle, effects, seed=seed, duration=duration)))
                    os.replace(staged, path)
                _SIMULATED[key] = path.read_bytes()
    return pickle.loads(_SIMULATED[key])


def simulated(vehicle: str, effects: tuple[str, ...], seed: int, duration: float) -> FlightLog:
    """The sensor log of :func:`simulated_run` (``simulate(vehicle, effects, seed=seed, duration=duration)``)."""
    return simulated_run(vehicle, effects, seed, duration).log
