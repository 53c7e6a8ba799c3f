"""``quad-modelling identify``: least-squares identification of a vehicle's motor constants."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from quad_modelling.atomic import atomic_output, check_distinct_inputs
from quad_modelling.commands import check_command_output
from quad_modelling.commands.evaluate import (
    add_span_arguments,
    config_from_args,
    input_files,
    load_evaluation_flights,
    warn_flight_span_overlap,
)
from quad_modelling.core.identification.physics_terms import identify_term_names
from quad_modelling.core.identification.identify import (
    identified_vehicle_document,
    identify,
    write_vehicle_yaml,
)
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError, DataError
from quad_modelling.io.loader import check_topic_map_applies

NAME = "identify"
HELP = "identify the motor constants marked 'identified' from flight data (training spans only)"
DESCRIPTION = """\
Identify the greybox model's motor constants from flights by least squares, on the training
span only (the evaluation span stays unseen): the motor pole A_m and the thrust gain
K = 2 B_m sqrt(a m g / 4) from the Z acceleration, the drag ratio d/a from the yaw
acceleration (a is held: only B_m sqrt(a) is identifiable), the thrust gain's battery-voltage
dependence, and a check of the motor order and spin directions against the config. When the
vehicle file has the physics model's constants, also those (rotor lag and delay, thrust and
torque constants, rotor drag and its arm, roll/pitch inertias; docs/models.md), fitted on the
model's own multi-step error with its disturbance observer.

Writes a vehicle YAML (loadable with --vehicle FILE) whose identified constants carry their
1-sigma uncertainty and a source naming the files and spans used; the 'identification'
section holds the details. Spans as for `evaluate` (thesis defaults; --preset short for
~40 s flights).

--jobs N / --scheduler ADDRESS read and check the flights on Dask workers; the fit itself
runs here (it is joint over all flights; docs/scale.md).

examples:
  quad-modelling identify $NANOBENCH/*.csv.gz --vehicle crazyflie21 --preset short --skip-bad -o cf_identified.yaml
  quad-modelling identify flight.mat --vehicle linkquad --train 30:150 -o linkquad_identified.yaml
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_span_arguments(parser)
    parser.add_argument("--effects", metavar="LIST", default=None,
                        help="optional terms of the physics model to fit with its constants and switch on in the output: "
                             "a comma list of ground_effect, battery, gyroscopic, motor_imbalance, and rotor_drag, "
                             "motor_lag, input_delay where the vehicle file switches them off (docs/models.md)")
    parser.add_argument("-o", "--output", required=True, metavar="VEHICLE.yaml", help="vehicle YAML to write")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")


def warn_held_speed_map(flights, vehicle: VehicleConfig) -> None:
    """One warning line when a simulated flight's notes say its rotors answered another speed map than the vehicle
    file's (identify holds the map, :data:`~quad_modelling.core.vehicle.HELD_BY_IDENTIFY`): a scale the thrust
    constant absorbs, an offset nothing does -- a simulated Crazyflie with offset 0 against its file's 381 rad/s
    gave k_f 1.64e-8 +- 3e-12 for 2.88e-8 and inertias 0.81x, sigmas far below the error (session 33's review;
    the simulator now answers the file's map). The flight's map: its notes' ``esc`` (Ω_off = -k_u u_0)."""
    for log in flights:
        esc = log.meta.notes.get("esc") or {}
        try:
            gain = float(esc["speed_gain"])
            used = {"rotor_speed_gain": gain, "rotor_speed_offset": 0.0 - gain * float(esc["zero_speed_input"])}
        except (KeyError, TypeError, ValueError):
            continue  # not simulated, or notes without the map
        differs = {key: value for key, value in used.items()
                   if abs(value - vehicle.value(key)) > 0.01 * max(abs(vehicle.value(key)), 1e-9)}
        if differs:
            print(f"warning: {log.meta.source} was simulated with the speed map {', '.join(f'{k} {v:g}' for k, v in differs.items())}; "
                  f"{vehicle.path} holds {', '.join(f'{k} {vehicle.value(k):g}' for k in differs)}, which identify keeps "
                  "(it fits k_f, not the map): the constants absorb the difference, their sigmas do not show it", file=sys.stderr)
            return


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    check_command_output(output, args.force, inputs=input_files(args))
    check_distinct_inputs(args.inputs, "FLIGHT")
    check_topic_map_applies(args.topic_map, args.inputs)
    if output.suffix not in (".yaml", ".yml"):  # what --vehicle reads back as a file
        raise ConfigError(f"-o {output}: a vehicle file is YAML; name it VEHICLE.yaml")
    config = config_from_args(args)
    if args.effects is not None and not args.effects.strip():  # as simulate and diagnose refuse a blank list
        raise ConfigError("--effects '': name the terms to fit (e.g. battery,motor_imbalance), or leave --effects out for none")
    terms = identify_term_names(args.effects.split(",")) if args.effects is not None else ()  # one line per bad term
    flights, vehicle, skipped = load_evaluation_flights(args)
    warn_flight_span_overlap(config, flights)
    warn_held_speed_map(flights, vehicle)
    result = identify(flights, vehicle, config, terms)
    document = identified_vehicle_document(vehicle, result, config.train)
    try:  # what we write must load
        VehicleConfig.from_dict(document, "identified vehicle")
    except ConfigError as err:
        raise DataError(f"{err} (identified from {len(flights)} flight(s)); nothing written to {output}") from err
    with atomic_output(output, args.force) as tmp:
        write_vehicle_yaml(document, tmp)
    print(result.summary())
    windowed = {span["file"] for span in result.spans}
    for log in flights:  # a flight that gave no window (too short, or every window on the ground) is said
        if log.meta.source not in windowed:
            print(f"warning: {log.meta.source}: no {config.window_s:g} s training window in span {config.train} (too short, "
                  "or every window touches the ground or a gap): the greybox fit did not use it", file=sys.stderr)
    if skipped:
        print(f"identified from {len(flights)} of {len(flights) + len(skipped)} inputs: {len(skipped)} skipped "
              "(above), not in identification.files", file=sys.stderr)
    print(f"-> {output}")
    return 1 if skipped else 0  # --skip-bad left a flight out: done, with less (as convert)
