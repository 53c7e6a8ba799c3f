"""The direct model's live forms (:mod:`~quad_modelling.core.models.direct`): its carried forecast
(:class:`DirectForecast`) and its window stream stepped by a compiled step (:class:`CompiledDirectStream`), both on the
physics model's (:mod:`~quad_modelling.core.live.forecast`, :mod:`~quad_modelling.core.live.compiled`) with the
regressions' body rates and down velocity given (:func:`~quad_modelling.core.export.casadi_model.given_rates_step`).
:mod:`~quad_modelling.core.live.forms` picks them for a direct model.
"""

from __future__ import annotations

import weakref

import numpy as np

from quad_modelling.core.export.casadi_model import ExportedModel, Step, casadi_functions, compile_step, given_rates_step
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.live.compiled import CompiledWindowStream
from quad_modelling.core.live.forecast import PhysicsForecast, newest_first
from quad_modelling.core.models.direct import DirectModel, DirectPredictor, DirectStream, down_acceleration
from quad_modelling.core.vehicle import VehicleConfig

_STEPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""predictor -> its :func:`direct_steps`, built once per predictor object."""


def direct_steps(predictor: DirectPredictor, vehicle: VehicleConfig) -> dict[str, Step]:
    """The direct model's compiled steps (:func:`~quad_modelling.core.export.casadi_model.compile_step`), built once per
    predictor: the given-rates step (``step``: ``F_given``), the continuous dynamics (``derivative``: ``f_disturbed``)
    and the window stream's step and outputs in one call (``window``: ``W_given``, as
    :func:`~quad_modelling.core.live.compiled.window_step`)."""
    if predictor not in _STEPS:
        import casadi

        model = predictor.model
        exported = ExportedModel(vehicle, model.params, model.physics.observer, "physics", None)
        step, derivative = given_rates_step(exported), casadi_functions(exported)["f_disturbed"]
        x, u, dt, d, w, g, v, gv = (casadi.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(8))
        u_now = casadi.SX.sym("u_now", step.sparsity_in(1))
        after = step(x, u, dt, d, w, g, v, gv)
        window = casadi.Function("W_given", [x, u, dt, d, u_now, w, g, v, gv], [after, derivative(after, u_now, d)],
                                 ["x", "u", "dt", "d", "u_now", "w", "g", "v", "gv"], ["x_next", "xdot"])
        _STEPS[predictor] = {"step": compile_step(step), "derivative": compile_step(derivative), "window": compile_step(window)}
    return _STEPS[predictor]


def direct_forecast(predictor: DirectPredictor, vehicle: VehicleConfig, steps: int) -> DirectForecast:
    """The receding horizon's carried form of a direct model for h = ``steps`` (:class:`DirectForecast`)."""
    compiled = direct_steps(predictor, vehicle)
    return DirectForecast(predictor.model, compiled["step"], compiled["derivative"], steps)


def compiled_direct_stream(predictor: DirectPredictor, vehicle: VehicleConfig, stream: DirectStream):
    """``stream`` stepped by the compiled window step (:class:`CompiledDirectStream`), or itself without a C compiler."""
    window = direct_steps(predictor, vehicle)["window"]
    return CompiledDirectStream(stream, window) if window.compiled else stream


class DirectForecast(PhysicsForecast):
    """The receding horizon's carried forecast (:mod:`~quad_modelling.core.live.forecast`): the physics model's
    (commands of the last δ, rotor speeds, yaw, observer rows), the regression's anchor inputs (the last n_ω rates,
    the last body velocity, the observer's disturbance and L + 1 commands) and the vertical map's (the last n_v down
    velocities, the last n_a down accelerations and the last row's tilt), rolled out by the compiled
    :func:`~quad_modelling.core.export.casadi_model.given_rates_step` chained h times, the regression's rates given for the first min(h, H) steps."""

    def __init__(self, model: DirectModel, step: Step, derivative: Step, steps: int):
        self.regression, self.vertical = model.regression, model.vertical
        super().__init__(step, derivative, model.params, model.physics.observer, steps)
        self._w, self._g, self._v, self._gv = np.zeros((steps, 3)), np.zeros(steps), np.zeros(steps), np.zeros(steps)
        self._g[:min(steps, self.regression.horizon)] = 1.0
        for i, array in enumerate((self._w, self._g, self._v, self._gv)):
            self._buffer.set_arg(4 + i, memoryview(array))

    def reset(self) -> None:
        super().reset()
        # the last rows newest first (before the first row added, that row: anchor_features), None before any
        self.rate_rows: np.ndarray | None = None  # (n_ω, 3) ω_s, ω_{s-1}, ... [rad/s]
        self.command_rows: np.ndarray | None = None  # (max L + 1, 4) u_s, u_{s-1}, ...
        self.body_velocity = np.zeros(3)  # v^B at the last row [m/s]
        self.vertical_on = False  # the vertical map gives v_D from the last row (it has an accelerometer)
        if self.vertical is not None:
            self.down_rows: np.ndarray | None = None  # (n_v,) v_D(s), v_D(s-1), ... [m/s]
            self.down_acceleration_rows: np.ndarray | None = None  # (n_a,) a_D of the last rows [m/s²]
            self.tilt = 1.0  # cos φ cos θ at the last row

    def add(self, rows: FlightLog, first: int) -> None:
        super().add(rows, first)
        if first >= len(rows):
            return
        r, lead = self.regression, max(self.regression.lead, 0 if self.vertical is None else self.vertical.lead)
        self.rate_rows = newest_first(self.rate_rows, rows.gyro_b[first:], r.rate_history)
        self.command_rows = newest_first(self.command_rows, rows.u[first:], lead + 1)
        _, _, velocity, _, rotation = self.anchor[:5]  # the last row's (R with the continued yaw: the same R)
        self.body_velocity = velocity @ rotation  # v^B = R^T v_N
        if self.vertical is not None:
            self.down_rows = newest_first(self.down_rows, rows.vel_n[first:, 2], self.vertical.velocity_history)
            self.vertical_on = rows.acc_b is not None  # without it the physics integrates v_D (DirectModel.uses_vertical)
            if self.vertical_on:
                added = down_acceleration(rows, np.arange(first, len(rows)))
                self.down_acceleration_rows = newest_first(self.down_acceleration_rows, added, self.vertical.acceleration_rows)
                self.tilt = float(rotation[2, 2])  # cos φ cos θ of the last row
            else:  # rows without the accelerometer: the next mean starts afresh, not across the gap
                self.down_acceleration_rows = None

    def predict(self, t_after: np.ndarray, u_after: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        r = self.regression
        given = min(len(t_after), r.horizon)
        anchor = {"body_velocity": self.body_velocity}
        if "angular_disturbance" in r.anchor_inputs:
            anchor["angular_disturbance"] = self.disturbance().angular_b[0]
        z = np.concatenate([self.rate_rows.ravel(), *(anchor[name] for name in r.anchor_inputs),
                            self.command_rows[r.lead::-1].ravel(), u_after[:given].ravel()])
        self._w[:given] = self.rate_rows[0] + r.changes_from(z, given)
        self._gv[:] = 0.0
        if self.vertical_on:
            v = self.vertical
            given_down = min(len(t_after), v.horizon)
            self._gv[:given_down] = 1.0
            z_v = np.concatenate([self.down_rows, [self.down_acceleration_rows.mean(), self.tilt],
                                  self.command_rows[v.lead::-1].ravel(), u_after[:given_down].ravel()])
            self._v[:given_down] = self.down_rows[0] + v.changes_from(z_v, given_down)[:, 0]
        return super().predict(t_after, u_after, rows)


class CompiledDirectStream(CompiledWindowStream):
    """A :class:`~quad_modelling.core.models.direct.DirectStream` stepped by a compiled step with given rates
    (:func:`direct_steps`' ``window``), as the physics model's window stream is by
    :class:`~quad_modelling.core.live.compiled.CompiledWindowStream`: the
    same numbers (test), without numpy's per-call cost on a batch of one."""

    def __init__(self, stream: DirectStream, step: Step):
        super().__init__(stream, step, None)
        self._w, self._g, self._v, self._gv = np.zeros(3), np.zeros(1), np.zeros(1), np.zeros(1)
        for i, array in enumerate((self._w, self._g, self._v, self._gv)):
            self._buffer.set_arg(5 + i, memoryview(array))

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        given, down = self.stream.given_rates(command), self.stream.given_down_velocity()
        self._g[0], self._gv[0] = float(given is not None), float(down is not None)
        if given is not None:
            self._w[:] = given[0]
        if down is not None:
            self._v[:] = down
        return super().push_at(command, t_s)
