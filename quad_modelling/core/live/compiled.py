r"""The models' CasADi steps compiled for the live predictor, built once per model object: the carried forecast's one
step (:func:`model_step`, chained h times by :mod:`~quad_modelling.core.live.forecast`) and continuous dynamics
(:func:`model_derivative`), and the window mode's step (:func:`window_step`, :class:`CompiledWindowStream`); which
model gets which: :mod:`~quad_modelling.core.live.forms`.

Each is an export Function of the one physics (:mod:`~quad_modelling.core.export.casadi_model`: ``F_disturbed``,
``f_disturbed``; a hybrid with command filters ``filtered_step``, their states beside x) compiled to C by the system's
C compiler where one is found (:func:`~quad_modelling.core.export.casadi_model.compile_step`), else run by CasADi's
virtual machine: the same numbers.

The window mode has its own compiled Function (:func:`window_step`: the step and the new state's derivative in one
call; :func:`~quad_modelling.core.live.forms.compiled_window_stream`): the physics and hybrid models' live streams
step from sample to sample and output with it instead of numpy on a batch of one (the most of a physics predictor's
answer to an input), the stream's own delay table and observer kept.
"""

from __future__ import annotations

import weakref

import numpy as np

from quad_modelling.core.export.casadi_model import (
    Step,
    casadi_functions,
    compile_step,
    exported_predictor,
    filtered_step,
    narx_step,
    output_row,
    with_filter_inputs,
)
from quad_modelling.core.models.hybrid import HybridModel, HybridPredictor
from quad_modelling.core.models.narx import NarxPredictor
from quad_modelling.core.models.physics import PhysicsPredictor
from quad_modelling.core.physics.rigid_body import PhysicsState, continued_yaw
from quad_modelling.core.physics.rotors import delayed_command_at
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import DataError


_STEPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""model -> its :class:`Step` (:func:`model_step`), built once per model object (its carried forecasts share it)."""

_WINDOW_STEPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""model -> its :func:`window_step`, built once per model object."""

_DERIVATIVES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""model -> its :func:`model_derivative`, built once per model object."""


def model_step(model, vehicle: VehicleConfig) -> Step | None:
    """The one-step CasADi Function a model's carried forecast chains (physics, hybrid: the export's ``F_disturbed``,
    a hybrid with command filters its ``filtered_step``; NARX: :func:`~quad_modelling.core.export.casadi_model.narx_step`), compiled (:func:`compile_step`); None for a model whose forecast needs none."""
    if model not in _STEPS:
        if isinstance(model, (PhysicsPredictor, HybridPredictor)):
            exported = exported_predictor(model, vehicle)  # a hybrid's command filters chained in its step:
            _STEPS[model] = compile_step(filtered_step(exported) if exported.hybrid and exported.hybrid.filters else casadi_functions(exported)["F_disturbed"])
        elif isinstance(model, NarxPredictor):
            _STEPS[model] = compile_step(narx_step(model.model))
        else:
            return None
    return _STEPS[model]


def window_step(model, vehicle: VehicleConfig) -> Step:
    """A physics or hybrid model's step and outputs in one compiled Function (:func:`compile_step`), what its live
    window stream calls per sample (:class:`CompiledWindowStream`):
    ``(x, u, dt, d, u_now) -> (x_next = F_disturbed(x, u, dt, d), xdot = f_disturbed(x_next, u_now, d))``, the
    export's Functions (:mod:`~quad_modelling.core.export.casadi_model`): the state after the step and its
    derivative under the command the rotors answer at the new sample (the accelerations the model outputs there); a
    hybrid with command filters steps their states beside x (x (22 + 4 M), u without the filters' inputs: ``filtered_step``)."""
    if model not in _WINDOW_STEPS:
        import casadi

        exported = exported_predictor(model, vehicle)
        functions, filters = casadi_functions(exported), exported.hybrid and exported.hybrid.filters  # beside x, as the forecast's
        step = filtered_step(exported) if filters else functions["F_disturbed"]
        x, u, dt, d = (casadi.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(4))
        u_now = casadi.SX.sym("u_now", step.sparsity_in(1))
        after = step(x, u, dt, d)
        xdot = functions["f_disturbed"](after[:22], with_filter_inputs(after[22:], u_now) if filters else u_now, d)
        _WINDOW_STEPS[model] = compile_step(casadi.Function("W_disturbed", [x, u, dt, d, u_now], [after, xdot],
                                                            ["x", "u", "dt", "d", "u_now"], ["x_next", "xdot"]))
    return _WINDOW_STEPS[model]


def model_derivative(model, vehicle: VehicleConfig) -> Step:
    """A physics or hybrid model's continuous dynamics of one state, the export's ``f_disturbed(x, u, d) -> xdot``,
    compiled (:func:`compile_step`): the accelerations its carried forecast outputs and its observer integrates."""
    if model not in _DERIVATIVES:
        _DERIVATIVES[model] = compile_step(casadi_functions(exported_predictor(model, vehicle))["f_disturbed"])
    return _DERIVATIVES[model]


class CompiledDerivative:
    """:func:`model_derivative` evaluated in place on one state (the export's layouts: x (22,), u, d (6,))."""

    def __init__(self, derivative: Step):
        f = derivative.function
        self.x, self.u, self.d, self.xdot = np.zeros(22), np.zeros(f.size1_in(1)), np.zeros(6), np.zeros(22)
        self._buffer, self._evaluate = f.buffer()
        for i, array in enumerate((self.x, self.u, self.d)):
            self._buffer.set_arg(i, memoryview(array))
        self._buffer.set_res(0, memoryview(self.xdot))

    def __call__(self, x: np.ndarray, u: np.ndarray, d: np.ndarray) -> np.ndarray:
        """dx/dt (22,) at state ``x`` under export input ``u`` with disturbance ``d`` (valid until the next call)."""
        self.x[:], self.u[:], self.d[:] = x, u, d
        self._evaluate()
        return self.xdot


# --- the live window stream through the compiled step ---------------------------------------------------------------

class CompiledWindowStream:
    """A physics or hybrid model's live window stream (:class:`~quad_modelling.core.models.physics.PhysicsStream`,
    :class:`~quad_modelling.core.models.hybrid.HybridStream`) whose step from sample to sample and outputs are the
    compiled :func:`window_step` instead of numpy's on a batch of one (~150 us a step and ~150 us the outputs here,
    the most of a physics predictor's answer to an input); the delay's table and the observer are the stream's own.
    The same numbers (test: 1e-9 over a window)."""

    def __init__(self, stream, step: Step, hybrid: HybridModel | None):
        self.stream, self.hybrid = stream, hybrid
        self._x, self._u = np.zeros(step.function.size1_in(0)), np.zeros(step.function.size1_in(1))
        self._dt, self._d, self._u_now = np.zeros(1), np.zeros(6), np.zeros(step.function.size1_in(1))
        self._after, self._xdot = np.zeros(step.function.size1_in(0)), np.zeros(22)
        self._buffer, self._evaluate = step.function.buffer()
        for i, array in enumerate((self._x, self._u, self._dt, self._d, self._u_now)):
            self._buffer.set_arg(i, memoryview(array))
        self._buffer.set_res(0, memoryview(self._after))
        self._buffer.set_res(1, memoryview(self._xdot))

    def push_at(self, command: np.ndarray, t_s: float) -> np.ndarray:
        s, p = self.stream, self.stream.params
        previous = s.times[-1]
        dt = t_s - previous
        if not dt > 0:
            raise DataError(f"physics stream: sample time {t_s:.6f} s is not after the previous {previous:.6f} s")
        state = s.state
        self._x[0:3], self._x[3:6], self._x[6:15] = state.pos_n[0], state.vel_n[0], state.rot[0].ravel()
        self._x[15:18], self._x[18:22] = state.rates[0], state.rotor[0]
        command = np.asarray(command, dtype=float).reshape(1, 4)
        self._u[0:4] = delayed_command_at(p, s.times, s.commands, previous)[0]  # the export's input layout
        s.times.append(float(t_s))
        s.commands.append(command)
        self._u_now[0:4] = delayed_command_at(p, s.times, s.commands, float(t_s))[0]  # what the rotors answer at t_s
        if self.hybrid is not None:  # the commands logged at the previous sample and at this one; the filters' states beside x
            self._u[4:8], self._u_now[4:8] = s.commands[-2][0], command[0]
            self._x[22:] = () if s.filtered is None else s.filtered.ravel()
        if p.battery is not None:
            self._u[-1] = self._u_now[-1] = s.voltage
        self._dt[0], self._d[0:3], self._d[3:6] = dt, s.disturbance.linear_n[0], s.disturbance.angular_b[0]
        self._evaluate()
        x, xdot = self._after, self._xdot
        if len(x) > 22:  # a hybrid's filters' states at the new sample
            s.filtered = x[22:].reshape(-1, 4).copy()
        rot = x[6:15].reshape(1, 3, 3).copy()
        s.state = PhysicsState(x[None, 0:3].copy(), x[None, 3:6].copy(), rot, x[None, 15:18].copy(), x[None, 18:22].copy(),
                               continued_yaw(float(state.yaw[0]), np.concatenate([state.rot, rot]))[1:])
        s._forget()
        return output_row(x, xdot, float(s.state.yaw[0]))

    def push(self, command: np.ndarray) -> np.ndarray:
        return self.push_at(command, self.stream.times[-1] + self.stream.period_s)
