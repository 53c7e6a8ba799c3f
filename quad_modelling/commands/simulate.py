"""``quad-modelling simulate``: fly the truth simulator and write a thesis .mat log (or an MCAP bag)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from quad_modelling.atomic import BAG_MARKERS, check_bag_name
from quad_modelling.commands import check_command_output, check_seed
from quad_modelling.core.effect_names import (
    DISTURBANCES,
    SIM_EFFECTS,
    SIMULATOR,
    parse_effect_names,
)
from quad_modelling.core.sim.params import SIMULATED_VEHICLES
from quad_modelling.core.sim.pilot import MAX_DURATION, MIN_DURATION
from quad_modelling.core.sim.simulate import run_simulation
from quad_modelling.errors import ConfigError

NAME = "simulate"
HELP = "simulate a LinkQuad- or Crazyflie-like flight with switchable physical effects"
DESCRIPTION = f"""\
Fly the truth simulator (nonlinear 6-DoF quadrotor, rotor dynamics, PID stabiliser,
seeded pilot script: take-off, hover with throttle/roll/pitch/yaw manoeuvres, landing)
and write its sensor log as a thesis MATLAB log (.mat) or, with --bag, an MCAP bag.
The effects, their parameters and the seed are stored in the log's notes (meta_json).

effects: {", ".join(SIM_EFFECTS)}
  --effects none | all | default (all but {", ".join(DISTURBANCES)}) | a comma list
  {", ".join(DISTURBANCES)} are disturbances no catalogue effect describes (moving air; the centre
  of mass below the IMU; motor 1 tilted 3 degrees about its arm): docs/simulator.md

examples:
  quad-modelling simulate -o flight.mat
  quad-modelling simulate -o flight.mat --vehicle crazyflie21 --effects rotor_drag,battery --seed 3
  quad-modelling simulate -o bags/sim_flight --bag --effects none --duration 60
  quad-modelling simulate -o damaged.mat --effects rotor_drag,battery,motor_lag,com_offset,bent_arm --seed 4
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", required=True, metavar="FLIGHT", help="output .mat file (or bag directory with --bag)")
    parser.add_argument("--vehicle", default="linkquad", choices=SIMULATED_VEHICLES, help="vehicle to fly (default linkquad)")
    parser.add_argument("--effects", default="default", help=f"none, all, default, or a comma list of effects (default: all but {', '.join(DISTURBANCES)})")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the pilot script, wind and sensors (default 0)")
    parser.add_argument("--duration", type=float, default=220.0, help="flight duration [s] (default 220, as the thesis flights)")
    parser.add_argument("--bag", action="store_true", help="write an MCAP bag directory instead of a .mat log")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    effects = parse_effect_names(args.effects, SIMULATOR)
    check_seed(args.seed)
    if not args.bag and output.suffix != ".mat":
        raise ConfigError(f"{output}: a thesis log needs a .mat name (or pass --bag for an MCAP bag directory)")
    if args.bag:
        check_bag_name(output)
    check_command_output(output, args.force, markers=BAG_MARKERS)  # fail before a long simulation, not after; a bag replaces a bag only
    if not MIN_DURATION <= args.duration <= MAX_DURATION:
        raise ConfigError(f"--duration {args.duration:g}: must be at least {MIN_DURATION:g} s and at most {MAX_DURATION:g} s")
    result = run_simulation(args.vehicle, effects, args.seed, args.duration, progress=sys.stderr.isatty())
    log = result.log
    short = result.script.short_flight()
    if short:
        print(f"warning: {short}", file=sys.stderr)
    if args.bag:
        from quad_modelling.io.bag_io import write_bag

        write_bag(log, output, force=args.force)
    else:
        from quad_modelling.io.matlog import write_matlog

        write_matlog(log, output, force=args.force)
    print(
        f"simulated {args.vehicle} for {log.duration + 1.0 / log.sample_rate:.1f} s, seed {args.seed}, "
        f"effects: {', '.join(effects) or 'none'} -> {output} ({len(log)} samples)"
    )
    return 0
