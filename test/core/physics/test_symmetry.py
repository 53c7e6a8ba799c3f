"""The airframe's symmetries: which turns and mirror images each bundled airframe has, that they form a group, and
that the one physics' wrench of the permuted commands is the image of the wrench (what makes them symmetries)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core import frames
from quad_modelling.core.physics import rigid_body
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.symmetry import airframe_symmetries
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.loader import load_flight


def symmetries_of(name: str):
    vehicle = load_vehicle(name)
    return airframe_symmetries(vehicle.motor_positions, vehicle.yaw_signs, vehicle.inertia)


def test_an_x_airframe_has_its_two_mirror_images_and_the_half_turn_and_a_plus_one_its_diagonals():
    crazyflie = {s.name: s.source.tolist() for s in symmetries_of("crazyflie21")}
    # M1 front-right ccw, M2 back-right cw, M3 back-left ccw, M4 front-left cw: mirrored across y, M4 flies M1's place
    assert crazyflie == {"identity": [0, 1, 2, 3], "turn 180°": [2, 3, 0, 1], "mirror x -> -x": [1, 0, 3, 2],
                         "mirror y -> -y": [3, 2, 1, 0]}
    linkquad = {s.name for s in symmetries_of("linkquad")}  # "+": front, right, back, left; I_xx, I_yy within 3 %
    assert linkquad == {"identity", "turn 180°", "mirror x <-> y", "mirror x <-> -y"}


def test_a_rotor_moved_a_spin_swapped_or_unequal_inertias_leave_fewer_symmetries():
    vehicle = load_vehicle("crazyflie21")
    positions, spins, inertia = vehicle.motor_positions, vehicle.yaw_signs, vehicle.inertia
    moved = positions.copy()
    moved[0] *= 1.1  # M1 4.6 mm further out: only the mirror across the diagonal through it remains, and it flips spins
    assert [s.name for s in airframe_symmetries(moved, spins, inertia)] == ["identity"]
    same_side = np.array([1.0, 1.0, -1.0, -1.0])  # both right rotors ccw, both left cw: only right <-> left keeps them
    assert [s.name for s in airframe_symmetries(positions, same_side, inertia)] == ["identity", "mirror y -> -y"]
    plus = load_vehicle("linkquad")
    unequal = plus.inertia * [1.0, 1.2, 1.0]
    assert [s.name for s in airframe_symmetries(plus.motor_positions, plus.yaw_signs, unequal)] == ["identity", "turn 180°"]


@pytest.mark.parametrize("name", ["crazyflie21", "linkquad", "px4_iris"])
def test_the_symmetries_form_a_group(name):
    found = symmetries_of(name)
    table = {(s.matrix.tobytes(), s.source.tobytes()) for s in found}
    for a, b in itertools.product(found, repeat=2):
        # b after a: the matrices multiply; the image flight's command j is the original's a.source[b.source[j]]
        assert ((b.matrix @ a.matrix).tobytes(), a.source[b.source].tobytes()) in table, (a.name, b.name)


@pytest.mark.parametrize("name", ["crazyflie21", "linkquad"])  # the Iris files hold no physics constants
def test_the_wrench_of_the_permuted_rotors_is_the_image_of_the_wrench(name):
    """F(Ω') = M F(Ω), τ(Ω') = det(M) M τ(Ω) for Ω' = Ω[source], with the rotor drag of the image airspeed M v^B and the
    propellers' reaction: each symmetry is one of the physics model's."""
    params = PhysicsParameters.from_vehicle(load_vehicle(name))
    rng = np.random.default_rng(1)
    rotor, rotor_dot, vel_b = rng.uniform(500.0, 2500.0, (6, 4)), rng.normal(0.0, 3e4, (6, 4)), rng.normal(0.0, 2.0, (6, 3))
    force, torque = rigid_body.rotor_wrench(params, rotor, rotor_dot, vel_b)
    for symmetry in symmetries_of(name):
        image_force, image_torque = rigid_body.rotor_wrench(params, rotor[:, symmetry.source], rotor_dot[:, symmetry.source],
                                                            vel_b @ symmetry.matrix.T)
        assert np.allclose(image_force, force @ symmetry.matrix.T, rtol=1e-12, atol=1e-15), symmetry.name
        assert np.allclose(image_torque, torque @ symmetry.axial.T, rtol=1e-12, atol=1e-15), symmetry.name


def test_a_flights_image_has_the_image_body_velocity_and_specific_force_and_a_mirror_image_twice_is_the_flight():
    flight = load_flight(Path(__file__).resolve().parents[3] / "bags" / "nanobench_B7_oval_medium_rep2")
    for symmetry in symmetries_of("crazyflie21"):
        image = symmetry.image(flight)
        assert np.array_equal(image.u, flight.u[:, symmetry.source]) and np.array_equal(image.t, flight.t)
        assert np.allclose(frames.nav_to_body(image.vel_n, image.euler),
                           frames.nav_to_body(flight.vel_n, flight.euler) @ symmetry.matrix.T, atol=1e-12)
        assert np.allclose(frames.body_to_nav(image.acc_b, image.euler),
                           frames.body_to_nav(flight.acc_b, flight.euler) @ symmetry.matrix.T, atol=1e-12)
        assert np.allclose(image.gyro_b, flight.gyro_b @ symmetry.axial.T)
        twice = symmetry.image(image)  # every symmetry of an "x" airframe is its own inverse
        assert np.allclose(twice.gyro_b, flight.gyro_b) and np.array_equal(twice.u, flight.u)
        assert np.allclose(frames.euler_ned_to_matrix(twice.euler), frames.euler_ned_to_matrix(flight.euler), atol=1e-12)


def test_the_physics_model_keeps_only_the_symmetries_its_motor_gains_and_cg_offset_keep():
    import dataclasses

    from quad_modelling.core.physics.symmetry import model_symmetries

    params = PhysicsParameters.from_vehicle(load_vehicle("crazyflie21"))
    assert [s.name for s in model_symmetries(params)] == ["identity", "turn 180°", "mirror x -> -x", "mirror y -> -y"]
    forward = dataclasses.replace(params, cg_offset=(0.001, 0.0))  # 1 mm forward: only right <-> left keeps it
    assert [s.name for s in model_symmetries(forward)] == ["identity", "mirror y -> -y"]
    right_weak = dataclasses.replace(params, motor_gains=(0.9, 0.9, 1.0, 1.0))  # M1, M2 (right) weaker: front <-> back
    assert [s.name for s in model_symmetries(right_weak)] == ["identity", "mirror x -> -x"]
    # and the wrench agrees: with the offset, the mirror across y is still one of the physics', the turn is not
    rotor = np.random.default_rng(2).uniform(500.0, 2500.0, (4, 4))
    zeros = np.zeros((4, 3))
    force, torque = rigid_body.rotor_wrench(forward, rotor, np.zeros_like(rotor), zeros)
    by_name = {s.name: s for s in symmetries_of("crazyflie21")}
    for name, kept in (("mirror y -> -y", True), ("turn 180°", False)):
        s = by_name[name]
        image_torque = rigid_body.rotor_wrench(forward, rotor[:, s.source], np.zeros_like(rotor), zeros)[1]
        assert np.allclose(image_torque, torque @ s.axial.T, rtol=1e-9, atol=1e-15) == kept, name
