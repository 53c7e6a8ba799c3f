"""The truth simulator's compiled steps (:meth:`QuadDynamics.advance`): the same numbers as its Python RK4 steps.

The simulator integrates each control tick with one call of a CasADi Function built from the very derivative and
step the truth model runs in Python; the two agree to rounding (CasADi evaluates the same IEEE operations, a few in
another order), in the air, on the ground, with every effect and disturbance switched on.
"""

from __future__ import annotations

import numpy as np
import pytest

from quad_modelling.core.sim.dynamics import N_STATE, QuadDynamics
from quad_modelling.core.sim.params import sim_params_for

EVERY_EFFECT = ("motor_lag", "rotor_drag", "ground_effect", "gyroscopic", "wind", "motor_imbalance", "bent_arm", "com_offset")


def _states(dynamics: QuadDynamics) -> list[list[float]]:
    """Hover at 0.08 (in ground effect), 0.3 and 1 m and standing on the feet, each moving and turning."""
    rng = np.random.default_rng(0)
    states = [dynamics.hover_state(h) for h in (0.08, 0.3, 1.0)] + [dynamics.state_at_rest()]
    for s in states:
        s[3:6] = rng.normal(size=3).tolist()
        s[10:13] = (0.5 * rng.normal(size=3)).tolist()
    states[-1][5] = 0.4  # pressing into the ground
    return states


@pytest.mark.parametrize("effects", [(), EVERY_EFFECT], ids=["no effect", "every effect"])
@pytest.mark.parametrize("steps", [1, 4])
def test_compiled_steps_are_the_python_steps(effects, steps):
    dynamics = QuadDynamics(sim_params_for("linkquad"), effects)
    targets, wind, dt = [500.0, 510.0, 520.0, 530.0], (0.4, -0.2, 0.1), 0.001
    for start in _states(dynamics):
        s, expected = start, []
        for _ in range(steps):
            after, k1 = dynamics.step(s, targets, wind, dt)
            expected.append(list(s) + k1[3:6] + k1[10:13])
            s = after
        expected.append(list(s) + [0.0] * 6)
        rows = dynamics.advance(start, targets, wind, dt, steps)
        assert rows.shape == (steps + 1, N_STATE + 6)
        scale = np.maximum(np.abs(np.array(expected)), 1.0)
        assert np.max(np.abs(rows - np.array(expected)) / scale) < 1e-12


def test_ground_contact_acts_in_the_compiled_steps():
    """Standing and pressed into the ground, the feet push back: the vertical acceleration of the compiled step's k1
    is the Python derivative's, far from free fall."""
    dynamics = QuadDynamics(sim_params_for("linkquad"), ())
    s = dynamics.state_at_rest()
    s[2] += 0.002  # 2 mm into the ground
    stopped = [0.0] * 4
    s[13:17] = stopped
    rows = dynamics.advance(s, stopped, (0.0, 0.0, 0.0), 0.001, 1)
    python = dynamics.derivative(s, stopped, (0.0, 0.0, 0.0))
    assert rows[0, N_STATE + 2] == pytest.approx(python[5], rel=1e-12)
    assert rows[0, N_STATE + 2] < -5.0  # the springs lift it: upward (NED -z) acceleration beyond g's 9.81 down
