"""``quad-modelling info``: what a bag holds."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from quad_modelling.core.windows import check_window_rate
from quad_modelling.errors import BagError, ConfigError, DataError
from quad_modelling.io.bag_io import read_bag_metadata, summarize_bag
from quad_modelling.io.topic_maps import add_topic_map_argument, choose_topic_map
from quad_modelling.core.preprocess import mark_time_base_holes
from quad_modelling.io.loader import bag_directory, detect_format, load_flight
from quad_modelling.io.reports.info import (
    bag_json,
    bag_text,
    flight_document,
    flight_json,
    flight_text,
)

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
  quad-modelling info lab.mat --mapping config/mappings/example_lab.yaml --vehicle linkquad
  quad-modelling info test/data/px4/sample_px4_events.ulg
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="bag directory, .mat log, NanoBench .csv/.csv.gz or PX4 .ulg")
    parser.add_argument("--vehicle", metavar="NAME", help="vehicle for a .mat log that names none")
    parser.add_argument("--mapping", metavar="FILE", help="YAML variable mapping for a foreign .mat log (as convert --mapping)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    add_topic_map_argument(parser)


def run(args: argparse.Namespace) -> int:
    file_format = detect_format(args.bag)
    if args.mapping and file_format != "thesis-mat":
        raise ConfigError(f"--mapping {args.mapping}: a mapping applies to .mat logs only, {args.bag} is a {file_format} input")
    if args.topic_map and file_format != "bag":
        raise ConfigError(f"--topic-map {args.topic_map}: a topic map applies to bags only, {args.bag} is a {file_format} input")
    if file_format != "bag":
        log = load_flight(args.bag, vehicle=args.vehicle, mapping_file=args.mapping)
        mark_time_base_holes(log)  # a CSV's missing rows, as convert marks them
        document = flight_document(log, str(args.bag))
        print(flight_json(document) if args.json else flight_text(document, file_format))
        try:  # read, but too slow for any window: every scoring verb will refuse it, say so now
            check_window_rate(log)
        except DataError as err:
            print(f"note: {err}", file=sys.stderr)
        return 0
    if Path(args.bag).suffix == ".mcap" and Path(args.bag).is_file():  # a bag named by its .mcap file, as evaluate takes it
        args.bag = str(bag_directory(Path(args.bag)))
    summary = summarize_bag(args.bag)
    topics = {t.name: t.msgtype for t in summary.topics}
    mapped = None
    if args.topic_map or (topics and not any(t.startswith("/quad/") for t in topics)):
        try:  # a bag of another stack: what its topic map reads from it
            chosen = choose_topic_map(topics, str(args.bag), args.topic_map)
        except BagError as err:
            if args.topic_map:
                raise
            chosen = None  # no map matches: the topics alone, and why no flight is read from them
            print(f"note: {err}", file=sys.stderr)
        if chosen is not None and chosen.is_contract and args.topic_map and chosen.missing(topics):
            raise BagError(f"{args.bag}: topic map {chosen.name} reads {'; '.join(chosen.missing(topics))}: not in the bag")
        if chosen is not None and not chosen.is_contract:
            mapped = flight_document(load_flight(args.bag, vehicle=args.vehicle, topic_map=args.topic_map), str(args.bag))
    if args.vehicle and mapped is None:  # a bag in the contract names its vehicle: --vehicle was ignored (review)
        from quad_modelling.core.vehicle import load_vehicle

        vehicle = load_vehicle(args.vehicle)  # an unknown name or file: its one line
        recorded = read_bag_metadata(args.bag).vehicle
        if recorded and recorded != vehicle.name:
            raise ConfigError(f"--vehicle {args.vehicle}: {args.bag} was converted for vehicle {recorded}; info reports the "
                              "bag as recorded (leave --vehicle out)")
    if args.json:
        document = json.loads(bag_json(summary))
        if mapped is not None:
            document["flight"] = mapped
        print(json.dumps(document, indent=2, default=str))
    else:
        print(bag_text(summary) + ("" if mapped is None else "\n\n" + flight_text(mapped, f"bag, topic map {chosen.name}")))
    return 0
