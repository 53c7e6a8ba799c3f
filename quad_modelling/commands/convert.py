"""``quad-modelling convert``: thesis .mat logs / NanoBench CSV / PX4 ULog / bags -> MCAP bags (or .mat)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm import tqdm

from quad_modelling.atomic import BAG_MARKERS, atomic_output, check_bag_name, check_distinct_inputs
from quad_modelling.commands import check_command_output
from quad_modelling.core.preprocess import mark_time_base_holes
from quad_modelling.core.vehicle import VehicleConfig, vehicle_dir, vehicle_file
from quad_modelling.errors import ConfigError, DataError, QuadModellingError
from quad_modelling.io.loader import FORMATS, check_topic_map_applies, detect_format, input_format, load_flight
from quad_modelling.io.topic_maps import add_topic_map_argument, topic_map_file
from quad_modelling.io.topics import check_namespace

NAME = "convert"
HELP = "convert flight logs (.mat, NanoBench .csv.gz, PX4 .ulg, bags) into MCAP bags"
DESCRIPTION = """\
Convert flight logs into rosbag2 MCAP bags with the quad_modelling topic contract
(/quad/motor_input, /quad/mocap/odom, /quad/imu, /quad/battery), or into a thesis .mat log.

Inputs: thesis-style MATLAB logs (.mat; default variable names in docs/formats.md, or a
--mapping YAML for foreign logs), NanoBench CSV flights (.csv, .csv.gz), PX4 ULog flights
(.ulg: topics aligned on the motor-command stamps, disarmed time dropped; docs/px4.md), contract bags.
Output: with one input, OUTPUT is the bag directory (or a .mat file); with several inputs,
OUTPUT is a new directory holding one bag per input, named after it.
Nothing is overwritten without --force; a failed run leaves no output behind.
Engine commands a little beyond the vehicle's input range are clipped to it (the actuator
saturates) with one warning line per column and the count kept in the bag's notes; negative
or far-out commands are refused. A log without accelerometer/gyro (pose-only motion capture)
converts to a bag without the imu topic. A motion-capture or IMU dropout longer than 0.5 s is
marked, never interpolated through: a warning, the gap kept in the bag (no message inside it) and
its notes; a .mat output of such a flight is refused (one time base).
--vehicle-from-log VEHICLE.yaml (one PX4 .ulg input): also write a vehicle config started from
the log's parameters (rotor positions CA_ROTORn_PX/PY symmetrised, spins from CA_ROTORn_KM,
input range from the motor topic and the PWM parameters; mass, inertia and motor constants
guessed from px4_iris) and convert the log with it (docs/px4.md).

examples:
  quad-modelling convert flight.mat --vehicle linkquad -o bags/flight
  quad-modelling convert $NANOBENCH/*.csv.gz -o bags/nanobench --skip-bad
  quad-modelling convert bags/flight -o flight_copy.mat
  quad-modelling convert test/data/px4/sample_px4_events.ulg -o bags/px4_events
  quad-modelling convert test/data/px4/sample_px4_events.ulg --vehicle-from-log iris.yaml -o bags/px4_events
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="flight logs to convert")
    parser.add_argument("-o", "--output", required=True, metavar="OUTPUT", help="bag directory, .mat file, or (several inputs) output directory")
    parser.add_argument("--format", default="auto", choices=("auto", *FORMATS), help="input format (default: from the file name)")
    parser.add_argument("--mapping", metavar="FILE", help="YAML variable mapping for foreign .mat logs")
    parser.add_argument("--vehicle", metavar="NAME", help="vehicle config name or YAML path (default: from the file; crazyflie21 for NanoBench; px4_iris or px4_iris_pwm for .ulg)")
    parser.add_argument("--vehicle-from-log", metavar="VEHICLE.yaml",
                        help="one PX4 .ulg input: write a vehicle config started from the log's parameters and convert with it")
    parser.add_argument("--namespace", default="/quad", help="topic namespace in the bag (default /quad)")
    add_topic_map_argument(parser)
    parser.add_argument("--skip-bad", action="store_true", help="with several inputs: report bad ones, convert the rest, exit 1")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")


def bag_name(path: Path) -> str:
    """Output name for an input: its file name without .mat/.csv/.csv.gz/.ulg/.mcap."""
    name = path.name
    for suffix in (".csv.gz", ".csv", ".mat", ".ulg", ".mcap"):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


def _write(log, target: Path, namespace: str, force: bool) -> None:
    if target.suffix == ".mat":
        from quad_modelling.io.matlog import write_matlog

        write_matlog(log, target, force=force)
        return
    from quad_modelling.io.bag_io import write_bag

    with tqdm(total=len(log), unit="row", desc=target.name, leave=False, disable=not sys.stderr.isatty()) as bar:
        write_bag(log, target, force=force, namespace=namespace, progress=bar.update)


def _vehicle_from_log(args: argparse.Namespace, inputs: list[Path], output: Path) -> int:
    """``--vehicle-from-log``: write the vehicle the log's parameters start, convert the log with it; both or neither."""
    from quad_modelling.io.ulog_vehicle import vehicle_from_ulog, vehicle_yaml

    target = Path(args.vehicle_from_log)
    fmt = detect_format(inputs[0]) if len(inputs) == 1 and args.format == "auto" else args.format
    if len(inputs) != 1 or fmt != "px4-ulog" or args.vehicle:
        kind = f", a {fmt} input" if len(inputs) == 1 and fmt != "px4-ulog" else ""
        raise ConfigError("--vehicle-from-log takes one PX4 .ulg input and no --vehicle "
                          f"(got {len(inputs)} input(s): {', '.join(p.name for p in inputs[:3])}{kind}"
                          f"{', --vehicle' if args.vehicle else ''})")
    if target.suffix not in (".yaml", ".yml"):
        raise ConfigError(f"--vehicle-from-log {args.vehicle_from_log!r}: the vehicle file must end in .yaml or .yml")
    ours, bag = target.resolve(), output.resolve()
    if ours == bag or bag in ours.parents or ours in bag.parents:
        raise ConfigError(f"--vehicle-from-log {target} and -o {output} overlap; give the vehicle file and the output different places")
    check_command_output(target, args.force, inputs=[inputs[0]], flag="--vehicle-from-log")
    if (vehicle_dir() / f"{target.stem}.yaml").exists():  # the bag names its vehicle: read later with the shipped file
        raise ConfigError(f"--vehicle-from-log {target}: {target.stem} is a shipped vehicle's name, which the bag would "
                          f"name (a later read without --vehicle takes the shipped {target.stem}); choose another file name")
    if not inputs[0].is_file():
        load_flight(inputs[0])  # the loader's one-line refusal of a missing or special file
    vehicle = vehicle_from_ulog(inputs[0], name=target.stem)
    config = VehicleConfig.from_dict(vehicle.document, str(target))
    for message in vehicle.warnings:
        print(f"warning: {message}", file=sys.stderr)
    log = _read(inputs[0], output.suffix == ".mat", vehicle=config)
    with atomic_output(target, args.force) as staging:
        staging.write_text(vehicle_yaml(vehicle), encoding="utf-8")
        _write(log, output, args.namespace, args.force)
    print(f"{inputs[0]} -> {target} (vehicle {config.name}: {config.geometry} frame, arm {config.value('arm_length'):.4g} m, "
          f"inputs {config.input_min:g}..{config.input_max:g} {config.input_unit})")
    print(f"{inputs[0]} -> {output} ({len(log)} samples, {log.duration:.1f} s, vehicle {log.meta.vehicle})")
    return 0


def _read(path: Path, to_mat: bool, **options):
    """The flight of ``path`` (:func:`load_flight` with ``options``) with its missing rows marked as gaps, refused for
    a .mat output (``to_mat``) whose gaps hold rows, its warnings printed (clipped commands, a cut tail, a gap: also
    kept in the bag's notes)."""
    log = load_flight(path, **options)
    mark_time_base_holes(log)  # a CSV's missing rows: a gap in the bag's notes and a warning, as evaluate says it
    if to_mat:  # refused before its warnings are printed: one line
        from quad_modelling.io.matlog import check_one_time_base

        check_one_time_base(log)
    for message in log.meta.notes.get("warnings", []):
        print(f"warning: {message}", file=sys.stderr)
    return log


def _is_mat_log(path: Path, given: str) -> bool:
    return input_format(path, given) == "thesis-mat"


def run(args: argparse.Namespace) -> int:
    inputs = [Path(p) for p in args.inputs]
    output = Path(args.output)
    check_namespace(args.namespace)
    check_command_output(output, args.force, inputs=[*inputs, args.mapping, vehicle_file(args.vehicle) if args.vehicle else None,
                                             topic_map_file(args.topic_map)], markers=BAG_MARKERS)
    if not (output.suffix == ".mat" and len(inputs) == 1):  # a bag, or a directory of bags
        check_bag_name(output)
    if args.vehicle_from_log is not None:
        return _vehicle_from_log(args, inputs, output)
    if args.mapping and not any(_is_mat_log(path, args.format) for path in inputs):  # else it would be ignored
        raise ConfigError(f"--mapping {args.mapping}: a mapping applies to .mat logs only, and no input is one "
                          f"({inputs[0]} is a {input_format(inputs[0], args.format)} input)")
    check_topic_map_applies(args.topic_map, inputs, args.format)

    def load(path: Path):
        return _read(path, output.suffix == ".mat" and len(inputs) == 1, vehicle=args.vehicle, fmt=args.format,
                     mapping_file=args.mapping, topic_map=args.topic_map)

    if len(inputs) == 1:
        log = load(inputs[0])
        _write(log, output, args.namespace, args.force)
        print(f"{inputs[0]} -> {output} ({len(log)} samples, {log.duration:.1f} s, vehicle {log.meta.vehicle})")
        return 0

    check_distinct_inputs(inputs)  # one file twice (./a.csv and a.csv): said so, not "the same bag name"
    names = [bag_name(p) for p in inputs]
    duplicates = {n for n in names if names.count(n) > 1}
    if duplicates:
        raise QuadModellingError(f"several inputs map to the same bag name(s) {sorted(duplicates)}")
    refused: list[str] = []
    converted, done = 0, []  # the success lines, printed once the output is in place (an error rolls it all back)
    with atomic_output(output, args.force) as staging:
        staging.mkdir()
        for path, name in tqdm(list(zip(inputs, names)), unit="file", desc="convert", disable=not sys.stderr.isatty()):
            try:
                log = load(path)
            except QuadModellingError as err:
                if not args.skip_bad:
                    raise
                refused.append(str(err))
                print(f"refused: {err}", file=sys.stderr)
                continue
            _write(log, staging / name, args.namespace, force=False)
            converted += 1
            done.append(f"{path} -> {output / name} ({len(log)} samples, {log.duration:.1f} s)")
        if not converted:  # nothing to keep: no empty output directory (the staging is removed)
            raise DataError(f"none of the {len(inputs)} inputs could be converted (each refused above); nothing written to {output}")
    if done:
        print("\n".join(done))
    print(f"converted {converted} of {len(inputs)} inputs into {output}" + (f"; refused {len(refused)}" if refused else ""))
    return 1 if refused else 0
