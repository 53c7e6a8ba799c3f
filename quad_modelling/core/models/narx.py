"""NARX blackbox model (thesis chapter 4, DESIGN 6.3): six small recurrent nets.

One net per velocity/rate ``y_k`` (k = X, Y, Z velocity in N [m/s]; roll,
pitch, yaw rate [rad/s]). Each net sees the four engine commands ``u`` at the
input delays ``d ∈ D_u`` and its own last ``n_y`` outputs, all normalised
(``ũ = (u − μ_u)/σ_u``, ``ỹ_k = (y_k − μ_k)/σ_k``):

.. math::

    x_k(t) = [ũ(t − d)]_{d ∈ D_u} ⊕ [ỹ_k(t − n_y), …, ỹ_k(t − 1)]

    h_k(t) = σ(W_{1,k} x_k(t) + b_{1,k}),   σ(z) = 1 / (1 + e^{−z})

    ỹ_k(t) = ρ ỹ_k(t − 1) + s_k (w_{2,k} · h_k(t) + b_{2,k}),     y_k(t) = μ_k + σ_k ỹ_k(t)

with ``H`` hidden units per net (thesis: H = 10, n_y = 20, i.e. 0.2 s of memory
at 100 Hz). The thesis's nets predict the output itself (ρ = 0, s_k = 1); the
*incremental* form (``NarxConfig.incremental``: ρ = 1, s_k = std(ỹ_k(t) − ỹ_k(t−1))
over the training data, stored as ``y_step``) predicts the normalised change per
sample, so holding the last output is the net's zero and one-step errors start
at the scale of one sample's change. ``W_{1,k}`` is stored split into its input part ``W_u`` and its
output-feedback part ``W_y`` (columns in ascending time, oldest first).

Training (:mod:`quad_modelling.core.training.narx`) is series-parallel (thesis Fig 4.4): the feedback inputs are the
*measured* past outputs, the loss is the mean squared error of ``ỹ_k(t)``.
Before normalisation, white Gaussian noise is added to the low-noise series
as the thesis did (section 6.2: 10 dB SNR on the angle rates, velocities left
as they are): noise variance = var(y_k) / 10^(SNR/10). All six nets are
trained at once as one batched module (they share no parameter; the loss is
the sum of their MSEs, so each net's gradient is its own) with full-batch
L-BFGS (strong-Wolfe line search): the nets are tiny (≈1000 weights), so a
second-order-like full-batch method converges in a few hundred iterations
where MATLAB's thesis default was Levenberg-Marquardt; one *epoch* is one
L-BFGS step of ``iterations_per_epoch`` iterations. The improved training
fine-tunes the nets closed loop over K steps afterwards (rollout loss,
:mod:`quad_modelling.core.training.rollout`).

Prediction is parallel / closed-loop (thesis Fig 4.3): the first ``n_y``
samples are measured, afterwards the nets feed back their own predictions. It
runs in numpy with the extracted weights (the input part ``W_u ũ`` is
computed for the whole window at once, only the feedback part is sequential).
Positions/angles are integrated (trapezoid, anchored at the measured value at
the window start) and accelerations differentiated (central differences)
from the predicted velocities/rates, so a model gives all 18
:data:`~quad_modelling.core.variables.VARIABLES` (thesis section 4.2; angles
integrate the body rates p, q, r as the thesis did, a small-angle
approximation).

Model files are ``.npz`` (``allow_pickle=False``) with a JSON header array
``header`` (format, version, vehicle, variables, delays, sample period,
training spans...) next to the weight and normalisation arrays.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.model_files import FORMAT, FORMAT_VERSION, header_flag, header_float, header_int, read_model_file
from quad_modelling.core.variables import VARIABLES, columns
from quad_modelling.errors import DataError, ModelError, reason

OUTPUTS: tuple[str, ...] = ("vel_x", "vel_y", "vel_z", "roll_rate", "pitch_rate", "yaw_rate")
"""The six net outputs (thesis section 4.2), in this order."""


INTEGRATED: tuple[str, ...] = ("pos_x", "pos_y", "pos_z", "roll", "pitch", "yaw")
"""Variables integrated from :data:`OUTPUTS` (same order)."""


DIFFERENTIATED: tuple[str, ...] = ("acc_x", "acc_y", "acc_z", "roll_acc", "pitch_acc", "yaw_acc")
"""Variables differentiated from :data:`OUTPUTS` (same order)."""

OUTPUT_COLUMNS, INTEGRATED_COLUMNS, DIFFERENTIATED_COLUMNS = (np.array(columns(names)) for names in (OUTPUTS, INTEGRATED, DIFFERENTIATED))
"""Their columns in an (N, 18) variables array, as index arrays (a list is converted at every indexing)."""


THESIS_NOISE_SNR_DB: tuple[float | None, ...] = (None, None, None, 10.0, 10.0, 10.0)
"""Thesis section 6.2: 10 dB noise on the angle rates, velocities kept as they were."""




MAX_HIDDEN = 1000
"""Most sigmoid units per net (the thesis used 10): ``train``'s limit, and a model file's."""

MAX_DELAYS = 1000
"""Most delayed outputs or input taps (10 s at 100 Hz; the thesis used 20): an edited model file's 10^9 asked for
gigabytes."""

ARRAY_NAMES = ("w_u", "w_y", "b_1", "w_2", "b_2", "u_mean", "u_std", "y_mean", "y_std", "y_step")


MIN_STD = 1e-9
"""Smallest standard deviation used for normalisation (a constant channel maps to 0)."""


@dataclass(frozen=True)
class NarxConfig:
    """Architecture and training settings (defaults: thesis section 4.2).

    hidden: sigmoid units per net (thesis 10).
    output_delays: n_y, number of past outputs fed back (thesis 20 = 0.2 s at 100 Hz).
    input_delays: delays D_u [samples] of the engine commands (0 = current command).
    epochs: L-BFGS steps (thesis 25 training epochs).
    iterations_per_epoch: L-BFGS iterations per step.
    noise_snr_db: per output (OUTPUTS order), SNR [dB] of the white noise added to
        that series before training, None for none (thesis: rates 10 dB).
    incremental: nets predict the normalised change per sample (ρ = 1, module doc);
        False = the thesis's nets predicting the output itself.
    """

    hidden: int = 10
    output_delays: int = 20
    input_delays: tuple[int, ...] = tuple(range(20))
    epochs: int = 25
    iterations_per_epoch: int = 20
    noise_snr_db: tuple[float | None, ...] = THESIS_NOISE_SNR_DB
    incremental: bool = False

    def __post_init__(self) -> None:
        if self.hidden < 1 or self.output_delays < 1 or self.epochs < 0 or self.iterations_per_epoch < 1:
            raise ModelError(f"NARX config: hidden, output_delays, iterations must be >= 1 and epochs >= 0, got {self}")
        if not self.input_delays or min(self.input_delays) < 0 or len(set(self.input_delays)) != len(self.input_delays):
            raise ModelError(f"NARX config: input_delays must be distinct delays >= 0, got {self.input_delays}")
        if self.hidden > MAX_HIDDEN or max(self.output_delays, *self.input_delays) > MAX_DELAYS:
            raise ModelError(f"NARX config: at most {MAX_HIDDEN} hidden units and delays of at most {MAX_DELAYS} samples, got "
                             f"hidden {self.hidden}, output_delays {self.output_delays}, input delays up to {max(self.input_delays)}")
        if len(self.noise_snr_db) != len(OUTPUTS):
            raise ModelError(f"NARX config: noise_snr_db needs {len(OUTPUTS)} entries, got {len(self.noise_snr_db)}")

    @property
    def warm_samples(self) -> int:
        """Measured samples needed before closed-loop prediction starts."""
        return max(self.output_delays, max(self.input_delays))


def sigmoid(z: np.ndarray) -> np.ndarray:
    """Logistic function σ(z) = 1/(1+e^{−z}), computed without overflow."""
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def lagged_inputs(u_norm: np.ndarray, input_delays: tuple[int, ...], first: int = 0) -> np.ndarray:
    """(N - first, len(D_u)·n_u) matrix of [ũ(t−d)]_{d∈D_u} at rows t = first .. N - 1 of ``u_norm`` (N, n_u); rows
    before a delay's reach repeat ũ(0)."""
    rows = np.maximum(np.arange(first, len(u_norm))[:, None] - np.asarray(input_delays, dtype=int)[None, :], 0)
    return u_norm[rows].reshape(len(rows), -1)  # one gather: the delays' blocks side by side, in D_u's order


@dataclass
class NarxModel:
    """Six trained NARX nets, their normalisation and provenance (see module doc).

    Arrays (float64): ``w_u`` (6, H, len(D_u)·n_u), ``w_y`` (6, H, n_y),
    ``b_1`` (6, H), ``w_2`` (6, H), ``b_2`` (6,); ``u_mean``/``u_std`` (n_u,),
    ``y_mean``/``y_std``/``y_step`` (6,) (``y_step`` = s_k, ones for the thesis form). ``header`` holds config, vehicle, sample period
    ``dt`` [s], training spans and anything a subclass adds.
    """

    config: NarxConfig
    dt: float
    vehicle: str
    w_u: np.ndarray
    w_y: np.ndarray
    b_1: np.ndarray
    w_2: np.ndarray
    b_2: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    y_step: np.ndarray
    kind: str = "narx"
    training: dict = field(default_factory=dict)

    # ---- normalisation -------------------------------------------------
    def normalise_inputs(self, u: np.ndarray) -> np.ndarray:
        """ũ = (u − μ_u)/σ_u."""
        return (np.asarray(u, dtype=float) - self.u_mean) / self.u_std

    def normalise_outputs(self, y: np.ndarray) -> np.ndarray:
        """ỹ = (y − μ_y)/σ_y."""
        return (np.asarray(y, dtype=float) - self.y_mean) / self.y_std

    def denormalise_outputs(self, y_norm: np.ndarray) -> np.ndarray:
        """y = μ_y + σ_y ỹ."""
        return self.y_mean + self.y_std * np.asarray(y_norm, dtype=float)

    @property
    def rho(self) -> float:
        """ρ of the module doc: 1 for incremental nets, 0 for the thesis's."""
        return 1.0 if self.config.incremental else 0.0

    def net_output(self, hidden: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """ỹ_k(t) = ρ ỹ_k(t−1) + s_k (w_{2,k}·h_k + b_{2,k}) from hidden activations (..., 6, H) and ỹ(t−1) (..., 6)."""
        return self.rho * previous + self.y_step * ((self.w_2 * hidden).sum(axis=-1) + self.b_2)

    def input_part(self, u: np.ndarray, first: int = 0) -> np.ndarray:
        """(N - first, 6, H) the nets' pre-activations from the commands, :math:`W_u [ũ(t − d)]_{d ∈ D_u} + b_1`, of
        rows ``first`` .. N - 1 of the raw commands ``u`` (N, n_u) (:func:`lagged_inputs`: rows before a delay's reach
        repeat u(0)), as one matrix product."""
        lagged = lagged_inputs(self.normalise_inputs(u), self.config.input_delays, first)
        w_u = self.w_u
        return (lagged @ w_u.reshape(-1, w_u.shape[2]).T).reshape(len(lagged), *w_u.shape[:2]) + self.b_1

    # ---- prediction ----------------------------------------------------
    def one_step(self, u: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Series-parallel (one-step-ahead) prediction from measured past outputs.

        u (N, n_u), y (N, 6) measured; returns (N, 6) where row t uses measured
        y(t−n_y..t−1); the first n_y rows are the measurements themselves.
        """
        y = np.asarray(y, dtype=float)
        y_norm = self.normalise_outputs(y)
        n_y = self.config.output_delays
        z = self.input_part(u)
        windows = np.lib.stride_tricks.sliding_window_view(y_norm, n_y, axis=0)[:-1]  # (N−n_y, 6, n_y)
        z[n_y:] += np.einsum("nkd,khd->nkh", windows, self.w_y)
        previous = np.concatenate([y_norm[:1], y_norm[:-1]])
        out = self.denormalise_outputs(self.net_output(sigmoid(z), previous))
        out[:n_y] = y[:n_y]
        return out

    def simulate(self, u: np.ndarray, y_warm: np.ndarray) -> np.ndarray:
        """Closed-loop (parallel) prediction of the six velocities/rates.

        u (N, n_u): engine commands over the window; y_warm (n, 6) with
        n ≥ n_y: measured outputs of the first n samples, returned unchanged.
        Rows n..N−1 are predicted from the nets' own past predictions.
        """
        u = np.asarray(u, dtype=float)
        y_warm = np.asarray(y_warm, dtype=float)
        n_y = self.config.output_delays
        if y_warm.ndim != 2 or y_warm.shape[1] != len(OUTPUTS) or len(y_warm) < n_y:
            raise ModelError(f"NARX closed loop needs at least {n_y} measured samples of {len(OUTPUTS)} outputs, got {y_warm.shape}")
        if len(y_warm) > len(u):
            raise ModelError(f"NARX closed loop: {len(y_warm)} warm samples for a window of {len(u)}")
        n = len(u)
        z_u = self.input_part(u)
        series = np.empty((len(OUTPUTS), n))  # normalised outputs, one row per net
        series[:, : len(y_warm)] = self.normalise_outputs(y_warm).T
        w_y = self.w_y
        for t in range(len(y_warm), n):
            z = z_u[t] + np.matmul(w_y, series[:, t - n_y : t, None])[..., 0]
            series[:, t] = self.net_output(0.5 + 0.5 * np.tanh(0.5 * z), series[:, t - 1])
        y = self.denormalise_outputs(series.T)
        y[: len(y_warm)] = y_warm  # exactly the measurements, not their normalisation round trip
        return y

    def simulate_from_starts(self, u: np.ndarray, y: np.ndarray, starts: np.ndarray, horizon: int) -> np.ndarray:
        """Closed-loop predictions of the six outputs from many starts at once: (S, horizon + 1, 6).

        u (N, n_u) commands and y (N, 6) measured outputs of one contiguous series.
        Row ``[i, 0]`` is y(s) (s = ``starts[i]``); row ``[i, h]`` predicts y(s + h) from
        the measured y(s − n_y + 1 … s) (rows before 0 repeat y(0), as the commands'
        lags repeat u(0) in :func:`lagged_inputs`) and the commands up to s + h, feeding
        back its own predictions; nothing after row s of y is read (causal). Vectorised
        over the starts; gives the numbers of :class:`NarxStream` seeded with rows ≤ s.
        """
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        starts = np.asarray(starts, dtype=int)
        n_y = self.config.output_delays
        if len(starts) and (starts.min() < 0 or starts.max() + horizon >= len(u) or len(y) != len(u)):
            raise ModelError(f"NARX horizons: starts {starts.min()}..{starts.max()} + {horizon} steps do not fit {len(u)} rows")
        z_u = self.input_part(u)
        y_norm = self.normalise_outputs(y)
        padded = np.concatenate([np.repeat(y_norm[:1], n_y - 1, axis=0), y_norm])  # row s + n_y − 1 = y(s)
        feedback = np.lib.stride_tricks.sliding_window_view(padded, n_y, axis=0)[starts].copy()  # (S, 6, n_y): y(s−n_y+1..s)
        out = np.empty((len(starts), horizon + 1, len(OUTPUTS)))
        out[:, 0] = y[starts]
        for h in range(1, horizon + 1):
            z = z_u[starts + h] + np.einsum("skd,khd->skh", feedback, self.w_y)
            y_h = self.net_output(0.5 + 0.5 * np.tanh(0.5 * z), feedback[:, :, -1])
            feedback[:, :, :-1] = feedback[:, :, 1:]
            feedback[:, :, -1] = y_h
            out[:, h] = self.denormalise_outputs(y_h)
        return out

    def stream(self, u_history: np.ndarray, y_history: np.ndarray) -> NarxStream:
        """Streaming closed-loop predictor seeded with measured history (see :class:`NarxStream`)."""
        return NarxStream(self, u_history, y_history)

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) absolute prediction of ``window`` in VARIABLES order (closed loop after warm-up).

        The first max(warm_samples, n_y) rows are the measurement (they seed the
        nets); later rows are predicted (see :func:`expand_outputs`). The
        window's sample rate must match the model's (within 1 %). Gives the same
        numbers as the streaming form :meth:`NarxPredictor.start_window`.
        """
        from quad_modelling.core.preprocess import measured_variables

        window.require(("gyro_b",), "model narx (its outputs are velocities and gyro rates)")
        check_sample_rate(self, window)
        warm = max(int(warm_samples), self.config.output_delays)
        if warm >= len(window):
            raise DataError(f"{window.meta.source}: window of {len(window)} samples is shorter than the {warm} warm-up samples")
        measured = np.zeros((len(window), len(VARIABLES)))
        measured[:warm] = measured_variables(window.slice(0, warm))  # only the warm rows are seen, as live
        y = self.simulate(window.u, measured[:warm, OUTPUT_COLUMNS])
        return expand_outputs(measured, y, warm, self.dt)

    # ---- files -----------------------------------------------------------
    def header(self) -> dict:
        """JSON-serialisable description stored in the model file."""
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "kind": self.kind,
            "vehicle": self.vehicle,
            "variables": list(VARIABLES),
            "outputs": list(OUTPUTS),
            "dt": self.dt,
            "config": {**dataclasses.asdict(self.config), "input_delays": list(self.config.input_delays)},
            "training": self.training,
        }

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in ARRAY_NAMES}

    def save(self, path: str | Path, force: bool = False) -> Path:
        """Write an .npz model file atomically (never overwrites without ``force``)."""
        from quad_modelling.atomic import atomic_output

        path = Path(path)
        with atomic_output(path, force) as tmp:
            with open(tmp, "wb") as stream:
                np.savez(stream, header=np.array(json.dumps(self.header())), **self.arrays())
        return path


class NarxStream:
    """Per-sample closed-loop NARX for live use: ``push(u(t)) -> y(t)``.

    Seeded with at least max(D_u) past commands and n_y measured outputs (the
    samples before t). Uses the same numpy weights as :meth:`NarxModel.simulate`,
    and gives the same numbers sample for sample.
    """

    def __init__(self, model: NarxModel, u_history: np.ndarray, y_history: np.ndarray) -> None:
        self.model = model
        n_y = model.config.output_delays
        self._u_span = max(model.config.input_delays) + 1
        u_history = np.atleast_2d(np.asarray(u_history, dtype=float))
        y_history = np.atleast_2d(np.asarray(y_history, dtype=float))
        if len(y_history) < n_y or y_history.shape[1] != len(OUTPUTS):
            raise ModelError(f"NARX stream needs at least {n_y} past outputs of {len(OUTPUTS)} variables, got {y_history.shape}")
        if len(u_history) == 0 or u_history.shape[1] != len(model.u_mean):
            raise ModelError(f"NARX stream needs past engine commands of {len(model.u_mean)} channels, got {u_history.shape}")
        u_norm = model.normalise_inputs(u_history)
        if len(u_norm) < self._u_span:  # repeat the oldest command, as lagged_inputs does
            u_norm = np.concatenate([np.repeat(u_norm[:1], self._u_span - len(u_norm), axis=0), u_norm])
        self._u = u_norm[-self._u_span :].copy()  # oldest first; the last row is replaced by u(t) on push
        self._y = model.normalise_outputs(y_history[-n_y:]).T.copy()  # (6, n_y), oldest first
        self._taps = np.array([self._u_span - 1 - d for d in model.config.input_delays])

    def push(self, u: np.ndarray) -> np.ndarray:
        """Feed command u(t) (n_u,), return the predicted outputs y(t) (6,) in SI units."""
        m = self.model
        self._u[:-1] = self._u[1:]
        self._u[-1] = m.normalise_inputs(u)
        x_u = self._u[self._taps].reshape(-1)
        z = m.w_u @ x_u + np.matmul(m.w_y, self._y[..., None])[..., 0] + m.b_1
        y_norm = m.net_output(sigmoid(z), self._y[:, -1])
        self._y[:, :-1] = self._y[:, 1:]
        self._y[:, -1] = y_norm
        return m.denormalise_outputs(y_norm)


# ---- measurements and the 18 variables --------------------------------------
def measured_outputs(log: FlightLog) -> np.ndarray:
    """(N, 6) best measurements of OUTPUTS (DESIGN 7): motion-capture velocity in N, gyro rates."""
    log.require(("gyro_b",), "NARX training (its outputs are velocities and gyro rates)")
    return np.concatenate([log.vel_n, log.gyro_b], axis=1)


def expand_outputs(measured: np.ndarray, y: np.ndarray, warm: int, dt: float) -> np.ndarray:
    """All 18 VARIABLES from predicted velocities/rates y (N, 6) (thesis section 4.2), causally.

    Rows < warm are the measurement (N, 18). From row warm on, with v = y and
    the measured v at row warm − 1 as start:
    s(t) = s(t−1) + ½ (v(t) + v(t−1)) dt (positions/angles, trapezoid from the
    measured s at row warm − 1) and a(t) = (v(t) − v(t−1)) / dt (accelerations,
    backward difference), with the model's sample period ``dt`` [s]; so the
    streaming form can give exactly the same numbers sample by sample.
    """
    out = np.array(measured, dtype=float, copy=True)
    v = np.concatenate([measured[warm - 1 : warm, OUTPUT_COLUMNS], y[warm:]])
    out[warm:, OUTPUT_COLUMNS] = y[warm:]
    steps = np.diff(v, axis=0)
    out[warm:, DIFFERENTIATED_COLUMNS] = steps / dt
    start = measured[warm - 1, INTEGRATED_COLUMNS]
    out[warm:, INTEGRATED_COLUMNS] = start + np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)
    return out


def horizons_from_measured(model: NarxModel, measured: np.ndarray, u: np.ndarray, starts: np.ndarray, horizon: int) -> np.ndarray:
    """(S, horizon + 1, 18) of :meth:`NarxPredictor.predict_horizons` from the measurement (N, 18, VARIABLES order; of
    each row only positions, velocities, angles and rates are read) and commands ``u`` (N, 4) of one series
    (the carried-state forecast, :mod:`quad_modelling.core.live.forecast`, calls it on its last rows)."""
    return expand_horizons(model, measured, starts, model.simulate_from_starts(u, measured[:, OUTPUT_COLUMNS], starts, horizon))


def expand_horizons(model: NarxModel, measured: np.ndarray, starts: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(S, H + 1, 18) of :func:`horizons_from_measured` from the predicted outputs ``v`` (S, H + 1, 6) (row 0: the
    measured y(s)): positions/angles integrated (trapezoid) from the measured ones at s, accelerations as backward
    differences (row 0: of the measured outputs)."""
    dt, horizon = model.dt, v.shape[1] - 1
    y = measured[:, OUTPUT_COLUMNS]
    out = np.empty((len(starts), horizon + 1, len(VARIABLES)))
    out[:, 0] = measured[starts]
    previous = y[np.maximum(starts - 1, 0)]
    out[:, 0, DIFFERENTIATED_COLUMNS] = (y[starts] - previous) / dt
    out[:, :, OUTPUT_COLUMNS] = v
    out[:, 1:, DIFFERENTIATED_COLUMNS] = (v[:, 1:] - v[:, :-1]) / dt
    start = measured[starts][:, INTEGRATED_COLUMNS]
    out[:, 0, INTEGRATED_COLUMNS] = start
    out[:, 1:, INTEGRATED_COLUMNS] = start[:, None, :] + np.cumsum(0.5 * (v[:, 1:] + v[:, :-1]) * dt, axis=1)
    return out


SAMPLE_PERIOD_TOLERANCE = 0.05
"""Largest relative difference between a window's mean sample period and the model's: a 50 Hz or 250 Hz log for a
100 Hz model is refused, a stack's stamps jittered by +-1 ms at 100 Hz are not (the median of 20 jittered warm
steps refused half the live windows at the 1 % this was)."""


def check_sample_rate(model: NarxModel, window: FlightLog) -> None:
    """Refuse a window whose mean sample period (t_last - t_first) / (N - 1) differs from the model's by more than
    :data:`SAMPLE_PERIOD_TOLERANCE`."""
    dt = float(window.t[-1] - window.t[0]) / (len(window) - 1) if len(window) > 1 else 1.0 / window.sample_rate
    if abs(dt - model.dt) > SAMPLE_PERIOD_TOLERANCE * model.dt:
        raise DataError(
            f"{window.meta.source}: sampled every {dt * 1e3:.3f} ms but the {model.kind} model was trained "
            f"at {model.dt * 1e3:.3f} ms; resample the log first"
        )


def model_from_parts(path: Path, header: dict, contents: dict[str, np.ndarray]) -> NarxModel:
    """Build a NarxModel from a checked header and arrays, validating every shape."""
    try:
        cfg = header["config"]
        config = NarxConfig(
            hidden=header_int(cfg["hidden"]), output_delays=header_int(cfg["output_delays"]),
            input_delays=tuple(header_int(d) for d in cfg["input_delays"]), epochs=header_int(cfg["epochs"]),
            iterations_per_epoch=header_int(cfg["iterations_per_epoch"]),
            noise_snr_db=tuple(None if s is None else header_float(s) for s in cfg["noise_snr_db"]),
            incremental=header_flag(cfg["incremental"]),
        )
        arrays = {name: np.asarray(contents[name], dtype=float) for name in ARRAY_NAMES}
        dt = float(header["dt"])
        training = dict(header.get("training", {}))
    except (KeyError, TypeError, ValueError, OverflowError) as err:
        raise ModelError(f"{path}: incomplete model file (missing or invalid {reason(err)})") from err
    if not 0 < dt < float("inf"):
        raise ModelError(f"{path}: model sample period dt = {dt!r} s, expected a positive finite number")
    k, h, n_u = len(OUTPUTS), config.hidden, len(arrays["u_mean"])
    expected = {
        "w_u": (k, h, n_u * len(config.input_delays)), "w_y": (k, h, config.output_delays),
        "b_1": (k, h), "w_2": (k, h), "b_2": (k,), "u_std": (n_u,), "y_mean": (k,), "y_std": (k,), "y_step": (k,),
    }
    for name, shape in expected.items():
        if arrays[name].shape != shape:
            raise ModelError(f"{path}: array {name} has shape {arrays[name].shape}, expected {shape}")
    for name, value in arrays.items():
        if not np.all(np.isfinite(value)):
            raise ModelError(f"{path}: array {name} holds non-finite values")
    for name in ("u_std", "y_std", "y_step"):  # scales the nets divide by
        if not np.all(arrays[name] > 0):
            raise ModelError(f"{path}: array {name} holds a scale <= 0 (index {int(np.argmin(arrays[name] > 0))}); scales are positive")
    return NarxModel(
        config=config, dt=dt, vehicle=str(header["vehicle"]), kind=str(header["kind"]),
        training=training, **arrays,
    )


def load_narx(path: str | Path, vehicle: str | None = None) -> NarxModel:
    """Load a NARX model file; ``vehicle`` (if given) must be the one it was trained for."""
    path = Path(path)
    header, contents = read_model_file(path, "narx", OUTPUTS, vehicle, ARRAY_NAMES.__contains__)
    return model_from_parts(path, header, contents)


# ---- the evaluation protocol (quad_modelling.core.models.base) ---------------------------
from quad_modelling.core.preprocess import trim_prediction  # noqa: E402  (shared with greybox and the evaluator)


class _ExpandingStream:
    """WindowStream of the 18 variables: NarxStream outputs, integrated and differentiated causally."""

    def __init__(self, nets: NarxStream, last: np.ndarray, dt: float) -> None:
        self.nets = nets
        self.last = np.array(last, dtype=float)
        self.dt = dt

    def push(self, command: np.ndarray) -> np.ndarray:
        """Command (4,) of the next sample -> its absolute prediction (18,), as :func:`expand_outputs`."""
        v = self.nets.push(command)
        previous = self.last[OUTPUT_COLUMNS]
        out = self.last.copy()
        out[OUTPUT_COLUMNS] = v
        out[DIFFERENTIATED_COLUMNS] = (v - previous) / self.dt
        out[INTEGRATED_COLUMNS] = self.last[INTEGRATED_COLUMNS] + 0.5 * (v + previous) * self.dt
        self.last = out
        return out.copy()


class NarxPredictor:
    """:class:`~quad_modelling.core.models.base.Predictor` and streaming predictor over a NARX model.

    predict_window: trimmed (protocol convention); start_window/push: absolute
    (:mod:`quad_modelling.core.models.streaming`), the same numbers before trimming.
    """

    def __init__(self, model: NarxModel, name: str = "narx", trim=None) -> None:
        self.model = model
        self.name = name
        self.trim = trim

    @property
    def sample_period_s(self) -> float:
        """The period [s] the model was trained at: the only one its windows may have (:func:`check_sample_rate`)."""
        return self.model.dt

    def predict_window(self, window: FlightLog, warm_samples: int) -> np.ndarray:
        """(N, 18) trimmed closed-loop prediction (VARIABLES order)."""
        return trim_prediction(window, self.model.predict_window(window, warm_samples), self.trim)

    def predict_horizons(self, segment: FlightLog, starts: np.ndarray, horizon: int) -> np.ndarray:
        """(S, horizon + 1, 18) absolute closed-loop predictions from each start (multi-step protocol), causally.

        ``[i, 0]`` is the state measured at s = ``starts[i]``: velocities, rates, positions and
        angles as measured (yaw unwrapped), accelerations as the backward difference of the
        measured velocities/rates, (v(s) − v(s−1))/dt (0 at s = 0). Rows h ≥ 1: the six
        outputs from :meth:`NarxModel.simulate_from_starts`, positions/angles integrated
        (trapezoid) from the measured ones at s, accelerations as backward differences, as
        :func:`expand_outputs` and the streaming form do. Nothing after row s of the
        measurements is read.
        """
        from quad_modelling.core.preprocess import measured_variables

        segment.require(("gyro_b",), "model narx (its outputs are velocities and gyro rates)")
        check_sample_rate(self.model, segment)
        return horizons_from_measured(self.model, np.asarray(measured_variables(segment), dtype=float), segment.u,
                                      np.asarray(starts, dtype=int), horizon)

    def start_window(self, warm: FlightLog):
        """Warm rows (at least n_y) -> (their measurement (W, 18), stream predicting each later sample)."""
        from quad_modelling.core.preprocess import measured_variables

        warm.require(("gyro_b",), "model narx (its outputs are velocities and gyro rates)")
        if len(warm) > 1:
            check_sample_rate(self.model, warm)
        if len(warm) < self.model.config.output_delays:
            raise DataError(f"{warm.meta.source}: NARX needs {self.model.config.output_delays} warm-start samples, got {len(warm)}")
        measured = measured_variables(warm)
        nets = self.model.stream(warm.u, measured[:, OUTPUT_COLUMNS])
        return measured, _ExpandingStream(nets, measured[-1], self.model.dt)
