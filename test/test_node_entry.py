"""The nodes' console entry points: each runs its node module's main; a Ctrl-C while importing it is one line, 130."""

import importlib

import pytest

from quad_modelling import node_entry


@pytest.mark.parametrize("name", ["replay", "predictor", "greybox_predictor", "narx_predictor", "evaluator"])
def test_each_entry_point_runs_its_node_modules_main(monkeypatch, name):
    called = []

    def fake_import(module):
        called.append(module)
        return type("Module", (), {"main": staticmethod(lambda: 7)})

    monkeypatch.setattr(importlib, "import_module", fake_import)
    assert getattr(node_entry, name)() == 7
    assert called == [f"quad_modelling.nodes.{name}_node"]
    assert importlib.util.find_spec(called[0]) is not None  # the module is real


def test_a_ctrl_c_while_the_node_module_imports_is_one_line_and_exit_130(monkeypatch, capsys):
    def interrupted(module):
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib, "import_module", interrupted)
    assert node_entry.evaluator() == 130
    assert capsys.readouterr().err == "evaluator: interrupted while starting\n"
