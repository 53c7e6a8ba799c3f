"""Atomic outputs: write to a temporary sibling, rename when complete.

An existing output is never replaced unless ``force`` is true; a failed write
leaves nothing behind (the temporary path is removed).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path

from quad_modelling.errors import OutputExistsError, QuadModellingError


class OutputDirError(QuadModellingError, PermissionError):
    """The output's directory is missing or not writable."""


def check_output(path: Path, force: bool) -> None:
    """Refuse an existing output without force, or a directory we cannot write to."""
    if path.exists() and not force:
        raise OutputExistsError(f"{path}: exists; pass --force to overwrite")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise OutputDirError(f"{parent}: output directory does not exist or is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputDirError(f"{parent}: output directory is not writable")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink()


@contextlib.contextmanager
def atomic_output(path: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path with the same name, in a hidden staging directory next to
    ``path``; rename it onto ``path`` on success.

    The temporary path does not exist when yielded: the caller creates a file or
    a directory there (keeping the final name, so a bag's inner ``.mcap`` file is
    named after the bag). On any exception the staging directory is removed and
    the error re-raised.
    """
    path = Path(path)
    check_output(path, force)
    staging = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        staging.mkdir()
    except OSError as err:
        raise OutputDirError(f"{path.parent}: cannot write in the output directory ({err.strerror})") from err
    tmp = staging / path.name
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"{tmp}: nothing was written")
        if path.exists():
            backup = path.with_name(f".{path.name}.old-{uuid.uuid4().hex[:8]}")
            path.rename(backup)
            tmp.rename(path)
            _remove(backup)
        else:
            tmp.rename(path)
    finally:
        _remove(staging)
