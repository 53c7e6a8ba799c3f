"""Model files: ``.npz`` (``allow_pickle=False``) with a JSON header; read and validated in one place."""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from quad_modelling.core.variables import VARIABLES
from quad_modelling.errors import ModelError, reason

FORMAT = "quad_modelling.narx"
"""Format name in every model file header (NARX and hybrid files share it)."""

FORMAT_VERSION = 1


MAX_MEMBER_BYTES = 256 << 20
"""Largest array a model file may hold [bytes, uncompressed]: a thesis NARX model is a few hundred kB."""


def _check_member(path: Path, archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> None:
    """Refuse, before numpy allocates anything, a member larger than MAX_MEMBER_BYTES, one that is not a
    plain .npy array, or whose .npy header declares more data than the member holds."""
    where = f"{path}: member {info.filename}"
    if info.file_size > MAX_MEMBER_BYTES:
        raise ModelError(f"{where} is {info.file_size} bytes uncompressed, larger than the {MAX_MEMBER_BYTES} a model file may hold")
    if not info.filename.endswith(".npy"):
        raise ModelError(f"{where} is not a .npy array")
    with archive.open(info) as stream:
        version = np.lib.format.read_magic(stream)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read_header(stream)
        header_bytes = stream.tell()
    if dtype.hasobject:
        raise ModelError(f"{where} holds Python objects (dtype {dtype}), not numbers or text")
    declared = math.prod(shape) * dtype.itemsize
    if declared > info.file_size - header_bytes:
        raise ModelError(f"{where} declares a {tuple(shape)} {dtype} array ({declared} bytes) but holds {info.file_size - header_bytes}")


# ---- files ----------------------------------------------------------------------
def read_model_file(path: str | Path, kind: str, outputs: Sequence[str], vehicle: str | None = None) -> tuple[dict, dict[str, np.ndarray]]:
    """Header and arrays of a model file, checked against ``kind``, ``vehicle`` and VARIABLES.

    Raises ModelError naming the file and the mismatch (missing, corrupt, other
    format/version/kind/vehicle/variable set).
    """
    path = Path(path)
    if not path.exists():
        raise ModelError(f"{path}: no such model file")
    if not path.is_file():
        raise ModelError(f"{path}: not a model file (not a regular file)")
    try:
        if not zipfile.is_zipfile(path):
            raise ModelError(f"{path}: not a readable model file (not a zip archive: a model file is a .npz archive)")
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                _check_member(path, archive, info)
        with np.load(path, allow_pickle=False) as archive:
            contents = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError) as err:
        if isinstance(err, ModelError):
            raise
        raise ModelError(f"{path}: not a readable model file ({reason(err)})") from err
    if "header" not in contents:
        raise ModelError(f"{path}: no header: not a quad_modelling model file")
    try:
        header = json.loads(str(contents.pop("header")))
    except (ValueError, RecursionError) as err:
        raise ModelError(f"{path}: corrupt model header ({reason(err)})") from err
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ModelError(f"{path}: not a {FORMAT} model file (format {header.get('format') if isinstance(header, dict) else None!r})")
    if header.get("format_version") != FORMAT_VERSION:
        raise ModelError(f"{path}: model format version {header.get('format_version')!r}, this program reads version {FORMAT_VERSION}")
    if header.get("kind") != kind:
        raise ModelError(f"{path}: is a {header.get('kind')!r} model, expected {kind!r}")
    if vehicle is not None and header.get("vehicle") != vehicle:
        raise ModelError(f"{path}: model was trained for vehicle {header.get('vehicle')!r}, not {vehicle!r}")
    if header.get("variables") != list(VARIABLES) or header.get("outputs") != list(outputs):
        raise ModelError(
            f"{path}: model variable set {header.get('variables')} / outputs {header.get('outputs')} "
            f"differs from this program's {list(VARIABLES)} / {list(outputs)}"
        )
    return header, contents
