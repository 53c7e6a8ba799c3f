r"""The identified physics model (and a hybrid's residual net) as CasADi Functions (docs/export.md).

Nothing here writes an equation: the expressions are built by the one physics definition
(:mod:`quad_modelling.core.physics`) and the hybrid's own code (:class:`~quad_modelling.core.models.hybrid.HybridModel`,
:class:`~quad_modelling.core.models.residual_net.ResidualNet`) fed *symbolic arrays* -- numpy arrays of CasADi
``SX`` scalars (:mod:`quad_modelling.core.physics.arrays`) -- for a batch of one. The exported step therefore equals
the numpy step of the model to rounding (test: 1e-9 on a held-out flight).

Layout (:data:`STATE`, :func:`input_names`, :data:`DISTURBANCE`), SI units, N = NED, B = FRD:

* state x (22): position p_N [m], velocity v_N [m/s], attitude R = R_N<-B (9, row-major: ``rot_ij`` = R[i, j]),
  body rates ω = (p, q, r) [rad/s], rotor speeds Ω_1..4 [rad/s] (command order);
* input u: the four commands the rotors answer now [input unit] -- the command logged δ = ``rotor_delay`` earlier
  (the model's command delay is not inside f: an MPC shifts its inputs by δ, docs/export.md) -- then, for a hybrid,
  the four commands logged at this sample (the net's other input) and, for a hybrid with command filters, the
  filters' inputs z_j - u (4 per filter, :func:`~quad_modelling.core.models.hybrid.filter_inputs`: the logged commands
  through a first-order lag of τ_j, minus the logged ones; an MPC carries z as states, z_{k+1} = u_k + (z_k - u_k)
  exp(-dt/τ_j), docs/export.md), then, with the ``battery`` term on, the battery voltage V [V];
* disturbance d (6), of the ``*_disturbed`` Functions only: the disturbance observer's constant accelerations
  :math:`\hat d_v` [m/s², N] and :math:`\hat d_\omega` [rad/s², B] (:class:`~quad_modelling.core.models.physics.Observer`),
  added to the rigid body's as in the model's predictions.

Functions (:func:`casadi_functions`): ``f(x, u) -> xdot`` (:func:`~quad_modelling.core.physics.rigid_body.derivative`,
d = 0), ``F(x, u, dt) -> x_next`` (:func:`~quad_modelling.core.physics.rigid_body.step`, d = 0: semi-implicit Euler
with the exact rotor lag over ``dt`` [s], rates and speed limited as the model's), ``f_disturbed(x, u, d)`` and
``F_disturbed(x, u, dt, d)``. NARX's closed-loop step (:func:`narx_step`), for its carried forecast, is built the
same way from the model's own net code. :func:`compile_step` compiles a Function to C for the live forms
(:mod:`quad_modelling.core.live.forecast`).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quad_modelling.core import frames
from quad_modelling.core.models.hybrid import ConstantsChangedError, HybridModel, HybridPredictor, filter_inputs, filter_step, load_hybrid
from quad_modelling.core.models.narx import OUTPUTS, sigmoid
from quad_modelling.core.models.physics import Observer
from quad_modelling.core.physics import rigid_body, rotors
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import PhysicsState
from quad_modelling.core.physics.rotors import effective_commands
from quad_modelling.core.variables import VARIABLES
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.physics.parameters import PHYSICS_KEYS
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError

FORMAT_VERSION = 2
"""Version of the export's layout (``layout.yaml``); bumped when the state or input layout changes (2: a hybrid's command
filters among its inputs)."""

STATE: tuple[tuple[str, str, str], ...] = (
    *((f"pos_n_{a}", "m", f"position {a} in N (NED)") for a in "xyz"),
    *((f"vel_n_{a}", "m/s", f"velocity {a} in N (NED)") for a in "xyz"),
    *((f"rot_{i}{j}", "1", f"R_N<-B[{i - 1}, {j - 1}] (B = FRD to N = NED)") for i in (1, 2, 3) for j in (1, 2, 3)),
    ("roll_rate", "rad/s", "body rate p about FRD x"), ("pitch_rate", "rad/s", "body rate q about FRD y"),
    ("yaw_rate", "rad/s", "body rate r about FRD z"),
    *((f"rotor_{i}", "rad/s", f"rotor {i}'s speed (command order)") for i in range(1, 5)),
)
"""The state x: (name, unit, meaning) of each element, in order (module docstring)."""

DISTURBANCE: tuple[tuple[str, str, str], ...] = (
    *((f"dist_acc_n_{a}", "m/s2", f"observer's linear acceleration {a} in N") for a in "xyz"),
    *((f"dist_ang_acc_{a}", "rad/s2", f"observer's angular acceleration about FRD {a}") for a in "xyz"),
)
"""The disturbance d of the ``*_disturbed`` Functions (module docstring)."""

FUNCTIONS: dict[str, str] = {
    "f": "f(x, u) -> xdot: continuous dynamics, no disturbance",
    "F": "F(x, u, dt) -> x_next: one step of dt seconds (semi-implicit Euler, exact rotor lag), no disturbance",
    "f_disturbed": "f_disturbed(x, u, d) -> xdot: continuous dynamics with the observer's disturbance d",
    "F_disturbed": "F_disturbed(x, u, dt, d) -> x_next: one step with the observer's disturbance d",
}
"""The exported Functions, each saved as ``NAME.casadi`` (casadi.Function.load)."""


@dataclass(frozen=True)
class ExportedModel:
    """What an export holds: the vehicle's physics constants and terms, the hybrid's net (None: the physics model),
    the observer the model anchors with, and the model spec as given (``physics`` or ``hybrid:FILE``)."""

    vehicle: VehicleConfig
    params: PhysicsParameters
    observer: Observer
    spec: str
    hybrid: HybridModel | None = None


def exportable_model(vehicle: VehicleConfig, hybrid_file: str | Path | None = None) -> ExportedModel:
    """The model to export for ``vehicle`` (and the hybrid in ``hybrid_file``), refused in one line when the
    vehicle lacks the physics constants, still holds starting values for constants to be identified
    (:meth:`~quad_modelling.core.vehicle.VehicleConfig.never_identified`), or the model file is not a hybrid of
    this vehicle and its constants (:func:`~quad_modelling.core.models.hybrid.load_hybrid`)."""
    params = PhysicsParameters.from_vehicle(vehicle)
    never = vehicle.never_identified(PHYSICS_KEYS)
    if never:
        raise ConfigError(f"{vehicle.path}: never identified: the physics constants {', '.join(never)} hold starting values "
                          f"(status identified, but no identification record names them); export a vehicle file written by "
                          f"`quad-modelling identify FLIGHTS --vehicle {vehicle.name} -o FILE`")
    try:  # the layout's hover trim: refused before anything is written
        hover_rotor_speeds(params)
    except ConfigError as err:
        raise ConfigError(f"{vehicle.path}: {err}") from err
    if hybrid_file is None:
        return ExportedModel(vehicle, params, Observer.from_vehicle(vehicle), "physics")
    try:
        hybrid = load_hybrid(hybrid_file, vehicle)
    except ConstantsChangedError as err:  # the vehicle it was trained with may hold starting values: export refuses those
        raise ConstantsChangedError(f"{hybrid_file}: the hybrid was trained with other physics constants than {vehicle.path} "
                                    f"holds; export takes a hybrid of the identified vehicle it exports: retrain it, "
                                    f"`quad-modelling train FLIGHTS --hybrid --vehicle {vehicle.path} -o FILE`") from err
    return ExportedModel(vehicle, params, hybrid.observer, f"hybrid:{hybrid_file}", hybrid)


def input_names(model: ExportedModel) -> tuple[tuple[str, str, str], ...]:
    """The input u: (name, unit, meaning) of each element, in order (module docstring)."""
    unit = model.vehicle.input_unit
    names = [(f"u_{i}", unit, f"command rotor {i} answers now: the logged commands at t - rotor_delay") for i in range(1, 5)]
    if model.hybrid is not None:
        names += [(f"u_logged_{i}", unit, f"command of rotor {i} logged at this sample (the net's input)") for i in range(1, 5)]
        names += [(f"u_filtered_{tau * 1000:g}ms_{i}", unit, f"rotor {i}'s logged commands through a first-order lag of {tau:g} s, "
                   "minus its command logged at this sample (the net's input)") for tau in model.hybrid.filters for i in range(1, 5)]
    if model.params.battery is not None:
        names.append(("battery_voltage", "V", "measured battery voltage (battery term)"))
    return tuple(names)


def symbolic_state(x) -> PhysicsState:
    """A batch-of-one :class:`PhysicsState` of symbolic arrays from a CasADi column ``x`` (22) in :data:`STATE` order."""
    e = _elements(x)
    return PhysicsState(e[None, 0:3], e[None, 3:6], e[6:15].reshape(1, 3, 3), e[None, 15:18], e[None, 18:22], np.zeros(1))


def _elements(column) -> np.ndarray:
    """The scalars of a CasADi column as a symbolic array (:mod:`quad_modelling.core.physics.arrays`)."""
    return np.array([column[i] for i in range(column.shape[0])], dtype=object)


def _column(parts):
    """One CasADi column of the symbolic (or float) arrays ``parts``, flattened row-major in order."""
    import casadi

    return casadi.vertcat(*(element for part in parts for element in np.asarray(part, dtype=object).ravel()))


def _dynamics(model: ExportedModel, x, u, d, dt=None, rates_next=None, down_velocity_next=None):
    """x_next of one step of ``dt`` (None: dx/dt) as a CasADi column, from the one physics (module docstring);
    ``rates_next`` (a CasADi column of 3) and ``down_velocity_next`` (a CasADi scalar): the step's end-of-step body
    rates and down velocity given (``rigid_body.step``'s)."""
    state = symbolic_state(x)
    inputs = _elements(u)
    voltage = inputs[-1:] if model.params.battery is not None else None
    commands = effective_commands(model.params, inputs[None, 0:4], voltage)
    disturbance = _elements(d)[None, :]
    linear, angular = disturbance[:, 0:3], disturbance[:, 3:6]
    if model.hybrid is not None:
        correction = model.hybrid.correction(state, np.concatenate([commands, inputs[None, 4:8 + 4 * len(model.hybrid.filters)]], axis=1))
        linear, angular = linear + correction[:, 0:3], angular + correction[:, 3:6]
    if dt is None:
        return _column(rigid_body.derivative(model.params, state, commands, linear, angular))
    given = None if rates_next is None else _elements(rates_next)[None, :]
    down = None if down_velocity_next is None else np.array([down_velocity_next], dtype=object)
    after = rigid_body.step(model.params, state, commands, np.array([dt], dtype=object), linear, angular, given, down)
    return _column((after.pos_n, after.vel_n, after.rot, after.rates, after.rotor))


def exported_predictor(model, vehicle: VehicleConfig) -> ExportedModel:
    """The :class:`ExportedModel` of a physics or hybrid predictor (:mod:`~quad_modelling.core.live.forecast`'s
    compiled steps)."""
    hybrid = model.model if isinstance(model, HybridPredictor) else None
    params, observer = (hybrid.params, hybrid.observer) if hybrid else (model.params, model.observer)
    return ExportedModel(vehicle, params, observer, "hybrid" if hybrid else "physics", hybrid)


def state_vector(pos, vel, rot, rates, rotor) -> np.ndarray:
    """The export's state layout (22,): position N, velocity N, R row-major, rates B, rotor speeds."""
    return np.concatenate([pos, vel, np.ravel(rot), rates, rotor])


def output_row(x: np.ndarray, xdot: np.ndarray, yaw: float) -> np.ndarray:
    """The VARIABLES row (18,) of export state ``x`` and its derivative ``xdot`` (accelerations, with the disturbance
    when ``xdot`` has it), yaw the continuous one: what :func:`~quad_modelling.core.models.physics.outputs` gives."""
    out = np.empty(len(VARIABLES))
    out[0:6], out[6:9] = x[0:6], xdot[3:6]
    out[9:12] = frames.matrix_to_euler_ned(x[6:15].reshape(1, 3, 3))[0]
    out[11] = yaw
    out[12:15], out[15:18] = x[15:18], xdot[15:18]
    return out


def casadi_functions(model: ExportedModel) -> dict:
    """The exported Functions (:data:`FUNCTIONS`) by name."""
    import casadi

    x = casadi.SX.sym("x", len(STATE))
    u = casadi.SX.sym("u", len(input_names(model)))
    d = casadi.SX.sym("d", len(DISTURBANCE))
    dt = casadi.SX.sym("dt")
    f_disturbed = casadi.Function("f_disturbed", [x, u, d], [_dynamics(model, x, u, d)], ["x", "u", "d"], ["xdot"])
    step_disturbed = casadi.Function("F_disturbed", [x, u, dt, d], [_dynamics(model, x, u, d, dt)], ["x", "u", "dt", "d"], ["x_next"])
    zero = casadi.SX.zeros(len(DISTURBANCE))
    return {
        "f": casadi.Function("f", [x, u], [f_disturbed(x, u, zero)], ["x", "u"], ["xdot"]),
        "F": casadi.Function("F", [x, u, dt], [step_disturbed(x, u, dt, zero)], ["x", "u", "dt"], ["x_next"]),
        "f_disturbed": f_disturbed,
        "F_disturbed": step_disturbed,
    }


def given_rates_step(model: ExportedModel):
    """``F_given(x, u, dt, d, w, g, v, gv) -> x_next``: ``F_disturbed``'s step whose end-of-step body rates are
    :math:`g\\, w + (1 - g)\\, \\omega_{k+1}` (w (3) given [rad/s, FRD], g 1 or 0, :math:`\\omega_{k+1}` the integrated
    rates) and whose end-of-step down velocity is :math:`g_v\\, v + (1 - g_v)\\, v_{D,k+1}` (v given [m/s, N down],
    g_v 1 or 0): the direct model's step (:mod:`quad_modelling.core.models.direct`), whose first H steps take the
    rates (and the down velocity) of its regressions; the attitude turns with those rates, the position moves with
    that velocity. Not an export Function (a regression's outputs are no state)."""
    import casadi

    x = casadi.SX.sym("x", len(STATE))
    u = casadi.SX.sym("u", len(input_names(model)))
    d = casadi.SX.sym("d", len(DISTURBANCE))
    dt, w, g = casadi.SX.sym("dt"), casadi.SX.sym("w", 3), casadi.SX.sym("g")
    v, gv = casadi.SX.sym("v"), casadi.SX.sym("gv")
    integrated = _dynamics(model, x, u, d, dt)
    rates = g * w + (1 - g) * integrated[15:18]
    down = gv * v + (1 - gv) * integrated[5]  # the step's velocity does not depend on its end-of-step rates
    after = _dynamics(model, x, u, d, dt, rates, down)
    return casadi.Function("F_given", [x, u, dt, d, w, g, v, gv], [after], ["x", "u", "dt", "d", "w", "g", "v", "gv"], ["x_next"])


def filtered_step(model: ExportedModel):
    r"""``F_filtered(xz, w, dt, d) -> xz_next``: ``F_disturbed``'s step of a hybrid with M command filters whose
    states are carried as state, as an MPC carries them (docs/export.md): xz = (x, z), z (4 M) the filters' states
    :math:`z_{j,k}` filter by filter; w the input without the filters' inputs (the delayed commands, the logged ones
    u_k, the voltage with a battery term). The step reads the filters' inputs :math:`z_{j,k} - u_k` and
    advances them over dt [s] with u_k held (:func:`~quad_modelling.core.models.hybrid.filter_step` on symbolic arrays):

    .. math:: z_{j,k+1} = u_k + (z_{j,k} - u_k)\, e^{-dt/\tau_j}

    The carried forecast's chained step (:mod:`~quad_modelling.core.live.forecast`): the filters inside the one
    compiled call instead of numpy over the horizon. Not an export Function (z is the MPC's own state)."""
    import casadi

    filters = model.hybrid.filters
    x = casadi.SX.sym("x", len(STATE))
    z = casadi.SX.sym("z", 4 * len(filters))
    w = casadi.SX.sym("w", len(input_names(model)) - 4 * len(filters))
    d = casadi.SX.sym("d", len(DISTURBANCE))
    dt = casadi.SX.sym("dt")
    after = filter_step(_elements(z).reshape(len(filters), 4), _elements(w)[4:8], _elements(dt), filters)  # the one lag, symbolic
    return casadi.Function("F_filtered", [casadi.vertcat(x, z), w, dt, d], [casadi.vertcat(_dynamics(model, x, with_filter_inputs(z, w), d, dt), _column([after]))],
                           ["xz", "w", "dt", "d"], ["xz_next"])


def with_filter_inputs(z, w):
    """The export's input u (a CasADi column) of the filters' states ``z`` (4 M) and the input ``w`` without their
    inputs (:func:`filtered_step`): w's delayed and logged commands, the filters' inputs z_j - u_logged, w's rest."""
    import casadi

    inputs = filter_inputs(_elements(z).reshape(-1, 4), _elements(w)[4:8])  # hybrid.filter_inputs on symbolic arrays
    return casadi.vertcat(w[0:8], _column([inputs]), w[8:w.shape[0]])


def terms_on(model: ExportedModel) -> list[str]:
    """The physics-model terms the vehicle file switches on (:mod:`quad_modelling.core.physics.effects`; the
    disturbance observer is not a term of f: it gives ``d``)."""
    return [name for name, term in model.vehicle.effects.items() if term.on and name != "disturbance_observer"]


def layout(model: ExportedModel) -> dict:
    """The export's description (``layout.yaml``): what each Function computes, the state, input and disturbance
    layout with units, and the constants a controller needs beside f (delay, command range, hover)."""
    import casadi

    p = model.params

    def rows(entries):
        return [{"name": name, "unit": unit, "meaning": meaning} for name, unit, meaning in entries]

    return {
        "format": "quad_modelling casadi export", "format_version": FORMAT_VERSION, "casadi_version": casadi.__version__,
        "vehicle": model.vehicle.name, "vehicle_file": model.vehicle.file_path, "model": model.spec,
        "terms_on": terms_on(model), "frames": "N = NED, B = FRD; SI units",
        "functions": {name: {"file": f"{name}.casadi", "computes": text} for name, text in FUNCTIONS.items()},
        "state": rows(STATE), "input": rows(input_names(model)), "disturbance": rows(DISTURBANCE),
        "constants": {
            "rotor_delay_s": float(p.delay), "input_min": float(p.input_min), "input_max": float(p.input_max),
            "input_unit": model.vehicle.input_unit, "mass_kg": float(p.mass), "gravity_m_s2": GRAVITY,
            "hover_command": float(p.hover_command(GRAVITY)), "hover_rotor_speed_rad_s": float(p.hover_rotor_speed(GRAVITY)),
            "hover_commands": [float(c) for c in hover_commands(p)],
            "hover_rotor_speeds_rad_s": [float(w) for w in hover_rotor_speeds(p)],
            "hover_voltage_v": None if p.battery is None else float(p.battery[1]),
        },
        "observer": {"linear_history_s": model.observer.linear_s, "angular_history_s": model.observer.angular_s,
                     "angular_trim": model.observer.angular_trim},
    }


def hover_rotor_speeds(p) -> np.ndarray:
    r"""(4,) rotor speeds [rad/s] of a level hover at rest out of ground effect (the trim an MPC linearises around):
    the thrusts T that carry the weight with no moment about the CG, :math:`M_c T = (m g, 0, 0, 0)`, M_c the
    allocation (:func:`~quad_modelling.core.physics.rigid_body.allocation_matrix`) of the rotor positions about the
    CG, :math:`r_i - c` (the motor imbalance's CG offset c; 0 when off), then :math:`\Omega_i = \sqrt{T_i / k_f}`.
    All four equal Ω_H without an offset. ConfigError when a thrust is not positive (an offset beyond the rotors)."""
    offset = np.zeros(2) if p.cg_offset is None else np.asarray(p.cg_offset, dtype=float)
    allocation = rigid_body.allocation_matrix(np.asarray(p.positions, dtype=float) - offset, p.spins,
                                              p.torque_constant / p.thrust_constant)
    thrusts = np.linalg.solve(allocation, [p.mass * GRAVITY, 0.0, 0.0, 0.0])
    if np.any(thrusts <= 0.0):
        raise ConfigError(f"no level hover: the CG offset ({offset[0]:g}, {offset[1]:g}) m lies beyond the rotors (thrusts "
                          f"{', '.join(f'{t:.3g}' for t in thrusts)} N carry the weight without a moment); check the motor "
                          "imbalance's cg_offset_x/y")
    return rotors.rotor_speed_for_thrust(p.thrust_constant, thrusts)


def hover_commands(p) -> np.ndarray:
    r"""(4,) each motor's command of the level hover :func:`hover_rotor_speeds`: :math:`u_i = u(\Omega_i) / g_i`,
    u(Ω) = (Ω - Ω_off) / k_u the rotor map's inverse and g_i the motor imbalance's gains (1 when off), at the battery
    term's reference voltage (``hover_voltage_v``; its factor is 1 there). f(x, u) is zero there (level, at rest,
    rotors at those speeds, out of ground effect: the ground effect adds its thrust near the ground)."""
    gains = np.ones(4) if p.motor_gains is None else np.asarray(p.motor_gains, dtype=float)
    return rotors.command_for_rotor_speed(hover_rotor_speeds(p), p.speed_gain, p.speed_offset) / gains


def write_casadi_export(model: ExportedModel, directory: Path) -> dict:
    """Write the Functions (``NAME.casadi``, casadi.Function.save) and ``layout.yaml`` into the new ``directory``
    (the caller's staging path: it writes atomically); returns the layout."""
    import yaml

    directory = Path(directory)
    directory.mkdir()
    for name, function in casadi_functions(model).items():
        function.save(str(directory / f"{name}.casadi"))
    description = layout(model)
    (directory / "layout.yaml").write_text(yaml.safe_dump(description, sort_keys=False, allow_unicode=True))
    return description


def narx_step(model):
    """CasADi Function (feedback ỹ (6, n_y), input part z_u (6, H)) -> (feedback after the step, ỹ of the step): one
    closed-loop step of :meth:`~quad_modelling.core.models.narx.NarxModel.simulate_from_starts`, built by the model's
    ``net_output`` and ``sigmoid`` on symbolic arrays (NARX's carried forecast chains it h times,
    :meth:`~Step.chained`: its arguments and results are then, as C arrays,
    feedback (6, n_y), z_u (h, 6, H), feedbacks (h, 6 n_y), outputs (h, 6))."""
    import casadi

    n_y, hidden, nets = model.config.output_delays, model.config.hidden, len(OUTPUTS)
    feedback = casadi.SX.sym("feedback", nets * n_y)  # column-major (n_y, 6) = C (6, n_y): net k's lags at k n_y ..
    z_u = casadi.SX.sym("z_u", nets * hidden)
    lags = np.array([feedback[i] for i in range(nets * n_y)], dtype=object).reshape(nets, n_y)
    inputs = np.array([z_u[i] for i in range(nets * hidden)], dtype=object).reshape(nets, hidden)
    z = inputs + np.matmul(model.w_y, lags[..., None])[..., 0]
    y = model.net_output(sigmoid(z), lags[:, -1])
    shifted = np.concatenate([lags[:, 1:], y[:, None]], axis=1)
    return casadi.Function("narx_step", [feedback, z_u], [casadi.vertcat(*shifted.ravel()), casadi.vertcat(*y)])


JIT_OPTIONS = {"flags": ["-O1"]}
"""CasADi's shell compiler options of a compiled step: the system's C compiler, no fast-math (the same float
operations as CasADi's virtual machine). Its files go to a temporary directory, removed once the step is loaded."""


@dataclass(frozen=True)
class Step:
    """A model's one-step CasADi Function (first input and output: the state) and whether it is compiled to C."""

    function: object
    compiled: bool

    def chained(self, steps: int):
        """The step chained ``steps`` times (``mapaccum``: the state carried, the other inputs one column per step)."""
        chained = self.function.mapaccum(f"{self.function.name()}_chained", steps)
        return chained if self.compiled else chained.expand()


def compile_step(step) -> Step:
    """``step`` (a CasADi SX Function) compiled to C by the system's C compiler when there is one (CasADi's ``jit``:
    about half a second once; the same numbers, measured 0 difference), else as it is, for CasADi's virtual machine:
    the hybrid's 50 steps (6357 instructions each) take ~0.1 ms compiled against ~0.4 ms
    (``bench/results/nodes_forecast.md``)."""
    import casadi

    symbols = [casadi.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in())]
    here = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="quad_modelling_jit_") as directory:
        os.chdir(directory)  # CasADi writes the C source into the working directory: a temporary one, removed after
        try:
            compiled = casadi.Function(f"{step.name()}_compiled", symbols, step.call(symbols),
                                       {"jit": True, "compiler": "shell", "jit_cleanup": False,
                                        "jit_options": {"directory": directory + os.sep, "cleanup": False, **JIT_OPTIONS}})
        except RuntimeError:  # no C compiler (CasADi names the failed command): its virtual machine
            return Step(step, False)
        finally:
            os.chdir(here)
    return Step(compiled, True)  # loaded: its library file may go
