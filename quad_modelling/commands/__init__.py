"""The verbs of ``quad-modelling`` (one module each, thin: arguments -> core and io -> printed lines)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from quad_modelling.atomic import OUTPUT_MARKERS, OutputOverlapsInputError, check_output
from quad_modelling.core.vehicle import config_dir
from quad_modelling.errors import ConfigError


def check_command_output(path: str | Path, force: bool, inputs: Iterable[str | Path | None] = (), flag: str = "-o",
                         directory: bool = False, markers: Iterable[str] = OUTPUT_MARKERS) -> None:
    """:func:`~quad_modelling.atomic.check_output` of a verb's output, which is also never the shipped configuration
    (:func:`~quad_modelling.core.vehicle.config_dir`: the vehicle files and topic maps a verb reads by name), inside
    it or around it, even with --force: ``identify FLIGHT -o config/vehicles/linkquad.yaml --force`` rewrote the
    shipped LinkQuad file it had just read (the flight named the vehicle, so no --vehicle listed it as an input)."""
    if Path(path).name not in ("", ".", ".."):
        shipped, out = config_dir().resolve(), Path(path).resolve()
        relation = ("is" if out == shipped else "lies inside" if shipped in out.parents else
                    "contains" if out in shipped.parents else None)
        if relation:
            raise OutputOverlapsInputError(f"{flag} {path}: the output {relation} the shipped configuration {shipped} (vehicle "
                                           "files and topic maps read by name); write your own file elsewhere (refused even "
                                           "with --force)")
    check_output(Path(path), force, inputs, flag, directory, markers)


MAX_SEED = 2**32 - 1
"""Largest seed of every verb (``simulate --seed``, ``train --seed``, ``diagnose --validate --seeds``): numpy's seed
range (torch takes 64 bits); a larger one ended in an OverflowError traceback in ``train``, and ``simulate`` took any."""


def check_seed(seed: int, flag: str = "--seed") -> None:
    """ConfigError unless 0 <= ``seed`` <= :data:`MAX_SEED`."""
    if not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"{flag} {seed}: must be a whole number in 0..{MAX_SEED}")
