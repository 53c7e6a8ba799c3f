"""``quad-modelling evaluate``: the thesis's evaluation protocol on flight files (DESIGN 7)."""

from __future__ import annotations

import argparse
import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

from quad_modelling.atomic import atomic_output, check_distinct_inputs
from quad_modelling.commands import check_command_output
from quad_modelling.core.evaluation.windowed import FlightEvaluation, evaluate_flight, merge_flights
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.registry import MODEL_FILE_KINDS, make_model, named_spec
from quad_modelling.core.preprocess import flight_warnings, resample_uniform
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle, vehicle_file
from quad_modelling.core.windows import MIN_SAMPLE_RATE_HZ, PRESETS, EvaluationConfig, check_window_rate
from quad_modelling.errors import ConfigError, DataError
from quad_modelling.fanout import add_fanout_arguments, check_fanout_options, iter_flights, tty_progress
from quad_modelling.io.loader import check_distinct_flights, check_topic_map_applies, load_flight_or_skip, load_flights
from quad_modelling.io.topic_maps import add_topic_map_argument, topic_map_file
from quad_modelling.io.reports.evaluation import (
    headline_scores,
    windows_text,
    write_report,
)

NAME = "evaluate"
HELP = "evaluate models with the thesis's windowed RMS/TIC protocol and the multi-step benchmark"
DESCRIPTION = """\
Evaluate models on flights (MCAP bags, thesis .mat logs, NanoBench .csv/.csv.gz) with the
thesis's protocol: drop take-off and landing, split into training and evaluation spans, cut
10 s windows that never cross a flight boundary, predict each from the first 0.2 s of
measurements, trim and smooth, and average RMS and TIC per variable over windows. The dummy
model (predicts zero) is always reported. Also the IDSIA multi-step table (MAE at 1, 10, 50
steps and SimErr, with the naive constant-state prediction and the ratio model/naive).

Spans (--train, --eval) are A:B in seconds from the flight start (thesis: 30:150 and
150:190, after dropping 30 s / 22 s), or A%:B% of the flying part. Short flights (NanoBench,
~40 s) need --preset short (drop 5 s / 5 s, train 0%:60%, eval 60%:100%) or explicit spans;
when no window fits, the error says so.

OUTDIR receives results.json (SI units), tables.md (thesis Tables 5-1/5-2, display units)
and fig_z/roll/pitch/yaw.png (input, acceleration, velocity/rate over one evaluation window).
results.json also stores the statistics the averages come from (window counts, sums of the
per-window RMS/TIC, multi-step sums), so `quad-modelling merge` combines evaluations exactly.

--jobs N (a local Dask cluster of N processes) or --scheduler ADDRESS (a running one) read
and score each flight on a worker; the numbers are the serial run's, bit for bit (docs/scale.md).

examples:
  quad-modelling evaluate bags/flight --vehicle linkquad -o flight_results
  quad-modelling evaluate $NANOBENCH/*.csv.gz --vehicle cf_identified.yaml --preset short --skip-bad -o nb_results
  quad-modelling evaluate a.mat b.mat --model greybox --model greybox:euler --train 30:120 --eval 120:190 -o out
  quad-modelling evaluate $NANOBENCH/*.csv.gz --preset short --skip-bad --jobs 2 -o nb_results
"""


def add_span_arguments(parser: argparse.ArgumentParser) -> None:
    """Inputs, vehicle and span options shared by evaluate and identify."""
    parser.add_argument("inputs", nargs="+", metavar="FLIGHT", help="MCAP bag directories, .mat logs or NanoBench .csv/.csv.gz files")
    parser.add_argument("--vehicle", metavar="NAME|FILE", help="vehicle config name or YAML (default: the one the first flight names)")
    parser.add_argument("--preset", default="thesis", choices=tuple(PRESETS), help="span defaults: thesis (220 s flights) or short (~40 s flights)")
    parser.add_argument("--drop", metavar="START:END", help="seconds dropped for take-off:landing (thesis 30:22)")
    parser.add_argument("--train", metavar="A:B", help="training span, seconds (30:150) or percent of the flying part (0%%:60%%)")
    parser.add_argument("--eval", metavar="C:D", help="evaluation span, like --train (thesis 150:190)")
    parser.add_argument("--window", type=float, default=EvaluationConfig.window_s, metavar="SECONDS",
                        help=f"window length (default {EvaluationConfig.window_s:g})")
    parser.add_argument("--warm", type=float, default=EvaluationConfig.warm_s, metavar="SECONDS",
                        help=f"warm start given to the models (default {EvaluationConfig.warm_s:g})")
    parser.add_argument("--skip-bad", action="store_true", help="report unreadable flights and continue with the rest")
    add_topic_map_argument(parser)
    add_fanout_arguments(parser)


def input_files(args: argparse.Namespace) -> list:
    """Every file the command reads: the flights, the vehicle file, model files (``narx:PATH``, ``hybrid:PATH``)."""
    specs = [named_spec(text)[1] for text in getattr(args, "model", None) or []]
    models = [spec.partition(":")[2] for spec in specs if spec.partition(":")[0] in MODEL_FILE_KINDS]
    return [*args.inputs, vehicle_file(args.vehicle), topic_map_file(getattr(args, "topic_map", None)), *models]


def config_from_args(args: argparse.Namespace, fits: bool = True, **extra) -> EvaluationConfig:
    """The evaluation configuration of the span options (core span grammar, :meth:`EvaluationConfig.from_options`);
    a warning line when its training and evaluation spans overlap (:func:`warn_span_overlap`) if the command ``fits``
    on the training span (identify; evaluate fits nothing: there the spans only label the scored windows)."""
    config = EvaluationConfig.from_options(args.preset, args.drop, train=args.train, eval=args.eval,
                                           window_s=args.window, warm_s=args.warm, **extra)
    if fits:
        warn_span_overlap(config)
    return config


def warn_span_overlap(config: EvaluationConfig) -> None:
    """One ``warning:`` line on stderr when ``config``'s training and evaluation spans share time."""
    overlap = config.span_overlap()
    if overlap:
        print(f"warning: {overlap}", file=sys.stderr)


def warn_flight_span_overlap(config: EvaluationConfig, flights: list[FlightLog]) -> None:
    """One ``warning:`` line when spans of mixed kinds (``--train 10:30`` with the preset's ``60%:100%``) share time on
    a flight (:meth:`~quad_modelling.core.windows.EvaluationConfig.flight_span_overlap`): the first such flight, and
    how many more."""
    overlaps = [text for text in map(config.flight_span_overlap, flights) if text]
    if overlaps:
        more = f" (and on {len(overlaps) - 1} more flight(s))" if len(overlaps) > 1 else ""
        print(f"warning: {overlaps[0]}{more}", file=sys.stderr)


def print_flight_warnings(flights: list[FlightLog]) -> None:
    """One ``warning:`` line on stderr per warning the reader recorded about each flight (a marked gap, whose windows
    are left out; clipped commands; a cut tail; a damaged file), and per logging hole the resampling to one period marks
    (:func:`~quad_modelling.core.preprocess.resample_uniform`, as every verb that scores or fits reads the flight; a
    flight too slow to score is left as read: the rate's refusal follows)."""
    for log in flights:
        uniform = resample_uniform(log) if log.sample_rate >= MIN_SAMPLE_RATE_HZ else log
        for message in flight_warnings(uniform):
            print(f"warning: {message}", file=sys.stderr)


def check_one_vehicle(flights: list[FlightLog], verb: str) -> None:
    """ConfigError (one line, naming a flight of each) when the flights are of more than one vehicle."""
    names = sorted({f.meta.vehicle for f in flights})
    if len(names) > 1:
        other = next(f for f in flights if f.meta.vehicle != flights[0].meta.vehicle)
        raise ConfigError(f"the flights are of different vehicles {names} ({flights[0].meta.source} of "
                          f"{flights[0].meta.vehicle!r}, {other.meta.source} of {other.meta.vehicle!r}); {verb} one vehicle at a time")


def warn_starting_values(vehicle, kind: str) -> None:
    """One warning line (stderr) when the physics base of a ``kind`` (physics, hybrid or direct) model holds constants
    no identification fitted: the model is built on them, and ``export`` refuses such a vehicle."""
    from quad_modelling.core.physics.parameters import PHYSICS_KEYS

    never = vehicle.never_identified(PHYSICS_KEYS)
    if never:
        what = "the physics model" if kind == "physics" else f"the {kind} model's physics base"
        print(f"warning: {vehicle.path}: {what} holds starting values, never identified "
              f"({', '.join(never)}); for the identified vehicle run `quad-modelling identify FLIGHTS --vehicle {vehicle.name} "
              f"-o FILE` and pass --vehicle FILE", file=sys.stderr)


def load_evaluation_flights(args: argparse.Namespace) -> tuple[list[FlightLog], VehicleConfig, list[str]]:
    """Read every input (one loader for all formats; on Dask with --jobs/--scheduler); returns flights, vehicle
    config and skipped-file messages."""
    given = load_vehicle(args.vehicle) if args.vehicle else None  # once for every flight
    flights, skipped = load_flights(args.inputs, given, args.skip_bad, jobs=args.jobs, scheduler=args.scheduler,
                                    progress=tty_progress(f"{getattr(args, 'verb', 'read')}: read", len(args.inputs)),
                                    topic_map=getattr(args, "topic_map", None))
    for message in skipped:
        print(f"skipped: {message}", file=sys.stderr)
    if not flights:
        raise ConfigError("no readable flight among the inputs")
    print_flight_warnings(flights)
    check_one_vehicle(flights, getattr(args, "verb", "evaluate"))
    check_distinct_flights([(f.meta.source, f.fingerprint()) for f in flights])
    vehicle = given or load_vehicle(flights[0].meta.vehicle)
    if vehicle.name != flights[0].meta.vehicle:
        raise ConfigError(f"--vehicle {args.vehicle} describes {vehicle.name!r}, the flights are of {flights[0].meta.vehicle!r}")
    return flights, vehicle, skipped


@dataclass
class FlightOutcome:
    """What one flight's evaluation task returns to the driver (small: statistics, no flight data)."""

    path: str
    evaluation: FlightEvaluation | None  # None: skipped (--skip-bad)
    skipped: str | None
    vehicle: str | None
    warnings: list[str]


def build_model(text: str, vehicle: VehicleConfig):
    """The predictor of one ``--model`` text (:func:`named_spec`), named as given."""
    name, spec = named_spec(text)
    model = make_model(spec, vehicle)
    if name:
        model.name = name
    return model


def model_file_digests(specs: list[str], models: list) -> dict[str, str]:
    """SHA-256 of the model file of every file-backed spec (``narx:PATH``, :data:`MODEL_FILE_KINDS`; ``NAME=`` allowed), by
    the model's name (the files were read to build ``models``)."""
    plain = [named_spec(text)[1] for text in specs]
    return {model.name: hashlib.sha256(Path(spec.partition(":")[2]).read_bytes()).hexdigest()
            for spec, model in zip(plain, models) if spec.partition(":")[0] in MODEL_FILE_KINDS}


def evaluate_flight_file(path: str, vehicle: VehicleConfig | None, specs: list[str], config: EvaluationConfig,
                         multistep: bool, skip_bad: bool, examples_from: str | None = None, topic_map: str | None = None) -> FlightOutcome:
    """The per-flight task of ``evaluate`` (run here or on a Dask worker): read the flight, build the models for
    its vehicle (``vehicle``, else the one the flight names) and return its statistics
    (:func:`~quad_modelling.core.evaluation.windowed.evaluate_flight`). Only the flight ``examples_from`` returns
    its example windows for the figures (0.6 MB per span; the statistics are about 0.1 MB), so a fleet's results
    cross the network small."""
    loaded = load_flight_or_skip(path, vehicle, skip_bad, topic_map)
    if loaded.log is None:
        return FlightOutcome(path, None, loaded.skipped, None, [])
    if skip_bad:  # a flight too slow for any window is a bad file like an unreadable one (else evaluate_flight refuses it)
        try:
            check_window_rate(loaded.log)
        except DataError as err:
            return FlightOutcome(path, None, str(err), None, [])
    flight_vehicle = vehicle or load_vehicle(loaded.log.meta.vehicle)
    models = [build_model(text, flight_vehicle) for text in specs]
    evaluation = evaluate_flight(loaded.log, models, flight_vehicle, config, multistep, examples=path == examples_from)
    evaluation.statistics.model_files = model_file_digests(specs, models)
    evaluation.statistics.model_specs = {name: spec for name, spec in map(named_spec, specs) if name} or None
    # the uniform log's warnings: the reader's, and a logging hole resampling marked as a gap (core.preprocess.resample_uniform)
    return FlightOutcome(path, evaluation, None, flight_vehicle.name, flight_warnings(resample_uniform(loaded.log)))


def _evaluations(outcomes, skipped: list[str], vehicles: list[str], first_in_span: dict[str, str]):
    """The flights' evaluations of the outcomes, in order; skipped files and gap warnings printed on the way;
    ``first_in_span``: span name -> the first flight with a window in it (filled on the way). A flight given twice
    (the same recorded numbers) is refused as soon as its second copy's result arrives, not after every flight. The
    flights without a window are said after the last one, and only when another flight has one (else the merge's
    one-line error says it: ``no_window_error``)."""
    fingerprints: list[tuple[str, str]] = []
    windowless: list[str] = []
    for outcome in outcomes:
        for message in outcome.warnings:
            print(f"warning: {message}", file=sys.stderr)
        if outcome.evaluation is None:
            print(f"skipped: {outcome.skipped}", file=sys.stderr)
            skipped.append(outcome.skipped)
            continue
        if vehicles and outcome.vehicle != vehicles[0]:
            raise ConfigError(f"the flights are of different vehicles {sorted({vehicles[0], outcome.vehicle})} "
                              f"({outcome.path} is of {outcome.vehicle!r}); evaluate one vehicle at a time")
        vehicles.append(outcome.vehicle)
        fingerprints.append((outcome.evaluation.flight["source"], outcome.evaluation.flight["fingerprint"]))
        check_distinct_flights(fingerprints)  # before anything is written
        windowed = outcome.evaluation.statistics.windowed
        for span, sums in windowed[next(iter(windowed))].items():
            if sums.windows:
                first_in_span.setdefault(span, outcome.path)
        if not outcome.evaluation.statistics.windows:  # counted among the flights, scored nowhere: said below
            windowless.append(outcome.path)
        yield outcome.evaluation
    if not vehicles:
        raise ConfigError("no readable flight among the inputs")
    for path in windowless if first_in_span else []:
        print(f"warning: {path}: no window in either span (too short, or every window touches the ground or a gap): not in "
              "the window scores", file=sys.stderr)


def example_windows(result, first_in_span: dict[str, str], task: tuple, topic_map: str | None = None) -> list:
    """The figures' windows: the first window of each span in flight order. The first flight sent its own; a span
    it has no window in takes the first flight that has, evaluated again here (once per such span)."""
    have = {example.span: example for example in result.examples}
    for span in [s.name for s in result.config.spans()]:
        if span not in have and span in first_in_span:
            path = first_in_span[span]
            for example in evaluate_flight_file(path, *task, path, topic_map).evaluation.examples:
                have.setdefault(example.span, example)
    return [have[s.name] for s in result.config.spans() if s.name in have]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_span_arguments(parser)
    parser.add_argument("--model", action="append", metavar="SPEC",
                        help="model to evaluate, repeatable: greybox, greybox:euler, dummy, naive, narx:PATH ...; NAME=SPEC names it (two "
                             "files of one kind: a=narx:a.npz, b=narx:b.npz) (default greybox)")
    parser.add_argument("--horizons", default="1,10,50", metavar="H,H,...", help="multi-step horizons in samples (default 1,10,50; SimErr sums 1..50)")
    parser.add_argument("--no-multistep", action="store_true", help="skip the multi-step table")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="new output directory")
    parser.add_argument("--force", action="store_true", help="overwrite an existing OUTDIR")


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    check_command_output(output, args.force, inputs=input_files(args), directory=True, markers=("results.json",))
    check_distinct_inputs(args.inputs, "FLIGHT")
    check_topic_map_applies(args.topic_map, args.inputs)
    check_fanout_options(args.jobs, args.scheduler)
    try:
        horizons = tuple(int(h) for h in args.horizons.split(","))
    except ValueError as err:
        raise ConfigError(f"--horizons {args.horizons!r}: expected comma-separated step counts") from err
    config = config_from_args(args, fits=False, horizons=horizons)
    given = load_vehicle(args.vehicle) if args.vehicle else None  # once for every flight
    specs = list(dict.fromkeys((args.model or ["greybox"]) + ["dummy"]))
    paths = [str(p) for p in args.inputs]
    task = (given, specs, config, not args.no_multistep, args.skip_bad)
    outcomes = iter_flights(evaluate_flight_file, paths, *task, paths[0], args.topic_map,
                            jobs=args.jobs, scheduler=args.scheduler, progress=tty_progress("evaluate", len(paths)))
    skipped: list[str] = []
    vehicles: list[str] = []
    first_in_span: dict[str, str] = {}
    result = merge_flights(_evaluations(outcomes, skipped, vehicles, first_in_span), config)
    if "physics" in [named_spec(text)[1] for text in specs]:  # its constants are the vehicle's: starting values unless identified (train warns alike)
        warn_starting_values(given or load_vehicle(vehicles[0]), "physics")
    result.examples = example_windows(result, first_in_span, task, args.topic_map)
    result.flights.extend({"source": s, "skipped": True} for s in skipped)
    with atomic_output(output, args.force) as tmp:
        files = write_report(result, tmp, title=f"Evaluation of {', '.join(specs)} on vehicle {vehicles[0]}")
    data = result.to_json()
    print(f"{len(vehicles)} flight(s), {windows_text(data)} -> {output}/ ({', '.join(files)})")
    for line in headline_scores(data, result.statistics.models):
        print(line)
    for span in config.spans():  # the other span held windows (else: no_window_error)
        if not data["windows"]["dummy"].get(span.name):
            print(f"warning: span {span.name} {span.text()} holds no {config.window_s:g} s window of any flight after "
                  f"dropping {config.drop_start:g} s/{config.drop_end:g} s: nothing scored there", file=sys.stderr)
    horizons_note = (data.get("horizons") or {}).get("note") if not args.no_multistep else None
    if horizons_note:  # --horizons beyond every flight: the table is empty, said where it is read
        print(f"warning: no multi-step table: {horizons_note} (the longest of the horizons {args.horizons})", file=sys.stderr)
    return 1 if skipped else 0  # --skip-bad left a flight out: done, with less (as convert)
