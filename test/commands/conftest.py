"""Fixtures shared by the command tests."""

import pytest

from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.matlog import write_matlog
from test.core.flightgen import linear_flight


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Two 42 s LinkQuad flights flown by the linear model itself (collective excitation), as thesis .mat logs."""
    directory = tmp_path_factory.mktemp("flights")
    vehicle = load_vehicle("linkquad")
    paths = []
    for seed in range(2):
        path = directory / f"flight{seed}.mat"
        write_matlog(linear_flight(vehicle, duration=42.0, seed=seed), path)
        paths.append(str(path))
    return paths
