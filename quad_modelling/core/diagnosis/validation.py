"""Known-answer validation of the gap diagnosis on simulated flights, run as a user runs it (DESIGN 8, point 4a).

For each seed s the truth simulator flies two training flights (seeds ``1000 + 10 s + k``) and one test flight
(``2000 + 10 s``, other manoeuvres) per *case*, and the diagnosis (:func:`~quad_modelling.core.diagnosis.diagnose.diagnose`)
is run on them exactly as ``quad-modelling diagnose --train ... --test ...`` runs it: by default
(``base_from="effects-on"``) the base model is identified on the same effect-on training flights the diagnosis
sees, as a user with only real flights must. ``base_from="effects-off"`` identifies it on the training seeds
flown with every effect off instead (the easier, earlier mode, kept for comparison). The cases and what is right:

* **single** -- one catalogue effect the simulator switches (:data:`~quad_modelling.core.effect_names.SWITCHED_EFFECTS`)
  on: right when it is ranked first and ``found`` (also reported: right by its signatures,
  :data:`~quad_modelling.core.effect_names.SIGNATURES` -- the battery's drain shows as trim drift -- and how often
  motor lag and input delay took each other's place on flights the diagnosis said cannot separate them);
* **null** -- no effect: right when nothing is found;
* **pair** -- two effects (``pairs``; only pairs of searched effects): right when both are found in the top 3;
* **all** -- every validated effect on at once: how many of them are found (target: 5 of 7);
* **disturbance** -- an out-of-catalogue disturbance (:data:`~quad_modelling.core.effect_names.DISTURBANCES`:
  wind, a CoM below the IMU, a bent arm): right when nothing is found; the run records where the gap lies
  (the diagnosis's ``where``: the variables, bands and regimes left unexplained).

Single-effect runs also carry the **sensor ceiling** (:mod:`~quad_modelling.core.diagnosis.ceiling`): the
shrink a perfect model, anchored as the diagnosis anchors, would reach on the same windows and variables,
computed from the simulator's noise-free IMU. The measured shrink should not exceed it by more than noise
(target: 2 points), and ``ceiling_fraction`` = shrink / ceiling is the share of the reachable shrink found.

Cases run in parallel on a local Dask cluster with ``jobs`` (:func:`~quad_modelling.fanout.map_flights`: one
task per (seed, case), each simulating its own flights); the results are the same, in the same order, as the
serial run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from quad_modelling.core.diagnosis.attribution import excited_windows
from quad_modelling.core.diagnosis.catalogue import CATALOGUE
from quad_modelling.core.diagnosis.ceiling import sensor_ceiling
from quad_modelling.core.diagnosis.diagnose import DIAGNOSIS_CONFIG, MOTOR_DYNAMICS_EFFECTS, diagnose
from quad_modelling.core.diagnosis.statistics import normalised_window_gap
from quad_modelling.core.effect_names import DISTURBANCES, SIGNATURES, SWITCHED_EFFECTS
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.identification.greybox_fit import BaseFit, identify_base
from quad_modelling.core.identification.window_batch import prepare_windows
from quad_modelling.core.sim.params import SimParams
from quad_modelling.core.variables import INDEX
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import ConfigError

DEFAULT_PAIRS: tuple[tuple[str, str], ...] = (("rotor_drag", "motor_imbalance"), ("battery", "ground_effect"), ("motor_lag", "rotor_drag"))

BASE_FROM = ("effects-on", "effects-off")
"""Where the validation's base model is identified (module docstring); ``effects-on`` is the user's way."""

VALIDATION_DURATION_S = 90.0
"""Simulated flight length [s]: 16 windows of 5 s per flight after take-off and landing."""

TRAIN_FLIGHTS = 2

COM_OFFSET_DEPTH_M = 0.04
"""Depth of the CoM below the IMU in the validation's ``com_offset`` case [m] (flown alone). The simulator's
LinkQuad default is 1 cm, because with rotor drag on a deeper CoM lengthens the drag's moment arm until the
3.5 rad/s attitude loop tips over (docs/simulator.md); flown alone 4 cm flies the script, and its lever-arm
accelerations are then large enough to be a case at all."""

ALL_EFFECTS_TARGET = 5
"""Effects of seven found with all of them on at once, base fitted the user's way (issue #17's target)."""

ALL_EFFECTS_OF = 7
"""The effects the all-on target is stated for: every candidate (:data:`ALL_EFFECTS_TARGET` of these)."""


def all_effects_needed(on: int) -> int:
    """Effects of the ``on`` switched on in the all-on case that must be found: :data:`ALL_EFFECTS_TARGET` of seven;
    of fewer (``--effects`` narrowed), as many as the target asks of seven but at most all of them."""
    return min(ALL_EFFECTS_TARGET, on)


def all_effects_target(on: int) -> str:
    """The all-on target stated against the ``on`` effects run: ">= 5 of 7 found" with all seven, else what applies
    to ``on`` (all of them, or 5 of 6) and that the issue's target is for all seven (validation.md once read ">= 5
    found: measured 3 found; met yes" with three candidates run)."""
    needed = all_effects_needed(on)
    if on == ALL_EFFECTS_OF:
        return f">= {needed} of {on} found"
    wanted = f"all {on} found" if needed == on else f">= {needed} of {on} found"
    return f"{wanted} ({on} effects run; the target >= {ALL_EFFECTS_TARGET} of {ALL_EFFECTS_OF} is for all {ALL_EFFECTS_OF})"


@dataclass(frozen=True)
class Case:
    """One validation case: its kind (module docstring), the simulator switches, the seed."""

    kind: str
    effects: tuple[str, ...]
    seed: int

    @property
    def label(self) -> str:
        return " + ".join(self.effects) or "none"


@dataclass(frozen=True)
class CaseSettings:
    """What every case task needs (small: sent to each worker)."""

    vehicle: str
    catalogue: tuple[str, ...]
    duration: float
    config: EvaluationConfig
    base_from: str
    sim_params: SimParams | None


def train_seeds(seed: int) -> list[int]:
    return [1000 + 10 * seed + k for k in range(TRAIN_FLIGHTS)]


def test_seeds(seed: int) -> list[int]:
    return [2000 + 10 * seed]


def simulated_flight(settings: CaseSettings, effects: tuple[str, ...], seed: int, noise_free: bool = False):
    """(log, the same log with the noise-free IMU or None) of one simulated flight (``com_offset`` alone at
    :data:`COM_OFFSET_DEPTH_M`)."""
    from quad_modelling.core.sim.params import ComOffsetParams, sim_params_for
    from quad_modelling.core.sim.simulate import run_simulation

    params = settings.sim_params
    if tuple(effects) == ("com_offset",):
        params = (params or sim_params_for(settings.vehicle)).replace(com_offset=ComOffsetParams(depth=COM_OFFSET_DEPTH_M))
    run = run_simulation(settings.vehicle, effects=effects, seed=seed, duration=settings.duration, params=params)
    if not noise_free:
        return run.log, None
    return run.log, noise_free_imu_log(run)


def noise_free_imu_log(run) -> FlightLog:
    """A simulated flight's log with the IMU channels replaced by the simulator's noise-free IMU: every sensor
    error (bias, its walk, the period averaging, the lever arm of an offset CoM) but the white noise."""
    return replace(run.log, acc_b=run.truth["imu_noise_free_acc_b"], gyro_b=run.truth["imu_noise_free_gyro_b"])


def run_case(case: Case, settings: CaseSettings) -> dict:
    """Simulate one case's flights, diagnose them, and score the answer (module docstring). A module-level
    function: a Dask task."""
    vehicle = load_vehicle(settings.vehicle)
    catalogue = [CATALOGUE[name] for name in settings.catalogue]
    clock = time.perf_counter()
    train = [simulated_flight(settings, case.effects, s)[0] for s in train_seeds(case.seed)]
    test, sensor = zip(*(simulated_flight(settings, case.effects, s, noise_free=case.kind == "single") for s in test_seeds(case.seed)))
    base = None
    if settings.base_from == "effects-off":
        null_train = [simulated_flight(settings, (), s)[0] for s in train_seeds(case.seed)]
        fit = identify_base(prepare_windows(null_train, vehicle, settings.config), vehicle)
        base = BaseFit(fit.model, fit.values, True, "identified on the training seeds flown with every effect off")
    simulated = time.perf_counter() - clock
    result = diagnose(train, list(test), vehicle, catalogue, settings.config, base=base)
    by_name = {o.effect.name: o for o in result.outcomes}
    ranking, found = result.ranking(), result.found
    out = {"kind": case.kind, "effects": list(case.effects), "seed": case.seed, "found": found, "ranking": ranking[:4],
           "verdicts": {o.effect.name: o.verdict for o in result.outcomes},
           "reasons": {o.effect.name: o.reason for o in result.outcomes[:4]},
           "top_shrinks": {o.effect.name: round(o.shrink, 4) for o in result.outcomes[:4]},
           "base": {"tau_m_s": result.base.fit.get("motor_time_constant_s") if result.base.fit else None,
                    "held": result.base.fit.get("held", []) if result.base.fit else []},
           "separability": result.separability.get("text", ""),
           "seconds": {"simulation": simulated, "diagnosis": time.perf_counter() - clock - simulated}}
    if case.kind == "single":
        outcome = by_name[case.effects[0]]
        out.update(_single(case, result, outcome, list(sensor), vehicle, settings.config))
    elif case.kind == "pair":
        out["top3"] = ranking[:3]
        out["right"] = all(e in ranking[:3] and e in found for e in case.effects)
        out["shrinks"] = {e: by_name[e].shrink for e in case.effects}
    elif case.kind == "all":
        out["found_of_on"] = sorted(set(found) & set(case.effects), key=case.effects.index)
        out["right"] = len(out["found_of_on"]) >= all_effects_needed(len(case.effects))
        out["false"] = sorted(set(found) - set(case.effects))
    else:  # null and disturbance: nothing may be found
        out["right"] = not found
        where = result.where
        out["where"] = {"variables": [(v["variable"], round(v["share"], 3)) for v in where.get("variables", [])[:3]],
                        "bands": [(b["band"], round(b["share"], 3)) for b in where.get("bands", [])[:2]]}
    return out


def _single(case: Case, result, outcome, sensor_flights, vehicle, config: EvaluationConfig) -> dict:
    """The score of a single-effect run: right, shrink, its sensor ceiling per run and variable."""
    test = result.test_batch
    cols = np.array([INDEX[v] for v in outcome.variables])
    scored = None
    if outcome.correction is not None:
        scored = excited_windows(test, outcome.correction, cols, result.scales,
                                 normalised_window_gap(test, result.base_test, cols, result.scales))
    ceiling = sensor_ceiling(test, prepare_windows(sensor_flights, vehicle, config), result.base_test, result.scales,
                             outcome.variables, scored)
    top = result.outcomes[0].effect.name
    name = case.effects[0]
    signature = SIGNATURES.get(name, (name,))
    twin = (name in MOTOR_DYNAMICS_EFFECTS and top in MOTOR_DYNAMICS_EFFECTS and bool(result.separability)
            and not result.separability["separable"])
    return {"effect": name, "top": top, "right": top == name and outcome.verdict == "found",
            "right_by_signature": top in signature and top in result.found,
            "inseparable_twin_first": twin and top != name and top in result.found,
            "shrink": outcome.shrink, "verdict": outcome.verdict, "reason": outcome.reason,
            "variables": list(outcome.variables), "params": outcome.to_json()["params"],
            "sensor_ceiling": ceiling["sensor_ceiling"], "ceiling_by_variable": ceiling["by_variable"],
            "ceiling_fraction": outcome.shrink / ceiling["sensor_ceiling"] if ceiling["sensor_ceiling"] > 0 else None,
            "shrink_above_ceiling": outcome.shrink - ceiling["sensor_ceiling"],
            "shrink_by_variable": outcome.shrink_by_variable.get("held_out", {})}


def case_progress(say: Callable[[str], None], total: int) -> Callable[[int, Case, object], None]:
    """The ``progress(index, case, result)`` of the cases' fan-out (:func:`~quad_modelling.fanout.map_flights`): one
    line per case done, ``case k/N done: seed S: KIND LABEL``, through ``say``."""
    finished = [0]

    def progress(_index: int, case: Case, _result=None) -> None:
        finished[0] += 1
        say(f"case {finished[0]}/{total} done: seed {case.seed}: {case.kind} {case.label}")

    return progress


def validation_cases(effects: Sequence[str], seeds: Sequence[int], pairs: Sequence[tuple[str, str]], all_effects: bool,
                     disturbances: Sequence[str], null: bool = True) -> list[Case]:
    """Every (seed, case) in run order: singles, null, pairs, all, disturbances per seed."""
    cases = []
    for seed in seeds:
        cases += [Case("single", (e,), seed) for e in effects]
        cases += [Case("null", (), seed)] if null else []
        cases += [Case("pair", tuple(p), seed) for p in pairs]
        cases += [Case("all", tuple(effects), seed)] if all_effects and len(effects) > 1 else []
        cases += [Case("disturbance", (d,), seed) for d in disturbances]
    return cases


def check_pairs(pairs: Sequence[tuple[str, ...]], searched: Sequence[str]) -> list[tuple[str, str]]:
    """The pairs, each of two different switched effects both searched (ConfigError naming the first that is not)."""
    out = []
    for pair in pairs:
        if len(pair) != 2 or pair[0] == pair[1]:
            raise ConfigError(f"--pairs {'+'.join(pair)!r}: a pair is two different effects, EFFECT+EFFECT")
        for name in pair:
            if name not in SWITCHED_EFFECTS:
                raise ConfigError(f"--pairs {'+'.join(pair)}: {name!r} is no effect the simulator switches ({', '.join(SWITCHED_EFFECTS)})")
            if name not in searched:
                raise ConfigError(f"--pairs {'+'.join(pair)}: {name!r} is not among the searched --effects, so the pair cannot be found")
        out.append((pair[0], pair[1]))
    return out


def validate(
    vehicle: str = "linkquad",
    effects: Sequence[str] = SWITCHED_EFFECTS,
    seeds: Sequence[int] = (0, 1, 2),
    pairs: Sequence[tuple[str, str]] | None = None,
    catalogue: Sequence[str] | None = None,
    duration: float = VALIDATION_DURATION_S,
    config: EvaluationConfig = DIAGNOSIS_CONFIG,
    progress: Callable[[str], None] | None = None,
    sim_params: SimParams | None = None,
    base_from: str = "effects-on",
    all_effects: bool = True,
    disturbances: Sequence[str] = DISTURBANCES,
    null: bool = True,
    jobs: int | None = None,
) -> dict:
    """The validation.json document (module docstring).

    ``effects``: the switched effects validated alone (and together in the *all* case); ``catalogue``: the
    effects the diagnosis searches (default the whole catalogue); ``pairs``: None for :data:`DEFAULT_PAIRS`
    restricted to searched effects; ``jobs``: Dask worker processes (None: serial, here).
    """
    from quad_modelling.fanout import map_flights

    if base_from not in BASE_FROM:
        raise ConfigError(f"--base-from {base_from!r}: expected one of {', '.join(BASE_FROM)}")
    searched = tuple(CATALOGUE) if catalogue is None else tuple(catalogue)
    unknown = [d for d in disturbances if d not in DISTURBANCES]
    if unknown:
        raise ConfigError(f"--disturbance {', '.join(unknown)}: known disturbances are {', '.join(DISTURBANCES)}")
    if pairs is None:
        pairs = [p for p in DEFAULT_PAIRS if all(e in searched and e in effects for e in p)]
    pairs = check_pairs(pairs, searched)
    settings = CaseSettings(vehicle, searched, duration, config, base_from, sim_params)
    cases = validation_cases(effects, seeds, pairs, all_effects, disturbances, null)
    say = progress or (lambda _m: None)
    say(f"{len(cases)} cases to simulate and diagnose, {jobs or 1} at a time")
    clock = time.perf_counter()
    results = map_flights(run_case, cases, settings, jobs=jobs,
                          progress=case_progress(say, len(cases)))
    return summarise(results, vehicle, seeds, duration, base_from, searched, time.perf_counter() - clock, jobs)


def summarise(results: list[dict], vehicle: str, seeds: Sequence[int], duration: float, base_from: str, searched: Sequence[str],
              seconds: float, jobs: int | None) -> dict:
    """The validation.json document from the case results, with the targets of issue #17 measured."""
    by_kind = {kind: [r for r in results if r["kind"] == kind] for kind in ("single", "null", "pair", "all", "disturbance")}
    singles = by_kind["single"]
    reachable = [r for r in singles if r["sensor_ceiling"] >= 0.2]
    over = [r for r in singles if r["shrink_above_ceiling"] > 0.02]
    return {
        "vehicle": vehicle,
        "seeds": list(seeds),
        "duration_s": duration,
        "base_from": base_from,
        "flights": {"train_seeds": {s: train_seeds(s) for s in seeds}, "test_seeds": {s: test_seeds(s) for s in seeds},
                    "base": ("identified on the same effect-on training flights the diagnosis sees (the user's way)"
                             if base_from == "effects-on" else "identified on the training seeds flown with every effect off")},
        "catalogue": list(searched),
        "runs": singles,
        "null": {"found": sorted({f for n in by_kind["null"] for f in n["found"]}), "runs": by_kind["null"]},
        "pairs": by_kind["pair"],
        "all": by_kind["all"],
        "disturbances": by_kind["disturbance"],
        "accuracy": _share([r["right"] for r in singles]),
        "pairs_accuracy": _share([p["right"] for p in by_kind["pair"]]),
        "shrink_by_effect": _by_effect(singles, "shrink"),
        "sensor_ceiling_by_effect": _by_effect(singles, "sensor_ceiling"),
        "ceiling_fraction_by_effect": _by_effect(singles, "ceiling_fraction"),
        "targets": {
            "single_right": {"target": 0.9, "value": _share([r["right"] for r in singles]), "runs": len(singles),
                             "by_signature": _share([r["right_by_signature"] for r in singles]),
                             "inseparable_twin_first": sum(r["inseparable_twin_first"] for r in singles)},
            "shrink_of_ceiling": {"target": 0.8, "runs": len(reachable),
                                  "met": sum(r["shrink"] >= 0.8 * r["sensor_ceiling"] for r in reachable),
                                  "min": min((r["ceiling_fraction"] for r in reachable), default=None)},
            "shrink_not_above_ceiling": {"target": "shrink <= ceiling + 2 points", "runs": len(singles), "above": len(over),
                                         "max_excess": max((r["shrink_above_ceiling"] for r in singles), default=None)},
            "pairs_both_top3": {"target": 0.9, "value": _share([p["right"] for p in by_kind["pair"]]), "runs": len(by_kind["pair"])},
            "null_clean": {"target": "nothing found", "runs": len(by_kind["null"]), "right": sum(r["right"] for r in by_kind["null"])},
            "disturbances_unexplained": {"target": "nothing found", "runs": len(by_kind["disturbance"]),
                                         "right": sum(r["right"] for r in by_kind["disturbance"])},
            "all_effects": {"target": "; ".join(all_effects_target(n) for n in sorted({len(r["effects"]) for r in by_kind["all"]}))
                            or all_effects_target(ALL_EFFECTS_OF), "runs": len(by_kind["all"]),
                            "found": [len(r["found_of_on"]) for r in by_kind["all"]], "of": [len(r["effects"]) for r in by_kind["all"]]},
            "seconds": {"target": 600, "value": seconds, "jobs": jobs},
        },
        "metrics": {
            "shrink": "held-out shrink of the effect's affected-variable gap (diagnosis definition, windows the effect excites), "
                      "base model without the effect -> with it",
            "sensor_ceiling": "1 - G_perfect/G_base on the same windows and variables: G_perfect the gap of a perfect model anchored as "
                              "the diagnosis anchors, from the simulator's noise-free IMU (core/diagnosis/ceiling.py)",
            "ceiling_fraction": "shrink / sensor_ceiling: the share of the reachable shrink the diagnosis finds",
        },
        "seconds": seconds,
    }


def _share(flags: list[bool]) -> float | None:
    return sum(flags) / len(flags) if flags else None


def _by_effect(runs: list[dict], key: str) -> dict:
    """{effect: {"min", "median", "max"}} of ``key`` over the runs (None values skipped)."""
    out = {}
    for name in dict.fromkeys(r["effect"] for r in runs):
        values = [r[key] for r in runs if r["effect"] == name and r.get(key) is not None]
        if values:
            out[name] = {"min": float(np.min(values)), "median": float(np.median(values)), "max": float(np.max(values))}
    return out
