"""Where the error after the best model lies: known residuals on a synthetic held-out batch give known
rankings, RMS, band shares and regime ratios."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from quad_modelling.core.diagnosis.localisation import (
    CONCENTRATION_MIN_RATIO,
    SCORED_VARIABLES,
    band_labels,
    band_power,
    frequency_split,
    rank_unexplained,
    residual_psd,
)
from quad_modelling.core.identification.window_batch import WindowBatch
from quad_modelling.core.variables import INDEX

DT = 0.01
WARM = 20
SCORED = 500  # 5 s after the warm start: whole periods of 0.5, 1 and 2 Hz


def _batch(measured: np.ndarray, speed: np.ndarray) -> WindowBatch:
    """A held-out batch whose only regime signals that vary are the speed (W, N) and the time in window:
    level attitude, constant height, throttle and yaw rate, no voltage."""
    windows, samples = measured.shape[:2]
    zeros3 = np.zeros((windows, samples, 3))
    velocity = zeros3.copy()
    velocity[:, :, 0] = speed
    return WindowBatch(
        sources=[f"flight_{w // 10}" for w in range(windows)], t0=np.arange(windows) * 5.0, dt=DT, warm=WARM,
        u=np.zeros((windows, samples, 4)), u_history=np.zeros((windows, 50, 4)), u_trim=np.full((windows, 4), 0.5), u_span=1.0,
        measured=measured, anchor_states=np.zeros((windows, 12)), velocity=velocity, velocity_abs=velocity,
        velocity_smooth=velocity, euler=zeros3, rates=zeros3, height=np.ones((windows, samples)), vbat=None, input_min=0.0)


def _scored_time() -> np.ndarray:
    """(N,) time of every sample, zero at the first scored sample."""
    return (np.arange(WARM + SCORED) - WARM) * DT


def test_the_variable_with_the_largest_unexplained_error_is_ranked_first_with_its_rms():
    """pitch_acc carries 0.2 sin(2 pi 2 t) rad/s2, acc_z 0.01 sin(2 pi 0.5 t) m/s2, the rest nothing."""
    t = _scored_time()
    measured = np.zeros((12, len(t), 18))
    measured[:, :, INDEX["pitch_acc"]] = 0.2 * np.sin(2 * np.pi * 2.0 * t)
    measured[:, :, INDEX["acc_z"]] = 0.01 * np.sin(2 * np.pi * 0.5 * t)
    scales = np.full(18, 0.1)
    where = rank_unexplained(_batch(measured, np.ones((12, len(t)))), np.zeros_like(measured), scales)
    assert where["scored_variables"] == list(SCORED_VARIABLES)
    first, second = where["variables"][:2]
    assert first["variable"] == "pitch_acc" and first["unit"] == "rad/s2"
    assert first["rms"] == pytest.approx(0.2 / np.sqrt(2), rel=1e-9)
    assert first["normalised"] == pytest.approx(2 / np.sqrt(2), rel=1e-9)
    assert first["share"] == pytest.approx(2.0 / 2.1, rel=1e-9)  # normalised 1.414 of 1.414 + 0.0707
    assert second["variable"] == "acc_z" and second["rms"] == pytest.approx(0.01 / np.sqrt(2), rel=1e-9)
    assert second["unit"] == "m/s2"
    assert [v["rms"] for v in where["variables"][2:]] == [0.0] * 4
    assert sum(v["share"] for v in where["variables"]) == pytest.approx(1.0)
    # the 2 Hz sinusoid is the power: band 1-3 Hz first, pitch_acc its contributor; the 0.5 Hz one next
    bands = where["bands"]
    assert bands[0]["band"] == "1-3 Hz" and bands[0]["share"] > 0.99
    assert bands[0]["variables"][0]["variable"] == "pitch_acc" and bands[0]["variables"][0]["share"] > 0.999
    assert bands[1]["band"] == "0.2-1 Hz" and bands[1]["variables"][0]["variable"] == "acc_z"
    assert sum(b["share"] for b in bands) == pytest.approx(1.0)
    # the amplitude does not depend on the (constant) speed: no regime concentrates it
    assert not any(r["concentrated"] for r in where["regimes"])


def test_only_the_given_variables_are_ranked():
    """A drifting velocity is left out of the default ranking and ranked first when asked for."""
    t = _scored_time()
    measured = np.zeros((8, len(t), 18))
    measured[:, :, INDEX["vel_x"]] = 5.0 * t  # open-loop drift
    measured[:, :, INDEX["roll_acc"]] = 0.05
    scales = np.full(18, 0.1)
    batch = _batch(measured, np.ones((8, len(t))))
    default = rank_unexplained(batch, np.zeros_like(measured), scales)
    assert [v["variable"] for v in default["variables"]][0] == "roll_acc"
    assert "vel_x" not in [v["variable"] for v in default["variables"]]
    asked = rank_unexplained(batch, np.zeros_like(measured), scales, names=("vel_x", "roll_acc"))
    assert [v["variable"] for v in asked["variables"]] == ["vel_x", "roll_acc"]
    assert asked["variables"][1]["rms"] == pytest.approx(0.05)


def test_a_residual_that_grows_with_speed_is_a_concentration_at_high_speed():
    """20 windows at speeds 0..3 m/s (constant in each); the residual amplitude is 1 + speed. The speed's
    quartiles hold 5 windows each, so the top/bottom ratio is the RMS amplitude of windows 15-19 over 0-4."""
    t = _scored_time()
    speeds = np.linspace(0.0, 3.0, 20)
    amplitude = 0.1 * (1.0 + speeds)
    measured = np.zeros((20, len(t), 18))
    measured[:, :, INDEX["acc_x"]] = amplitude[:, None] * np.sin(2 * np.pi * 1.0 * t)
    where = rank_unexplained(_batch(measured, np.repeat(speeds[:, None], len(t), axis=1)), np.zeros_like(measured),
                             np.full(18, 0.2))
    top = where["regimes"][0]
    expected = np.sqrt(np.mean(amplitude[15:] ** 2) / np.mean(amplitude[:5] ** 2))
    assert top["regime"] == "speed" and top["unit"] == "m/s"
    assert top["ratio_top_to_bottom"] == pytest.approx(expected, rel=1e-6) and expected > CONCENTRATION_MIN_RATIO
    assert top["side"] == "high" and top["concentrated"]
    assert top["quartile_edges"][0] == 0.0 and top["quartile_edges"][-1] == 3.0
    # constant regime signals cannot be cut and come last
    assert [r["regime"] for r in where["regimes"][-4:]] == ["height", "tilt", "throttle", "yaw_rate"]
    assert all(r["ratio"] is None and not r["concentrated"] for r in where["regimes"][-4:])
    # amplitude falling with speed: the same ratio, on the low side
    low = rank_unexplained(_batch(measured[::-1], np.repeat(speeds[:, None], len(t), axis=1)), np.zeros_like(measured),
                           np.full(18, 0.2))["regimes"][0]
    assert low["regime"] == "speed" and low["side"] == "low" and low["ratio"] == pytest.approx(expected, rel=1e-6)


def test_a_residual_independent_of_the_regime_is_not_called_a_concentration():
    """27 windows: residual = noise low-passed at 3 Hz, window gains lognormal (sigma 0.3), speed a slow
    random signal (0.2 Hz) unrelated to it. Chance alone gives ratios above 1 (here 1.06 for the speed,
    1.17 for the time in window), below the bound."""
    rng = np.random.default_rng(3)
    b, a = signal.butter(2, 3.0 / 50.0)
    bs, as_ = signal.butter(2, 0.2 / 50.0)
    t = _scored_time()
    measured = np.zeros((27, len(t), 18))
    noise = signal.filtfilt(b, a, rng.standard_normal((27, len(t), 6)), axis=1) * np.exp(0.3 * rng.standard_normal((27, 1, 1)))
    measured[:, :, [INDEX[v] for v in SCORED_VARIABLES]] = noise
    speed = 1.0 + signal.filtfilt(bs, as_, rng.standard_normal((27, len(t) + 200)), axis=1)[:, 100:-100]
    where = rank_unexplained(_batch(measured, speed), np.zeros_like(measured), np.full(18, noise.std()))
    speed_rank = next(r for r in where["regimes"] if r["regime"] == "speed")
    assert 1.0 < speed_rank["ratio"] < CONCENTRATION_MIN_RATIO
    assert not any(r["concentrated"] for r in where["regimes"])


def test_welch_power_keeps_the_offset_and_integrates_to_the_mean_square():
    """0.3 + 0.2 sin(2 pi 2 t): mean square 0.09 + 0.02. The constant is power in the lowest bands
    (2/3 in the 0 Hz bin, 1/3 leaked by the Hann window into the 0.39 Hz bin), the sinusoid in 1-3 Hz."""
    t = _scored_time()[WARM:]
    resid = np.zeros((4, len(t), 2))
    resid[:, :, 0] = 0.3 + 0.2 * np.sin(2 * np.pi * 2.0 * t)
    resid[:, :, 1] = 0.3
    f, pxx = residual_psd(resid, 1.0 / DT)
    power = band_power(f, pxx)
    assert power.sum(axis=0) == pytest.approx([0.11, 0.09], rel=0.01)
    assert band_labels() == ["0-0.2 Hz", "0.2-1 Hz", "1-3 Hz", ">3 Hz"]
    assert power[:, 1] == pytest.approx([0.06, 0.03, 0.0, 0.0], abs=1e-9)
    assert power[2, 0] == pytest.approx(0.02, rel=0.02)
    split = frequency_split(resid, 1.0 / DT, ("with_sine", "constant"))
    assert split["constant"] == pytest.approx({"0-0.2 Hz": 2 / 3, "0.2-1 Hz": 1 / 3, "1-3 Hz": 0.0, ">3 Hz": 0.0}, abs=1e-9)
    assert split["with_sine"]["1-3 Hz"] == pytest.approx(0.02 / 0.11, rel=0.02)
