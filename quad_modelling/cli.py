"""``quad-modelling <verb>``: the offline command line.

Each verb lives in ``quad_modelling/commands/<verb>.py`` with ``NAME``, ``HELP``,
``DESCRIPTION`` (shown by ``--help``, with an example), ``add_arguments(parser)``
and ``run(args) -> int``. This module only dispatches, and turns the package's
errors into one line on stderr and a non-zero exit.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from quad_modelling.errors import QuadModellingError

VERB_MODULES = (
    "convert",
    "info",
    "train",
    "identify",
    "evaluate",
    "simulate",
    "run_bag",
    "diagnose",
)
"""Modules under quad_modelling.commands, in --help order."""

EXIT_ERROR = 2
"""Exit code for bad input/config (a clear one-line message was printed)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="quad-modelling",
        description="Model quadrotor flight dynamics from flight data: convert logs to MCAP bags, "
        "simulate, identify, evaluate, train and diagnose.",
    )
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    for module_name in VERB_MODULES:
        module = importlib.import_module(f"quad_modelling.commands.{module_name}")
        sub = verbs.add_parser(
            module.NAME,
            help=module.HELP,
            description=module.DESCRIPTION,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(sub)
        sub.set_defaults(run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except QuadModellingError as err:
        print(f"quad-modelling {args.verb}: error: {err}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"quad-modelling {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
