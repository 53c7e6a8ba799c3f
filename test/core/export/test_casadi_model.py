"""The CasADi export equals the numpy model: physics with every term on, and a hybrid, on a held-out flight."""

from __future__ import annotations

import casadi
import numpy as np
import pytest

from quad_modelling.core.export.casadi_model import (
    DISTURBANCE,
    STATE,
    ExportedModel,
    casadi_functions,
    filtered_step,
    input_names,
    layout,
)
from quad_modelling.core.models import physics
from quad_modelling.core.models.hybrid import filter_inputs, filtered_commands
from quad_modelling.core.models.physics import Observer, PhysicsPredictor
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rotors import delayed_commands, effective_commands, rotor_acceleration
from quad_modelling.core.preprocess import state_measurement
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.io.loader import load_flight
from test.conftest import FIXTURES
from test.core.export.vehicles import crazyflie_document, random_hybrid, vehicle_of

FLIGHT = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"
ANCHORS = np.arange(250, 900, 25)
"""26 anchors over the airborne part of the fixture (take-off near the ground included: ground effect acts)."""
HORIZON = 50
TOLERANCE = 1e-9


@pytest.fixture(scope="module")
def vehicle():
    return vehicle_of(crazyflie_document())


@pytest.fixture(scope="module")
def flight(vehicle):
    """Held out: no constant of the vehicle was fitted on it (they are the shipped values and the terms' test values)."""
    return load_flight(FLIGHT, vehicle)


@pytest.fixture(scope="module")
def physics_model(vehicle):
    return ExportedModel(vehicle, PhysicsParameters.from_vehicle(vehicle), Observer.from_vehicle(vehicle), "physics")


def as_vector(state) -> np.ndarray:
    """(B, 22) states in the export's layout (STATE)."""
    return np.concatenate([state.pos_n, state.vel_n, state.rot.reshape(-1, 9), state.rates, state.rotor], axis=1)


def assert_close(exported, numpy_values, what):
    scale = 1.0 + np.abs(numpy_values)
    worst = float(np.max(np.abs(np.asarray(exported) - numpy_values) / scale))
    assert worst <= TOLERANCE, f"{what}: largest relative difference {worst:.3g}"


def test_the_layout_is_22_states_5_inputs_with_the_battery_and_6_disturbances(physics_model):
    assert len(STATE) == 22 and len(DISTURBANCE) == 6
    assert [name for name, _, _ in input_names(physics_model)] == ["u_1", "u_2", "u_3", "u_4", "battery_voltage"]
    assert physics_model.params.terms_on == ("ground_effect", "battery", "motor_imbalance", "gyroscopic")


def test_exported_step_equals_the_physics_models_multistep_prediction_on_a_held_out_flight(physics_model, flight):
    """Same anchored states, same commands, same observer disturbance: 50 steps of F_disturbed from 26 anchors equal
    the physics model's own multi-step prediction (PhysicsPredictor.predict_horizons) and its numpy step to 1e-9."""
    p = physics_model.params
    step = casadi_functions(physics_model)["F_disturbed"].map(len(ANCHORS))
    state, disturbance, _ = physics.anchor_state(p, flight, ANCHORS, physics_model.observer)
    d = np.concatenate([disturbance.linear_n, disturbance.angular_b], axis=1).T
    delayed = delayed_commands(p, flight.u, flight.t)
    rows = ANCHORS[:, None] + np.arange(HORIZON + 1)[None, :]
    numpy_commands = physics.horizon_commands(p, flight, ANCHORS, rows)
    predicted = PhysicsPredictor(physics_model.vehicle).predict_horizons(flight, ANCHORS, HORIZON)
    x = as_vector(state).T
    for h in range(HORIZON):
        dt = flight.t[rows[:, h] + 1] - flight.t[rows[:, h]]
        u = np.concatenate([delayed[rows[:, h]], flight.vbat[ANCHORS][:, None]], axis=1).T  # the anchor's voltage held
        x = np.asarray(step(x, u, dt[None, :], d))
        state = physics.step(p, state, numpy_commands[:, h], dt, disturbance)
        assert_close(x.T, as_vector(state), f"step {h + 1}")
    assert_close(x[0:6].T, predicted[:, HORIZON, 0:6], "position and velocity after 50 steps")
    assert_close(x[15:18].T, predicted[:, HORIZON, 12:15], "body rates after 50 steps")
    assert np.abs(predicted[:, HORIZON, 3:6] - predicted[:, 0, 3:6]).max() > 0.1  # the flight moved: not a trivial match


def test_exported_derivative_is_the_models_accelerations_on_measured_states(physics_model, flight):
    """f_disturbed at the measured states equals the model's acceleration outputs (physics.outputs) plus the
    disturbance, dp/dt = v, dΩ/dt the rotor lag, dR/dt = R [ω]x."""
    p = physics_model.params
    state, disturbance, _ = physics.anchor_state(p, flight, ANCHORS, physics_model.observer)
    commands = physics.rotor_commands(p, flight)[ANCHORS]
    outputs = physics.outputs(p, state, commands, disturbance)
    u = np.concatenate([delayed_commands(p, flight.u, flight.t)[ANCHORS], flight.vbat[ANCHORS][:, None]], axis=1)
    xdot = np.asarray(casadi_functions(physics_model)["f_disturbed"].map(len(ANCHORS))(
        as_vector(state).T, u.T, np.concatenate([disturbance.linear_n, disturbance.angular_b], axis=1).T)).T
    assert_close(xdot[:, 0:3], state.vel_n, "dp/dt")
    assert_close(xdot[:, 3:6], outputs[:, 6:9], "dv/dt")
    assert_close(xdot[:, 15:18], outputs[:, 15:18], "dω/dt")
    assert_close(xdot[:, 18:22], rotor_acceleration(p, state.rotor, commands), "dΩ/dt")
    skew = np.zeros((len(ANCHORS), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -state.rates[:, 2], state.rates[:, 1], -state.rates[:, 0]
    skew -= skew.transpose(0, 2, 1)
    assert_close(xdot[:, 6:15], (state.rot @ skew).reshape(-1, 9), "dR/dt")


def test_exported_hybrid_step_equals_the_numpy_hybrid_step(vehicle, flight):
    """A hybrid with a random (non-zero) net and three command filters: F_disturbed (u = delayed commands, logged
    commands, the filters' inputs, voltage) over 50 steps equals HybridModel.step, anchored by the hybrid's own
    observer, to 1e-9."""
    hybrid = random_hybrid(vehicle)
    model = ExportedModel(vehicle, hybrid.params, hybrid.observer, "hybrid:test", hybrid)
    assert len(hybrid.filters) == 3 and len(input_names(model)) == 9 + 12
    assert [name for name, _, _ in input_names(model)][8:10] == ["u_filtered_30ms_1", "u_filtered_30ms_2"]
    filters = filter_inputs(filtered_commands(flight.u, flight.t, hybrid.filters), flight.u)  # (N, 12)
    step = casadi_functions(model)["F_disturbed"].map(len(ANCHORS))
    state, disturbance = hybrid.anchor(flight, ANCHORS, state_measurement(flight))
    d = np.concatenate([disturbance.linear_n, disturbance.angular_b], axis=1).T
    p = hybrid.params
    delayed = delayed_commands(p, flight.u, flight.t)
    x = as_vector(state).T
    corrections = []
    for h in range(HORIZON):
        rows = ANCHORS + h
        dt = flight.t[rows + 1] - flight.t[rows]
        voltage = flight.vbat[ANCHORS]
        u = np.concatenate([delayed[rows], flight.u[rows], filters[rows], voltage[:, None]], axis=1).T
        x = np.asarray(step(x, u, dt[None, :], d))
        numpy_u = np.concatenate([effective_commands(p, delayed[rows], voltage), flight.u[rows], filters[rows]], axis=1)  # as hybrid_commands
        corrections.append(np.abs(hybrid.correction(state, numpy_u)).max())
        state = hybrid.step(state, numpy_u, dt, disturbance)
        assert_close(x.T, as_vector(state), f"hybrid step {h + 1}")
    assert min(corrections) > 0.05  # the net acts: its corrections are part of what matched


def test_the_filtered_step_carries_the_filters_states_and_steps_as_f_disturbed_with_their_inputs(vehicle, flight):
    """F_filtered (the carried forecast's step: the filters' states z beside x) over 50 logged, changing commands
    at the flight's irregular stamps: z equals filtered_commands' scan and x equals F_disturbed fed z - u, to 1e-9."""
    hybrid = random_hybrid(vehicle)
    model = ExportedModel(vehicle, hybrid.params, hybrid.observer, "hybrid:test", hybrid)
    step, plain = filtered_step(model), casadi_functions(model)["F_disturbed"]
    rows = np.arange(400, 400 + HORIZON + 1)
    t = flight.t[400] + np.concatenate([[0.0], np.cumsum(0.01 + 0.004 * np.sin(np.arange(HORIZON)))])  # irregular: 6-14 ms
    assert np.ptp(flight.u[rows], axis=0).min() > 0  # changing commands
    z = filtered_commands(flight.u[rows], t, hybrid.filters, start=flight.u[rows[0]] * np.array([[0.9], [1.0], [1.1]]))
    delayed = delayed_commands(hybrid.params, flight.u, flight.t)
    state, disturbance = hybrid.anchor(flight, rows[:1], state_measurement(flight))
    d = np.concatenate([disturbance.linear_n, disturbance.angular_b], axis=1)[0]
    x, xz = as_vector(state)[0], np.concatenate([as_vector(state)[0], z[0].ravel()])
    for k, row in enumerate(rows[:-1]):
        dt, logged = t[k + 1] - t[k], flight.u[row]
        w = np.concatenate([delayed[row], logged, [flight.vbat[row]]])
        xz = np.asarray(step(xz, w, dt, d)).ravel()
        x = np.asarray(plain(x, np.concatenate([w[:8], filter_inputs(z[k], logged), w[8:]]), dt, d)).ravel()
        assert_close(xz[22:], z[k + 1].ravel(), f"filters' states, step {k + 1}")
        assert_close(xz[:22], x, f"state, step {k + 1}")


def test_the_exported_step_is_differentiable_at_rest_and_the_layouts_hover_is_an_equilibrium(physics_model):
    """At hover with zero rates (where |ω| has no derivative) F's Jacobian is finite, and the layout's hover (each
    motor's command and rotor speed) makes f zero but for the ground effect's last thrust at 5 m: with the CG offset
    the four thrusts differ so that their moment about the CG is zero (the commands were the equal-thrust ones, which
    left the offset's moment c_y m g / I_xx, -c_x m g / I_yy: 4.8 and 7.4 rad/s² on an identified Crazyflie)."""
    p = physics_model.params
    functions = casadi_functions(physics_model)
    x, u = casadi.SX.sym("x", len(STATE)), casadi.SX.sym("u", len(input_names(physics_model)))
    jacobian = casadi.Function("jacobian", [x, u], [casadi.jacobian(functions["F"](x, u, 0.01), casadi.vertcat(x, u))])
    hover = np.zeros(len(STATE))
    hover[[6, 10, 14]] = 1.0
    hover[2] = -5.0  # 5 m up: out of ground effect but for 1e-6 of the thrust
    constants = layout(physics_model)["constants"]  # the layout's hover: each motor's command at the reference voltage
    reference, u_hover = constants["hover_voltage_v"], np.asarray(constants["hover_commands"])
    speeds = np.asarray(constants["hover_rotor_speeds_rad_s"])
    c_x, c_y = p.cg_offset
    assert reference == p.battery[1] and c_x != 0.0 and c_y != 0.0
    assert len(set(u_hover)) == 4 and len(set(speeds)) == 4  # the motor gains and the offset differ per motor
    assert p.thrust_constant * (speeds ** 2).sum() == pytest.approx(p.mass * GRAVITY, rel=1e-12)  # thrust = weight
    hover[18:] = speeds
    J = np.asarray(jacobian(hover, [*u_hover, reference]))
    assert J.shape == (22, 27) and np.all(np.isfinite(J))
    xdot = np.asarray(functions["f"](hover, [*u_hover, reference])).ravel()
    coefficient, offset = p.ground_effect
    assert xdot[5] == pytest.approx(-GRAVITY * coefficient / (5.0 + offset) ** 2, rel=1e-6)  # ground effect's last 1e-6 of thrust
    assert np.abs(np.delete(xdot, 5)).max() < 1e-9  # level, at rest, no moment about the CG, rotors settled
    equal = p.hover_command(GRAVITY) / np.asarray(p.motor_gains)  # the equal thrusts: the offset's moment is left
    hover[18:] = p.hover_rotor_speed(GRAVITY)
    xdot = np.asarray(functions["f"](hover, [*equal, reference])).ravel()
    weight = p.mass * GRAVITY
    assert xdot[15] == pytest.approx(c_y * weight / p.inertia[0], rel=1e-5) and xdot[16] == pytest.approx(-c_x * weight / p.inertia[1], rel=1e-5)


def test_a_step_of_zero_seconds_leaves_the_state_as_it_is(physics_model):
    """F(x, u, 0) = x (an MPC splitting its first step at the command delay calls F with dt = 0 when the delay is a
    whole number of steps; it gave NaN: the step's mean dΩ/dt and the lag's interval mean were 0/0), for a turning,
    climbing state whose rotors are off their commands' speeds; and F stays continuous at dt -> 0."""
    p = physics_model.params
    functions = casadi_functions(physics_model)
    state = np.zeros(len(STATE))
    state[[6, 10, 14]] = 1.0
    state[:6] = [0.3, -0.2, -1.5, 0.4, 0.1, -0.3]
    state[15:18] = [0.8, -0.5, 0.3]
    state[18:] = p.hover_rotor_speed(GRAVITY) * np.array([1.05, 0.95, 1.02, 0.98])
    command = [*(p.hover_command(GRAVITY) / np.asarray(p.motor_gains) * 1.1), p.battery[1]]
    assert np.array_equal(np.asarray(functions["F"](state, command, 0.0)).ravel(), state)
    tiny = np.asarray(functions["F"](state, command, 1e-7)).ravel()
    assert np.all(np.isfinite(tiny)) and np.abs(tiny - state).max() < 1e-3
