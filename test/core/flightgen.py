"""Synthetic flights for tests: the linear greybox model's own response as a FlightLog."""

import numpy as np
from scipy import signal

from quad_modelling.core import frames
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.models.greybox import GreyboxModel
from quad_modelling.core.physics.rigid_body import GRAVITY


def linear_flight(vehicle, duration=60.0, rate=100.0, seed=0, amplitude=None, u0=None, source="linear"):
    """A flight flown by the linear model itself from hover, with smooth random collective commands.

    Only the collective (all four motors together) is excited, so the attitude stays level and
    the model's small-angle equations are exact; returns the FlightLog.
    """
    rng = np.random.default_rng(seed)
    n = int(duration * rate)
    dt = 1.0 / rate
    amplitude = amplitude if amplitude is not None else (2e-6 if vehicle.name == "linkquad" else 300.0)
    u0 = u0 if u0 is not None else (1.5e-3 if vehicle.name == "linkquad" else 40000.0)
    b, a = signal.butter(2, 2.0 / (rate / 2))
    collective = signal.lfilter(b, a, rng.standard_normal(n)) * amplitude * 4
    du = np.repeat(collective[:, None], 4, axis=1)
    model = GreyboxModel(vehicle).discretise(dt)
    states, outputs = model.simulate(np.zeros(16), du)
    acc_n = outputs[:, 6:9]
    euler = np.zeros((n, 3))
    acc_b = frames.nav_to_body(acc_n - np.array([0.0, 0.0, GRAVITY]), euler)
    return FlightLog(
        t=np.arange(n) * dt, u=u0 + du, acc_b=acc_b, gyro_b=states[:, 9:12], pos_n=states[:, 0:3] + [0, 0, -1.0],
        vel_n=states[:, 3:6], euler=euler, meta=FlightMeta(vehicle.name, source), vbat=np.full(n, 11.1),
    )
