"""The one Markdown table writer and the display-unit number formatters: known input -> exact text."""

import math

import numpy as np
import pytest

from quad_modelling.io.reports.formatting import (
    display_number,
    display_unit,
    display_value,
    json_text,
    markdown_table,
    narrow_table,
    percent,
    prose,
    tic_text,
    variable_label,
)


def test_markdown_table_is_header_rule_and_rows():
    assert markdown_table(["variable", "RMS"], [["vel_x", 0.5], ["acc_z", "n/a"]]) == [
        "| variable | RMS |",
        "|---|---|",
        "| vel_x | 0.5 |",
        "| acc_z | n/a |",
    ]


def test_markdown_table_escapes_a_pipe_inside_a_cell():
    assert markdown_table(["note"], [["a | b"]])[2] == "| a \\| b |"


def test_aligned_markdown_table_pads_labels_left_and_numbers_right():
    lines = markdown_table(["variable", "unit", "greybox (eval)"], [["vel_x", "m/s", "0.98 / 13.3"], ["roll_acc", "deg/s2", "0.4 / 4"]],
                           align=True, label_columns=2)
    assert lines == [
        "| variable | unit   | greybox (eval) |",
        "|----------|--------|---------------:|",
        "| vel_x    | m/s    |    0.98 / 13.3 |",
        "| roll_acc | deg/s2 |        0.4 / 4 |",
    ]


def test_aligned_column_is_at_least_three_wide_as_markdown_rules_need():
    assert markdown_table(["a", "b"], [["x", "1"]], align=True) == ["| a   |   b |", "|-----|----:|", "| x   |   1 |"]


def test_a_row_of_the_wrong_width_is_refused():
    with pytest.raises(ValueError, match="2 cells, the header"):
        markdown_table(["a", "b", "c"], [["x", "y"]])


def test_numbers_in_display_units():
    # SI rad/s2 -> deg/s2: 0.0686 rad/s2 * 180/pi = 3.9305 deg/s2, three significant digits
    assert display_value("roll_acc", 0.0686) == "3.93 deg/s2"
    assert display_number("roll_rate", math.pi) == "180"
    assert display_number("vel_x", 0.123456) == "0.123"
    assert display_unit("acc_z") == "m/s2" and display_unit("yaw_rate") == "deg/s"
    assert variable_label("pitch_acc") == "pitch_acc [deg/s2]"


def test_tic_and_percent():
    assert tic_text(0.5) == "0.50" and tic_text(0.996) == "1.00"
    assert percent(0.4) == "40.0%" and percent(0.4567, 0) == "46%"
    assert percent(None) == "-"
    assert percent(float("nan")) == "nan%"


def test_json_text_writes_numpy_numbers_and_arrays():
    assert json_text({"rms": np.float64(0.25), "edges": np.array([1.0, 2.0]), "n": np.int64(3)}) == (
        '{\n  "rms": 0.25,\n  "edges": [\n    1.0,\n    2.0\n  ],\n  "n": 3\n}')
    with pytest.raises(TypeError, match="is not JSON serializable"):
        json_text({"x": object()})


def test_json_text_writes_a_number_that_is_not_finite_as_null():
    """diagnosis.json held a bare NaN (a sigma the fit cannot give), which JSON.parse and jq refuse."""
    import json

    text = json_text({"sigma": float("nan"), "values": np.array([1.0, np.inf]), "x": np.float64("nan")})
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"sigma": None, "values": [1.0, None], "x": None}


def test_prose_wraps_to_the_width_with_list_indents():
    text = "the base model's held-out gap " * 8
    lines = prose(text, 40, first="- ", rest="  ")
    assert max(len(line) for line in lines) <= 40
    assert lines[0].startswith("- the base") and all(line.startswith("  ") for line in lines[1:])
    assert " ".join(line[2:] for line in lines) == text.strip()
    assert prose("/a/" + "x" * 150, 100)[0] == "/a/" + "x" * 97  # a path longer than a line is broken
    assert prose("", first="- ") == ["-"]


def test_narrow_table_is_a_table_when_it_fits_and_a_list_when_it_does_not():
    assert narrow_table(["flight", "start [s]"], [["a.mat", "1.0"]]) == ["| flight | start [s] |", "|---|---|", "| a.mat | 1.0 |"]
    long = "flight_" * 13 + "x" * 5
    assert narrow_table(["flight", "start [s]", "gap"], [[long, "1.0", "2.35"], ["b.mat", "2.0", "1.1"]]) == [
        f"- {long}:", "  start [s] 1.0; gap 2.35", "- b.mat: start [s] 2.0; gap 1.1"]
