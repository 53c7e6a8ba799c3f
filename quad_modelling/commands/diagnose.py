"""``quad-modelling diagnose``: sim-to-real gap diagnosis (DESIGN 8), and its known-answer validation."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from quad_modelling.atomic import atomic_output, check_distinct_inputs
from quad_modelling.commands import check_command_output, check_seed
from quad_modelling.commands.evaluate import check_one_vehicle, print_flight_warnings
from quad_modelling.core.diagnosis.catalogue import parse_effect_list
from quad_modelling.core.diagnosis.diagnose import (
    DIAGNOSIS_CONFIG,
    diagnose,
    narx_floor,
)
from quad_modelling.core.diagnosis.injection import injection_checks, parse_injection
from quad_modelling.core.diagnosis.physics_base import CANDIDATES, IN_BASE, SWITCHED_BASE
from quad_modelling.core.physics.effects import switched_off
from quad_modelling.core.diagnosis.physics_validation import PHYSICS_VALIDATION_DURATION_S
from quad_modelling.core.diagnosis.validation import BASE_FROM, DEFAULT_PAIRS, VALIDATION_DURATION_S
from quad_modelling.core.effect_names import (
    CATALOGUE_EFFECTS,
    DISTURBANCES,
    SWITCHED_EFFECTS,
)
from quad_modelling.core.evaluation.multistep import check_protocol_starts, protocol_starts
from quad_modelling.core.preprocess import check_cutoff, resample_uniform
from quad_modelling.core.sim.pilot import check_duration
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle, vehicle_file
from quad_modelling.core.windows import EvaluationConfig, check_window_rate
from quad_modelling.errors import ConfigError, DataError
from quad_modelling.fanout import add_fanout_arguments, check_fanout_options, map_flights, tty_progress
from quad_modelling.io.loader import check_distinct_flights, check_topic_map_applies, load_flight_or_skip
from quad_modelling.io.topic_maps import add_topic_map_argument, topic_map_file
from quad_modelling.io.reports.diagnosis import verdict_text, write_diagnosis
from quad_modelling.io.reports.physics_diagnosis import verdict_lines, write_physics_diagnosis
from quad_modelling.io.reports.validation import validation_summary, write_validation

NAME = "diagnose"
HELP = "diagnose the sim-to-real gap: where the model diverges, which effect causes it, how far it shrinks"
DESCRIPTION = f"""\
Find which unmodelled effect explains the gap between the model and the flights. Default (physics
base): the physics model users predict with is identified on the --train flights with the candidate
effects off; the candidates ({", ".join(CANDIDATES)}; motor_lag and input_delay only where the
vehicle file switches them off, rotor_drag unless it switches it on) are terms of that model, chosen jointly
(forward: each refitted with the chosen ones, the best joins when its shrink of the held-out
multi-step error J has a bootstrap 5 % bound >= 1 % and its main component is resolved;
backward: one whose shrink of J on top of the rest has a 5 % bound under 1 % leaves). J is the mean over velocity and angular velocity of
the held-out SimErr (h = 1..50) relative to naive. The report gives each effect's components with
value, sigma and whether each is resolved, the command delay and each motor's command gain, the
constants with their at-bound flags. --write-vehicle V.yaml writes the final model; --inject
delay:MS | gain:M:K | swap:A:B | none checks the diagnosis on your own flights against a known
answer (exit 1 when a check fails).

--base greybox: the thesis's linear greybox on 5 s windows with the catalogue's hooks
({", ".join(CATALOGUE_EFFECTS)}): each effect added alone, verdicts found / weak / not supported,
a greedy ladder, where the gap lies (variables, regimes, frequency bands), --narx for the learnable
floor.

--validate flies simulated known-answer flights and diagnoses them as above (--base): with the physics
base the vehicle switches motor lag and input delay off so that all seven candidates are assessed, and
each case (each candidate alone, none, --pairs, all on, --disturbance: {", ".join(DISTURBANCES)}) is
scored against what the simulator switched on, with the perfect-model ceiling (the simulator's own
physics); --jobs N runs the cases on N local Dask workers.

--jobs N / --scheduler ADDRESS read and check the --train/--test flights on Dask workers;
the fits and the scoring run here (joint over flights; docs/scale.md).

examples:
  quad-modelling diagnose --train slow1.csv.gz slow2.csv.gz --test fast1.csv.gz -o diag
  quad-modelling diagnose --train a.mat --test b.mat --vehicle linkquad --effects rotor_drag,battery -o diag
  quad-modelling diagnose --train m1.csv.gz m2.csv.gz --test f1.csv.gz --inject delay:20 -o diag
  quad-modelling diagnose --validate --vehicle linkquad --seeds 0,1,2 --jobs 2 -o validation
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--train", nargs="+", metavar="FLIGHT", help="training flights (bags, .mat, NanoBench .csv.gz)")
    parser.add_argument("--test", nargs="+", metavar="FLIGHT", help="held-out flights")
    parser.add_argument("--vehicle", metavar="NAME|FILE", help="vehicle config name or YAML (default: the one the first flight names)")
    parser.add_argument("--effects", default="all", metavar="all|LIST", help="all (= default) or a comma list of candidates; "
                        "greybox base: also none (catalogue effects)")
    parser.add_argument("--no-identify", action="store_true", help="greybox base: use the vehicle's constants as the base model "
                        "instead of identifying them on --train")
    parser.add_argument("--narx", action="store_true", help="greybox base: also train a NARX model on --train as the learnable floor (slower)")
    parser.add_argument("--window", type=float, metavar="SECONDS", help=f"greybox base: window length (default {DIAGNOSIS_CONFIG.window_s:g})")
    parser.add_argument("--drop", metavar="START:END",
                        help=f"seconds dropped at take-off:landing of every flight (default: physics base "
                             f"{PHYSICS_CONFIG.drop_start:g}:{PHYSICS_CONFIG.drop_end:g}, greybox "
                             f"{DIAGNOSIS_CONFIG.drop_start:g}:{DIAGNOSIS_CONFIG.drop_end:g})")
    parser.add_argument("--smooth", type=float, metavar="HZ", help="greybox base: low-pass cutoff applied to measurement and "
                        f"prediction alike before scoring (default {DIAGNOSIS_CONFIG.smooth_cutoff_hz:g} Hz)")
    parser.add_argument("--skip-bad", action="store_true", help="report unreadable flights and continue with the rest")
    add_topic_map_argument(parser)
    add_fanout_arguments(parser)
    parser.add_argument("--base", choices=("physics", "greybox"), default="physics",
                        help="the model diagnosed (and validated with --validate): the identified physics model (default; its terms "
                             "are the candidates) or the thesis's linear greybox on 5 s windows (the catalogue's hooks)")
    parser.add_argument("--inject", metavar="SPEC", help="physics base: change every flight's commands by a known answer and "
                        "compare with the un-injected run: delay:MS, gain:MOTOR:K, swap:A:B or none (docs/diagnosis.md)")
    parser.add_argument("--write-vehicle", metavar="V.yaml", help="physics base: write the identified vehicle with the found "
                        "effects switched on")
    parser.add_argument("--validate", action="store_true", help="known-answer validation on simulated flights instead")
    parser.add_argument("--seeds", metavar="LIST", help="validation seeds (default 0,1,2)")
    parser.add_argument("--duration", type=float, metavar="SECONDS",
                        help=f"validation flight length (default: physics base {PHYSICS_VALIDATION_DURATION_S:g}, greybox "
                             f"{VALIDATION_DURATION_S:g})")
    parser.add_argument("--base-from", choices=BASE_FROM,
                        help="validation: identify the base on the effect-on training flights (default, as a user must) "
                             "or on the same seeds flown with every effect off")
    parser.add_argument("--pairs", metavar="LIST|none",
                        help="validation pairs, e.g. rotor_drag+motor_imbalance,battery+ground_effect (default: "
                             + ", ".join("+".join(p) for p in DEFAULT_PAIRS) + ", those searched)")
    parser.add_argument("--disturbance", metavar="LIST|none",
                        help=f"validation out-of-catalogue disturbances, right answer 'unexplained' (default all: {', '.join(DISTURBANCES)})")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="new output directory")
    parser.add_argument("--force", action="store_true", help="overwrite an existing OUTDIR")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr (one per phase of the run)")


PHYSICS_CONFIG = EvaluationConfig.preset("short", train="0%:100%", eval="0%:100%", horizons=(1, 10, 50))
"""The physics base's spans and scorer: the models table's (bench/bench_models.py), every flight whole after the drops."""


def _config(args: argparse.Namespace) -> EvaluationConfig:
    if not args.smooth > 0:
        raise ConfigError(f"--smooth {args.smooth:g}: the low-pass cutoff must be a positive frequency in Hz")
    if args.base == "physics":
        config = PHYSICS_CONFIG.with_drop(args.drop) if args.drop is not None else PHYSICS_CONFIG
        config.validate()
        return config
    drop = args.drop if args.drop is not None else f"{DIAGNOSIS_CONFIG.drop_start:g}:{DIAGNOSIS_CONFIG.drop_end:g}"
    config = replace(DIAGNOSIS_CONFIG.with_drop(drop), window_s=args.window, smooth_cutoff_hz=args.smooth)
    config.validate()
    return config


def _progress(args: argparse.Namespace, label: str = "diagnose"):
    """``say(message)``: one line ``LABEL: message`` on stderr per phase of the run (the base fit, each fitted rung, each
    step, the folds, each validation case done), on a terminal or not, flushed so that a log file or a pipe shows it
    as it happens (a diagnosis of 3 + 1 flights said nothing for 50 s, minutes with more); none with ``--quiet``."""
    if args.quiet:
        return lambda _message: None

    def say(message: str) -> None:
        print(f"{label}: {message}", file=sys.stderr, flush=True)

    return say


def _fast_enough(flights: list, skip_bad: bool, skipped: list[str]) -> list:
    """The flights fast enough for a window (:func:`~quad_modelling.core.windows.check_window_rate`: a 10 Hz ULog is
    refused for its rate, not for its spans); with ``skip_bad`` a slow one is left out and its reason added to
    ``skipped``, as an unreadable one."""
    kept = []
    for log in flights:
        try:
            check_window_rate(log)
        except DataError as err:
            if not skip_bad:
                raise
            skipped.append(str(err))
            continue
        kept.append(log)
    return kept


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    inputs = [*(args.train or []), *(args.test or []), vehicle_file(args.vehicle), topic_map_file(args.topic_map)]
    check_command_output(output, args.force, inputs=inputs, directory=True, markers=("diagnosis.json", "validation.json"))
    check_distinct_inputs(args.train or [], "--train")
    check_distinct_inputs(args.test or [], "--test")
    check_topic_map_applies(args.topic_map, [*(args.train or []), *(args.test or [])])
    physics = args.base == "physics" and not args.validate
    if not physics and (args.inject is not None or args.write_vehicle):
        raise ConfigError("--inject and --write-vehicle diagnose the physics base: drop --base greybox / --validate")
    if args.base == "physics":  # --validate --base physics scores as the physics base does: the same options
        _refuse_greybox_options(args)
    _refuse_other_mode_options(args)
    args.window = DIAGNOSIS_CONFIG.window_s if args.window is None else args.window  # the greybox base's defaults
    args.smooth = DIAGNOSIS_CONFIG.smooth_cutoff_hz if args.smooth is None else args.smooth
    injection = parse_injection(args.inject) if args.inject is not None else None
    if args.write_vehicle:
        written = Path(args.write_vehicle)
        if written.suffix not in (".yaml", ".yml"):
            raise ConfigError(f"--write-vehicle {written}: a vehicle file is YAML; name it V.yaml")
        if written.resolve() == output.resolve():
            raise ConfigError(f"--write-vehicle {written}: the same path as -o; name the vehicle file apart from the output directory")
        check_command_output(written, args.force, inputs=inputs, flag="--write-vehicle")
    config = _config(args)
    check_fanout_options(args.jobs, args.scheduler)
    effects = None if args.base == "physics" else parse_effect_list(args.effects)
    if args.validate:
        if args.scheduler is not None:
            raise ConfigError("--scheduler: --validate runs its cases on a local cluster (--jobs N) or here")
        return _run_validation(args, config, effects, output)
    if not args.train or not args.test:
        raise ConfigError("diagnose needs --train FLIGHT... and --test FLIGHT... (or --validate)")
    given = load_vehicle(args.vehicle) if args.vehicle else None  # once for every flight
    paths = [*args.train, *args.test]  # read in one fan-out (--jobs/--scheduler), split again below
    loaded = map_flights(load_flight_or_skip, [str(p) for p in paths], given, args.skip_bad, args.topic_map, jobs=args.jobs,
                         scheduler=args.scheduler, progress=None if args.quiet else tty_progress("diagnose: read", len(paths)))
    train = [one.log for one in loaded[: len(args.train)] if one.log is not None]
    test = [one.log for one in loaded[len(args.train):] if one.log is not None]
    skipped = [one.skipped for one in loaded if one.log is None]
    train, test = (_fast_enough(flights, args.skip_bad, skipped) for flights in (train, test))
    for message in skipped:
        print(f"skipped: {message}", file=sys.stderr)
    if not train or not test:
        raise ConfigError("no readable flight left in --train or --test")
    print_flight_warnings(train + test)
    check_one_vehicle(train + test, "diagnose")
    for flag, flights in (("--train", train), ("--test", test)):  # one flight in both is in-sample: warned (in_sample)
        check_distinct_flights([(f.meta.source, f.fingerprint()) for f in flights], flag)
    for log in train + test:
        check_cutoff(args.smooth, log, config.window_s)
    vehicle = given or load_vehicle(train[0].meta.vehicle)
    if physics:
        return _run_physics(args, train, test, vehicle, config, injection, output, skipped)
    warn_in_sample(train, test)  # as the flights are read, not after minutes of fitting
    learnable = (lambda: narx_floor(train, test, vehicle, config)) if args.narx else None
    result = diagnose(train, test, vehicle, effects, config, identify=not args.no_identify, learnable=learnable,
                      progress=_progress(args))
    data = result.to_json()
    data["skipped"] = skipped
    with atomic_output(output, args.force) as tmp:
        files = write_diagnosis(result, data, tmp, vehicle.name)
    print(verdict_text(data))
    print(f"-> {output}/ ({', '.join(files)})")
    return 1 if skipped else 0  # --skip-bad left a flight out: done, with less (as convert)


def in_sample(train, test) -> list[str]:
    """The held-out flights that are also training flights -- the same numbers (:meth:`FlightLog.fingerprint`) under
    any path or name -- as given to ``--test``, with the ``--train`` path when it is another (their held-out scores
    are in-sample)."""
    trained = {f.fingerprint(): f.meta.source for f in train}
    return sorted(f.meta.source + ("" if trained[f.fingerprint()] == f.meta.source else f" (= --train {trained[f.fingerprint()]})")
                  for f in test if f.fingerprint() in trained)


def warn_in_sample(train, test) -> None:
    """One warning line (stderr) when a flight is both a training and a held-out flight: its scores are in-sample."""
    both = in_sample(train, test)
    if both:
        print(f"warning: {', '.join(both)} in both --train and --test: the held-out scores of the diagnosis are in-sample",
              file=sys.stderr)


def _refuse_greybox_options(args: argparse.Namespace) -> None:
    """ConfigError (one line) naming the greybox base's options given to a physics-base diagnosis, which reads none of
    them (its spans and scorer are the models table's: :data:`PHYSICS_CONFIG`)."""
    given = [flag for flag, on in (("--window", args.window is not None), ("--smooth", args.smooth is not None),  # even at the default
                                   ("--no-identify", args.no_identify), ("--narx", args.narx)) if on]
    if given:
        raise ConfigError(f"{', '.join(given)}: option(s) of the greybox base (--base greybox); the physics base identifies its "
                          f"constants and scores every start over h = 1..50 (docs/diagnosis.md)")


VALIDATION_OPTIONS = (("--seeds", "seeds"), ("--duration", "duration"), ("--base-from", "base_from"), ("--pairs", "pairs"),
                      ("--disturbance", "disturbance"))
"""The options only ``--validate`` reads (each None unless given; their defaults are resolved there)."""

FLIGHT_OPTIONS = (("--train", "train"), ("--test", "test"), ("--skip-bad", "skip_bad"), ("--no-identify", "no_identify"),
                  ("--narx", "narx"), ("--topic-map", "topic_map"))
"""The options only a diagnosis of ``--train``/``--test`` flights reads (``--validate`` flies its own flights; its
greybox validation identifies the base and trains no NARX; ``--inject``/``--write-vehicle`` are refused apart)."""


def _refuse_other_mode_options(args: argparse.Namespace) -> None:
    """ConfigError (one line) naming the options of the other mode: ``--validate``'s given to a diagnosis of
    ``--train``/``--test`` flights, or theirs given to ``--validate``; neither reads the other's."""
    if args.validate:
        given = [flag for flag, name in FLIGHT_OPTIONS if getattr(args, name)]
        if given:
            raise ConfigError(f"{', '.join(given)}: option(s) of a diagnosis of --train/--test flights; --validate flies "
                              f"its own simulated flights and reads none of them (docs/diagnosis.md)")
        if args.duration is not None:  # before a cluster starts or a progress line is said (the greybox cases checked it)
            check_duration(args.duration)
        return
    given = [flag for flag, name in VALIDATION_OPTIONS if getattr(args, name) is not None]
    if given:
        raise ConfigError(f"{', '.join(given)}: option(s) of --validate (known answers on simulated flights); a diagnosis "
                          f"of --train/--test flights reads none of them (docs/diagnosis.md)")


def _physics_candidates(text: str) -> tuple[str, ...]:
    """``--effects`` for the physics base: all/default, none, or a comma list of its candidates (catalogue effects that
    are base constants are named as such)."""
    text = text.strip()
    if text in ("all", "default"):
        return CANDIDATES
    if text == "none":
        raise ConfigError("--effects none: the diagnosis needs at least one candidate")
    names = [n.strip() for n in text.split(",")]
    if not any(names):
        raise ConfigError(f"--effects {text!r}: names no candidate; give some of {', '.join(CANDIDATES)} (or all)")
    if not all(names):
        raise ConfigError(f"--effects {text}: an empty name in the list (a comma too many?); name each candidate once")
    for name in names:
        if name in IN_BASE:
            raise ConfigError(f"--effects {name}: {IN_BASE[name]}; the physics base's candidates are {', '.join(CANDIDATES)}")
        if name not in CANDIDATES:
            raise ConfigError(f"--effects {name}: unknown; the physics base's candidates are {', '.join(CANDIDATES)}")
    if len(set(names)) != len(names):
        raise ConfigError(f"--effects {text}: an effect is named twice")
    return tuple(c for c in CANDIDATES if c in names)  # the canonical order, whatever the typed one (ties break alike)


def _run_physics(args, train, test, vehicle, config, injection, output: Path, skipped: list[str]) -> int:
    """The physics-base diagnosis (:mod:`quad_modelling.core.diagnosis.physics_base`), with --inject and --write-vehicle."""
    import yaml

    from quad_modelling.core.diagnosis.physics_base import diagnose_physics, identified_document

    candidates = _physics_candidates(args.effects)
    if args.effects.strip() not in ("all", "default"):
        for name in candidates:
            if name in SWITCHED_BASE and not switched_off(vehicle.effects, name):
                raise ConfigError(f"{vehicle.path}: --effects {name}: {SWITCHED_BASE[name]}")
    if injection is not None:
        parse_injection(args.inject, len(vehicle.motors))  # the motor numbers against this vehicle
        if injection.kind == "gain" and "motor_imbalance" not in candidates:
            raise ConfigError(f"--inject {injection.spec}: its check reads the motor command gains, which the motor_imbalance "
                              f"candidate fits; add motor_imbalance to --effects")
        if injection.kind == "delay" and switched_off(vehicle.effects, "input_delay") and "input_delay" not in candidates:
            raise ConfigError(f"--inject {injection.spec}: {vehicle.path} switches input_delay off and it is not among "
                              "--effects, so the delay is held at 0, not searched; add input_delay to --effects")
        injected_train = [injection.apply(f) for f in train]
        injected_test = [injection.apply(f) for f in test]
    for flights in (train, injected_train if injection is not None else []):
        flying = [log.duration - config.drop_start - config.drop_end for log in flights]
        if flights and max(flying) < config.window_s:  # no training flight holds one identification window
            longest = flights[int(np.argmax(flying))]
            raise DataError(f"{longest.meta.source}: {max(max(flying), 0.0):.1f} s of flight left after --drop "
                            f"{config.drop_start:g}:{config.drop_end:g}" + (f" and --inject {injection.spec}" if flights is not train else "")
                            + f", the longest of the --train flights; the physics base identifies on {config.window_s:g} s windows")
    for flights in (test, injected_test if injection is not None else []):  # before a progress line: the scoring needs a start
        if flights:
            check_protocol_starts([resample_uniform(f) for f in flights], config, airborne=True)
    for log in train:  # one too short among longer ones added nothing without a word (and left a check skipped)
        if log.duration - config.drop_start - config.drop_end < config.window_s:
            print(f"warning: {log.meta.source}: {max(log.duration - config.drop_start - config.drop_end, 0.0):.1f} s of flight "
                  f"after --drop {config.drop_start:g}:{config.drop_end:g}, under one {config.window_s:g} s window: it adds "
                  "nothing to the fit (the others are fitted without it)", file=sys.stderr)
    for log in test:
        if next(protocol_starts([resample_uniform(log)], config, 1, airborne=True), None) is None:
            print(f"warning: {log.meta.source}: no airborne start of the protocol after --drop {config.drop_start:g}:"
                  f"{config.drop_end:g}: it adds nothing to the held-out scores", file=sys.stderr)
    warn_in_sample(train, test)  # as the flights are read, not after minutes of fitting
    say = _progress(args)
    say(f"{len(train)} training and {len(test)} held-out flight(s) read"
        + (f"; then again on the flights with --inject {injection.spec}" if injection is not None else ""))
    result = diagnose_physics(train, test, vehicle, config, candidates, progress=say)
    injected = None
    if injection is not None:
        injected = diagnose_physics(injected_train, injected_test, vehicle, config, candidates,
                                    progress=_progress(args, f"diagnose --inject {injection.spec}"))
    plain = result
    data = result.to_json()
    data["skipped"] = skipped
    if injected is not None:
        data = {**injected.to_json(), "un_injected": {k: data[k] for k in ("summary", "found", "held_out", "multistep", "motor_order")},
                "injection": injection_checks(injection, result.summary, injected.summary), "skipped": skipped}
        result = injected
    data["in_sample_flights"] = in_sample(train, test)  # saved with the scores, not only said on stderr
    document = None
    if args.write_vehicle:
        names = ", ".join(Path(f).name for f in args.train)
        swap = (plain.motor_order or {}).get("diagnosed_with_swap")
        document = identified_document(vehicle, plain.final, f"identified by quad-modelling diagnose on {names}", swap)
        VehicleConfig.from_dict(document, args.write_vehicle)  # what we write must load
        data["vehicle_written"] = {"path": args.write_vehicle, "from": "the un-injected run" if injected is not None else "this run",
                                   "evaluate": "quad-modelling evaluate TEST... --model physics --vehicle V.yaml --preset short --eval 0%:100%"}
    with atomic_output(output, args.force) as tmp:
        files = write_physics_diagnosis(data, tmp)
    if document is not None:
        with atomic_output(Path(args.write_vehicle), args.force) as tmp:
            tmp.write_text(yaml.safe_dump(document, sort_keys=False, allow_unicode=True))
    print("\n".join(verdict_lines(data)))
    print(f"-> {output}/ ({', '.join(files)})" + (f", {args.write_vehicle}" if document is not None else ""))
    return 1 if skipped or (injection is not None and data["injection"]["passed"] is False) else 0


def _run_validation(args, config, effects, output: Path) -> int:
    say = _progress(args, "diagnose --validate")
    try:
        result = _physics_validation(args, config, say) if args.base == "physics" else _greybox_validation(args, config, effects, say)
    except DataError as err:  # its advice named --train/--drop/--window, which --validate refuses
        default = PHYSICS_VALIDATION_DURATION_S if args.base == "physics" else VALIDATION_DURATION_S
        if args.duration is None or args.duration >= default:
            raise
        raise DataError(f"--validate --duration {args.duration:g}: the simulated flights leave the diagnosis nothing to work "
                        f"on ({str(err).split('; adjust')[0]}); give --duration {default:g} (the default) or more") from err
    with atomic_output(output, args.force) as tmp:
        write_validation(result, tmp)
    print(f"{validation_summary(result)} -> {output}/")
    return 0


def _greybox_validation(args, config, effects, say) -> dict:
    from quad_modelling.core.diagnosis.validation import validate

    names = [e.name for e in effects]
    switched = [e for e in SWITCHED_EFFECTS if e in names]  # the simulator can fly these with the effect on
    return validate(args.vehicle or "linkquad", switched, _seeds(args.seeds), pairs=_pairs(args.pairs), catalogue=names,
                    duration=VALIDATION_DURATION_S if args.duration is None else args.duration, config=config, progress=say,
                    base_from=args.base_from or "effects-on", disturbances=_disturbances(args.disturbance),
                    jobs=validation_jobs(args.jobs))


def _physics_validation(args, config, say) -> dict:
    from quad_modelling.core.diagnosis.physics_validation import validate_physics

    if args.base_from not in (None, "effects-on"):
        raise ConfigError("--base-from effects-off: the physics base's validation identifies the base on the effect-on "
                          "training flights, as a user must (--base-from is the greybox validation's)")
    candidates = list(_physics_candidates(args.effects))  # one --effects rule with the diagnosis of flights
    return validate_physics(args.vehicle or "linkquad", config, _seeds(args.seeds), candidates, _pairs(args.pairs),
                            _disturbances(args.disturbance), PHYSICS_VALIDATION_DURATION_S if args.duration is None else args.duration,
                            validation_jobs(args.jobs), say)


def _seeds(text: str | None) -> list[int]:
    """``--seeds``: comma-separated non-negative integers (ConfigError otherwise); not given, 0,1,2."""
    text = "0,1,2" if text is None else text
    _list_items(text, "--seeds")
    try:
        seeds = [int(s) for s in text.split(",")]
    except ValueError as err:
        raise ConfigError(f"--seeds {text!r}: expected comma-separated integers") from err
    if not seeds:
        raise ConfigError(f"--seeds {text!r}: expected comma-separated non-negative integers")
    for seed in seeds:
        check_seed(seed, "--seeds")
    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:  # the same flights flown and diagnosed twice (review)
        raise ConfigError(f"--seeds {text!r}: seed {', '.join(map(str, twice))} given more than once; give each seed once")
    return seeds


def _list_items(text: str, flag: str) -> list[str]:
    """The stripped items of a comma list ``text`` given to ``flag``; ConfigError in one line for a blank list or an empty
    item between commas (which the list once dropped silently, or read as the default)."""
    items = [item.strip() for item in text.split(",")]
    if not all(items):
        raise ConfigError(f"{flag} {text!r}: " + ("an empty list" if not any(items) else "an empty entry (a comma too many?)")
                          + "; name each item once")
    twice = sorted({item for item in items if items.count(item) > 1})
    if twice:
        raise ConfigError(f"{flag} {text!r}: {', '.join(twice)} given more than once; name each item once")
    return items


def validation_jobs(jobs: int | None) -> int | None:
    """``--jobs`` for ``--validate``: as given, else two local workers where the machine has two cores (the cases
    are independent simulations and fits; on one core, here), None meaning serial."""
    if jobs is not None:
        return jobs
    return 2 if (os.cpu_count() or 1) >= 2 else None


def _pairs(text: str | None) -> list[tuple[str, ...]] | None:
    """``--pairs``: None for the default pairs (not given or ``default``), [] for none, else the A+B items of the comma list."""
    text = "default" if text is None else text.strip()
    if text == "default":
        return None
    if text == "none":
        return []
    items = _list_items(text, "--pairs")
    pairs = [tuple(part.strip() for part in item.split("+")) for item in items]
    seen: dict[frozenset, str] = {}
    for item, pair in zip(items, pairs):
        if frozenset(pair) in seen:  # the same pair simulated and diagnosed twice
            raise ConfigError(f"--pairs {text!r}: {item} is {seen[frozenset(pair)]} in another order; name each pair once")
        seen[frozenset(pair)] = item
    return pairs


def _disturbances(text: str | None) -> tuple[str, ...]:
    """``--disturbance``: all (also when not given), none or a comma list of :data:`DISTURBANCES` (ConfigError naming an
    unknown one)."""
    text = "all" if text is None else text.strip()
    if text == "all":
        return DISTURBANCES
    if text == "none":
        return ()
    names = tuple(_list_items(text, "--disturbance"))
    unknown = [n for n in names if n not in DISTURBANCES]
    if unknown:
        raise ConfigError(f"--disturbance {', '.join(unknown)}: known disturbances are {', '.join(DISTURBANCES)} (or all, none)")
    return names
