"""Atomic outputs: write to a temporary sibling, rename when complete.

An existing output is never replaced unless ``force`` is true, and never when it
is, lies inside or contains one of the command's inputs (not even with
``force``); a failed or interrupted write leaves nothing behind (the staging
path is removed, and the final rename cannot be cut in half by SIGINT/SIGTERM).
A replaced output is swapped in one step (:func:`_replace`): a reader of it finds
the old or the new output at every moment.
A full disk, a read-only file system or a name too long for the file system is
one :class:`OutputDirError` naming the output.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import shutil
import signal
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path

from quad_modelling.errors import ConfigError, OutputExistsError, QuadModellingError, shown_path

STAGING_SUFFIX_LEN = len(".tmp-") + 8 + 1
"""Characters the staging and backup names add to an output's name (``.NAME.tmp-XXXXXXXX``)."""

WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.ENAMETOOLONG}
"""OSErrors of writing an output that are the output's fault, not a bug: reported as one line."""


class OutputDirError(QuadModellingError, PermissionError):
    """The output's directory is missing or not writable, or the output cannot be written there."""


class OutputOverlapsInputError(QuadModellingError, ValueError):
    """The output path is an input, lies inside one or contains one: refused even with --force."""


def _name_max(directory: Path) -> int:
    try:
        return os.pathconf(directory, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


FILE_SUFFIXES = (".mat", ".csv", ".gz", ".ulg", ".mcap", ".npz", ".yaml", ".yml", ".json")
"""Names of files a command reads or writes: a bag directory named so would pass for one."""


def check_bag_name(path: Path, flag: str = "-o") -> None:
    """ConfigError (one line) when the bag directory ``path`` is named like a file of another format
    (``-o flight.csv`` makes a directory a user takes for a CSV)."""
    if path.suffix.lower() in FILE_SUFFIXES:
        raise ConfigError(f"{flag} {path}: an MCAP bag is a directory; a name ending in {path.suffix} passes for a "
                          f"{path.suffix.lstrip('.')} file: name the bag without it")


OUTPUT_MARKERS = ("results.json", "diagnosis.json", "validation.json", "layout.yaml", "metadata.yaml")
"""The files that mark a directory as an earlier output of some verb (evaluate, run-bag and merge; diagnose; diagnose
--validate; export; a bag's rosbag2 metadata): a verb passes its own (``check_output``'s ``markers``)."""

BAG_MARKERS = ("metadata.yaml",)
"""What marks an earlier output of a verb that writes bags (convert): ``convert -o EVAL --force`` deleted an
evaluation's results, any verb's marker counting."""


def earlier_output(path: Path, markers: Iterable[str]) -> bool:
    """Whether directory ``path`` holds one of ``markers``, or is a directory of such directories (convert's bags of
    several inputs): an earlier output of the verb that writes those files."""
    markers = tuple(markers)
    if any((path / marker).exists() for marker in markers):
        return True
    entries = [entry for entry in path.iterdir() if not entry.name.startswith(".")]
    return bool(entries) and all(entry.is_dir() and any((entry / marker).exists() for marker in markers) for entry in entries)


def check_output(path: Path, force: bool, inputs: Iterable[str | Path] = (), flag: str = "-o",
                 directory: bool = False, markers: Iterable[str] = OUTPUT_MARKERS) -> None:
    """Refuse an output that names no file (``''``, ``.``, ``..``), is too long a name, is or holds an
    input (``inputs``: every file the command reads), exists without force, or whose directory we
    cannot write to; ``flag`` is the option that named it, as the error says. A ``directory`` output refuses an
    existing regular file even with force (``--force`` replaces an earlier output directory, not another file), and
    every output refuses an existing directory that is not empty and not an earlier output (:func:`earlier_output` by
    the verb's ``markers``, default :data:`OUTPUT_MARKERS`): ``-o precious --force`` deleted a directory of the user's
    notes, ``evaluate -o my_recording --force`` a PX4 bag."""
    given = str(path)  # as typed: Path("") is "."
    path = Path(path)
    if path.name in ("", ".", ".."):
        raise OutputDirError(f"{flag} {given!r}: the output must name a new file or directory, not {given!r}")
    parent = path.parent if str(path.parent) else Path(".")
    try:
        parent_is_dir = parent.is_dir()
    except OSError as err:  # a path longer than the file system allows (ENAMETOOLONG), a loop of links
        raise OutputDirError(f"{shown_path(parent)}: output directory path cannot be looked up ({err.strerror})") from err
    limit = _name_max(parent if parent_is_dir else Path(".")) - STAGING_SUFFIX_LEN
    if len(os.fsencode(path.name)) > limit:
        raise OutputDirError(f"{path.name[:40]}...: output name is {len(os.fsencode(path.name))} bytes long; "
                             f"the file system allows {limit} here")
    if not directory and given.endswith(os.sep) and path.suffix:  # train -o m.npz/ wrote the file m.npz
        raise OutputDirError(f"{flag} {given!r}: ends in {os.sep!r} (a directory) but names a {path.suffix} file; drop the {os.sep!r}")
    check_not_input(path, inputs, flag)
    if path.is_symlink() and not path.exists() and not force:  # exists() follows the link: a dangling one was replaced
        raise OutputExistsError(f"{path}: exists (a symbolic link to {os.readlink(path)}, which does not); pass --force to overwrite")
    if path.exists() and not force:
        raise OutputExistsError(f"{path}: exists; pass --force to overwrite")
    if directory and path.exists() and not path.is_dir():
        raise OutputExistsError(f"{flag} {path}: an existing file, not an output directory; --force replaces an earlier "
                                "output directory only: choose another name")
    markers = tuple(markers)
    if path.is_dir() and any(path.iterdir()) and not earlier_output(path, markers):
        raise OutputExistsError(f"{flag} {path}: an existing directory that is no earlier output of this command (none of "
                                f"{', '.join(markers)}); --force replaces an earlier output only: choose another name or "
                                "empty it")
    if not parent_is_dir:
        raise OutputDirError(f"{flag} {path}: its parent directory {parent} does not exist (or is not a directory); "
                             f"create it first")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputDirError(f"{parent}: output directory is not writable")


def check_not_input(path: Path, inputs: Iterable[str | Path], flag: str = "-o") -> None:
    """OutputOverlapsInputError when ``path`` is one of ``inputs``, lies inside one or contains one
    (symbolic links resolved): overwriting or deleting an input is never what the user meant."""
    out = Path(path).resolve()
    for given in inputs:
        if given is None or str(given) == "":
            continue
        source = Path(given).resolve()
        if source.suffix == ".mcap" and (source.parent / "metadata.yaml").is_file():
            source = source.parent  # a bag named by its .mcap file: the bag directory is the input
        if out == source:
            relation = "is the input"
        elif source in out.parents:
            relation = "lies inside the input"
        elif out in source.parents:
            relation = "contains the input"
        else:
            continue
        raise OutputOverlapsInputError(f"{flag} {path}: the output {relation} {given}; choose another output (refused even with --force)")


def check_distinct_inputs(paths: Iterable[str | Path], flag: str = "input", other: Iterable[str | Path] = (),
                          other_flag: str = "") -> None:
    """ConfigError when a file is given twice among ``paths`` (symbolic links and ``./`` resolved; its windows would
    count twice), or is also among ``other`` (``other_flag``'s files, e.g. ``--val-flights``)."""
    seen: dict[Path, str] = {}
    for given in paths:
        key = Path(given).resolve()
        if key in seen:
            raise ConfigError(f"{flag} {given}: given twice (also as {seen[key]}); every flight counts once, give it once")
        seen[key] = str(given)
    for given in other:
        if Path(given).resolve() in seen:
            raise ConfigError(f"{other_flag} {given}: also a {flag} ({seen[Path(given).resolve()]}); a flight is one or the other")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink()


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT/SIGTERM wait until the block is done (the final renames are never cut in half)."""
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


@contextlib.contextmanager
def atomic_output(path: str | Path, force: bool = False, markers: Iterable[str] = OUTPUT_MARKERS) -> Iterator[Path]:
    """Yield a temporary path with the same name, in a hidden staging directory next to
    ``path``; rename it onto ``path`` on success.

    The temporary path does not exist when yielded: the caller creates a file or
    a directory there (keeping the final name, so a bag's inner ``.mcap`` file is
    named after the bag). On any exception (KeyboardInterrupt and SystemExit
    included) the staging directory is removed and the error re-raised; a full
    disk or read-only file system becomes one OutputDirError. ``markers``: as :func:`check_output`'s.
    """
    path = Path(path)
    check_output(path, force, markers=markers)
    staging = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        staging.mkdir()
    except OSError as err:
        raise OutputDirError(f"{path.parent}: cannot write in the output directory ({err.strerror})") from err
    tmp = staging / path.name
    try:
        try:
            yield tmp
        except OSError as err:
            if isinstance(err, QuadModellingError) or err.errno not in WRITE_ERRNOS:
                raise
            raise OutputDirError(f"{path}: cannot write the output ({err.strerror}); nothing was written") from err
        if not tmp.exists():
            raise FileNotFoundError(f"{tmp}: nothing was written")
        with _signals_held():
            earlier = path.exists() or path.is_symlink()
            try:
                _replace(tmp, path) if earlier else tmp.rename(path)
            except OSError as err:  # an immutable or foreign earlier output: one line, not a traceback
                raise OutputDirError(f"{path}: cannot put the output in place ({err.strerror}); nothing was written"
                                     + (", the earlier output kept" if earlier else "")) from err
    finally:
        _remove(staging)


RENAME_EXCHANGE = 2
"""``renameat2`` flag (linux/fs.h): swap two paths in one step."""


def _exchange(a: Path, b: Path) -> bool:
    """Swap ``a`` and ``b`` in one step (Linux ``renameat2(RENAME_EXCHANGE)``, glibc 2.28); False where the system or
    the file system cannot (then nothing was done)."""
    rename2 = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if rename2 is None:
        return False
    at_cwd = -100  # AT_FDCWD: paths relative to the working directory
    if rename2(at_cwd, os.fsencode(a), at_cwd, os.fsencode(b), RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.EPERM):
        return False
    raise OSError(code, os.strerror(code), str(b))


def _replace(tmp: Path, path: Path) -> None:
    """Put ``tmp`` where the existing ``path`` is, so that a reader of ``path`` at any moment finds the old or the new
    output, never none: a file over a file by ``os.replace`` (one rename); a directory by swapping the two
    (:func:`_exchange`), then removing the old one; where the system cannot swap, the old output renamed aside first
    (a moment without it)."""
    if tmp.is_file() and path.is_file() and not path.is_symlink():
        os.replace(tmp, path)
    elif _exchange(tmp, path):
        _remove(tmp)
    else:
        backup = path.with_name(f".{path.name}.old-{uuid.uuid4().hex[:8]}")
        path.rename(backup)
        try:
            tmp.rename(path)
        except OSError:
            backup.rename(path)  # the earlier output back where it was
            raise
        _remove(backup)


def name_final_paths(files: list[Path], moves: dict[Path, Path]) -> None:
    """Rewrite the staging paths written into ``files`` (``moves``: staging path -> where it ends up, the longest
    first), so they name the output the user gets, not a hidden directory that is gone once the output is in place
    (run-bag: the params file its nodes were given and the logs they wrote)."""
    for path in files:
        text = original = path.read_text(errors="replace")
        for staged, final in moves.items():
            for form in dict.fromkeys((str(staged.absolute()), str(staged))):
                text = text.replace(form, str(final.absolute() if form == str(staged.absolute()) else final))
        if text != original:
            path.write_text(text)
