"""The MPC example (examples/mpc_figure8.py), short: 3 s of the figure-8 on the exported LinkQuad model.

The model is the shipped LinkQuad vehicle's physics (its starting values, exported without the identification
check: the example's machinery is under test, docs/mpc.md has the identified models' numbers); the truth
simulator flies every default effect, so the model is wrong by the simulator's CG offset, motor gains, battery and
ground effect, and the observer has to take that up.
"""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest

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
