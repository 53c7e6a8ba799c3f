"""Known-answer validation of the gap diagnosis on simulated flights (DESIGN 8, point 4a).

For each catalogue effect the truth simulator can switch on
(:data:`~quad_modelling.core.effect_names.SWITCHED_EFFECTS`) and each seed:

* the *base* model is the greybox identified (:func:`~quad_modelling.core.identification.greybox_fit.identify_base`)
  on the training flights flown with every effect off (same seeds, same
  manoeuvres: the effects-off-consistent training data), so the only
  systematic gap left is the withheld effect;
* training flights (seeds ``1000 + 10 s + k``) and test flights (seed
  ``2000 + 10 s``, other manoeuvres) are flown with the effect on;
* the diagnosis ranks the catalogue; the run is *correct* when the top-ranked
  effect is the switched-on one and its verdict is ``found``.

The null case flies every flight with no effect: no effect may be found.
Pairs switch two effects on: both must be in the top 3 and found.

Two shrink numbers per run (:func:`attributable_gap`):

* ``shrink`` -- the literal target: the diagnosis's held-out shrink of the effect's affected-variable
  gap (:mod:`~quad_modelling.core.diagnosis.diagnose`, point 3). Its ceiling is below 1: the base model keeps a
  gap on flights with *no* effect (IMU noise through the derivative and the low-pass, commands logged
  slower than the stabiliser sends them, the noise of the warm-start linearisation point;
  bench/bench_diagnose_floor.py splits it);
* ``attributable_removed`` -- the share of the *effect-attributable* gap removed,
  :math:`(G_{on} - G_{after}) / (G_{on} - G_{off})` with G the base model's normalised gap on the
  effect's variables summed over all held-out windows, :math:`G_{off}` on the same test seed flown with
  every effect off (same manoeuvres; the closed loop flies them slightly differently, so this share can
  exceed 1). ``attributable_share`` = :math:`1 - G_{off}/G_{on}` is the literal shrink's ceiling on all
  windows. Only the validation can compute these: it needs the effects-off twin flight.

And the ceiling no model can pass (:func:`sensor_ceiling`):

* ``sensor_ceiling`` -- :math:`1 - G_{sensor}/G_{on}` on the windows and variables the shrink is scored on,
  :math:`G_{sensor}` the normalised gap between the measurement and the simulator's *true* IMU signals put
  through the same preprocessing (the IMU's noise and drift after the derivative and the low-pass). A
  prediction cannot follow noise it never sees, so even a model that predicted the true signals exactly
  would keep :math:`G_{sensor}`: the literal shrink of a run cannot (in expectation) exceed its sensor
  ceiling, and a run whose ceiling is below the 50 % target cannot meet it with any model. The truth is
  used to *measure* only; the diagnosis never sees it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from quad_modelling.core.diagnosis.attribution import excited_windows
from quad_modelling.core.diagnosis.catalogue import CATALOGUE, Effect
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG, diagnose
from quad_modelling.core.diagnosis.statistics import normalised_window_gap
from quad_modelling.core.effect_names import SWITCHED_EFFECTS
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.identification.base_model import predict_batch
from quad_modelling.core.identification.greybox_fit import BaseFit, identify_base
from quad_modelling.core.identification.window_batch import prepare_windows
from quad_modelling.core.sim.params import SimParams
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import DataError

DEFAULT_PAIRS: tuple[tuple[str, str], ...] = (("rotor_drag", "motor_imbalance"), ("battery", "ground_effect"), ("motor_lag", "rotor_drag"))

VALIDATION_DURATION_S = 90.0
"""Simulated flight length [s]: 16 windows of 5 s per flight after take-off and landing."""

TRAIN_FLIGHTS = 2


@dataclass
class FlightCache:
    """Simulated flights by (effects, seed), so every run reuses them (``params``: simulator parameters,
    None for the vehicle's)."""

    vehicle: str
    duration: float
    flights: dict
    params: SimParams | None = None

    def _logs(self, effects: tuple[str, ...], seed: int) -> tuple[FlightLog, FlightLog]:
        """(sensor log, the same log with the true IMU signals) of one flight, simulated once."""
        from quad_modelling.core.sim.simulate import run_simulation

        key = (tuple(sorted(effects)), int(seed))
        if key not in self.flights:
            run = run_simulation(self.vehicle, effects=effects, seed=seed, duration=self.duration, params=self.params)
            self.flights[key] = (run.log, imu_truth_log(run))
        return self.flights[key]

    def get(self, effects: tuple[str, ...], seed: int) -> FlightLog:
        return self._logs(effects, seed)[0]

    def imu_truth(self, effects: tuple[str, ...], seed: int) -> FlightLog:
        return self._logs(effects, seed)[1]


def imu_truth_log(run) -> FlightLog:
    """A simulated flight's log with the IMU channels replaced by the simulator's true signals (specific
    force and body rates at the IMU's sampling, no noise, bias or drift)."""
    return replace(run.log, acc_b=run.truth["specific_force_b"], gyro_b=run.truth["rates_b"])


def train_seeds(seed: int) -> list[int]:
    return [1000 + 10 * seed + k for k in range(TRAIN_FLIGHTS)]


def test_seeds(seed: int) -> list[int]:
    return [2000 + 10 * seed]


def attributable_gap(result, outcome, off_flights: Sequence[FlightLog], vehicle, config: EvaluationConfig) -> dict:
    """The effect-attributable gap of one single-effect run (module docstring): G_on, G_off, G_after on the
    effect's variables over all held-out windows, ``attributable_share`` and ``attributable_removed``."""
    cols = np.array([INDEX[v] for v in outcome.variables])
    test = result.test_batch
    g_on = float(normalised_window_gap(test, result.base_test, cols, result.scales).sum())
    after = result.base_test + outcome.correction if outcome.correction is not None else result.base_test
    g_after = float(normalised_window_gap(test, after, cols, result.scales).sum())
    off = prepare_windows(off_flights, vehicle, config)
    g_off_mean = float(normalised_window_gap(off, predict_batch(result.base.model, off), cols, result.scales).mean())
    g_off = g_off_mean * len(test)  # per-window mean scaled to the effect-on window count
    attributable = g_on - g_off
    return {
        "gap_on": g_on / len(test), "gap_off": g_off_mean, "gap_after": g_after / len(test),
        "shrink_all_windows": 1.0 - g_after / g_on if g_on > 0 else 0.0,
        "attributable_share": attributable / g_on if g_on > 0 else 0.0,
        "attributable_removed": (g_on - g_after) / attributable if attributable > 0 else None,
    }


def sensor_ceiling(result, outcome, truth_flights: Sequence[FlightLog], vehicle, config: EvaluationConfig) -> dict:
    """The sensor ceiling of one single-effect run (module docstring): ``gap_sensor`` (per scored window) and
    ``sensor_ceiling`` = 1 - G_sensor/G_on over the windows the run's shrink is scored on (the windows the fitted
    effect excites, :func:`~quad_modelling.core.diagnosis.attribution.excited_windows`; all held-out windows when it excites
    too few), on the effect's affected variables. ``truth_flights``: the test flights with the true IMU signals
    (:func:`imu_truth_log`)."""
    cols = np.array([INDEX[v] for v in outcome.variables])
    test = result.test_batch
    truth = prepare_windows(truth_flights, vehicle, config)
    if truth.measured.shape != test.measured.shape or not np.array_equal(truth.t0, test.t0):
        raise DataError(f"the true-IMU flights cut into other windows ({len(truth)}) than the test flights ({len(test)})")
    g_on = normalised_window_gap(test, result.base_test, cols, result.scales)
    g_sensor = normalised_window_gap(test, truth.measured, cols, result.scales)
    scored = np.ones(len(test), dtype=bool)
    if outcome.correction is not None:
        excited = excited_windows(test, outcome.correction, cols, result.scales, g_on)
        scored = excited if excited.any() else scored
    total = float(g_on[scored].sum())
    return {"gap_sensor": float(g_sensor[scored].mean()),
            "sensor_ceiling": 1.0 - float(g_sensor[scored].sum()) / total if total > 0 else 0.0}


def validate(
    vehicle: str = "linkquad",
    effects: Sequence[str] = SWITCHED_EFFECTS,
    seeds: Sequence[int] = (0, 1, 2),
    pairs: Sequence[tuple[str, str]] = DEFAULT_PAIRS,
    catalogue: Sequence[Effect] | None = None,
    duration: float = VALIDATION_DURATION_S,
    config: EvaluationConfig = DIAGNOSIS_CONFIG,
    progress: Callable[[str], None] | None = None,
    sim_params: SimParams | None = None,
) -> dict:
    """The validation.json document (module docstring). ``sim_params``: simulator parameters (e.g. another
    sensor model), None for the vehicle's."""
    say = progress or (lambda _m: None)
    config_vehicle = load_vehicle(vehicle)
    catalogue = list(CATALOGUE.values()) if catalogue is None else list(catalogue)
    cache = FlightCache(vehicle, duration, {}, sim_params)
    runs, nulls, pair_runs = [], [], []
    clock = time.perf_counter()
    for seed in seeds:
        null_train = [cache.get((), s) for s in train_seeds(seed)]
        base = identify_base(prepare_windows(null_train, config_vehicle, config), config_vehicle)
        base = BaseFit(base.model, base.values, True, "identified on the effects-off training flights")
        cases = [(e,) for e in effects] + [()] + [tuple(p) for p in pairs]
        for case in cases:
            say(f"seed {seed}: effects {', '.join(case) or 'none'}")
            train = [cache.get(case, s) for s in train_seeds(seed)]
            test = [cache.get(case, s) for s in test_seeds(seed)]
            result = diagnose(train, test, config_vehicle, catalogue, config, base=base)
            ranking = result.ranking()
            found = result.found
            by_name = {o.effect.name: o for o in result.outcomes}
            if len(case) == 1:
                outcome = by_name.get(case[0])
                off_test = [cache.get((), s) for s in test_seeds(seed)]
                truth_test = [cache.imu_truth(case, s) for s in test_seeds(seed)]
                runs.append({
                    **(attributable_gap(result, outcome, off_test, config_vehicle, config) if outcome is not None else {}),
                    **(sensor_ceiling(result, outcome, truth_test, config_vehicle, config) if outcome is not None else {}),
                    "effect": case[0], "seed": seed, "top": ranking[0], "correct": ranking[0] == case[0] and case[0] in found,
                    "shrink": outcome.shrink if outcome else None, "verdict": outcome.verdict if outcome else "not in catalogue",
                    "variables": list(outcome.variables) if outcome else [],
                    "variable_correction": {k: round(v, 3) for k, v in outcome.variable_correction.items()} if outcome else {},
                    "found": found, "ranking": ranking[:4], "params": outcome.to_json()["params"] if outcome else {},
                    "top_shrinks": {o.effect.name: round(o.shrink, 4) for o in result.outcomes[:4]},
                    "confounded_with": outcome.confounded_with if outcome else [],
                })
            elif not case:
                nulls.append({"seed": seed, "found": found, "ranking": ranking[:4],
                              "top_shrinks": {o.effect.name: round(o.shrink, 4) for o in result.outcomes[:4]}})
            else:
                top3 = ranking[:3]
                pair_runs.append({
                    "effects": list(case), "seed": seed, "top3": top3, "found": found,
                    "both_found_in_top3": all(e in top3 and e in found for e in case),
                    "shrinks": {e: by_name[e].shrink for e in case if e in by_name},
                })
    correct = sum(r["correct"] for r in runs)
    return {
        "vehicle": vehicle,
        "seeds": list(seeds),
        "duration_s": duration,
        "flights": {"train_seeds": {s: train_seeds(s) for s in seeds}, "test_seeds": {s: test_seeds(s) for s in seeds},
                    "base": "greybox identified on the training seeds flown with every effect off"},
        "catalogue": [e.name for e in catalogue],
        "runs": runs,
        "null": {"found": sorted({f for n in nulls for f in n["found"]}), "runs": nulls},
        "pairs": pair_runs,
        "accuracy": correct / len(runs) if runs else None,
        "pairs_accuracy": (sum(p["both_found_in_top3"] for p in pair_runs) / len(pair_runs)) if pair_runs else None,
        "min_shrink_of_correct": min((r["shrink"] for r in runs if r["correct"]), default=None),
        "shrink_by_effect": _by_effect(runs, "shrink"),
        "attributable_removed_by_effect": _by_effect(runs, "attributable_removed"),
        "attributable_share_by_effect": _by_effect(runs, "attributable_share"),
        "sensor_ceiling_by_effect": _by_effect(runs, "sensor_ceiling"),
        "metrics": {
            "shrink": "literal target: held-out shrink of the effect's affected-variable gap (diagnosis definition, windows the "
                      "effect excites), base model without the effect -> base model with it",
            "attributable_share": "1 - G_off/G_on: the share of the base model's held-out gap (all windows) that the effect-off "
                                  "twin flight does not have; the ceiling of the literal shrink",
            "attributable_removed": "(G_on - G_after) / (G_on - G_off): share of that effect-attributable gap the fitted effect removes",
            "sensor_ceiling": "1 - G_sensor/G_on on the scored windows and variables: G_sensor the gap between the measurement and the "
                              "true IMU signals (same preprocessing), which no model can remove; the literal shrink cannot exceed it",
        },
        "seconds": time.perf_counter() - clock,
    }


def _by_effect(runs: list[dict], key: str) -> dict:
    """{effect: {"min", "median", "max"}} of ``key`` over the runs (None values skipped)."""
    out = {}
    for name in dict.fromkeys(r["effect"] for r in runs):
        values = [r[key] for r in runs if r["effect"] == name and r.get(key) is not None]
        if values:
            out[name] = {"min": float(np.min(values)), "median": float(np.median(values)), "max": float(np.max(values))}
    return out
