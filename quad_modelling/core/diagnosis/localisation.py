"""Where the residual concentrates: per variable, per regime (quantile bins) and per frequency band."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import signal

from quad_modelling.core.diagnosis.statistics import window_rms
from quad_modelling.core.evaluation.metrics import root_mean_square
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import EVAL_VARIABLES, INDEX

REGIME_BINS = 4
"""Quantile bins per regime variable."""


FREQUENCY_BANDS_HZ = ((0.0, 0.2), (0.2, 1.0), (1.0, 3.0), (3.0, math.inf))
"""Bands of the residual power split [Hz]."""


# ----------------------------------------------------------------------------- where


REGIME_UNITS = {"speed": "m/s", "height": "m", "battery_voltage": "V", "tilt": "deg", "throttle": "fraction of input range",
                "yaw_rate": "deg/s", "time_in_window": "s"}


def regime_signals(batch: WindowBatch) -> dict[str, np.ndarray]:
    """(W, N) regime variables per sample: speed, height above ground, voltage, tilt, throttle, |yaw rate|, time since anchor."""
    phi, theta = batch.euler[:, :, 0], batch.euler[:, :, 1]
    tilt = np.degrees(np.arccos(np.clip(np.cos(phi) * np.cos(theta), -1.0, 1.0)))
    throttle = ((batch.u + batch.u_trim[:, None, :]).mean(axis=2) - batch.input_min) / batch.u_span
    out = {
        "speed": np.linalg.norm(batch.velocity_abs, axis=2),
        "height": batch.height,
        "tilt": tilt,
        "throttle": throttle,
        "yaw_rate": np.degrees(np.abs(batch.rates[:, :, 2])),
        "time_in_window": np.broadcast_to((np.arange(batch.samples) - (batch.warm - 1)) * batch.dt, batch.height.shape),
    }
    if batch.vbat is not None:
        out["battery_voltage"] = batch.vbat
    return out


def localise(batch: WindowBatch, predicted: np.ndarray, scales: np.ndarray, names: Sequence[str] = EVAL_VARIABLES) -> dict:
    """Where the residual concentrates: by regime (quantile bins), by frequency band, and the worst windows."""
    cols = np.array([INDEX[v] for v in names])
    resid = (batch.measured - predicted)[:, batch.warm :, :][:, :, cols]  # (W, M, k)
    norm = resid / scales[cols]
    regimes = {}
    for name, values in regime_signals(batch).items():
        x = np.asarray(values)[:, batch.warm :].ravel()
        edges = np.quantile(x, np.linspace(0.0, 1.0, REGIME_BINS + 1))
        if not np.all(np.isfinite(edges)) or edges[-1] - edges[0] <= 1e-12:
            regimes[name] = {"unit": REGIME_UNITS[name], "note": "constant over the held-out windows"}
            continue
        which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, REGIME_BINS - 1)
        flat = norm.reshape(-1, len(cols))
        per_var = {}
        normalised = []
        for b in range(REGIME_BINS):
            mask = which == b
            rms_b = root_mean_square(resid.reshape(-1, len(cols))[mask], axis=0) if mask.any() else np.full(len(cols), np.nan)
            for i, v in enumerate(names):
                per_var.setdefault(v, []).append(float(rms_b[i]))
            normalised.append(float(root_mean_square(flat[mask], axis=(0, 1))) if mask.any() else float("nan"))
        top, bottom = normalised[-1], normalised[0]
        regimes[name] = {
            "unit": REGIME_UNITS[name],
            "edges": [float(e) for e in edges],
            "rms": per_var,
            "normalised_rms": normalised,
            "ratio_top_to_bottom": float(top / bottom) if bottom > 0 else None,
        }
    bands = frequency_split(resid, 1.0 / batch.dt, names)
    gaps = (window_rms(batch, predicted, cols) / scales[cols]).mean(axis=1)
    order = np.argsort(gaps)[::-1]
    worst = [{"flight": batch.sources[i], "t_start_s": float(batch.t0[i]), "t_end_s": float(batch.t0[i] + batch.samples * batch.dt),
              "normalised_gap": float(gaps[i])} for i in order[:5]]
    return {"regimes": regimes, "frequency": bands, "worst_windows": worst, "window_gap": [float(g) for g in gaps]}


def frequency_split(resid: np.ndarray, rate: float, names: Sequence[str]) -> dict:
    """Fraction of each variable's residual power per band of :data:`FREQUENCY_BANDS_HZ` (Welch PSD per window, averaged)."""
    nperseg = min(256, resid.shape[1])
    f, pxx = signal.welch(resid, fs=rate, nperseg=nperseg, axis=1)
    pxx = pxx.mean(axis=0)  # (F, k)
    total = pxx.sum(axis=0)
    out = {}
    for i, v in enumerate(names):
        fractions = {}
        for lo, hi in FREQUENCY_BANDS_HZ:
            mask = (f >= lo) & (f < hi)
            label = f"{lo:g}-{hi:g} Hz" if math.isfinite(hi) else f">{lo:g} Hz"
            fractions[label] = float(np.sum(pxx[mask, i]) / total[i]) if total[i] > 0 else 0.0
        out[v] = fractions
    return out
