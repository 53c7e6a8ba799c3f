"""``quad-modelling <verb>``: the offline command line.

Each verb lives in ``quad_modelling/commands/<verb>.py`` with ``NAME``, ``HELP``,
``DESCRIPTION`` (shown by ``--help``, with an example), ``add_arguments(parser)``
and ``run(args) -> int``. This module only dispatches, and turns the package's
errors (and argparse's) into one line on stderr and exit 2. SIGTERM is turned into
a KeyboardInterrupt, as SIGINT is, so every ``finally`` and context manager on the
way out runs: staging directories are removed, run-bag's nodes are stopped.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import signal
import sys
import warnings

from quad_modelling.errors import QuadModellingError, VehicleKeyWarning

VERB_MODULES = (
    "convert",
    "info",
    "train",
    "identify",
    "evaluate",
    "simulate",
    "run_bag",
    "diagnose",
    "merge",
    "export",
)
"""Modules under quad_modelling.commands, in --help order."""

EXIT_ERROR = 2
"""Exit code for bad input/config (a clear one-line message was printed)."""


EXIT_INTERRUPTED = {signal.SIGINT: 130, signal.SIGTERM: 143}
"""Exit codes after SIGINT / SIGTERM (128 + signal number, as a shell reports them)."""

EXIT_BROKEN_PIPE = 141
"""Exit code when the reader of stdout went away (``quad-modelling info BAG | head``): 128 + SIGPIPE, as a
shell reports a command killed by it; nothing more is printed."""


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (no usage block) and exit 2."""

    def error(self, message: str):
        self.exit(EXIT_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class Interrupted(KeyboardInterrupt):
    """Raised by the SIGTERM handler, so clean-up runs as for Ctrl-C."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="quad-modelling",
        description="Model quadrotor flight dynamics from flight data: convert logs to MCAP bags, "
        "simulate, identify, evaluate, train, diagnose and export.",
    )
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    parser.verb_parsers = {}  # verb -> its parser: an unknown option is reported by the verb's (main)
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
        parser.verb_parsers[module.NAME] = sub
    return parser


def _one_line_warnings(verb: str):
    """A ``warnings.showwarning`` that prints the project's warnings (:class:`VehicleKeyWarning`) as one line
    ``quad-modelling VERB: warning: ...`` on stderr, once per message; others as Python would."""
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, VehicleKeyWarning):
            print(f"quad-modelling {verb}: warning: {' '.join(str(message).split())}", file=sys.stderr)
        else:
            default(message, category, filename, lineno, file, line)

    return show


def main(argv: list[str] | None = None) -> int:
    try:  # first: the verbs' modules (numpy, scipy, torch) take seconds to import
        previous = signal.signal(signal.SIGTERM, _raise_interrupted)
        # Ctrl-C must interrupt whatever started this process: a parent that ignores SIGINT (a background job, a
        # test worker) or blocks it hands that on to its children, and a run-bag would then run to its end.
        previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    except ValueError:  # not the main thread: signals stay as they are
        previous = previous_int = None
    try:
        return _parse_and_run(argv)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
            signal.signal(signal.SIGINT, previous_int)


DASH_VALUE = re.compile(r"-(?:\.?\d|inf|nan)", re.IGNORECASE)
"""A command-line word that starts like a negative number (``-5:0``, ``-.5``, ``-5%:10%``, ``-inf``, ``-nan``): the value of the option
before it, not an option (:func:`attach_dash_values`)."""


def attach_dash_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``--drop -5:0`` -> ``--drop=-5:0``: a word starting like a negative number after an option of the verb that takes
    one value is that option's value. argparse takes only a plain negative number (``-5``) so and read ``-5:0`` as an
    unknown option ("argument --drop: expected one argument", naming neither the value nor what is wrong with it);
    attached, the verb's own check says what is wrong (a negative span bound)."""
    verb = next((word for word in argv if word in parser.verb_parsers), None)
    if verb is None:
        return list(argv)
    actions = parser.verb_parsers[verb]._actions
    takes_value = {o for a in actions if a.nargs is None for o in a.option_strings}
    every = {o for a in actions for o in a.option_strings}

    def option(word: str) -> bool:
        """Whether ``word`` names an option taking one value: exactly, or as the one option of all the verb's that it
        abbreviates (``--dur``: ``--duration``), as argparse resolves it (``--hybrid`` is the flag, not ``--hybrid-hidden``)."""
        if word in every:
            return word in takes_value
        matches = [o for o in every if o.startswith(word)] if word.startswith("--") and len(word) > 2 else []
        return len(matches) == 1 and matches[0] in takes_value

    out: list[str] = []
    for k, word in enumerate(argv):
        if word == "--":  # what follows is positional: as given
            return out + list(argv[k:])
        if out and option(out[-1]) and DASH_VALUE.match(word):
            out[-1] = f"{out[-1]}={word}"
        else:
            out.append(word)
    return out


def _parse_and_run(argv: list[str] | None) -> int:
    """Parse ``argv`` and run the verb; the package's errors as one line and exit 2, signals as 130 / 143."""
    try:
        parser = build_parser()
        argv = attach_dash_values(parser, sys.argv[1:] if argv is None else argv)
        args, unknown = parser.parse_known_args(argv)
    except KeyboardInterrupt as err:
        signum = getattr(err, "signum", signal.SIGINT)
        print(f"quad-modelling: interrupted while starting ({signal.Signals(signum).name})", file=sys.stderr)
        return EXIT_INTERRUPTED[signum]
    if unknown:  # named by the verb's parser: "quad-modelling convert: error: ... (see quad-modelling convert --help)"
        parser.verb_parsers[args.verb].error(f"unrecognized arguments: {' '.join(unknown)}")
    if getattr(args, "output", None) == "":  # as typed: the verbs' Path("") would be "."
        parser.verb_parsers[args.verb].error("-o '': the output must name a new file or directory, not ''")
    options = {option for action in parser.verb_parsers[args.verb]._actions for option in action.option_strings}
    for flag in ("vehicle", "topic_map"):  # '' read as "not given": the default vehicle without a word
        if f"--{flag.replace('_', '-')}" in options and getattr(args, flag, None) is not None and not str(getattr(args, flag)).strip():
            parser.verb_parsers[args.verb].error(f"--{flag.replace('_', '-')} {getattr(args, flag)!r}: names nothing; give a name or a "
                                                 "YAML file, or leave it out")
    previous_show = warnings.showwarning
    warnings.showwarning = _one_line_warnings(args.verb)
    try:
        return int(args.run(args) or 0)
    except QuadModellingError as err:
        message = " ".join(str(err).split())  # one line, whatever a wrapped library said
        print(f"quad-modelling {args.verb}: error: {message}", file=sys.stderr)
        return EXIT_ERROR
    except BrokenPipeError:
        # stdout's reader is gone: say nothing more (Python would print a traceback at exit flushing it)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt as err:
        signum = getattr(err, "signum", signal.SIGINT)
        print(f"quad-modelling {args.verb}: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
        return EXIT_INTERRUPTED[signum]
    finally:
        warnings.showwarning = previous_show


if __name__ == "__main__":
    sys.exit(main())
