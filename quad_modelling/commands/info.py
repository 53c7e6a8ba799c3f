"""``quad-modelling info``: what a bag holds."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict

from quad_modelling.io.bag_io import summarize_bag
from quad_modelling.io.loader import detect_format, load_flight

NAME = "info"
HELP = "show what a bag (topics, counts, rates) or flight log (.mat, .csv.gz, .ulg) holds"
DESCRIPTION = """\
Print what an MCAP (or SQLite) rosbag2 bag holds: for each topic its message type, count,
rate and time span, plus the bag's duration and the vehicle/source it was converted from.
For a thesis .mat log, a NanoBench CSV or a PX4 ULog: samples, duration, rate, fields and the
notes it carries (a simulated flight's effects and seed; a ULog's sources, their logged rates,
what was interpolated and the disarmed time dropped).

examples:
  quad-modelling info bags/nanobench_B7_oval_medium_rep2
  quad-modelling info bags/flight --json
  quad-modelling info flight.mat
  quad-modelling info test/data/px4/sample_px4_events.ulg
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="bag directory, .mat log, NanoBench .csv/.csv.gz or PX4 .ulg")
    parser.add_argument("--vehicle", metavar="NAME", help="vehicle for a .mat log that names none")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def _flight_info(args: argparse.Namespace) -> int:
    log = load_flight(args.bag, vehicle=args.vehicle)
    doc = {
        "path": str(args.bag),
        "vehicle": log.meta.vehicle,
        "samples": len(log),
        "duration_s": log.duration,
        "rate_hz": log.sample_rate,
        "start_s": float(log.t[0]),
        "end_s": float(log.t[-1]),
        "fields": [name for name in ("u", "acc_b", "gyro_b", "pos_n", "vel_n", "euler", "vbat", "omega") if getattr(log, name) is not None],
        "notes": log.meta.notes,
    }
    if args.json:
        print(json.dumps(doc, indent=2, default=str))
        return 0
    print(f"flight:    {doc['path']} ({detect_format(args.bag)})")
    print(f"vehicle:   {doc['vehicle']}")
    print(f"samples:   {doc['samples']} at {doc['rate_hz']:.2f} Hz, duration {doc['duration_s']:.3f} s")
    print(f"start/end: {doc['start_s']:.3f} .. {doc['end_s']:.3f} s")
    print(f"fields:    {', '.join(doc['fields'])}")
    for key, value in log.meta.notes.items():
        if isinstance(value, dict):
            print(f"{key}:")
            for name, entry in value.items():
                print(f"  {name + ':':<15} {entry}")
        else:
            print(f"{key + ':':<10} {value}")
    return 0


def run(args: argparse.Namespace) -> int:
    if detect_format(args.bag) != "bag":
        return _flight_info(args)
    summary = summarize_bag(args.bag)
    if args.json:
        doc = asdict(summary)
        for topic, entry in zip(summary.topics, doc["topics"]):
            entry["rate_hz"] = topic.rate_hz
        print(json.dumps(doc, indent=2))
        return 0
    print(f"bag:       {summary.path}")
    print(f"storage:   {summary.storage}")
    print(f"duration:  {summary.duration_s:.3f} s")
    print(f"start/end: {summary.start_s:.3f} .. {summary.end_s:.3f} s (header time)")
    print(f"messages:  {summary.message_count}")
    for key in ("vehicle", "source"):
        if f"quad_modelling.{key}" in summary.custom_data:
            print(f"{key + ':':<10} {summary.custom_data[f'quad_modelling.{key}']}")
    width = max(len(t.name) for t in summary.topics) if summary.topics else 5
    print(f"\n{'topic':<{width}}  {'type':<28} {'count':>7} {'rate Hz':>8} {'span s':>8}")
    for t in summary.topics:
        print(f"{t.name:<{width}}  {t.msgtype:<28} {t.count:>7} {t.rate_hz:>8.2f} {t.end_s - t.start_s:>8.2f}")
    return 0
