"""``quad-modelling info``: what a bag holds."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict

from quad_modelling.io.bag_io import summarize_bag

NAME = "info"
HELP = "show a bag's topics, types, message counts, rates and time span"
DESCRIPTION = """\
Print what an MCAP (or SQLite) rosbag2 bag holds: for each topic its message type, count,
rate and time span, plus the bag's duration and the vehicle/source it was converted from.

example:
  quad-modelling info bags/nanobench_B7_oval_medium_rep2
  quad-modelling info bags/flight --json
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="bag directory")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args: argparse.Namespace) -> int:
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
