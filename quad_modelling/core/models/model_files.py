"""Model files: ``.npz`` (``allow_pickle=False``) with a JSON header; read and validated in one place."""

from __future__ import annotations

import json
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from quad_modelling.core.variables import VARIABLES
from quad_modelling.errors import ModelError

FORMAT = "quad_modelling.narx"
"""Format name in every model file header (NARX and hybrid files share it)."""

FORMAT_VERSION = 1


# ---- files ----------------------------------------------------------------------
def read_model_file(path: str | Path, kind: str, outputs: Sequence[str], vehicle: str | None = None) -> tuple[dict, dict[str, np.ndarray]]:
    """Header and arrays of a model file, checked against ``kind``, ``vehicle`` and VARIABLES.

    Raises ModelError naming the file and the mismatch (missing, corrupt, other
    format/version/kind/vehicle/variable set).
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            contents = {name: archive[name] for name in archive.files}
    except FileNotFoundError as err:
        raise ModelError(f"{path}: no such model file") from err
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise ModelError(f"{path}: not a readable model file ({err})") from err
    if "header" not in contents:
        raise ModelError(f"{path}: no header: not a quad_modelling model file")
    try:
        header = json.loads(str(contents.pop("header")))
    except ValueError as err:
        raise ModelError(f"{path}: corrupt model header ({err})") from err
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
