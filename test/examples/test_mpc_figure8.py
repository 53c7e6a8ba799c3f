"""The MPC example (examples/mpc_figure8.py), short: 3 s of the figure-8 on the exported LinkQuad model.

The model is the shipped LinkQuad vehicle's physics (its starting values, exported without the identification
check: the example's machinery is under test, docs/mpc.md has the identified models' numbers); the truth
simulator flies every default effect, so the model is wrong by the simulator's CG offset, motor gains, battery and
ground effect, and the observer has to take that up.
"""

from __future__ import annotations

import importlib.util
import shutil
import sys

import numpy as np
import pytest
import yaml

from quad_modelling.core.export.casadi_model import ExportedModel as Export, write_casadi_export
from quad_modelling.core.models.physics import Observer
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.vehicle import load_vehicle
from test.conftest import REPO


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("mpc_figure8", REPO / "examples" / "mpc_figure8.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    vehicle = load_vehicle("linkquad")
    directory = tmp_path_factory.mktemp("mpc") / "linkquad_model"
    write_casadi_export(Export(vehicle, PhysicsParameters.from_vehicle(vehicle), Observer.from_vehicle(vehicle), "physics"), directory)
    return directory


def test_the_mpc_tracks_the_figure8_far_closer_than_the_simulators_controller(example, exported):
    reference = example.Figure8()
    assert np.linalg.norm(reference.at(3.0)[0] - reference.at(1.0)[0]) > 1.0  # the reference moves over a metre
    mpc = example.fly_mpc(example.ExportedModel(exported), reference, duration=3.0, use_observer=True)
    stabiliser = example.fly_stabiliser(reference, duration=3.0)
    assert mpc["rms_m"] < 0.03 and mpc["max_m"] < 0.06, mpc
    assert stabiliser["rms_m"] > 5 * mpc["rms_m"], (stabiliser, mpc)


def test_an_export_of_another_vehicle_and_a_too_short_flight_are_refused_in_one_line(example, exported, tmp_path, capsys):
    """The example flies the simulator's LinkQuad: a Crazyflie export flew it with no word (2.4 m RMS); a flight
    shorter than the 1 s before scoring ended in an AxisError traceback."""
    crazyflie = load_vehicle("crazyflie21")
    other = tmp_path / "crazyflie_model"
    write_casadi_export(Export(crazyflie, PhysicsParameters.from_vehicle(crazyflie), Observer.from_vehicle(crazyflie), "physics"), other)
    hybrid = tmp_path / "hybrid_model"  # a hybrid's export: its input adds the logged commands (it exited 1, no usage)
    shutil.copytree(exported, hybrid)
    layout = yaml.safe_load((hybrid / "layout.yaml").read_text())
    layout["input"] += [{"name": f"u_logged_{i}", "unit": "PWM", "meaning": "test"} for i in range(1, 5)]
    (hybrid / "layout.yaml").write_text(yaml.safe_dump(layout))
    for argv, message in ((["--model", str(other)], f"{other}: a model of vehicle crazyflie21; this example flies the simulator's linkquad"),
                          (["--model", str(exported), "--duration", "0.5"], "--duration 0.5 s: the tracking error is scored from 1 s on"),
                          (["--model", str(exported), "--height", "-1"], "--height -1 m: the figure-8 flies above the ground"),
                          (["--model", str(hybrid)], f"{hybrid}: the example flies a physics model export"),
                          (["--model", str(tmp_path / "nope")], f"{tmp_path / 'nope'}: not an export directory (no layout.yaml)")):
        with pytest.raises(SystemExit) as stopped:
            example.main([*argv, "-o", str(tmp_path / "out")])
        err = capsys.readouterr().err.strip().splitlines()
        assert stopped.value.code == 2 and len(err) == 1 and message in err[0], err  # no usage block before it
    assert not (tmp_path / "out").exists()


def test_outputs_that_are_files_or_inputs_and_a_slow_model_are_refused_before_flying(example, exported, tmp_path, capsys):
    """-o onto a file ended in a FileExistsError traceback; -o inside the export it reads was written into; a model
    whose rotor_delay is not under the MPC step was refused only after the stabiliser's flight, exit 1, leaving an
    empty -o directory."""
    slow = tmp_path / "slow_model"
    shutil.copytree(exported, slow)
    layout = yaml.safe_load((slow / "layout.yaml").read_text())
    layout["constants"]["rotor_delay_s"] = 0.045
    (slow / "layout.yaml").write_text(yaml.safe_dump(layout))
    (tmp_path / "a_file").write_text("mine")
    for argv, message in (([str(slow), "-o", str(tmp_path / "out")], "the model's rotor_delay 0.045 s must be shorter than the MPC step 0.04 s"),
                          ([str(exported), "-o", str(tmp_path / "a_file")], "exists and is not a directory"),
                          ([str(exported), "-o", str(tmp_path / "a_file" / "sub")], f"{tmp_path / 'a_file'} is not a directory"),
                          ([str(exported), "-o", str(exported)], f"the output lies in the export {exported} it reads"),
                          ([str(exported), "-o", str(exported / "results")], f"the output lies in the export {exported} it reads"),
                          ([str(exported), "-o", str(exported.parent)], f"the output holds the export {exported} it reads")):
        with pytest.raises(SystemExit) as stopped:
            example.main(["--model", *argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert stopped.value.code == 2 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "out").exists() and (tmp_path / "a_file").read_text() == "mine"
    assert not (exported / "results").exists() and not (exported / "results.json").exists()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "results.json").write_text("{}")  # an earlier run's: kept without --force (it was overwritten)
    with pytest.raises(SystemExit) as stopped:
        example.main(["--model", str(exported), "-o", str(tmp_path / "out")])
    assert stopped.value.code == 2 and "holds the results of an earlier run; pass --force" in capsys.readouterr().err
    assert (tmp_path / "out" / "results.json").read_text() == "{}"
