"""Fuzz: NanoBench CSV and .csv.gz files a user could produce, through ``load_flight``."""

from __future__ import annotations

import gzip
import tempfile
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.errors import QuadModellingError
from quad_modelling.io.loader import load_flight
from test.conftest import FIXTURES
from test.fuzz.properties import byte_edits, mutated, outcome

LINES = gzip.open(FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", "rt").read().splitlines()[:31]
HEADER = LINES[0].split(",")
ROWS = len(LINES) - 1
GZIP = gzip.compress("\n".join(LINES).encode(), mtime=0)

CELLS = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "1e300", "-1e300", "1e-300", "", " ", "abc", "0x10", "1,5", "65536", "-1", "1e9"]),
    st.floats().map(repr),
    st.text(max_size=8),
)

EDITS = st.one_of(
    st.tuples(st.just("drop_column"), st.integers(0, len(HEADER) - 1)),
    st.tuples(st.just("duplicate_column"), st.integers(0, len(HEADER) - 1)),
    st.tuples(st.just("cell"), st.integers(1, ROWS), st.integers(0, len(HEADER) - 1), CELLS),
    st.tuples(st.just("swap_rows"), st.integers(1, ROWS), st.integers(1, ROWS)),
    st.tuples(st.just("keep_rows"), st.integers(0, ROWS)),
    st.tuples(st.just("cut_text"), st.integers(0, 20_000)),
)


def apply(edit: tuple, lines: list[list[str]]) -> list[list[str]] | str:
    kind = edit[0]
    if kind == "drop_column":
        return [[c for i, c in enumerate(row) if i != edit[1]] for row in lines]
    if kind == "duplicate_column":
        return [row + [row[edit[1]]] if edit[1] < len(row) else row for row in lines]
    if kind == "cell":
        _, row, column, value = edit
        if column < len(lines[row]) if row < len(lines) else False:
            lines[row][column] = value
        return lines
    if kind == "swap_rows":
        _, i, j = edit
        if max(i, j) < len(lines):
            lines[i], lines[j] = lines[j], lines[i]
        return lines
    if kind == "keep_rows":
        return lines[: edit[1] + 1]
    return "\n".join(",".join(row) for row in lines)[: edit[1]]


def csv_text(edits: list[tuple]) -> str:
    lines = [line.split(",") for line in LINES]
    for edit in edits:
        result = apply(edit, lines)
        if isinstance(result, str):
            return result
        lines = result
    return "\n".join(",".join(row) for row in lines) + "\n"


def check(data: bytes, name: str):
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / name
        path.write_bytes(data)
        result = outcome(lambda: load_flight(path), path)
        assert isinstance(result, (FlightLog, QuadModellingError))
        return result


@settings(max_examples=150)
@given(st.lists(EDITS, max_size=3), st.booleans())
def test_edited_csv_gives_a_flight_or_one_line(edits, compressed):
    text = csv_text(edits).encode("utf-8", "surrogatepass")
    check(gzip.compress(text, mtime=0) if compressed else text, "flight.csv.gz" if compressed else "flight.csv")


@settings(max_examples=60)
@given(byte_edits(len(GZIP)))
def test_corrupt_gzip_gives_one_line(edits):
    check(mutated(GZIP, edits), "flight.csv.gz")


@settings(max_examples=40)
@given(st.binary(max_size=3000), st.sampled_from(["flight.csv", "flight.csv.gz"]))
def test_random_bytes_give_one_line(data, name):
    check(data, name)


def test_unedited_rows_are_a_flight():
    """The base of the mutations is itself a valid flight (so the property above tests edits, not a broken base)."""
    assert len(check("\n".join(LINES).encode(), "flight.csv")) == ROWS
