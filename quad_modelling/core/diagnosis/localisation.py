"""Where the residual concentrates: per variable, per regime (quantile bins) and per frequency band.

:func:`localise` splits one prediction's held-out residual (the base model's, in the diagnosis);
:func:`rank_unexplained` ranks what the best model (base + found effects) leaves unexplained, on the
scored variables, by variable, regime and frequency band."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import signal

from quad_modelling.core.diagnosis.statistics import variable_scores, window_rms
from quad_modelling.core.diagnosis.verdicts import SCORED_VARIABLES
from quad_modelling.core.evaluation.metrics import root_mean_square
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import EVAL_VARIABLES, INDEX, SI_UNIT

REGIME_BINS = 4
"""Quantile bins per regime variable."""


FREQUENCY_BANDS_HZ = ((0.0, 0.2), (0.2, 1.0), (1.0, 3.0), (3.0, math.inf))
"""Bands of the residual power split [Hz]."""


WELCH_SEGMENT = 256
"""Samples per Welch segment (fewer when a window's scored part is shorter): 2.56 s at 100 Hz, a
resolution of 0.39 Hz, so a 5 s window gives three half-overlapping segments."""


CONCENTRATION_MIN_RATIO = 1.5
"""Smallest ratio of the normalised residual RMS in the top and the bottom quartile of a regime signal
(either way round) that the reports call a concentration. A residual that does not depend on the regime
shows ratios from chance alone: it varies from window to window and a slowly varying regime signal puts
whole windows into one quartile. Simulated (residual low-passed at 3 Hz, window gains lognormal with
sigma 0.3 / 0.5, regime signal low-passed at 0.2 Hz, 300 draws) the ratio's 99th percentile is
1.26 / 1.48 over 27 windows of 5 s (1.40 / 1.71 over 10 windows); the NanoBench speed split's 1.1-1.2x
throttle and speed ratios, once reported as concentrations, are within it. A test holds a
regime-independent residual below this bound."""


# ----------------------------------------------------------------------------- where


REGIME_UNITS = {"speed": "m/s", "height": "m", "battery_voltage": "V", "tilt": "deg", "throttle": "fraction",
                "yaw_rate": "deg/s", "time_in_window": "s"}
"""Unit of each regime signal of :func:`regime_signals`; the throttle is the mean command as a fraction of
the input range (0 at its minimum, 1 at its maximum)."""


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


def residual_psd(resid: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Welch PSD of a (W, M, k) residual along its samples, averaged over the W windows: frequencies (F,)
    [Hz] and the one-sided density (F, k) [unit^2/Hz]; ``rate`` the sample rate [Hz].

    Segments of :data:`WELCH_SEGMENT` samples, Hann window, half overlap; no detrending, so the density
    integrates to the residual's mean square (its RMS^2, offset included): a constant error of the
    linearisation point is power in the lowest bands, not lost.
    """
    nperseg = min(WELCH_SEGMENT, resid.shape[1])
    f, pxx = signal.welch(resid, fs=rate, nperseg=nperseg, detrend=False, axis=1)
    return f, pxx.mean(axis=0)


def band_labels() -> list[str]:
    """Labels of :data:`FREQUENCY_BANDS_HZ`: ``"1-3 Hz"``, the open last one ``">3 Hz"``."""
    return [f"{lo:g}-{hi:g} Hz" if math.isfinite(hi) else f">{lo:g} Hz" for lo, hi in FREQUENCY_BANDS_HZ]


def band_power(f: np.ndarray, pxx: np.ndarray) -> np.ndarray:
    """(B, k) power of a PSD ``pxx`` (F, k) in each band of :data:`FREQUENCY_BANDS_HZ` (bins f in [lo, hi))."""
    df = f[1] - f[0] if len(f) > 1 else 1.0
    return np.array([pxx[(f >= lo) & (f < hi)].sum(axis=0) * df for lo, hi in FREQUENCY_BANDS_HZ])


def frequency_split(resid: np.ndarray, rate: float, names: Sequence[str]) -> dict:
    """Fraction of each variable's residual power per band of :data:`FREQUENCY_BANDS_HZ`
    (:func:`residual_psd`): {variable: {band label: fraction}}."""
    power = band_power(*residual_psd(resid, rate))
    total = power.sum(axis=0)
    labels = band_labels()
    return {v: {label: float(power[b, i] / total[i]) if total[i] > 0 else 0.0 for b, label in enumerate(labels)}
            for i, v in enumerate(names)}


# ----------------------------------------------------------------------------- after the best model


def scaled_residual(batch: WindowBatch, predicted: np.ndarray, scales: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """(W, N - warm, k) held-out residual (measured - predicted) of ``names`` after the warm start, each
    variable divided by its scale s_v (dimensionless)."""
    cols = np.array([INDEX[v] for v in names])
    return (batch.measured - predicted)[:, batch.warm :][:, :, cols] / scales[cols]


def rank_unexplained(batch: WindowBatch, best: np.ndarray, scales: np.ndarray, names: Sequence[str] = SCORED_VARIABLES) -> dict:
    """Where the held-out error the best model leaves lies: variables, regimes and frequency bands ranked.

    ``best`` (W, N, 18) is the best model's prediction of the held-out ``batch`` (the base model plus the
    found effects; the base prediction when nothing is found), ``scales`` (18,) the per-variable scales
    s_v (the base model's training residual RMS). Only ``names`` are ranked, by default
    :data:`~quad_modelling.core.diagnosis.verdicts.SCORED_VARIABLES`: the effects are scored on the accelerations
    and angular accelerations, which the forces and torques drive without integration, because the open-loop
    velocities and rates drift from the anchor on (NanoBench: 35 m/s RMS on vel_x over 5 s) and that drift
    would lead any ranking that included them.

    * ``variables``: per variable the mean over windows of its RMS ``rms`` [SI ``unit``] (as the held-out
      gap), ``normalised`` = rms / s_v and ``share`` = normalised / the sum over ``names``; descending.
    * ``regimes``: :func:`localise`'s quartiles of each regime signal on the residual after ``best``, with
      ``ratio`` = max(top/bottom, bottom/top) of the normalised RMS, ``side`` the end (high/low) where it is
      larger and ``concentrated`` = ratio >= :data:`CONCENTRATION_MIN_RATIO`; descending by ratio, regimes
      that could not be cut (constant signal) last.
    * ``bands``: share of the summed normalised residual power per band of :data:`FREQUENCY_BANDS_HZ`
      (:func:`residual_psd`) with the variables contributing most to the band (their share of it);
      descending.
    """
    names = tuple(names)
    cols = np.array([INDEX[v] for v in names])
    scores = variable_scores(batch, best, names)
    rms = np.array([scores[v]["rms"] for v in names])
    normalised = rms / scales[cols]
    total = float(normalised.sum())
    variables = [{"variable": v, "rms": float(rms[i]), "unit": SI_UNIT[v], "normalised": float(normalised[i]),
                  "share": float(normalised[i] / total) if total > 0 else 0.0} for i, v in enumerate(names)]
    variables.sort(key=lambda row: row["normalised"], reverse=True)
    regimes = [_regime_rank(name, r) for name, r in localise(batch, best, scales, names)["regimes"].items()]
    regimes.sort(key=lambda r: -1.0 if r["ratio"] is None else r["ratio"], reverse=True)
    power = band_power(*residual_psd(scaled_residual(batch, best, scales, names), 1.0 / batch.dt))  # (B, k)
    all_power = float(power.sum())
    bands = []
    for label, row in zip(band_labels(), power):
        in_band = float(row.sum())
        order = np.argsort(row)[::-1][:3]
        bands.append({"band": label, "share": in_band / all_power if all_power > 0 else 0.0,
                      "variables": [{"variable": names[i], "share": float(row[i] / in_band) if in_band > 0 else 0.0} for i in order]})
    bands.sort(key=lambda b: b["share"], reverse=True)
    return {"scored_variables": list(names), "variables": variables, "regimes": regimes, "bands": bands,
            "concentration_min_ratio": CONCENTRATION_MIN_RATIO}


def _regime_rank(name: str, regime: dict) -> dict:
    """One entry of :func:`rank_unexplained`'s regimes from :func:`localise`'s quartiles of ``name``."""
    unit = regime["unit"]
    ratio_up = regime.get("ratio_top_to_bottom")
    if "edges" not in regime or ratio_up is None or not math.isfinite(ratio_up) or ratio_up <= 0:
        return {"regime": name, "unit": unit, "ratio_top_to_bottom": None, "ratio": None, "side": None, "concentrated": False,
                "note": regime.get("note", "no residual in the lowest quartile")}
    side, ratio = ("high", ratio_up) if ratio_up >= 1.0 else ("low", 1.0 / ratio_up)
    return {"regime": name, "unit": unit, "quartile_edges": regime["edges"], "normalised_rms": regime["normalised_rms"],
            "ratio_top_to_bottom": ratio_up, "ratio": ratio, "side": side, "concentrated": ratio >= CONCENTRATION_MIN_RATIO}
