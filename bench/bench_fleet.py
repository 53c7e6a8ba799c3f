"""Fleet evaluation on Dask: 100 flights evaluated serially, with 1 and 2 local workers and through a
running scheduler; wall time, peak memory, scaling efficiency, Dask start-up cost, exact merge.

The fleet is one vehicle (the Crazyflie 2.1): the real NanoBench flights from ``../shared/data/nanobench``
when present, topped up to ``--flights`` with simulated Crazyflie flights (``quad-modelling simulate
--vehicle crazyflie21 --duration 40``, seeds 1, 2, ...; cached in ``bench/results/tmp/fleet/``).
Every run is the same command, ``quad-modelling evaluate FLIGHTS --preset short --model greybox
--model naive``, started as a subprocess; its memory is sampled every 0.1 s over its whole process tree
(psutil), so the Dask workers a ``--jobs`` run starts are counted; through a scheduler the
workers are separate processes, sampled beside it.

Figures:
- wall time per run (median of ``--repeats``), and flights per second;
- scaling efficiency of N workers: E_N = T_1 / (N * T_N), with T_1 the ``--jobs 1`` run;
- Dask start-up: a 1-flight evaluation with ``--jobs 2`` minus the serial one (cluster start and
  teardown, as a user pays it), and a bare ``LocalCluster(n_workers=2)`` + ``Client`` start;
- memory against fleet size: peak tree RSS of the serial run on 10 and on all flights (streamed
  flights: the ratio stays near 1);
- merge: four contiguous shards evaluated separately and merged with ``quad-modelling merge`` equal the one
  evaluation of all flights (every number compared), and the merge's wall time.

Usage: ``.venv/bin/python -m bench.bench_fleet [--flights 100] [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

from bench.common import RESULTS, SHARED_DATA, write_results

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "quad_modelling.cli"]
FLEET_DIR = RESULTS / "tmp" / "fleet"
SIM_DURATION_S = 40.0
"""Simulated flights as long as a NanoBench flight (~40 s), so ``--preset short`` cuts both alike [s]."""
EVALUATE_ARGS = ["--preset", "short", "--model", "greybox", "--model", "naive"]
SAMPLE_PERIOD_S = 0.1


def fleet(n_flights: int) -> list[Path]:
    """The NanoBench flights (when present) and simulated Crazyflie flights up to ``n_flights``."""
    real = sorted((SHARED_DATA / "nanobench").glob("*.csv.gz"))[:n_flights]
    FLEET_DIR.mkdir(parents=True, exist_ok=True)
    simulated = []
    for seed in range(1, n_flights - len(real) + 1):
        path = FLEET_DIR / f"sim_cf_{seed:03d}.mat"
        if not path.exists():
            subprocess.run([*CLI, "simulate", "--vehicle", "crazyflie21", "--duration", str(SIM_DURATION_S),
                            "--seed", str(seed), "-o", str(path)], check=True, cwd=REPO, stdout=subprocess.DEVNULL)
        simulated.append(path)
    return real + simulated


class TreeMemory:
    """Peak resident memory [bytes] of a process and its descendants (plus ``extra`` processes), sampled."""

    def __init__(self, pid: int, extra: list[int] = ()):
        self.root = psutil.Process(pid)
        self.extra = [psutil.Process(p) for p in extra]
        self.peak_total = 0
        self.peak_single = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                procs = [self.root, *self.root.children(recursive=True), *self.extra]
            except psutil.NoSuchProcess:
                break
            rss = []
            for proc in procs:
                try:
                    rss.append(proc.memory_info().rss)
                except psutil.Error:
                    pass  # the process ended between listing and sampling: nothing left to count
            if rss:
                self.peak_total = max(self.peak_total, sum(rss))
                self.peak_single = max(self.peak_single, max(rss))
            self._stop.wait(SAMPLE_PERIOD_S)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def run_evaluate(paths: list[Path], output: Path, extra_args: list[str], watch: list[int] = ()) -> dict:
    """One ``evaluate`` run: wall time [s], peak tree RSS and largest process [MiB]."""
    shutil.rmtree(output, ignore_errors=True)
    command = [*CLI, "evaluate", *map(str, paths), *EVALUATE_ARGS, *extra_args, "--skip-bad", "-o", str(output)]
    start = time.perf_counter()
    proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    memory = TreeMemory(proc.pid, list(watch))
    out, err = proc.communicate()
    wall = time.perf_counter() - start
    memory.stop()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:6])} ... exited {proc.returncode}: {err.strip()[-500:]}")
    return {"wall_s": wall, "peak_tree_mib": memory.peak_total / 2**20, "peak_process_mib": memory.peak_single / 2**20}


def repeated(label: str, repeats: int, paths, output, extra_args, watch=()) -> dict:
    runs = [run_evaluate(paths, output, extra_args, watch) for _ in range(repeats)]
    walls = [r["wall_s"] for r in runs]
    summary = {"label": label, "flights": len(paths), "runs": runs, "wall_median_s": statistics.median(walls),
               "wall_min_s": min(walls), "wall_max_s": max(walls),
               "peak_tree_mib": max(r["peak_tree_mib"] for r in runs),
               "peak_process_mib": max(r["peak_process_mib"] for r in runs)}
    summary["flights_per_s"] = len(paths) / summary["wall_median_s"]
    print(f"{label}: {summary['wall_median_s']:.1f} s median ({min(walls):.1f}-{max(walls):.1f}), "
          f"peak tree {summary['peak_tree_mib']:.0f} MiB", flush=True)
    return summary


class RunningScheduler:
    """``dask scheduler`` and ``workers`` ``dask worker`` processes on 127.0.0.1 (1 thread each)."""

    def __init__(self, workers: int):
        self.workdir = Path(tempfile.mkdtemp(prefix="qm_dask_"))
        scheduler_file = self.workdir / "scheduler.json"
        start = time.perf_counter()
        self.procs = [subprocess.Popen(["dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                                        "--dashboard-address", ":0", "--scheduler-file", str(scheduler_file)],
                                       env=self._env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                       start_new_session=True)]
        while not scheduler_file.exists():
            time.sleep(0.05)
            if time.perf_counter() - start > 60:
                raise RuntimeError("dask scheduler did not start in 60 s")
        time.sleep(0.2)
        self.address = json.loads(scheduler_file.read_text())["address"]
        for _ in range(workers):
            self.procs.append(subprocess.Popen(["dask", "worker", self.address, "--nthreads", "1", "--nworkers", "1",
                                                "--host", "127.0.0.1", "--dashboard-address", ":0", "--no-nanny"],
                                               env=self._env(), cwd=self.workdir, stdout=subprocess.DEVNULL,
                                               stderr=subprocess.DEVNULL, start_new_session=True))
        from distributed import Client

        with Client(self.address, timeout=60) as client:
            client.wait_for_workers(workers, timeout=60)
        self.startup_s = time.perf_counter() - start

    @staticmethod
    def _env() -> dict:
        env = dict(os.environ)
        env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
        env["PYTHONPATH"] = str(REPO)
        return env

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self.procs]

    def close(self) -> None:
        for proc in reversed(self.procs):
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass  # already exited
        for proc in self.procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
        shutil.rmtree(self.workdir, ignore_errors=True)


def bare_cluster_start(repeats: int) -> list[float]:
    """Seconds to start ``LocalCluster(n_workers=2)`` + ``Client`` and close them, in a fresh interpreter each."""
    code = ("import time; t=time.perf_counter(); from distributed import LocalCluster, Client; "
            "c=LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host='127.0.0.1', dashboard_address=None); "
            "cl=Client(c); cl.wait_for_workers(2); print(time.perf_counter()-t); cl.close(); c.close()")
    runs = []
    for _ in range(repeats):
        out = subprocess.run([sys.executable, "-c", code], cwd=REPO, check=True, capture_output=True, text=True).stdout
        runs.append(float(out.strip().splitlines()[-1]))
    return runs


def numbers(results_json: Path):
    """Every number of a results.json, path -> value, for an exact comparison (flight lists and notes left out)."""
    flat = {}

    def walk(node, path):
        if isinstance(node, dict):
            for key, value in node.items():
                if key not in ("flights", "sources", "notes", "config_source"):
                    walk(value, f"{path}/{key}")
        elif isinstance(node, list):
            for i, value in enumerate(node):
                walk(value, f"{path}[{i}]")
        elif isinstance(node, (int, float)) and not isinstance(node, bool):
            flat[path] = node
    walk(json.loads(results_json.read_text()), "")
    return flat


def compare(a: Path, b: Path) -> dict:
    x, y = numbers(a), numbers(b)
    keys = sorted(set(x) | set(y))
    differ = [k for k in keys if k not in x or k not in y
              or not (x[k] == y[k] or (isinstance(x[k], float) and math.isnan(x[k]) and math.isnan(y[k])))]
    return {"numbers": len(keys), "differing": len(differ), "first_differing": differ[:5]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    paths = fleet(args.flights)
    n_real = sum(1 for p in paths if p.name.endswith(".csv.gz"))
    print(f"fleet: {len(paths)} flights ({n_real} NanoBench, {len(paths) - n_real} simulated)", flush=True)
    work = RESULTS / "tmp" / "fleet_runs"
    work.mkdir(parents=True, exist_ok=True)

    runs = {
        "serial": repeated("serial", args.repeats, paths, work / "serial", []),
        "jobs1": repeated("--jobs 1", args.repeats, paths, work / "jobs1", ["--jobs", "1"]),
        "jobs2": repeated("--jobs 2", args.repeats, paths, work / "jobs2", ["--jobs", "2"]),
    }
    scheduler = RunningScheduler(workers=2)
    try:
        runs["scheduler2"] = repeated("--scheduler (2 workers)", args.repeats, paths, work / "scheduler", ["--scheduler", scheduler.address],
                                      watch=scheduler.pids)
    finally:
        scheduler.close()
    equal = {name: compare(work / "serial" / "results.json", work / name.replace("scheduler2", "scheduler") / "results.json")
             for name in ("jobs1", "jobs2", "scheduler2")}

    one = paths[:1]
    startup = {"evaluate_1_flight_serial": repeated("1 flight serial", args.repeats, one, work / "one_serial", []),
               "evaluate_1_flight_jobs2": repeated("1 flight --jobs 2", args.repeats, one, work / "one_jobs2", ["--jobs", "2"]),
               "bare_local_cluster_s": bare_cluster_start(args.repeats),
               "running_scheduler_start_s": scheduler.startup_s}
    startup["jobs2_overhead_s"] = (startup["evaluate_1_flight_jobs2"]["wall_median_s"]
                                   - startup["evaluate_1_flight_serial"]["wall_median_s"])

    small = repeated("serial, 10 flights", 1, paths[:10], work / "serial10", [])
    memory_ratio = runs["serial"]["peak_tree_mib"] / small["peak_tree_mib"]

    size = math.ceil(len(paths) / 4)
    shards = [paths[i:i + size] for i in range(0, len(paths), size)]
    shard_dirs = []
    for i, shard in enumerate(shards):
        shard_dirs.append(work / f"shard{i}")
        run_evaluate(shard, shard_dirs[-1], [])
    merged = work / "merged"
    shutil.rmtree(merged, ignore_errors=True)
    start = time.perf_counter()
    subprocess.run([*CLI, "merge", *map(str, shard_dirs), "-o", str(merged)], check=True, cwd=REPO, capture_output=True)
    merge_s = time.perf_counter() - start
    # Contiguous shards merged in order sum the windows in the flights' order: bitwise equal is the target.
    merged_vs_serial = compare(work / "serial" / "results.json", merged / "results.json")
    merged_close = _close(work / "serial" / "results.json", merged / "results.json")

    t1 = runs["jobs1"]["wall_median_s"]
    efficiency = {"jobs2": t1 / (2 * runs["jobs2"]["wall_median_s"]), "scheduler2": t1 / (2 * runs["scheduler2"]["wall_median_s"])}
    data = {"flights": len(paths), "nanobench": n_real, "simulated": len(paths) - n_real, "evaluate_args": EVALUATE_ARGS,
            "runs": runs, "scaling_efficiency": efficiency, "equal_to_serial": equal, "startup": startup,
            "memory_10_flights": small, "memory_ratio_all_to_10": memory_ratio,
            "merge": {"shards": 4, "wall_s": merge_s, "exactly_equal": merged_vs_serial, "max_relative_difference": merged_close},
            "load_average": os.getloadavg()}
    write_results("fleet", data, markdown(data))
    return 0


def _close(a: Path, b: Path) -> float:
    x, y = numbers(a), numbers(b)
    worst = 0.0
    for key in set(x) & set(y):
        if isinstance(x[key], float) and not (math.isnan(x[key]) or math.isnan(y[key])):
            worst = max(worst, abs(x[key] - y[key]) / max(abs(x[key]), 1e-300))
    return worst


def markdown(d: dict) -> str:
    r = d["runs"]
    rows = ["| run | wall median [s] (min-max) | flights/s | peak RSS, process tree [MiB] | largest process [MiB] |",
            "|---|---|---|---|---|"]
    for key in ("serial", "jobs1", "jobs2", "scheduler2"):
        x = r[key]
        rows.append(f"| {x['label']} | {x['wall_median_s']:.1f} ({x['wall_min_s']:.1f}-{x['wall_max_s']:.1f}) | "
                    f"{x['flights_per_s']:.2f} | {x['peak_tree_mib']:.0f} | {x['peak_process_mib']:.0f} |")
    s = d["startup"]
    eq = d["equal_to_serial"]
    lines = [f"# Fleet evaluation on Dask ({d['flights']} flights: {d['nanobench']} NanoBench, {d['simulated']} simulated Crazyflie)",
             "", f"`quad-modelling evaluate FLIGHTS {' '.join(d['evaluate_args'])}`; load average at the end "
             f"{d['load_average'][0]:.1f}.", "", *rows, "",
             f"- Scaling efficiency E = T(--jobs 1) / (2 T(2 workers)): --jobs 2 {d['scaling_efficiency']['jobs2']:.2f}, "
             f"scheduler with 2 workers {d['scaling_efficiency']['scheduler2']:.2f}.",
             f"- Equal to serial (every number in results.json): --jobs 1 {eq['jobs1']['differing']} of {eq['jobs1']['numbers']} differ, "
             f"--jobs 2 {eq['jobs2']['differing']}, scheduler {eq['scheduler2']['differing']}.",
             f"- Dask start-up: a 1-flight evaluation costs {s['jobs2_overhead_s']:.1f} s more with --jobs 2 than serial; "
             f"a bare LocalCluster(2) + Client starts in {statistics.median(s['bare_local_cluster_s']):.1f} s (median); "
             f"the running scheduler and its 2 workers took {s['running_scheduler_start_s']:.1f} s to start.",
             f"- Memory against fleet size (serial): {d['memory_10_flights']['peak_tree_mib']:.0f} MiB for 10 flights, "
             f"{r['serial']['peak_tree_mib']:.0f} MiB for {d['flights']} (ratio {d['memory_ratio_all_to_10']:.2f}).",
             f"- Merge of 4 shards ({d['merge']['wall_s']:.1f} s): {d['merge']['exactly_equal']['differing']} of "
             f"{d['merge']['exactly_equal']['numbers']} numbers differ bitwise from the one evaluation, largest relative "
             f"difference {d['merge']['max_relative_difference']:.1e}."]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
