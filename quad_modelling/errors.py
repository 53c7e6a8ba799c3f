"""Exceptions of quad_modelling, and the helpers that quote a third-party error or a path in their messages.

Every exception carries a one-line message that names the file, topic, field or
row at fault, so the CLI can print it as is and exit non-zero.
"""

import os
from pathlib import Path


class QuadModellingError(Exception):
    """Base class of every error this package raises on purpose.

    The message is kept on one line whatever went into it (a key, a file name or a
    third-party text with line breaks): each line break becomes a space.
    """

    def __init__(self, message: object = "", *args: object) -> None:
        if isinstance(message, str):
            message = " ".join(message.splitlines())
        super().__init__(message, *args)


class VehicleKeyWarning(FutureWarning):
    """A vehicle file uses old key names, read as the new ones; the message (one line) names the file and each
    old -> new key. The CLI prints it as one ``warning:`` line."""


class DataError(QuadModellingError, ValueError):
    """A flight log, CSV, MATLAB file or bag holds data that cannot be used."""


class ConfigError(QuadModellingError, ValueError):
    """A vehicle config, mapping file or parameter is missing or invalid."""


class BagError(QuadModellingError, OSError):
    """An MCAP bag cannot be read or written (corrupt, truncated, missing topic)."""


class ModelError(QuadModellingError, ValueError):
    """A model file is invalid or does not fit the vehicle/variables asked for."""


class ClusterError(QuadModellingError, RuntimeError):
    """The Dask cluster of ``--jobs``/``--scheduler`` failed under the work: a worker died running a flight,
    or the scheduler went away."""


class OutputExistsError(QuadModellingError, FileExistsError):
    """An output path exists and --force was not given."""


REASON_LIMIT = 200
"""Longest third-party error text quoted in a project message [characters]."""


def reason(err: BaseException) -> str:
    """A third-party exception as one short line for a project message: its type and its text,
    whitespace (newlines of YAML or numpy messages) collapsed, cut at :data:`REASON_LIMIT` characters."""
    text = " ".join(str(err).split()) or "no details"
    if len(text) > REASON_LIMIT:
        text = text[: REASON_LIMIT - 3] + "..."
    return f"{type(err).__name__}: {text}"


SHOWN_PATH_CHARS = 120
"""Longest path quoted whole in an error [characters]; a longer one is shown by its start and its length."""


def shown_path(path: str | Path) -> str:
    """``path`` as an error message names it: whole, or (longer than :data:`SHOWN_PATH_CHARS`) its first 60
    characters, ``...`` and its length in bytes (a path too long for the file system stays a readable line)."""
    text = str(path)
    if len(text) <= SHOWN_PATH_CHARS:
        return text
    return f"{text[:60]}... ({len(os.fsencode(text))} bytes)"
