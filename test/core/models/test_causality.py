"""Causality of every model (issue #16 item 3; the rule is in the docstring of core/models/base.py).

A prediction anchored at row s reads the measurements of rows <= s and the commands up to the
predicted row, nothing later. The helpers alter a real flight after the anchor and assert that
every prediction that ends before the alteration is unchanged (to 1e-12), and, so that the check is
not hollow, that the model does read the altered data where it may.

Four forms are checked, each when the model has it: the multi-step form (``predict_horizons``),
the live form (``start_window``/``push``), the offline window form (``predict_window``, compared
as absolute values: the evaluation's trim over the window's first second is added back, since that
trim belongs to the evaluation, not to the model) and the receding horizon's carried-state forecast
(:mod:`quad_modelling.core.live.forecast`, the command held after the anchor).

To check another model, add one line to :data:`MODELS`; a model that needs a trained file gets a
trainer in :data:`TRAINERS` and ``{kind}`` in its spec (as ``narx:{narx}``). The ``truth`` model predicts
simulated flights only: its test runs the same helpers on one.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.base import MultiStepPredictor
from quad_modelling.core.models.greybox import GreyboxPredictor
from quad_modelling.core.models.registry import make_model
from quad_modelling.core.models.streaming import StreamingPredictor, predict_window_by_stream
from quad_modelling.core.preprocess import TrimConfig, measured_variables, trim_values
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.io.loader import load_flight
from test.conftest import FIXTURES

FLIGHT = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"
"""A real Crazyflie flight, its first 1000 rows (10 s at 100 Hz; motors off, take-off at row ~250, the oval)."""

HORIZON = 50
ANCHORS = (300, 700)
"""Multi-step anchors [rows]: during the take-off (motors off until row ~250: the trim second before it
holds stopped motors), and in flight."""

WARM = 20
"""Warm-start rows of a window (the thesis's 0.2 s); the window's anchor is row WARM - 1."""

TOLERANCE = 1e-12


def _train_narx(directory: Path, vehicle) -> Path:
    """A tiny NARX (2 hidden units, 2 output delays) trained in a second on the fixture flight."""
    from quad_modelling.core.models.narx import NarxConfig
    from quad_modelling.core.training.narx import train_narx_on_flights

    config = NarxConfig(hidden=2, output_delays=2, input_delays=(0, 1), epochs=2, iterations_per_epoch=5,
                        noise_snr_db=(None,) * 6)
    model = train_narx_on_flights([load_flight(FLIGHT, vehicle)], [None], config, seed=3)
    return model.save(directory / "narx.npz")


def _train_hybrid(directory: Path, vehicle) -> Path:
    """A tiny hybrid (4 hidden units, one 5-step rollout epoch) trained in a second on the fixture flight."""
    from quad_modelling.core.training.hybrid import HybridTrainingConfig, train_hybrid_on_flights
    from quad_modelling.core.training.rollout import RolloutConfig

    config = HybridTrainingConfig(hidden=(4,), rollout=RolloutConfig(horizon=5, batch_size=64, max_epochs=1, windows_per_epoch=128))
    return train_hybrid_on_flights([load_flight(FLIGHT, vehicle)], [None], vehicle, config, seed=3).save(directory / "hybrid.npz")


def _train_direct(directory: Path, vehicle) -> Path:
    """The direct model's regression fitted (closed-form, a second) on the fixture flight."""
    from quad_modelling.core.training.direct import train_direct

    return train_direct([load_flight(FLIGHT, vehicle)], [None], vehicle).save(directory / "direct.npz")


TRAINERS = {"narx": _train_narx, "hybrid": _train_hybrid, "direct": _train_direct}
"""Kind -> trainer(directory, vehicle) -> model file, for specs with ``{kind}`` in them."""

MODELS = [
    # spec, reads commands, needs a gyro
    pytest.param("greybox", True, False, id="greybox"),
    pytest.param("greybox:euler", True, False, id="greybox-euler"),
    pytest.param("naive", False, False, id="naive"),
    pytest.param("narx:{narx}", True, True, id="narx"),
    pytest.param("physics", True, True, id="physics"),
    pytest.param("hybrid:{hybrid}", True, True, id="hybrid"),
    pytest.param("direct:{direct}", True, True, id="direct"),
]


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("crazyflie21")


@pytest.fixture(scope="module")
def flight(vehicle) -> FlightLog:
    return load_flight(FLIGHT, vehicle)


@pytest.fixture(scope="module")
def build(tmp_path_factory, vehicle):
    """spec -> model, training the files a spec names once per module."""
    files: dict[str, Path] = {}

    def make(spec: str):
        for kind, trainer in TRAINERS.items():
            if "{" + kind + "}" in spec and kind not in files:
                files[kind] = trainer(tmp_path_factory.mktemp(kind), vehicle)
        return make_model(spec.format(**files), vehicle)

    return make


# ---- the reusable helpers ---------------------------------------------------------------------------
def altered(log: FlightLog, first_row: int, commands: bool = True, measurements: bool = True, seed: int = 7) -> FlightLog:
    """``log`` with rows >= ``first_row`` changed (plausibly: within sensor and actuator ranges)."""
    rng = np.random.default_rng(seed)
    tail = slice(first_row, None)
    n = len(log) - first_row
    changes = {}

    def shifted(name: str, scale: float) -> None:
        value = getattr(log, name)
        if value is not None:
            value = value.copy()
            value[tail] += scale * rng.standard_normal(value[tail].shape)
            changes[name] = value

    if commands:
        u = log.u.copy()
        u[tail] = np.clip(u[tail] * (1.0 + 0.3 * rng.uniform(-1, 1, (n, 4))), 0.0, 65535.0)
        changes["u"] = u
    if measurements:
        shifted("pos_n", 0.5)
        shifted("vel_n", 1.0)
        shifted("acc_b", 3.0)
        shifted("gyro_b", 2.0)
        shifted("omega", 100.0)
        euler = log.euler.copy()
        euler[tail, :2] = np.clip(euler[tail, :2] + 0.3 * rng.standard_normal((n, 2)), -3.0, 3.0)
        euler[tail, 2] = np.angle(np.exp(1j * (euler[tail, 2] + rng.standard_normal(n))))
        changes["euler"] = euler
        if log.vbat is not None:
            vbat = log.vbat.copy()
            vbat[tail] *= 0.9
            changes["vbat"] = vbat
    return dataclasses.replace(log, **changes)


def assert_unchanged(new: np.ndarray, old: np.ndarray, what: str) -> None:
    np.testing.assert_allclose(new, old, rtol=TOLERANCE, atol=TOLERANCE, err_msg=f"{what}: reads data after its anchor")


def assert_changed(new: np.ndarray, old: np.ndarray, what: str) -> None:
    assert not np.allclose(new, old, rtol=1e-6, atol=1e-9), f"{what}: the model does not read the data it should"


def assert_multistep_causal(model: MultiStepPredictor, log: FlightLog, anchor: int, horizon: int = HORIZON,
                            reads_commands: bool = True) -> None:
    """Every start s <= ``anchor``: [s, h] unchanged when the measurements after the anchor change; with the
    commands after the anchor changed as well, unchanged for s + h <= anchor."""
    starts = np.arange(anchor + 2)  # every start up to the anchor, and one after it
    base = model.predict_horizons(log, starts, horizon)
    measured_later = model.predict_horizons(altered(log, anchor + 1, commands=False), starts, horizon)
    assert_unchanged(measured_later[:-1], base[:-1], f"{model.name} multi-step (measurements after row {anchor})")
    assert_changed(measured_later[-1], base[-1], f"{model.name} multi-step start {anchor + 1}")
    both_later = model.predict_horizons(altered(log, anchor + 1), starts, horizon)[:-1]
    before = (starts[:-1, None] + np.arange(horizon + 1)[None, :]) <= anchor
    assert_unchanged(both_later[before], base[:-1][before], f"{model.name} multi-step (commands after row {anchor})")
    if reads_commands:
        assert_changed(both_later[~before], base[:-1][~before], f"{model.name} multi-step after row {anchor}")


def assert_streaming_causal(model: StreamingPredictor, window: FlightLog, warm: int = WARM, reads_commands: bool = True) -> None:
    """Live form: the measurements after the anchor (row warm - 1) change nothing; commands changed from row
    a > warm leave the predictions of rows < a unchanged."""
    base = predict_window_by_stream(model, window, warm)
    assert_unchanged(predict_window_by_stream(model, altered(window, warm, commands=False), warm), base,
                     f"{model.name} live (measurements after the warm start)")
    later = warm + 30
    moved = predict_window_by_stream(model, altered(window, later), warm)
    assert_unchanged(moved[:later], base[:later], f"{model.name} live (commands from row {later})")
    if reads_commands:
        assert_changed(moved[later:], base[later:], f"{model.name} live from row {later}")


def absolute_window(model, window: FlightLog, warm: int) -> np.ndarray:
    """``predict_window`` with the evaluation's trim (measured mean over the first ``trim_s``) added back."""
    trim = getattr(model, "trim", None) or TrimConfig()
    return model.predict_window(window, warm) + trim_values(measured_variables(window), trim.trim_samples(window))


def assert_window_causal(model, window: FlightLog, warm: int = WARM, reads_commands: bool = True) -> None:
    """Offline window form, absolute: as :func:`assert_streaming_causal`."""
    base = absolute_window(model, window, warm)
    assert_unchanged(absolute_window(model, altered(window, warm, commands=False), warm), base,
                     f"{model.name} window (measurements after the warm start)")
    later = warm + 30
    moved = absolute_window(model, altered(window, later), warm)
    assert_unchanged(moved[:later], base[:later], f"{model.name} window (commands from row {later})")
    if reads_commands:
        assert_changed(moved[later:], base[later:], f"{model.name} window from row {later}")


def carried_held_forecasts(model, vehicle, log: FlightLog, anchors: np.ndarray, horizon: int = HORIZON) -> np.ndarray:
    """(A, horizon + 1, 18) carried-state forecasts (:func:`~quad_modelling.core.live.forms.carried_forecast`) from
    each of the increasing ``anchors``, the anchor's command held at its period after it: the rows are added as the
    receding horizon adds them (the first anchor's rows from row 0 at once, then each later row behind the last)."""
    from quad_modelling.core.live.forms import carried_forecast

    period = float(np.median(np.diff(log.t)))
    carried = carried_forecast(model, vehicle, period, horizon)
    out, added = [], None
    for a in anchors:
        carried.add(log.slice(0 if added is None else added, a + 1), 0 if added is None else 1)
        added = a
        out.append(carried.predict(log.t[a] + period * np.arange(1, horizon + 1), np.tile(log.u[a], (horizon, 1))))
    return np.array(out)


def assert_carried_causal(model, vehicle, log: FlightLog, anchor: int, horizon: int = HORIZON) -> None:
    """Measurements and commands after ``anchor`` changed: the held forecasts from the anchors up to it are
    unchanged; the one from the next row changes."""
    anchors = np.arange(anchor - 5, anchor + 2)
    base = carried_held_forecasts(model, vehicle, log, anchors, horizon)
    moved = carried_held_forecasts(model, vehicle, altered(log, anchor + 1), anchors, horizon)
    assert_unchanged(moved[:-1], base[:-1], f"{model.name} carried forecast (data after row {anchor})")
    assert_changed(moved[-1], base[-1], f"{model.name} carried forecast from row {anchor + 1}")


# ---- every model ------------------------------------------------------------------------------------
def _flights(flight: FlightLog, needs_gyro: bool) -> list[FlightLog]:
    """The flight, and (for models that do without) the same flight without its gyro: rates from the attitude."""
    return [flight] if needs_gyro else [flight, dataclasses.replace(flight, gyro_b=None)]


@pytest.mark.parametrize(("spec", "reads_commands", "needs_gyro"), MODELS)
def test_multistep_predictions_read_nothing_after_their_start(build, flight, spec, reads_commands, needs_gyro):
    model = build(spec)
    assert isinstance(model, MultiStepPredictor), f"{spec} has no vectorised multi-step form"
    for log in _flights(flight, needs_gyro):
        for anchor in ANCHORS:
            assert_multistep_causal(model, log, anchor, HORIZON, reads_commands)


@pytest.mark.parametrize(("spec", "reads_commands", "needs_gyro"), MODELS)
def test_live_and_window_predictions_read_nothing_after_their_anchor(build, flight, spec, reads_commands, needs_gyro):
    model = build(spec)
    assert isinstance(model, StreamingPredictor)
    for log in _flights(flight, needs_gyro):
        window = log.slice(300, 500)  # a 2 s window in flight
        assert_streaming_causal(model, window, WARM, reads_commands)
        assert_window_causal(model, window, WARM, reads_commands)


@pytest.mark.parametrize(("spec", "reads_commands", "needs_gyro"), [m for m in MODELS if m.id != "naive"])
def test_carried_forecasts_read_nothing_after_their_anchor(build, flight, vehicle, spec, reads_commands, needs_gyro):
    """Every model with a carried form (naive has none: the receding horizon re-runs its multi-step form)."""
    model = build(spec)
    for anchor in ANCHORS:
        assert_carried_causal(model, vehicle, flight, anchor)


# ---- the helpers catch a leak --------------------------------------------------------------------------
class SegmentMeanNaive:
    """A leaking model: the naive held state, but roll from the mean over the whole segment (the old greybox's
    roll/pitch offset)."""

    name = "leaky"

    def predict_horizons(self, segment, starts, horizon):
        measured = measured_variables(segment)
        held = measured[starts].copy()
        held[:, 9] = measured[:, 9].mean()  # roll from the whole segment: future rows
        return np.repeat(held[:, None, :], horizon + 1, axis=1)


def test_the_multistep_helper_catches_a_segment_wide_trim(flight):
    with pytest.raises(AssertionError, match="reads data after its anchor"):
        assert_multistep_causal(SegmentMeanNaive(), flight, ANCHORS[1], HORIZON, reads_commands=False)


def test_the_window_helper_catches_a_model_that_trims_over_the_first_second(flight, vehicle):
    """The greybox's window trim over the 0.2 s warm start is causal; over the evaluation's 1 s it would read
    0.8 s past the anchor, and the helper says so."""

    class FirstSecondTrim(GreyboxPredictor):
        def predict_absolute(self, window, warm_samples):
            model, predictions, state, _, output_trim = self._anchor(window.slice(0, warm_samples))
            input_trim = window.u[:100].mean(axis=0)  # the thesis's input trim: the window's first second
            _, outputs = model.simulate(state, window.u[warm_samples:] - input_trim)
            return np.concatenate([predictions, output_trim + outputs])

    leaky = FirstSecondTrim(vehicle)
    with pytest.raises(AssertionError, match="reads data after its anchor"):
        assert_window_causal(leaky, flight.slice(300, 500), WARM)


# ---- the causal greybox multi-step trim, known answers ----------------------------------------------------
def _still(vehicle, rows: int, u: np.ndarray) -> FlightLog:
    """The vehicle still and level at 1 m for ``rows`` samples at 100 Hz, commands ``u`` (rows, 4)."""
    zeros = np.zeros((rows, 3))
    acc = zeros.copy()
    acc[:, 2] = -GRAVITY
    pos = zeros.copy()
    pos[:, 2] = -1.0
    from quad_modelling.core.flight_log import FlightMeta

    return FlightLog(t=np.arange(rows) * 0.01, u=u, acc_b=acc, gyro_b=zeros.copy(), pos_n=pos, vel_n=zeros.copy(),
                     euler=zeros.copy(), meta=FlightMeta(vehicle.name, "still"))


def test_greybox_multistep_trims_commands_over_the_second_before_each_start(vehicle):
    """Commands step from c1 to c2 at row 300 of a still flight. From a start 4 s after the step the trim is c2
    and the motors have settled (80 time constants): the model stays at rest. Half a second after it, the trim is (c1 + c2) / 2 over the last 100 rows,
    so the model sees u - trim = (c2 - c1) / 2 on every motor: the climb of the linear model's own simulation
    from a thrust state the motor filter built over the step."""
    c1, c2 = 30000.0, 34000.0
    u = np.full((800, 4), c1)
    u[300:] = c2
    log = _still(vehicle, 800, u)
    greybox = GreyboxPredictor(vehicle)
    rest, half = greybox.predict_horizons(log, np.array([700, 349]), 50)
    np.testing.assert_allclose(rest[:, 0:6], np.tile([0, 0, -1.0, 0, 0, 0], (51, 1)), atol=1e-12)
    np.testing.assert_allclose(rest[:, 9:15], 0.0, atol=1e-12)

    model = greybox.discrete(log)
    trim = (c1 + c2) / 2  # rows 250..349: 50 rows of c1, 50 of c2
    thrusts = model.motor_thrusts(u[:, 0] - trim)[349]  # the filter over the raw past, as the trim moved
    x0 = np.zeros(16)
    x0[2] = -1.0
    x0[12:] = thrusts
    _, expected = model.simulate(x0, u[349:400] - trim)
    np.testing.assert_allclose(half, expected, rtol=1e-9, atol=1e-12)
    # the thrust deviation is positive, the model climbs (NED: z decreases) faster than at rest
    assert thrusts > 0 and half[-1, 2] < -1.0 - 1e-3 and half[-1, 5] < 0


# ---- the truth model, on a simulated flight ------------------------------------------------------------
@pytest.fixture(scope="module")
def simulated():
    """4 s of a simulated LinkQuad flight with the default effects (delay, motor lag, battery, ground effect...), in the
    climb from 1 s after the take-off. (On the ground the truth model evaluates the simulator's contact law member by
    member: slow for hundreds of starts.)"""
    from quad_modelling.core.sim.simulate import simulate

    return simulate("linkquad", seed=2, duration=14.0).slice(300, 700)


@pytest.mark.slow
def test_truth_model_reads_nothing_after_its_anchor(simulated):
    """The truth model (the simulator's physics from the log's notes) in its three forms, with the physics model's
    disturbance observer (its default has none: a subset); the battery voltage after the anchor is altered too."""
    model = make_model("truth:0.5,0.5", load_vehicle("linkquad"))
    assert_multistep_causal(model, simulated, 150, HORIZON)
    window = simulated.slice(200, 320)
    assert_streaming_causal(model, window, WARM)
    assert_window_causal(model, window, WARM)
