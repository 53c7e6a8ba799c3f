"""The one property every reader keeps, and byte-level mutations shared by the fuzz tests.

Property: reading a file a user could hand in gives a validated result (a FlightLog is
validated on construction), or raises a :class:`~quad_modelling.errors.QuadModellingError`
whose message is one line and names the file; never any other exception. A hang is
caught by the hypothesis deadline of the ``ci`` profile (test/conftest.py).
"""

from __future__ import annotations

from pathlib import Path

from hypothesis import strategies as st

from quad_modelling.errors import QuadModellingError

MAX_MESSAGE = 1000
"""Longest message a reader error may have [characters]: a line a user reads, not a dump."""


def outcome(call, path: str | Path):
    """Run ``call()``; return its result, or the project error it raised after checking its message.

    Any other exception propagates (and fails the test with its traceback)."""
    try:
        return call()
    except QuadModellingError as err:
        message = str(err)
        assert "\n" not in message and "\r" not in message, f"multi-line message: {message!r}"
        assert str(path) in message, f"message does not name {path}: {message!r}"
        assert len(message) <= MAX_MESSAGE, f"message of {len(message)} characters: {message[:300]!r}..."
        return err


@st.composite
def byte_edits(draw, size: int, max_flips: int = 8) -> tuple:
    """Edits of a file of ``size`` bytes: ("truncate", length), or ("flip" | "overwrite", [(offset, value)...]).

    Drawn as a short description, not as the bytes, so a failing example prints in one line."""
    kind = draw(st.sampled_from(["flip", "overwrite", "truncate"]))
    if kind == "truncate":
        return kind, draw(st.integers(0, max(size - 1, 0)))
    return kind, draw(st.lists(st.tuples(st.integers(0, size - 1), st.integers(0, 255 if kind == "overwrite" else 7)), min_size=1, max_size=max_flips))


def mutated(original: bytes, edits: tuple) -> bytes:
    """``original`` with :func:`byte_edits` applied: bits flipped, bytes overwritten, or cut short."""
    kind, what = edits
    if kind == "truncate":
        return original[:what]
    data = bytearray(original)
    for offset, value in what:
        data[offset] = data[offset] ^ (1 << value) if kind == "flip" else value
    return bytes(data)


YAML_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
)

yaml_values = st.recursive(
    YAML_SCALARS,
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(st.text(max_size=10), children, max_size=4)),
    max_leaves=20,
)
"""Any document ``yaml.safe_dump`` writes: nested lists and mappings of scalars, NaN/inf and huge ints included."""
