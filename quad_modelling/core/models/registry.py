"""The model registry: a spec string -> a predictor, offline (:func:`make_model`) and live (:func:`streaming_predictor`).

Built-in specs (a factory receives the text after the first ``:``, or ``""``, and the vehicle config):

=================  ==========================================================
``greybox``        linear thesis model (ZOH), :mod:`quad_modelling.core.models.greybox`
``greybox:euler``  same with the thesis's explicit-Euler discretisation
``narx:PATH``      NARX nets from a model file (window, live, multi-step), :mod:`quad_modelling.core.models.narx`
``hybrid:PATH``    physics model + residual net (window, live, multi-step), :mod:`quad_modelling.core.models.hybrid`
``direct:PATH``    physics model with body rates from a direct multi-horizon regression (window, live, multi-step),
                   :mod:`quad_modelling.core.models.direct`
``physics``        nonlinear rigid body + rotor map/lag/drag, :mod:`quad_modelling.core.models.physics`
``physics:L,A``    same with the disturbance observer's linear/angular histories [s] (0 = off)
``dummy``          :class:`~quad_modelling.core.models.base.DummyPredictor`, zero (thesis Fig 5.2)
``naive``          :class:`~quad_modelling.core.models.base.ConstantStatePredictor`, the last warm-start state held
``truth``          simulated logs only: the simulator's own physics and constants from the log's notes (perfect-model
                   floor), :mod:`quad_modelling.core.sim.truth_model` (a plug-in module, :data:`PLUGIN_MODULES`)
``truth:NOTES``    same with the simulator notes from a JSON file (the live node's windows carry no notes)
=================  ==========================================================

The learned models are imported on first use (torch is imported only to train).
:func:`register_model` adds a kind (a plug-in model, a test double).
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable

from quad_modelling.core.models.base import (
    ConstantStatePredictor,
    DummyPredictor,
    Predictor,
)
from quad_modelling.core.models.streaming import StreamingPredictor
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import ConfigError

ModelFactory = Callable[[str, VehicleConfig], Predictor]


_REGISTRY: dict[str, ModelFactory] = {}

MODEL_FILE_KINDS = ("narx", "hybrid", "direct")
"""Kinds whose spec argument is a model file (``narx:PATH``): the file is the model (``evaluate`` records its digest);
the other kinds' arguments are options (``greybox:euler``, ``physics:L,A``)."""

PLUGIN_MODULES = {"truth": "quad_modelling.core.sim.truth_model"}
"""Kinds whose factory lives outside core/models: the module, imported by name on the kind's first use, registers
it (:func:`register_model`). The ``truth`` model runs the simulator (core/sim) and anchors with the physics model's
observer (core/models): core/sim imports core/models, so core/models names it here instead of importing it."""


BASELINE_NAMES = ("naive", "dummy")
"""The evaluation's baselines, found by their names (the multi-step table's reference is the rows named naive)."""


def baseline_name_clash(name: str, spec: str) -> str | None:
    """Why ``name`` cannot name the model ``spec`` (None when it can): a baseline's name on another model
    (``naive=greybox`` replaced the greybox's multi-step rows with the baseline's)."""
    if name in BASELINE_NAMES and spec != name:
        return f"{name} is the name of a baseline every evaluation holds; name the {spec} model otherwise"
    return None


def named_spec(text: str, flag: str = "--model") -> tuple[str | None, str]:
    """A model text of ``--model`` (evaluate) or ``--models`` (run-bag) -> (its name or None, the model spec):
    ``NAME=SPEC`` names a model (two files of one kind in one table, e.g. ``a=narx:a.npz`` and ``b=narx:b.npz``; NAME
    letters, digits and '_': it names the predictor node and its topics), else the spec; ConfigError naming ``flag``
    for a bad name or a baseline's name on another model. The one rule of both verbs (run-bag refused a file path
    holding '=', evaluate read it as the spec)."""
    name, sep, spec = text.partition("=")
    if not sep or ":" in name:  # a spec whose argument holds '=' (narx:/runs/lr=0.1.npz)
        return None, text
    name, spec = name.strip(), spec.strip()
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ConfigError(f"{flag} {text!r}: model name {name!r} must be letters, digits and '_', not starting with a digit "
                          "(it names the predictor node and its topics)")
    if not spec:
        raise ConfigError(f"{flag} {text!r}: NAME= names no model; expected SPEC or NAME=SPEC")
    clash = baseline_name_clash(name, spec)
    if clash:
        raise ConfigError(f"{flag} {text!r}: {clash}")
    return name, spec


def register_model(kind: str, factory: ModelFactory) -> None:
    """Add (or replace) the factory for specs ``kind`` and ``kind:ARG``."""
    _REGISTRY[kind] = factory


def _make_greybox(arg: str, vehicle: VehicleConfig) -> Predictor:
    from quad_modelling.core.models.greybox import DISCRETISATIONS, GreyboxPredictor

    method = arg or "zoh"
    if method not in DISCRETISATIONS:
        raise ConfigError(f"model spec greybox:{arg}: discretisation must be one of {', '.join(DISCRETISATIONS)}")
    return GreyboxPredictor(vehicle, discretisation=method)


def _make_dummy(arg: str, vehicle: VehicleConfig) -> Predictor:
    if arg:
        raise ConfigError(f"model spec dummy:{arg}: the dummy model takes no argument")
    return DummyPredictor()


def _make_naive(arg: str, vehicle: VehicleConfig) -> Predictor:
    if arg:
        raise ConfigError(f"model spec naive:{arg}: the naive model takes no argument")
    return ConstantStatePredictor(vehicle)



def make_model(spec: str, vehicle: VehicleConfig) -> Predictor:
    """Build a predictor from a spec such as ``greybox``, ``dummy``, ``narx:model.pt``.

    Raises ConfigError naming the spec and the known kinds when unknown.
    """
    kind, _, arg = spec.partition(":")
    if kind not in _REGISTRY and kind in PLUGIN_MODULES:
        importlib.import_module(PLUGIN_MODULES[kind])
    if kind not in _REGISTRY:
        raise ConfigError(f"unknown model {spec!r}; known: {', '.join(sorted({*_REGISTRY, *PLUGIN_MODULES}))}")
    model = _REGISTRY[kind](arg, vehicle)
    if not getattr(model, "name", None):
        raise ConfigError(f"model spec {spec!r}: the predictor has no name")
    return model


def _make_narx(arg: str, vehicle: VehicleConfig) -> Predictor:
    """``narx:PATH``: the thesis NARX model from a model file (torch is not needed to predict)."""
    from quad_modelling.core.models.narx import NarxPredictor, load_narx

    if not arg:
        raise ConfigError("model spec narx needs a model file: narx:PATH")
    return NarxPredictor(load_narx(arg, None if vehicle is None else getattr(vehicle, "name", vehicle)))


def _make_hybrid(arg: str, vehicle: VehicleConfig) -> Predictor:
    """``hybrid:PATH``: the physics model plus its residual net from a model file."""
    from quad_modelling.core.models.hybrid import make_hybrid_predictor

    return make_hybrid_predictor(arg, vehicle)


def _make_direct(arg: str, vehicle: VehicleConfig) -> Predictor:
    """``direct:PATH``: the physics model with the body rates of a direct regression from a model file."""
    from quad_modelling.core.models.direct import make_direct_predictor

    return make_direct_predictor(arg, vehicle)


def _make_physics(arg: str, vehicle: VehicleConfig) -> Predictor:
    """``physics`` / ``physics:L`` / ``physics:L,A``: the nonlinear physics model from the vehicle's physics constants,
    with the disturbance observer's linear (and angular) history in seconds (0 = off)."""
    from quad_modelling.core.models.physics import Observer, PhysicsPredictor

    if not arg:
        return PhysicsPredictor(vehicle)
    try:
        histories = [float(x) for x in arg.split(",")]
        if len(histories) > 2:
            raise ValueError(arg)
        trim = Observer.from_vehicle(vehicle).angular_trim  # the vehicle's disturbance_observer term says how the angular part anchors
        observer = Observer(*histories, trim) if len(histories) == 2 else Observer(histories[0], angular_trim=trim)
    except ValueError as err:
        raise ConfigError(f"model spec physics:{arg}: the argument is the disturbance observer's history in seconds, "
                          f"linear[,angular], each 0 (off) or positive, e.g. physics:0.5,2") from err
    return PhysicsPredictor(vehicle, observer, name=f"physics:{arg}")


register_model("greybox", _make_greybox)
register_model("physics", _make_physics)
register_model("dummy", _make_dummy)
register_model("naive", _make_naive)
register_model("narx", _make_narx)
register_model("hybrid", _make_hybrid)
register_model("direct", _make_direct)

def streaming_predictor(spec: str, vehicle) -> StreamingPredictor:
    """The live form of a model spec (``greybox``, ``narx:PATH``, ``naive``...).

    Built by the same registry as the offline models
    (:func:`quad_modelling.core.models.registry.make_model`), so a node and
    ``quad-modelling evaluate`` run the same object. ConfigError when the model
    has no live form.
    """

    model = make_model(spec, vehicle)
    if not isinstance(model, StreamingPredictor):
        raise ConfigError(f"model {spec!r} has no live (streaming) form")
    return model
