"""Big PX4 recordings through the topic map: peak memory of reading a 6 min and a 60 min bag at PX4's native rates.

Writes (into a temporary directory) a synthetic PX4 uXRCE-DDS recording as ``ros2 bag record`` stores it (MCAP,
px4_msgs definitions stored in the bag, float32 fields, stamps in microseconds since boot), each stream at its own
rate on its own phase: vehicle_odometry 100 Hz, actuator_motors 200 Hz, sensor_combined 250 Hz, battery_status 10 Hz
(a hover with slow sinusoidal motion). Then reads it with ``load_flight`` (topic map ``px4``, vehicle px4_iris) in a
child process and records the child's peak resident set (``ru_maxrss`` of :func:`os.wait4`), the FlightLog's array
bytes and the difference: the memory beyond the result, which must not grow with the recording's length (the
messages are converted one at a time into fixed-size numpy chunks, no message objects are kept).

Run: .venv/bin/python bench/bench_topic_maps.py [--minutes 6,60]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import write_results  # noqa: E402

BOOT_US = 5_000_000
"""PX4 stamps: microseconds since boot (as test/stack_bags.py)."""

RATES_HZ = {"/fmu/out/vehicle_odometry": 100, "/fmu/out/actuator_motors": 200, "/fmu/out/sensor_combined": 250,
            "/fmu/out/battery_status": 10}
"""Native rates of the recorded streams (PX4 uXRCE-DDS defaults are of this order; motors and IMU at their own)."""

READ = """
import resource, sys
from quad_modelling.io import mapped_flight
from quad_modelling.io.loader import load_flight
streaming = []
finish = mapped_flight.FlightAssembler.finish
def measured_finish(self, notes=None):  # the peak of the streamed part, and the output arrays it has filled
    streaming.append((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, self.t_ns.nbytes + sum(a.nbytes for a in self.out.values())))
    return finish(self, notes)
mapped_flight.FlightAssembler.finish = measured_finish
if sys.argv[1] == "--imports-only":
    import quad_modelling.io.bag_io, quad_modelling.io.topic_maps, scipy.spatial.transform
    print(0, 0, 0, 0)
else:
    log = load_flight(sys.argv[1], vehicle="px4_iris")
    arrays = sum(a.nbytes for a in (log.t, log.u, log.pos_n, log.vel_n, log.euler, log.acc_b, log.gyro_b, log.vbat))
    print(len(log), arrays, *streaming[0])
"""


def write_px4_bag(path: Path, minutes: float) -> int:
    """A synthetic PX4 recording of ``minutes`` at :data:`RATES_HZ` (module doc); returns the message count."""
    from quad_modelling.io.bag_io import ForeignBagWriter
    from test.stack_bags import definitions

    f32 = np.float32
    events = []
    for k, (topic, rate) in enumerate(RATES_HZ.items()):
        n = int(minutes * 60 * rate)
        stamps = BOOT_US + 137 * k + np.arange(n, dtype=np.int64) * (1_000_000 // rate)  # own phase per stream
        events.append((stamps, np.full(n, k)))
    stamps = np.concatenate([e[0] for e in events])
    which = np.concatenate([e[1] for e in events])
    order = np.argsort(stamps, kind="stable")
    topics = list(RATES_HZ)
    nan8 = np.full(8, np.nan, dtype=f32)
    with ForeignBagWriter(path, definitions()) as writer:
        for stamp, k in zip(stamps[order].tolist(), which[order].tolist()):
            t = (stamp - BOOT_US) * 1e-6
            yaw = 0.3 * np.sin(0.05 * t)
            if k == 0:
                msg = writer.new("px4_msgs/msg/VehicleOdometry", timestamp=stamp, timestamp_sample=stamp, pose_frame=1, velocity_frame=1,
                                 position=np.array([np.sin(0.1 * t), np.cos(0.1 * t), -2.0], dtype=f32),
                                 q=np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)], dtype=f32),
                                 velocity=np.array([0.1 * np.cos(0.1 * t), -0.1 * np.sin(0.1 * t), 0.0], dtype=f32))
            elif k == 1:
                msg = writer.new("px4_msgs/msg/ActuatorMotors", timestamp=stamp, timestamp_sample=stamp,
                                 control=np.concatenate([np.full(4, 0.55 + 0.01 * np.sin(t), dtype=f32), nan8]))
            elif k == 2:
                msg = writer.new("px4_msgs/msg/SensorCombined", timestamp=stamp, gyro_rad=np.array([0.0, 0.0, 0.015], dtype=f32),
                                 accelerometer_m_s2=np.array([0.0, 0.0, -9.81], dtype=f32))
            else:
                msg = writer.new("px4_msgs/msg/BatteryStatus", timestamp=stamp, connected=True, id=1, voltage_v=f32(16.0 - t * 1e-4))
            writer.write(topics[k], stamp * 1000, msg)
    return len(stamps)


def read_peak(path: Path | str) -> dict:
    """Read the bag in a child process (``--imports-only``: only import the reader): its peak RSS, wall time, the
    FlightLog's rows and array bytes. The parent stays small (no bag, no reader imported): a child starts with the
    peak RSS of its parent on Linux (ru_maxrss is kept across fork and exec)."""
    started = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-c", READ, str(path)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    output = child.stdout.read()
    _, status, usage = os.wait4(child.pid, 0)
    if status != 0:
        raise RuntimeError(f"reading {path} failed with status {status}")
    rows, arrays, streaming_peak, filled = map(int, output.split())
    peak = usage.ru_maxrss * 1024
    return {"rows": rows, "read_s": time.perf_counter() - started, "peak_rss_mb": peak / 2**20, "flight_arrays_mb": arrays / 2**20,
            "streaming_peak_rss_mb": streaming_peak / 2**20, "streaming_output_mb": filled / 2**20}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", default="6,60", help="recording lengths [min] (default 6,60)")
    parser.add_argument("--write", nargs=2, metavar=("BAG", "MINUTES"), help=argparse.SUPPRESS)  # the writer child
    args = parser.parse_args()
    if args.write:
        print(write_px4_bag(Path(args.write[0]), float(args.write[1])))
        return 0
    baseline = read_peak("--imports-only")["peak_rss_mb"]
    cases = []
    with tempfile.TemporaryDirectory(prefix="bench_topic_maps_") as tmp:
        for minutes in map(float, args.minutes.split(",")):
            bag = Path(tmp) / f"px4_{minutes:g}min"
            started = time.perf_counter()  # written by a child: Linux keeps a parent's peak RSS in its children's
            messages = int(subprocess.run([sys.executable, __file__, "--write", str(bag), str(minutes)], check=True,
                                          stdout=subprocess.PIPE, text=True).stdout)
            written = time.perf_counter() - started
            size = sum(p.stat().st_size for p in bag.iterdir()) / 2**20
            case = {"minutes": minutes, "messages": messages, "bag_mb": size, "write_s": written, **read_peak(bag)}
            case["beyond_imports_and_result_mb"] = case["peak_rss_mb"] - baseline - case["flight_arrays_mb"]
            case["streaming_working_mb"] = case["streaming_peak_rss_mb"] - baseline - case["streaming_output_mb"]
            print(case, flush=True)
            cases.append(case)
    first, last = cases[0], cases[-1]
    data = {"rates_hz": RATES_HZ, "imports_peak_rss_mb": baseline, "cases": cases,
            "peak_ratio": last["peak_rss_mb"] / first["peak_rss_mb"],
            "streaming_working_ratio": last["streaming_working_mb"] / first["streaming_working_mb"]}
    lines = ["# Reading big PX4 recordings through the topic map", "",
             "Synthetic PX4 uXRCE-DDS bag (MCAP, definitions stored, float32, us stamps): vehicle_odometry 100 Hz, "
             "actuator_motors 200 Hz, sensor_combined 250 Hz, battery_status 10 Hz. Read with `load_flight` (map px4) in a "
             "child process; peak RSS = the child's ru_maxrss; imports = the peak RSS of a child that only imports the reader "
             f"({baseline:.0f} MB). Streaming working set = the peak RSS when the last message has been read (before the "
             "FlightLog is built) - imports - the output arrays filled so far: the message buffers, pending rows and "
             "deserialisation, what must not grow with the length. Beyond = final peak RSS - imports - the FlightLog's arrays "
             "(adds the transient copies of the FlightLog's checks and the command saturation, proportional to the result).", "",
             "| minutes | messages | bag MB | write s | read s | rows | FlightLog arrays MB | streaming working set MB | "
             "peak RSS MB | beyond MB |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {c['minutes']:g} | {c['messages']} | {c['bag_mb']:.1f} | {c['write_s']:.0f} | {c['read_s']:.1f} | {c['rows']} | "
              f"{c['flight_arrays_mb']:.1f} | {c['streaming_working_mb']:.1f} | {c['peak_rss_mb']:.0f} | "
              f"{c['beyond_imports_and_result_mb']:.0f} |" for c in cases]
    lines += ["", f"Streaming working set {last['minutes']:g} min / {first['minutes']:g} min: {data['streaming_working_ratio']:.2f}; "
                  f"peak RSS: {data['peak_ratio']:.2f} (the FlightLog itself grows with the length)."]
    write_results("topic_maps", data, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
