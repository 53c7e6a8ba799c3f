"""The user's input files, read with bounds: regular files only; YAML of bounded size and expansion.

A FIFO, a device or a socket given as an input would block or never end; it is refused before it is
opened (:func:`check_regular_file`). ``yaml.safe_load`` builds no objects of its own, but input still
decides its cost: a file of any size, and alias bombs (a few lines whose anchors expand to billions of
nodes once anything walks the document, e.g. to quote a value in an error message). :func:`read_yaml`
(vehicle configs, mapping files, a bag's metadata.yaml) refuses each of those in one line naming the file
before the document reaches any other code.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

import yaml

from quad_modelling.errors import ConfigError, QuadModellingError, reason, shown_path

MAX_YAML_BYTES = 1 << 20
"""Largest YAML file read [bytes]: a vehicle config or mapping is a few kB, a bag's metadata.yaml tens of kB."""

MAX_YAML_NODES = 100_000
"""Most nodes a document may hold with every alias expanded (a 1 MiB file of plain values holds fewer)."""



def input_path_mode(path: str | Path, what: str, error: type[QuadModellingError] = ConfigError) -> int | None:
    """The ``st_mode`` of an input path (symbolic links followed), None when nothing is there; ``error`` in one line
    naming the path when it cannot even be looked up: a name or path longer than the file system allows
    (ENAMETOOLONG), a loop of symbolic links, a directory on the way without search permission. The one place
    every input path of every verb is first looked at (flight files, bags, results, YAML)."""
    try:
        return os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as err:
        if err.errno == errno.ENAMETOOLONG:
            longest = max((len(os.fsencode(part)) for part in Path(path).parts), default=0)
            raise error(f"{shown_path(path)}: {what} path is too long for the file system (longest name {longest} bytes, "
                        f"path {len(os.fsencode(str(path)))} bytes; it allows {_limit('PC_NAME_MAX', 255)} and "
                        f"{_limit('PC_PATH_MAX', 4096)})") from err
        raise error(f"{shown_path(path)}: cannot look up the {what} ({err.strerror or reason(err)})") from err


def _limit(name: str, default: int) -> int:
    """A file system limit of the working directory (``os.pathconf``), ``default`` when it cannot be read."""
    try:
        return os.pathconf(".", name)
    except (OSError, ValueError):
        return default


def check_regular_file(path: str | Path, what: str, error: type[QuadModellingError] = ConfigError) -> Path:
    """``path`` if it is a regular file (symbolic links followed); ``error`` naming it otherwise."""
    path = Path(path)
    mode = input_path_mode(path, what, error)
    if mode is None:
        raise error(f"{shown_path(path)}: no such {what}")
    if stat.S_ISDIR(mode):
        raise error(f"{path}: is a directory, not a {what}")
    if not stat.S_ISREG(mode):
        kind = "a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else "a special file"
        raise error(f"{path}: is {kind}, not a regular file; give the {what} as a file")
    return path


def expanded_size(node: yaml.Node, sizes: dict[int, int] | None = None) -> int:
    """Node count of ``node`` with every alias expanded; each shared node is counted once per use, computed once."""
    sizes = {} if sizes is None else sizes
    key = id(node)
    if key in sizes:
        return sizes[key]
    sizes[key] = MAX_YAML_NODES + 1  # a node that contains itself (recursive alias) expands without end
    if isinstance(node, yaml.SequenceNode):
        total = 1 + sum(expanded_size(child, sizes) for child in node.value)
    elif isinstance(node, yaml.MappingNode):
        total = 1 + sum(expanded_size(k, sizes) + expanded_size(v, sizes) for k, v in node.value)
    else:
        total = 1
    sizes[key] = min(total, MAX_YAML_NODES + 1)
    return sizes[key]


def duplicate_key(node: yaml.Node) -> str | None:
    """``'KEY' at lines A and B`` for the first mapping of ``node`` (its sub-tree, each node once) that holds a key twice
    (YAML forbids it; PyYAML keeps the last silently, so a file edited by appending ``name: other`` renamed its
    vehicle without a word), or None. Merge keys (``<<``) are YAML's own and left alone."""
    seen, stack = set(), [node]
    while stack:
        current = stack.pop()
        if id(current) in seen:
            continue
        seen.add(id(current))
        if isinstance(current, yaml.MappingNode):
            lines: dict = {}
            for key, value in current.value:
                if isinstance(key, yaml.ScalarNode) and key.value != "<<":
                    if key.value in lines:
                        return f"{key.value!r} at lines {lines[key.value]} and {key.start_mark.line + 1}"
                    lines[key.value] = key.start_mark.line + 1
                stack += [key, value]
        elif isinstance(current, yaml.SequenceNode):
            stack += current.value
    return None


def read_yaml(path: str | Path, what: str):
    """The parsed document of the YAML file ``path`` (``what`` names it in errors, e.g. "vehicle config").

    Raises ConfigError in one line naming the file: missing, not a regular file, larger
    than :data:`MAX_YAML_BYTES`, not UTF-8, not valid YAML, expanding (through
    aliases) to more than :data:`MAX_YAML_NODES` nodes, or a mapping holding a key twice (:func:`duplicate_key`).
    """
    path = check_regular_file(path, what)
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise ConfigError(f"{path}: {what} is {size} bytes, larger than the {MAX_YAML_BYTES} read")
        text = path.read_bytes().decode("utf-8")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read {what}: {err.strerror or reason(err)}") from err
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: {what} is not UTF-8 text (byte {err.start}: {err.object[err.start:err.start + 1]!r})") from err
    loader = None
    try:
        loader = yaml.SafeLoader(text)
        node = loader.get_single_node()
        if node is None:
            return None
        if expanded_size(node) > MAX_YAML_NODES:
            raise ConfigError(f"{path}: {what} expands (through YAML aliases) to more than {MAX_YAML_NODES} nodes")
        twice = duplicate_key(node)
        if twice:
            raise ConfigError(f"{path}: {what} holds key {twice} (a key may appear once; which one was meant?)")
        return loader.construct_document(node)
    except ConfigError:
        raise
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        line = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or reason(err)
        raise ConfigError(f"{path}: {what} is not valid YAML{line}: {' '.join(str(problem).split())}") from err
    except (ValueError, TypeError) as err:  # e.g. a timestamp 2024-13-01 that the resolver took for a date
        raise ConfigError(f"{path}: {what} holds a value YAML cannot construct ({reason(err)})") from err
    except RecursionError as err:
        raise ConfigError(f"{path}: {what} nests deeper than YAML can be read") from err
    finally:
        if loader is not None:
            loader.dispose()


def yaml_number(value) -> float:
    """``float(value)`` of a number read from YAML, refusing a YAML boolean (``true`` would be 1.0, ``false`` 0.0: a
    misplaced flag read as a mass or a bound); TypeError or ValueError as ``float`` raises them, for the caller's
    one-line error naming the key. A string of a number stays accepted (PyYAML reads ``1e-5`` as one)."""
    if isinstance(value, bool):
        raise TypeError(f"a YAML boolean ({str(value).lower()}) is not a number")
    return float(value)
