"""Fitting the direct model's maps: the vertical map on a known vertical system, what needs the accelerometer, and the
rate maps fitted on the airframe's mirror images (equal to fitting on mirrored flights; equivariant)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.models.direct import ACCELERATION_ROWS, COMMAND_LEAD, VELOCITY_HISTORY, vertical_feature_count
from quad_modelling.core.physics.symmetry import airframe_symmetries
from quad_modelling.core.training.direct import fit_rate_regression, fit_vertical_regression, train_direct
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import DataError
from quad_modelling.io.loader import load_flight

BAG = Path(__file__).resolve().parents[3] / "bags" / "nanobench_B7_oval_medium_rep2"
THRUST_GAIN = 5e-4
"""K [m/s² per command unit]: the down acceleration a unit more of collective command takes away."""
DAMPING = 1.0
"""c [1/s]: a_D = -K ũ_{k-DELAY} - c v_D, the known vertical system of the synthetic flights."""
DELAY = 3
NOISE = 0.002
"""e_k's standard deviation [m/s]: the part of each row's v_D no model can predict."""
DT = 0.01


def vertical_flight(seed: int, rows: int = 6000) -> tuple[FlightLog, np.ndarray]:
    """(a level 100 Hz flight whose down velocity follows v_{D,k+1} = v_{D,k} + Δt a_{D,k} + e_k with
    a_{D,k} = -K ũ_{k-DELAY} - c v_{D,k}, ũ the centred mean command; the accelerometer reads f_B = (0, 0, a_D - g), ũ)."""
    rng = np.random.default_rng(seed)
    u = 40000.0 + np.cumsum(rng.standard_normal((rows, 4)) * 300.0, axis=0) * 0.05 + rng.standard_normal((rows, 4)) * 800.0
    centred = u.mean(axis=1) - 40000.0
    down, acc = np.zeros(rows), np.zeros(rows)
    for k in range(rows):
        acc[k] = -THRUST_GAIN * centred[max(k - DELAY, 0)] - DAMPING * down[k]
        if k + 1 < rows:
            down[k + 1] = down[k] + DT * acc[k] + NOISE * rng.standard_normal()
    zeros = np.zeros((rows, 3))
    log = FlightLog(t=np.arange(rows) * DT, u=u, acc_b=np.stack([0 * acc, 0 * acc, acc - GRAVITY], axis=1), gyro_b=zeros,
                    pos_n=zeros + [0.0, 0.0, -1.0], vel_n=np.stack([0 * down, 0 * down, down], axis=1), euler=zeros,
                    meta=FlightMeta("crazyflie21", f"vertical seed {seed}"))
    return log, centred


def expected_down(log: FlightLog, centred: np.ndarray, anchor: int, horizon: int) -> np.ndarray:
    """E[v_D(s+h) | rows <= s, commands]: the known system run from the measured v_D(s) without its noise."""
    out = [log.vel_n[anchor, 2]]
    for h in range(horizon):
        out.append(out[-1] + DT * (-THRUST_GAIN * centred[anchor + h - DELAY] - DAMPING * out[-1]))
    return np.array(out)


def test_the_vertical_map_recovers_a_known_vertical_system_on_a_flight_it_never_saw():
    vertical = fit_vertical_regression([vertical_flight(0)[0]], [None], horizon=20)
    assert vertical.weights.shape == (20, vertical_feature_count(20), 1)
    held_out, centred = vertical_flight(1)
    starts = np.arange(100, 5900, 7)
    predicted = vertical.velocities(held_out, starts, 20)
    truth = np.array([expected_down(held_out, centred, s, 20) for s in starts])
    assert np.array_equal(predicted[:, 0], held_out.vel_n[starts, 2])
    measured = held_out.vel_n[starts[:, None] + np.arange(21)[None, :], 2]
    for h in (1, 5, 10, 20):
        floor = NOISE * np.sqrt(np.sum((1 - DAMPING * DT) ** (2 * np.arange(h))))  # std of the summed, damped noise
        assert np.sqrt(np.mean((predicted[:, h] - truth[:, h]) ** 2)) < 0.6 * floor, h
        rms_model = np.sqrt(np.mean((measured[:, h] - predicted[:, h]) ** 2))
        rms_known = np.sqrt(np.mean((measured[:, h] - truth[:, h]) ** 2))
        assert rms_model < 1.2 * rms_known, (h, rms_model, rms_known)


def test_the_vertical_maps_inputs_are_the_anchors_velocities_acceleration_tilt_and_commands():
    log, _ = vertical_flight(2, rows=200)
    from quad_modelling.core.models.direct import vertical_features

    z = vertical_features(log, np.array([50]), 3)[0]
    assert len(z) == vertical_feature_count(3) == VELOCITY_HISTORY + 2 + 4 * (COMMAND_LEAD + 4)
    assert np.array_equal(z[:VELOCITY_HISTORY], log.vel_n[50 - np.arange(VELOCITY_HISTORY), 2])
    rows = 50 - np.arange(ACCELERATION_ROWS)  # level: a_D = f_z + g, averaged over the last n_a rows
    assert ACCELERATION_ROWS > 1 and np.ptp(log.acc_b[rows, 2]) > 0  # the mean differs from the anchor's row
    assert z[VELOCITY_HISTORY] == pytest.approx(np.mean(log.acc_b[rows, 2]) + GRAVITY, abs=1e-12)
    assert vertical_features(log, np.array([1]), 3, acceleration_rows=4)[0, VELOCITY_HISTORY] == pytest.approx(
        np.mean(log.acc_b[[1, 0, 0, 0], 2]) + GRAVITY, abs=1e-12)  # rows before the first are the first
    assert z[VELOCITY_HISTORY + 1] == 1.0  # level: all the thrust points down
    assert np.array_equal(z[VELOCITY_HISTORY + 2:], log.u[50 - COMMAND_LEAD:54].ravel())


def test_without_an_accelerometer_the_model_has_no_vertical_map_and_says_why():
    vehicle = load_vehicle("crazyflie21")
    flight = load_flight(BAG)
    no_imu = dataclasses.replace(flight, acc_b=None)
    model = train_direct([no_imu], [(5.0, 25.0)], vehicle)
    assert model.vertical is None
    assert model.training["vertical_map"] == f"not fitted: no accelerometer in {no_imu.meta.source}"
    with pytest.raises(DataError, match="the direct model's vertical map .* needs the accelerometer") as err:
        fit_vertical_regression([flight, no_imu], [None, None])
    assert "\n" not in str(err.value)
    assert train_direct([flight], [(5.0, 25.0)], vehicle).training["vertical_map"] == "fitted"


def turning_flight(seed: int, rows: int = 3000) -> FlightLog:
    """A 100 Hz flight with random commands, rates that follow them and the body velocity (an ARX system that is *not*
    symmetric), a tilted, turning attitude and a wandering velocity: something to mirror."""
    rng = np.random.default_rng(seed)
    u = 40000.0 + rng.standard_normal((rows, 4)) * 800.0
    vel_n = np.cumsum(rng.standard_normal((rows, 3)) * 0.02, axis=0)
    euler = np.column_stack([0.2 * np.sin(np.arange(rows) / 70.0), 0.1 * np.cos(np.arange(rows) / 50.0),
                             np.cumsum(rng.standard_normal(rows) * 0.01)])
    vel_b = frames.nav_to_body(vel_n, euler)
    gain = rng.standard_normal((3, 4)) * 2e-5
    rates = np.zeros((rows, 3))
    for k in range(rows - 1):
        rates[k + 1] = 0.9 * rates[k] + gain @ (u[max(k - 3, 0)] - 40000.0) + 0.01 * vel_b[k] + 0.002 * rng.standard_normal(3)
    return FlightLog(t=np.arange(rows) * DT, u=u, acc_b=np.zeros((rows, 3)) + [0.0, 0.0, -GRAVITY], gyro_b=rates,
                     pos_n=np.cumsum(vel_n, axis=0) * DT, vel_n=vel_n, euler=euler, meta=FlightMeta("crazyflie21", f"turning {seed}"))


def rate_step(log: FlightLog, anchors: np.ndarray) -> np.ndarray:
    """A stand-in for the observer's angular disturbance that mirrors as one does: ω_s - ω_{s-1}."""
    return log.gyro_b[anchors] - log.gyro_b[anchors - 1]


def test_the_rate_maps_on_the_airframes_images_equal_the_maps_fitted_on_mirrored_flights_and_are_equivariant():
    vehicle = load_vehicle("crazyflie21")
    symmetries = airframe_symmetries(vehicle.motor_positions, vehicle.yaw_signs, vehicle.inertia)
    assert len(symmetries) == 4
    flights = [turning_flight(0), turning_flight(1, rows=2000)]
    spans = [None, (2.0, 18.0)]
    fitted = fit_rate_regression(flights, spans, horizon=12, angular_disturbance=rate_step, symmetries=symmetries)
    mirrored = [s.image(log) for s in symmetries for log in flights]
    by_images = fit_rate_regression(mirrored, spans * len(symmetries), horizon=12, angular_disturbance=rate_step)
    assert fitted[1] == by_images[1] // 4  # anchors: the flights' own
    assert np.allclose(fitted[0].weights, by_images[0].weights, rtol=1e-9, atol=1e-9 * np.abs(by_images[0].weights).max())
    # every rate axis changes sign under one of the four, so neither fit has a bias beyond rounding (u ~ 4e4 x w)
    assert np.abs(fitted[0].bias).max() < 1e-9 and np.abs(by_images[0].bias).max() < 1e-9
    plain = fit_rate_regression(flights, spans, horizon=12, angular_disturbance=rate_step)[0]
    assert not np.allclose(plain.weights, fitted[0].weights, rtol=1e-3)  # the flights' system is not symmetric
    # an image flight's predicted rates are the images of the flight's
    held_out = turning_flight(2)
    starts = np.arange(50, 2900, 13)
    rates = fitted[0].rates(held_out, starts, 12, rate_step(held_out, starts))
    for symmetry in symmetries:
        image = symmetry.image(held_out)
        image_rates = fitted[0].rates(image, starts, 12, rate_step(image, starts))
        assert np.allclose(image_rates, rates @ symmetry.axial.T, rtol=1e-9, atol=1e-12), symmetry.name
