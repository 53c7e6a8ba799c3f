"""``python -m quad_modelling.demo``: its arguments (the demo itself runs in CI as ``make demo``)."""

from __future__ import annotations

import pytest

from quad_modelling import demo


def test_help_says_what_the_demo_does_and_touches_nothing(monkeypatch, capsys):
    """``--help`` deleted and rebuilt demo_output/ and started the run (the module read no argument)."""
    monkeypatch.setattr(demo, "run", lambda: pytest.fail("the demo ran"))
    with pytest.raises(SystemExit) as exit_:
        demo.main(["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "Identify the vehicle's constants" in out and f"Writes {demo.OUTPUT}" in out
    with pytest.raises(SystemExit) as exit_:
        demo.main(["--fast"])
    assert exit_.value.code == 2 and "unrecognized arguments: --fast" in capsys.readouterr().err
