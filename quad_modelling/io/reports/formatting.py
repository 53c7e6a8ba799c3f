"""Text building blocks of every report: the one Markdown table writer, numbers in display units, JSON.

Reports (``evaluate``'s tables.md, ``diagnose``'s report.md and validation.md, the ``run-bag``
summary) show the thesis's display units: a variable's SI value ``x_si`` is shown as
``x_display = x_si * factor`` with ``(unit, factor) = DISPLAY[variable]``
(:data:`quad_modelling.core.variables.DISPLAY`: m/s, m/s², deg/s, deg/s²; factor 180/π for the
angular variables, 1 otherwise). Their JSON documents keep the SI units
(:data:`quad_modelling.core.variables.SI_UNIT`).
"""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Iterable, Sequence

import numpy as np

from quad_modelling.core.variables import DISPLAY

RMS_DIGITS = 3
"""Significant digits of an RMS error or other magnitude in display units (thesis Tables 5-1/5-2 give 2-3)."""

TIC_DECIMALS = 2
"""Decimals of a Theil inequality coefficient (0 = perfect, 1 = no match), as the thesis tables."""


REPORT_WIDTH = 100
"""Longest line of a Markdown report or console summary [characters]: prose is wrapped to it
(:func:`prose`), and a table that would be wider becomes a list (:func:`narrow_table`)."""


def markdown_table(header: Sequence[object], rows: Iterable[Sequence[object]], align: bool = False,
                   label_columns: int = 1) -> list[str]:
    """The lines of a Markdown table: ``| a | b |``, the rule ``|---|---|``, one line per row.

    Cells are ``str()``-ed; a ``|`` inside a cell is written ``\\|`` so it cannot split the cell.
    ``align=True`` pads every column to its widest cell (at least 3): the first ``label_columns``
    left-aligned, the others (numbers) right-aligned and marked so in the rule (``---:``), so the
    table also reads in a terminal.
    Raises ValueError when a row has another number of cells than the header.
    """
    head = [_cell(c) for c in header]
    body = [[_cell(c) for c in row] for row in rows]
    for row in body:
        if len(row) != len(head):
            raise ValueError(f"Markdown table row {row} has {len(row)} cells, the header {head} has {len(head)}")
    if not align:
        return [_line(head), "|" + "---|" * len(head)] + [_line(row) for row in body]
    widths = [max(3, len(head[k]), *(len(row[k]) for row in body)) for k in range(len(head))]

    def padded(row: list[str]) -> str:
        return _line([c.ljust(w) if k < label_columns else c.rjust(w) for k, (c, w) in enumerate(zip(row, widths))])

    rule = "|" + "|".join("-" * (w + 2) if k < label_columns else "-" * (w + 1) + ":" for k, w in enumerate(widths)) + "|"
    return [padded(head), rule] + [padded(row) for row in body]


def narrow_table(header: Sequence[object], rows: Iterable[Sequence[object]], width: int = REPORT_WIDTH) -> list[str]:
    """:func:`markdown_table` when every line fits in ``width`` characters; otherwise one bullet per row,
    ``- cell 1: header 2 cell 2; header 3 cell 3`` wrapped to ``width`` (long names or units cannot make
    a report line wider than ``width``)."""
    rows = [list(row) for row in rows]
    table = markdown_table(header, rows)
    if all(len(line) <= width for line in table):
        return table
    out = []
    for row in rows:
        text = f"{row[0]}: " + "; ".join(f"{h} {c}" for h, c in zip(header[1:], row[1:]))
        out += prose(text, width, first="- ", rest="  ")
    return out


def prose(text: str, width: int = REPORT_WIDTH, first: str = "", rest: str = "") -> list[str]:
    """``text`` wrapped to lines of at most ``width`` characters (:func:`textwrap.wrap`), the first line
    prefixed by ``first``, the others by ``rest`` (e.g. ``"- "`` and ``"  "`` for a list item); a word
    longer than a line (a path) is broken. Empty text gives ``[first.rstrip()]``."""
    lines = textwrap.wrap(text, width, initial_indent=first, subsequent_indent=rest, break_on_hyphens=False)
    return lines or [first.rstrip()]


def _cell(value: object) -> str:
    return str(value).replace("|", "\\|")


def _line(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def display_unit(variable: str) -> str:
    """Display unit of one of the 18 variables (``roll_rate`` -> ``deg/s``)."""
    return DISPLAY[variable][0]


def display_number(variable: str, value_si: float) -> str:
    """``value_si`` [SI unit of ``variable``] in display units, :data:`RMS_DIGITS` significant digits, no unit."""
    return f"{value_si * DISPLAY[variable][1]:.{RMS_DIGITS}g}"


def display_value(variable: str, value_si: float) -> str:
    """``value_si`` in display units with the unit: ``display_value("roll_acc", 0.0686)`` -> ``"3.93 deg/s2"``."""
    return f"{display_number(variable, value_si)} {display_unit(variable)}"


def variable_label(variable: str) -> str:
    """Row label naming the variable and its display unit: ``vel_x [m/s]``."""
    return f"{variable} [{display_unit(variable)}]"


def tic_text(tic: float) -> str:
    """A Theil inequality coefficient with :data:`TIC_DECIMALS` decimals."""
    return f"{tic:.{TIC_DECIMALS}f}"


def percent(fraction: float | None, decimals: int = 1) -> str:
    """``0.4`` -> ``"40.0%"``; ``None`` (not measured) -> ``"-"``."""
    return "-" if fraction is None else f"{fraction:.{decimals}%}"


def json_text(document: dict) -> str:
    """A report's JSON document, indented by 2; numpy scalars and arrays become numbers and lists, and a number that
    is not finite (a sigma the fit cannot give: NaN) null -- JSON has no NaN, and strict parsers (JavaScript's
    JSON.parse, jq) refuse Python's bare ``NaN``."""
    return json.dumps(_finite(document), indent=2, allow_nan=False)


def _finite(value):
    """``value`` with numpy scalars and arrays made Python numbers and lists and every non-finite float None."""
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item) for item in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
