"""Model files: ``.npz`` (``allow_pickle=False``) with a JSON header; read and validated in one place.

Read with bounds, before anything is allocated: the file must be a regular file and a
zip archive; each member an ``.npy`` array whose declared shape and dtype need at most
:data:`MAX_ARRAY_BYTES` and no more bytes than the member holds (a header declaring
petabytes is refused, not allocated), and no member may inflate beyond
:data:`MAX_ARRAY_BYTES`. The header's fields have the types the loaders expect.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from quad_modelling.core.input_files import check_regular_file
from quad_modelling.core.variables import VARIABLES
from quad_modelling.errors import ModelError, reason

FORMAT = "quad_modelling.narx"
"""Format name in every model file header (NARX and hybrid files share it)."""

FORMAT_VERSION = 2
"""2: NARX nets may be incremental (config ``incremental``, array ``y_step``); version-1 files are refused."""

MAX_ARRAY_BYTES = 64 << 20
"""Largest array [bytes] a model file may hold (the thesis NARX needs about 50 kB)."""

MAX_MEMBERS = 64
"""Most arrays a model file may hold."""

HEADER_TYPES: dict[str, tuple[type, ...]] = {
    "format": (str,), "format_version": (int,), "kind": (str,), "vehicle": (str,), "variables": (list,),
    "outputs": (list,), "config": (dict,), "dt": (int, float), "training": (dict,),
}
"""Type of each header field the loaders read (``training`` may be absent)."""


def _check_archive(path: Path) -> None:
    """ModelError, before numpy allocates anything, unless ``path`` is a zip of at most MAX_MEMBERS .npy
    arrays, each of a plain dtype, at most MAX_ARRAY_BYTES uncompressed and declaring no more data than it holds."""
    check_regular_file(path, "model file", ModelError)
    if not zipfile.is_zipfile(path):
        raise ModelError(f"{path}: not a readable model file: not an .npz (zip) archive; expected a file written by quad-modelling train")
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
            if len(members) > MAX_MEMBERS:
                raise ModelError(f"{path}: holds {len(members)} arrays, a model file has at most {MAX_MEMBERS}")
            names = [member.filename for member in members]
            twice = next((name for name in names if names.count(name) > 1), None)
            if twice is not None:  # numpy reads one of them: which one is the model?
                raise ModelError(f"{path}: holds member {twice} twice; corrupt model file")
            for member in members:
                where = f"{path}: member {member.filename}"
                if member.file_size > MAX_ARRAY_BYTES:
                    raise ModelError(f"{where} inflates to {member.file_size} bytes, more than the {MAX_ARRAY_BYTES} a model array may have")
                if not member.filename.endswith(".npy"):
                    raise ModelError(f"{where} is not a .npy array")
                with archive.open(member) as stream:
                    version = np.lib.format.read_magic(stream)
                    read_header = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}.get(version)
                    if read_header is None:
                        raise ValueError(f"member {member.filename}: .npy format version {version} is not read")
                    shape, _, dtype = read_header(stream, max_header_size=10000)
                    header_bytes = stream.tell()
                if dtype.hasobject:
                    raise ModelError(f"{where} holds Python objects (dtype {dtype}), not numbers or text")
                declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if declared > member.file_size - header_bytes:
                    raise ModelError(f"{where} declares a {tuple(shape)} {dtype} array ({declared} bytes) but holds "
                                     f"{member.file_size - header_bytes}; corrupt model file")
                if dtype.kind not in ("U" if member.filename == "header.npy" else "biuf") or dtype.names is not None:
                    raise ModelError(f"{where} holds dtype {dtype}, not {'text' if member.filename == 'header.npy' else 'real numbers'}")
    except ModelError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, NotImplementedError, RuntimeError, zlib.error) as err:
        raise ModelError(f"{path}: not a readable model file ({reason(err)})") from err


def header_int(value) -> int:
    """A whole-number setting of a model header; TypeError for anything else (JSON's "10" or true is no count)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{str(value)[:40]!r} is not a whole number")
    return value


def header_float(value) -> float:
    """A number setting of a model header; TypeError for a string or a boolean."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{str(value)[:40]!r} is not a number")
    return float(value)


def header_flag(value) -> bool:
    """A true/false setting of a model header; TypeError for anything else ("no" was read as true)."""
    if not isinstance(value, bool):
        raise TypeError(f"{str(value)[:40]!r} is not true or false")
    return value


def _unique_keys(pairs: list) -> dict:
    """A JSON object's pairs as a dict; ValueError for a key given twice (json keeps the last, silently)."""
    keys = [key for key, _ in pairs]
    twice = next((key for key in keys if keys.count(key) > 1), None)
    if twice is not None:
        raise ValueError(f"key {twice!r} appears twice")
    return dict(pairs)


def _check_header(path: Path, header: dict) -> None:
    for key, types in HEADER_TYPES.items():
        if key == "training" and key not in header:
            continue
        value = header.get(key)
        if not isinstance(value, types) or isinstance(value, bool):
            raise ModelError(f"{path}: header field {key!r} is {type(value).__name__} {str(value)[:40]!r}, "
                             f"expected {' or '.join(t.__name__ for t in types)}")
    if not (np.isfinite(header["dt"]) and header["dt"] > 0):
        raise ModelError(f"{path}: header field 'dt' must be a positive sample period [s], got {header['dt']}")


# ---- files ----------------------------------------------------------------------
def read_model_file(path: str | Path, kind: str, outputs: Sequence[str], vehicle: str | None = None,
                    reads: Callable[[str], bool] | None = None) -> tuple[dict, dict[str, np.ndarray]]:
    """Header and arrays of a model file, checked against ``kind``, ``vehicle`` and VARIABLES.

    ``reads(name)``: whether the caller's loader reads an array of that name. A file holding an array the loader
    does not read is refused: the format version is shared by every kind, so a newer program's file with a part
    this one does not know (the direct model's vertical map, session 22) would otherwise predict without it, silently.

    Raises ModelError naming the file and the mismatch (missing, corrupt, other
    format/version/kind/vehicle/variable set, an unknown array).
    """
    path = Path(path)
    _check_archive(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            contents = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError) as err:
        if isinstance(err, ModelError):
            raise
        raise ModelError(f"{path}: not a readable model file ({reason(err)})") from err
    if "header" not in contents:
        raise ModelError(f"{path}: no header: not a quad_modelling model file")
    try:
        header = json.loads(str(contents.pop("header")), object_pairs_hook=_unique_keys)
    except (ValueError, RecursionError) as err:
        raise ModelError(f"{path}: corrupt model header ({reason(err)})") from err
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ModelError(f"{path}: not a {FORMAT} model file (format {header.get('format') if isinstance(header, dict) else None!r})")
    _check_header(path, header)
    if header.get("format_version") != FORMAT_VERSION:
        raise ModelError(f"{path}: model format version {header.get('format_version')!r}, this program reads version {FORMAT_VERSION}; "
                         f"retrain the model with quad-modelling train")
    if header.get("kind") != kind:
        raise ModelError(f"{path}: is a {header.get('kind')!r} model, expected {kind!r}")
    unknown = sorted(name for name in contents if reads is not None and not reads(name))
    if unknown:
        raise ModelError(f"{path}: holds array {unknown[0]!r}, which this program's {kind} model does not read (a file from a newer "
                         f"quad-modelling?): predicting without it would be wrong; update quad-modelling or retrain the model")
    if vehicle is not None and header.get("vehicle") != vehicle:
        raise ModelError(f"{path}: model was trained for vehicle {header.get('vehicle')!r}, not {vehicle!r}")
    if header.get("variables") != list(VARIABLES) or header.get("outputs") != list(outputs):
        raise ModelError(
            f"{path}: model variable set {header.get('variables')} / outputs {header.get('outputs')} "
            f"differs from this program's {list(VARIABLES)} / {list(outputs)}"
        )
    return header, contents
