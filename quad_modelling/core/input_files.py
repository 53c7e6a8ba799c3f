"""The user's input files, read with bounds: regular files only, YAML of bounded size and aliases.

A FIFO, a device or a socket given as an input would block or never end; it is
refused before it is opened (:func:`check_regular_file`). A YAML file (vehicle
config, mapping) is read as UTF-8 (a bad byte is named by its offset), at most
:data:`MAX_YAML_BYTES` long and with at most :data:`MAX_YAML_ALIASES` aliases,
so an alias bomb ("billion laughs") is refused instead of expanded.
"""

from __future__ import annotations

import stat
from pathlib import Path

import yaml

from quad_modelling.errors import ConfigError, QuadModellingError

MAX_YAML_BYTES = 1 << 20
"""Largest YAML input [bytes]: a vehicle config or mapping is a few kB."""

MAX_YAML_ALIASES = 64
"""Most YAML aliases (``*name``) one file may use; the shipped files use none."""


def check_regular_file(path: str | Path, what: str, error: type[QuadModellingError] = ConfigError) -> Path:
    """``path`` if it is a regular file (symbolic links followed); ``error`` naming it otherwise."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError as err:
        raise error(f"{path}: no such {what}") from err
    except OSError as err:
        raise error(f"{path}: cannot read {what}: {err.strerror}") from err
    if stat.S_ISDIR(mode):
        raise error(f"{path}: is a directory, not a {what}")
    if not stat.S_ISREG(mode):
        kind = "a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else "a special file"
        raise error(f"{path}: is {kind}, not a regular file; give the {what} as a file")
    return path


class _AliasBomb(yaml.YAMLError):
    pass


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader that stops at the :data:`MAX_YAML_ALIASES` + 1st alias."""

    def __init__(self, stream):
        super().__init__(stream)
        self.aliases = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self.aliases += 1
            if self.aliases > MAX_YAML_ALIASES:
                mark = self.peek_event().start_mark
                raise _AliasBomb(f"more than {MAX_YAML_ALIASES} aliases (line {mark.line + 1}); write the values out")
        return super().compose_node(parent, index)


def read_yaml(path: str | Path, what: str) -> object:
    """The document of a YAML ``what`` file (``vehicle config``, ``mapping file``); ConfigError naming the
    file and the fault: not a regular file, too large, not UTF-8, not YAML, too many aliases."""
    path = check_regular_file(path, what)
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise ConfigError(f"{path}: {what} is {size} bytes, more than the {MAX_YAML_BYTES} a {what} may be")
        raw = path.read_bytes()
    except OSError as err:
        raise ConfigError(f"{path}: cannot read {what}: {err.strerror}") from err
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: {what} is not UTF-8 text (byte 0x{raw[err.start]:02x} at offset {err.start})") from err
    try:
        return yaml.load(text, Loader=_BoundedLoader)  # noqa: S506 - a SafeLoader subclass
    except _AliasBomb as err:
        raise ConfigError(f"{path}: {what} has {err}") from err
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: {what} is not valid YAML: {' '.join(str(err).split())}") from err
