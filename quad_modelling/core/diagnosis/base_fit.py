"""Identifying the diagnosis base model (motor time constant, gains, arm scale) on training windows."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize

from quad_modelling.core.diagnosis.base_model import BaseModel, predict_batch
from quad_modelling.core.diagnosis.batch import WindowBatch
from quad_modelling.core.models.greybox import GreyboxParameters
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import GRAVITY, VehicleConfig

MIN_MOTOR_TIME_CONSTANT = 0.002
"""Lower bound of the base model's motor time constant [s] (a fifth of a 100 Hz sample). The discrete
model's thrust state already answers a command one sample late; rotors that follow their command within
a sample (the effects-off simulator: instant rotors, IMU averaged over the sample before the log time)
drove a 10 ms bound to its limit, and the base then carried ~10 ms of lag that an input delay would have
to explain."""


# ----------------------------------------------------------------------------- base model


@dataclass
class BaseFit:
    """The base model used by the diagnosis and how it was obtained."""

    model: BaseModel
    values: dict[str, float]
    identified: bool
    note: str


def base_from_vehicle(vehicle: VehicleConfig, reference_voltage: float | None = None) -> BaseModel:
    """The linear greybox of the vehicle's configured constants."""
    return BaseModel(GreyboxParameters.from_vehicle(vehicle), reference_voltage)


def _base_parameters(p: GreyboxParameters, tau_m: float, gain: float, yaw_ratio: float, arm_scale: float,
                     rotor_reaction_scale: float = 1.0) -> GreyboxParameters:
    root = 2.0 * math.sqrt(p.thrust_constant * p.mass * GRAVITY / 4.0)
    return replace(
        p,
        motor_a_m=-1.0 / tau_m,
        motor_b_m=gain / root,
        drag_constant=yaw_ratio * p.thrust_constant,
        motor_positions=tuple((arm_scale * x, arm_scale * y) for x, y in p.motor_positions),
        prop_inertia=rotor_reaction_scale * p.prop_inertia,
    )


def identify_base(batch: WindowBatch, vehicle: VehicleConfig) -> BaseFit:
    """Fit the linear model's identifiable constants on training windows.

    Parameters (output error on the smoothed acc_z, roll_acc, pitch_acc and
    yaw_acc, each normalised by its measured RMS -- the variables the thrusts
    drive without integration, so open-loop drift does not enter):

    * motor time constant :math:`\\tau_m = -1/A_m \\in` [:data:`MIN_MOTOR_TIME_CONSTANT`, 2] s;
    * steady thrust gain :math:`G = K \\tau_m` [N per unit command] (the static
      gain; :math:`K` itself would trade off against :math:`\\tau_m`);
    * yaw drag ratio :math:`d/a`;
    * a common scale of the motor arm lengths (torque per thrust / inertia for
      roll and pitch);
    * a scale :math:`k_R` of the rotor-reaction yaw term
      :math:`I_{prop} \\sum_i s_i \\dot\\Omega_i / I_{zz}` (Eq 3-13...3-16), i.e. of
      :math:`I_{prop} / (2 a \\Omega_0)` and :math:`I_{prop} B_m`. These products
      hold :math:`a` through :math:`\\Omega_0` and :math:`B_m = K / (2\\sqrt{a m g/4})`,
      and Table 3-1's :math:`a` is not consistent with its other constants
      (docs/simulator.md): held at the configured values the term is ~8x too
      strong for the LinkQuad, and the fit then inflated :math:`\\tau_m`
      (to 34 ms on flights with instant rotors) to shrink :math:`K` and with it
      the yaw feedthrough :math:`I_{prop} B_m u`.

    :math:`a` is held (only :math:`B_m\\sqrt a` is identifiable).
    """
    p0 = GreyboxParameters.from_vehicle(vehicle)
    v_ref = float(batch.vbat.mean()) if batch.vbat is not None else None
    cols = np.array([INDEX[v] for v in ("acc_z", "roll_acc", "pitch_acc", "yaw_acc")])
    rows = slice(batch.warm, None, 4)
    target = batch.measured[:, rows][:, :, cols]
    scale = np.maximum(np.sqrt(np.mean(target**2, axis=(0, 1))), 1e-9)
    tau_config = -1.0 / p0.motor_a_m
    steady_config = p0.input_gain * tau_config
    tau0 = min(max(tau_config, 1.1 * MIN_MOTOR_TIME_CONSTANT), 1.9)
    x0 = np.array([math.log(tau0), 0.0, p0.drag_constant / p0.thrust_constant, 1.0, 0.0])
    lower = np.array([math.log(MIN_MOTOR_TIME_CONSTANT), math.log(0.05), -1.0, 0.3, math.log(1e-3)])
    upper = np.array([math.log(2.0), math.log(20.0), 1.0, 3.0, math.log(1e3)])
    x0 = np.clip(x0, lower + 1e-9, upper - 1e-9)

    def parameters(z: np.ndarray) -> GreyboxParameters:
        tau = math.exp(z[0])
        return _base_parameters(p0, tau, steady_config * math.exp(z[1]) / tau, z[2], z[3], math.exp(z[4]))

    def residuals(z: np.ndarray) -> np.ndarray:
        pred = predict_batch(BaseModel(parameters(z)), batch, columns=cols)
        return ((target - pred[:, rows][:, :, cols]) / scale).ravel()

    best = None
    for start_gain in (0.0, math.log(3.0), -math.log(3.0)):
        z = x0.copy()
        z[1] = start_gain
        fit = optimize.least_squares(residuals, z, bounds=(lower, upper), method="trf", x_scale=np.array([1.0, 1.0, 0.05, 0.3, 1.0]),
                                     max_nfev=80)
        if best is None or fit.cost < best.cost:
            best = fit
    p = parameters(best.x)
    values = {"motor_a_m": p.motor_a_m, "motor_b_m": p.motor_b_m, "drag_constant": p.drag_constant,
              "thrust_gain_K": p.input_gain, "arm_scale": float(best.x[3]), "rotor_reaction_scale": float(math.exp(best.x[4])),
              "prop_inertia": p.prop_inertia, "reference_voltage": v_ref}
    return BaseFit(BaseModel(p, v_ref), values, True,
                   "identified on the training windows (acc_z, roll/pitch/yaw acceleration): tau_m, steady gain, d/a, arm scale, rotor-reaction scale")
