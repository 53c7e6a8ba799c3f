"""Vehicle documents and hybrid models for the export tests (small, built in memory: no identification run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from quad_modelling.core.models.hybrid import COMMAND_FILTERS_S, CORRECTIONS, HybridModel, features
from quad_modelling.core.models.residual_net import zero_net
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.parameters import PHYSICS_KEYS
from quad_modelling.core.vehicle import VehicleConfig, vehicle_dir

TERM_VALUES = {
    "ground_effect": {"coefficient": (3e-5, "m2", 0.0, 0.01), "offset": (0.02, "m", 0.0, 0.5)},
    "battery": {"kappa": (0.05, "1/V", -1.0, 1.0), "reference_voltage": (3.9, "V", 0.0, 30.0)},
    "motor_imbalance": {**{f"gain_{i}": (g, "1", 0.5, 1.5) for i, g in zip(range(1, 5), (1.02, 0.98, 1.01, 0.99))},
                        "cg_offset_x": (0.0015, "m", -0.01, 0.01), "cg_offset_y": (-0.001, "m", -0.01, 0.01)},
    "gyroscopic": {"body_scale": (1.0, "1", 0.0, 2.0), "rotor_scale": (1.0, "1", 0.0, 2.0)},
}
"""Every term of the physics model switched on, with plausible Crazyflie values (not fitted: the equality tests
only need every term's code to run)."""


def crazyflie_document(terms: bool = True, identified: bool = True, cg_offset: bool = True) -> dict:
    """The shipped Crazyflie 2.1 vehicle document with every term of :data:`TERM_VALUES` on (``terms``; without the
    motor imbalance's CG offset unless ``cg_offset``, as an older file: a level hover is then an equilibrium) and an
    identification record naming its physics constants, as ``identify`` writes one (``identified``)."""
    doc = yaml.safe_load((vehicle_dir() / "crazyflie21.yaml").read_text())
    if terms:
        doc["effects"] = {name: {"enabled": True, **{key: {"value": value, "unit": unit, "bounds": [low, high], "source": "test",
                                                            "status": "identified"}
                                                      for key, (value, unit, low, high) in parameters.items()
                                                      if cg_offset or not key.startswith("cg_offset")}}
                          for name, parameters in TERM_VALUES.items()}
    if identified:
        doc["identification"] = {"files": ["test"], "constants": {key: {"value": doc["constants"][key]["value"]} for key in PHYSICS_KEYS}}
    return doc


def write_vehicle(doc: dict, path: Path) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def vehicle_of(doc: dict) -> VehicleConfig:
    return VehicleConfig.from_dict(doc, "test vehicle")


def random_hybrid(vehicle: VehicleConfig, seed: int = 0, filters: tuple[float, ...] = COMMAND_FILTERS_S) -> HybridModel:
    """A hybrid of ``vehicle``'s physics with the command filters ``filters`` (a trained one's by default) and a random
    (non-zero) residual net of 12 tanh units, scaled to corrections of a few m/s² and rad/s² over the features'
    typical ranges (a filter's input z - u: a few thousand units of command)."""
    rng = np.random.default_rng(seed)
    mean = np.concatenate([np.zeros(9), np.full(4, 30000.0), np.full(4, 1500.0), np.full(4, 30000.0), np.zeros(4 * len(filters))])
    std = np.concatenate([np.ones(9), np.full(4, 5000.0), np.full(4, 300.0), np.full(4, 5000.0), np.full(4 * len(filters), 3000.0)])
    net = zero_net(mean, std, np.array([1.0, 1.0, 2.0, 5.0, 5.0, 2.0]), (12,), rng)
    net.weights[-1][:] = rng.normal(0.0, 0.5, net.weights[-1].shape)
    net.biases[-1][:] = rng.normal(0.0, 0.1, len(CORRECTIONS))
    assert net.n_inputs == len(features(filters))
    return HybridModel(PhysicsParameters.from_vehicle(vehicle), net, vehicle.name, filters=filters)
