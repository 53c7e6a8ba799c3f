"""``quad_modelling/cli.py``: a word starting like a negative number reaches the option before it (attach_dash_values)."""

from __future__ import annotations

from quad_modelling.cli import attach_dash_values, build_parser


def attach(*argv: str) -> list[str]:
    return attach_dash_values(build_parser(), list(argv))


def test_a_negative_looking_value_joins_the_option_that_takes_one():
    assert attach("evaluate", "f.mat", "--drop", "-5:0", "-o", "out") == ["evaluate", "f.mat", "--drop=-5:0", "-o", "out"]
    assert attach("simulate", "--duration", "-inf", "-o", "s.mat") == ["simulate", "--duration=-inf", "-o", "s.mat"]
    assert attach("simulate", "--dur", "-5", "-o", "s.mat") == ["simulate", "--dur=-5", "-o", "s.mat"]  # as argparse abbreviates
    assert attach("simulate", "-o", "-5.mat") == ["simulate", "-o=-5.mat"]


def test_nothing_is_attached_after_a_flag_after_double_dash_or_to_a_word_that_is_no_number():
    # --hybrid is a flag (store_true), not an abbreviation of --hybrid-hidden
    assert attach("train", "f.mat", "--hybrid", "-5", "-o", "m.npz") == ["train", "f.mat", "--hybrid", "-5", "-o", "m.npz"]
    # after --, every word is positional as given (merge's only value option once took '--' for its abbreviation)
    assert attach("merge", "-o", "out", "--", "-5.json") == ["merge", "-o", "out", "--", "-5.json"]
    assert attach("evaluate", "f.mat", "--vehicle", "-x") == ["evaluate", "f.mat", "--vehicle", "-x"]
    assert attach("evaluate", "f.mat", "--drop", "5:0") == ["evaluate", "f.mat", "--drop", "5:0"]
