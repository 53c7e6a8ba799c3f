"""``quad-modelling export``: the identified physics model (or a hybrid) as CasADi Functions for an MPC."""

from __future__ import annotations

import argparse
import sys

from quad_modelling.atomic import atomic_output
from quad_modelling.commands import check_command_output
from quad_modelling.core.vehicle import load_vehicle, vehicle_file
from quad_modelling.errors import ConfigError

FORMATS = ("casadi",)
"""Export formats (docs/export.md)."""

NAME = "export"
HELP = "write the identified physics model (or a hybrid) as CasADi Functions f(x, u) and F(x, u, dt)"
DESCRIPTION = """\
Write the vehicle's identified nonlinear physics model with the terms its `effects:` section
switches on -- and, with --model hybrid:FILE, the hybrid's residual net -- as CasADi Functions
(casadi.Function.load): continuous dynamics f(x, u), one step F(x, u, dt), and both with the
disturbance observer's constant accelerations as an extra input d. OUT is a new directory with
f.casadi, F.casadi, f_disturbed.casadi, F_disturbed.casadi and layout.yaml (state, input and
disturbance layout with units; the command delay, command range and hover command). The
expressions are built by the same code as the model's numpy step (docs/export.md).

The vehicle file must be one `quad-modelling identify` wrote: constants still marked
`identified` that no identification record names (starting values) are refused.

examples:
  quad-modelling export cf_identified.yaml --format casadi -o cf_model
  quad-modelling train bags/nanobench_B7_oval_medium_rep2 --preset short --vehicle cf_identified.yaml --hybrid -o cf_hybrid.npz
  quad-modelling export cf_identified.yaml --model hybrid:cf_hybrid.npz --format casadi -o cf_hybrid
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("vehicle", metavar="VEHICLE.yaml", help="identified vehicle file (written by identify)")
    parser.add_argument("--model", action="append", metavar="SPEC",
                        help="physics (default: the vehicle's physics model and terms) or hybrid:FILE (a train --hybrid model)")
    parser.add_argument("--format", required=True, metavar="FORMAT", help=f"export format: {', '.join(FORMATS)}")
    parser.add_argument("-o", "--output", required=True, metavar="OUT", help="directory to write (new; --force replaces it)")
    parser.add_argument("--force", action="store_true", help="replace an existing OUT")


def _hybrid_file(spec: str) -> str | None:
    """The model file of ``--model``: None for ``physics``, FILE for ``hybrid:FILE``; ConfigError otherwise."""
    kind, _, path = spec.partition(":")
    if spec == "physics":
        return None
    if kind == "hybrid" and path:
        return path
    raise ConfigError(f"--model {spec}: export takes physics or hybrid:FILE")


def run(args: argparse.Namespace) -> int:
    if args.format not in FORMATS:
        raise ConfigError(f"--format {args.format}: unknown export format; known: {', '.join(FORMATS)}")
    specs = args.model or ["physics"]
    if len(specs) > 1:  # the last one was exported, the others dropped without a word
        raise ConfigError(f"--model given {len(specs)} times ({', '.join(specs)}): export writes one model; run it once per model")
    hybrid_file = _hybrid_file(specs[0])
    check_command_output(args.output, args.force, inputs=[vehicle_file(args.vehicle), hybrid_file], directory=True,
                         markers=("layout.yaml",))
    from quad_modelling.core.export.casadi_model import exportable_model, write_casadi_export

    model = exportable_model(load_vehicle(args.vehicle), hybrid_file)
    with atomic_output(args.output, args.force) as staging:
        layout = write_casadi_export(model, staging)
    terms = ", ".join(layout["terms_on"]) or "none"
    print(f"{args.output}: {layout['model']} model of {layout['vehicle']} (terms on: {terms}) as CasADi Functions "
          f"{', '.join(layout['functions'])}; x has {len(layout['state'])} states, u {len(layout['input'])} inputs "
          f"(layout.yaml; docs/export.md)")
    constants = layout["constants"]
    outside = [i + 1 for i, u in enumerate(constants["hover_commands"]) if not constants["input_min"] <= u <= constants["input_max"]]
    if outside:  # the model cannot hover within its commands: an MPC's hover reference would break its bounds
        print(f"warning: the model's level hover needs commands outside [{constants['input_min']:g}, {constants['input_max']:g}] "
              f"on motor(s) {', '.join(map(str, outside))} (hover_commands {[round(u, 1) for u in constants['hover_commands']]}): "
              + ("check the identified thrust constant k_f, the rotor speed map and the mass" if len(outside) == len(constants["hover_commands"]) else
                 "check the identified motor gains and CG offset")
              + " (identify's AT BOUND flags)", file=sys.stderr)
    return 0
