"""``quad-modelling train``: train the NARX (or hybrid physics + residual net) model on flights."""

from __future__ import annotations

import argparse
import sys
import time

from quad_modelling.commands import check_command_output, check_seed
from quad_modelling.core.models.hybrid import COMMAND_FILTERS_S
from quad_modelling.core.models.narx import MAX_DELAYS, MAX_HIDDEN
from quad_modelling.core.models.narx import OUTPUTS as NARX_OUTPUTS
from quad_modelling.core.training.hybrid import HYBRID_HIDDEN, HYBRID_ROLLOUT
from quad_modelling.core.training.narx import DEFAULT_ROLLOUT, PRETRAIN_EPOCHS
from quad_modelling.core.training.rollout import VAL_FRACTION
from quad_modelling.errors import ConfigError
from quad_modelling.fanout import add_fanout_arguments
from quad_modelling.io.topic_maps import add_topic_map_argument, topic_map_file

TRAINING_METHODS = ("rollout", "thesis")

MAX_EPOCHS = 10_000
"""Most training epochs (L-BFGS steps; the thesis used 25)."""


NAME = "train"
HELP = "train the NARX blackbox model (or the hybrid or direct physics-based model) and write a model file"
DESCRIPTION = """\
Train the NARX model (thesis chapter 4: six nets for the X/Y/Z velocities and roll/pitch/yaw
rates, 10 sigmoid hidden units, 20 delayed outputs) on the training span of one or more flights,
and write it as an .npz model file (no pickle) that `quad-modelling evaluate --model narx:MODEL`
and the NARX predictor node load.

--training rollout (default): incremental nets, a short series-parallel pre-training, then
closed-loop fine-tuning over --horizon steps from every start (mini-batches, Adam), early-stopped
on whole training flights held back for validation (--val-fraction, or --val-flights) with the
best epoch kept. --training thesis: the thesis's training exactly (series-parallel, 25 L-BFGS
epochs, 10 dB noise on the rates). With --hybrid, train the hybrid model instead: the vehicle's
nonlinear physics model with a residual net (--hybrid-hidden) correcting its accelerations inside
the integration, trained through the physics step with the same rollout loss, horizon, early
stopping and validation flights; evaluate it with --model hybrid:MODEL. With --direct, fit the
direct model: the physics model whose body rates (and, with an accelerometer in every flight, down
velocity) for the first 0.5 s come from ridge regressions per horizon on the last rows and the
commands (closed-form, seconds, no torch; give the identified vehicle with --vehicle); evaluate it
with --model direct:MODEL.

Spans follow the evaluation: take-off/landing are dropped (--drop, thesis 30:22 s) and --train
A:B is seconds from each flight's start (thesis 30:150) or percent of the flying part
(0%:60%, --preset short for ~40 s NanoBench flights).

--jobs N / --scheduler ADDRESS read and check the flights on Dask workers; the training
itself runs here (one network on all flights; docs/scale.md).

examples:
  quad-modelling train bags/nanobench_B7_oval_medium_rep2 --preset short -o narx.npz
  quad-modelling train flight1.mat flight2.mat --vehicle linkquad --train 30:150 -o narx.npz
  quad-modelling train bags/nanobench_B7_oval_medium_rep2 --preset short --hybrid -o hybrid.npz
  quad-modelling train bags/nanobench_B7_oval_medium_rep2 --preset short --vehicle identified.yaml --direct -o direct.npz
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("flights", metavar="FLIGHT", nargs="+", help="flights: MCAP bag directories, thesis .mat logs, NanoBench "
                        ".csv.gz or PX4 .ulg")
    parser.add_argument("-o", "--output", required=True, metavar="MODEL", help="model file to write (.npz)")
    parser.add_argument("--vehicle", metavar="NAME|FILE", help="vehicle config name or YAML (default: the one the flight names)")
    add_topic_map_argument(parser)
    parser.add_argument("--preset", choices=("thesis", "short"), default="thesis",
                        help="span preset: thesis (drop 30:22 s, train 30:150) or short (drop 5:5 s, train 0%%:60%%)")
    parser.add_argument("--train", metavar="A:B", help="training span (seconds, or percent of the flying part)")
    parser.add_argument("--drop", metavar="A:B", help="seconds dropped at take-off:landing")
    parser.add_argument("--training", choices=TRAINING_METHODS, default="rollout",
                        help="rollout (default: closed-loop fine-tuning, early stopping) or thesis (series-parallel only)")
    parser.add_argument("--epochs", type=int, help="series-parallel epochs (L-BFGS steps; thesis 25, rollout pre-training 3)")
    parser.add_argument("--horizon", type=int, default=50, help="rollout: closed-loop steps per training window (default 50)")
    parser.add_argument("--rollout-epochs", type=int, help=f"rollout: most fine-tuning epochs (NARX {DEFAULT_ROLLOUT.max_epochs}, hybrid {HYBRID_ROLLOUT.max_epochs})")
    parser.add_argument("--patience", type=int, help=f"rollout: epochs without a better validation loss before stopping (NARX {DEFAULT_ROLLOUT.patience}, hybrid {HYBRID_ROLLOUT.patience})")
    parser.add_argument("--val-fraction", type=float, default=VAL_FRACTION,
                        help="rollout: fraction of the training flights held back whole for early stopping (default 0.2)")
    parser.add_argument("--val-flights", nargs="+", metavar="FLIGHT", help="rollout: validation flights (early stopping only) instead of --val-fraction")
    parser.add_argument("--hidden", type=int, default=10, help="sigmoid units per net (thesis 10)")
    parser.add_argument("--delays", type=int, default=20, help="delayed outputs fed back (thesis 20 = 0.2 s at 100 Hz)")
    parser.add_argument("--input-delays", type=int, default=20, help="engine-command taps u(t)..u(t-N+1) (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (weights init, noise)")
    parser.add_argument("--hybrid", action="store_true", help="train the hybrid model: physics model + residual net (rollout loss)")
    parser.add_argument("--direct", action="store_true", help="fit the direct model: physics model with body rates and down "
                        "velocity from direct multi-horizon ridge regressions (seconds; no torch)")
    parser.add_argument("--hybrid-hidden", metavar="W[,W...]", default=",".join(map(str, HYBRID_HIDDEN)),
                        help="hybrid: widths of the residual net's tanh hidden layers (default %(default)s)")
    parser.add_argument("--command-filters", metavar="MS[,MS...]|none", default=",".join(f"{tau * 1000:g}" for tau in COMMAND_FILTERS_S),
                        help="hybrid: time constants [ms] of the first-order lags of the logged commands the net reads "
                             "(docs/narx.md); none: the net reads the commands of each sample only (default %(default)s)")
    parser.add_argument("--no-mirror-images", action="store_true",
                        help="hybrid: train on the flights alone, not also on their mirror images under the physics "
                             "model's symmetries (docs/narx.md); for a vehicle less symmetric than its model")
    add_fanout_arguments(parser)
    parser.add_argument("--force", action="store_true", help="overwrite an existing model file")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def training_spans(logs, args) -> list[tuple[float, float]]:
    """Training span [s from each flight's start] per flight, as the evaluation computes it; a warning line when it
    overlaps the preset's evaluation span (what ``evaluate --preset`` then scores partly in-sample)."""
    from quad_modelling.commands.evaluate import warn_flight_span_overlap
    from quad_modelling.core.windows import EvaluationConfig

    config = EvaluationConfig.from_options(args.preset, args.drop, train=args.train)
    overlap = config.span_overlap()
    if overlap:  # train has no evaluation span of its own: say whose it is and what to do (it read as train's own)
        print(f"warning: {overlap} if `evaluate --preset {args.preset}` scores these flights; evaluate the model on "
              "other flights, or give evaluate an --eval span after the training one", file=sys.stderr)
    warn_flight_span_overlap(config, logs)
    span = config.spans()[0]
    spans = []
    for log in logs:
        a, b = span.interval(log, config.drop_start, config.drop_end)
        if b - a <= 0:
            raise ConfigError(
                f"{log.meta.source}: training span {span.text()} is empty after dropping {config.drop_start:g}/{config.drop_end:g} s "
                f"of a {log.duration:.1f} s flight; use --preset short or --train with percentages"
            )
        spans.append((a, b))
    return spans


ROLLOUT_OPTIONS = ("horizon", "rollout_epochs", "patience", "val_fraction", "val_flights", "seed")
OPTIONS_READ = {
    "narx": ("hidden", "delays", "input_delays", "epochs", "training", *ROLLOUT_OPTIONS),
    "hybrid": (*ROLLOUT_OPTIONS, "hybrid_hidden", "command_filters", "no_mirror_images"),
    "direct": (),
}
"""The model options each kind of model reads (argparse names); another one set away from its default is refused."""


def check_model_options(args: argparse.Namespace, kind: str) -> None:
    """ConfigError (one line) naming the first model option given with a value other than its default that the
    ``kind`` model does not read (``--hidden 5 --direct``): nothing is silently ignored."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    every = sorted({name for names in OPTIONS_READ.values() for name in names})
    for name in every:
        value = getattr(args, name)
        if name not in OPTIONS_READ[kind] and value is not None and value != parser.get_default(name):
            shown = "" if value is True else " " + (" ".join(value) if isinstance(value, list) else str(value))  # a switch: its name
            reads = ", ".join("--" + n.replace("_", "-") for n in OPTIONS_READ[kind]) or "no model option (the fit is closed-form)"
            raise ConfigError(f"--{name.replace('_', '-')}{shown}: the {kind} model does not read it (it reads {reads})")


def training_configs(args: argparse.Namespace):
    """(NarxConfig, RolloutConfig or None) of the options, validated (ConfigError naming the flag)."""
    from quad_modelling.core.models.narx import NarxConfig
    from quad_modelling.core.training.narx import rollout_preset

    epochs = args.epochs if args.epochs is not None else (25 if args.training == "thesis" else PRETRAIN_EPOCHS)
    check_seed(args.seed)
    check_ranges((("--epochs", epochs, 0, MAX_EPOCHS), ("--hidden", args.hidden, 1, MAX_HIDDEN),
                  ("--delays", args.delays, 1, MAX_DELAYS), ("--input-delays", args.input_delays, 1, MAX_DELAYS)))
    shape = {"hidden": args.hidden, "output_delays": args.delays, "input_delays": tuple(range(args.input_delays)), "epochs": epochs}
    if args.training == "thesis" or args.hybrid:
        return NarxConfig(**shape), None
    rollout_defaults(args, DEFAULT_ROLLOUT)
    if not 0 <= args.val_fraction < 1:
        raise ConfigError(f"--val-fraction {args.val_fraction}: must lie in [0, 1)")
    return rollout_preset(**shape, horizon=args.horizon, max_epochs=args.rollout_epochs, patience=args.patience)


def rollout_defaults(args: argparse.Namespace, defaults) -> None:
    """Fill --rollout-epochs and --patience from the model's defaults (``defaults``, a RolloutConfig) when not given,
    then check --horizon, --rollout-epochs and --patience (ConfigError naming the flag)."""
    if args.rollout_epochs is None:
        args.rollout_epochs = defaults.max_epochs
    if args.patience is None:
        args.patience = defaults.patience
    check_ranges((("--horizon", args.horizon, 1, MAX_DELAYS), ("--rollout-epochs", args.rollout_epochs, 0, MAX_EPOCHS),
                  ("--patience", args.patience, 1, MAX_EPOCHS)))


def check_ranges(options) -> None:
    """ConfigError naming the first of ``options`` ((flag, value, low, high), ...) whose value lies outside [low, high]
    (the error listed every option's range without saying which was wrong, review)."""
    for flag, value, low, high in options:
        if not low <= value <= high:
            raise ConfigError(f"{flag} {value}: must lie in [{low}, {high}]")


def hybrid_config(args: argparse.Namespace):
    """The HybridTrainingConfig of the options (--horizon, --rollout-epochs, --patience, --val-fraction,
    --hybrid-hidden, --command-filters, --no-mirror-images), validated (ConfigError naming the flag)."""
    import dataclasses

    from quad_modelling.core.training.hybrid import HybridTrainingConfig

    check_seed(args.seed)
    rollout_defaults(args, HYBRID_ROLLOUT)
    if not 0 <= args.val_fraction < 1:
        raise ConfigError(f"--val-fraction {args.val_fraction}: must lie in [0, 1)")
    try:
        hidden = tuple(int(w) for w in args.hybrid_hidden.split(","))
    except ValueError as err:
        raise ConfigError(f"--hybrid-hidden {args.hybrid_hidden!r}: expected layer widths such as 32,32") from err
    if not hidden or not all(1 <= w <= MAX_HIDDEN for w in hidden) or len(hidden) > 4:
        raise ConfigError(f"--hybrid-hidden {args.hybrid_hidden!r}: one to four widths in [1, {MAX_HIDDEN}]")
    default = HybridTrainingConfig()
    rollout = dataclasses.replace(default.rollout, horizon=args.horizon, max_epochs=args.rollout_epochs, patience=args.patience)
    return HybridTrainingConfig(hidden=hidden, rollout=rollout, val_fraction=args.val_fraction,
                                mirror_images=not args.no_mirror_images, command_filters_s=command_filters(args.command_filters))


MAX_COMMAND_FILTERS = 6
"""Most command filters ``--command-filters`` takes (each adds four net inputs)."""


def command_filters(text: str) -> tuple[float, ...]:
    """``--command-filters`` MS[,MS...] (time constants in milliseconds) or ``none`` -> time constants [s]."""
    if text.strip().lower() == "none":
        return ()
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError as err:
        raise ConfigError(f"--command-filters {text!r}: expected time constants in ms such as 30,100,300, or none") from err
    if not 1 <= len(values) <= MAX_COMMAND_FILTERS or not all(0 < v <= 10000 for v in values) or len(set(values)) < len(values):
        raise ConfigError(f"--command-filters {text!r}: one to {MAX_COMMAND_FILTERS} different time constants in (0, 10000] ms, or none")
    return tuple(v / 1000.0 for v in values)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from quad_modelling.atomic import check_distinct_inputs, check_output
    from quad_modelling.commands.evaluate import print_flight_warnings, warn_starting_values
    from quad_modelling.core.training.narx import train_narx_on_flights
    from quad_modelling.core.vehicle import load_vehicle, vehicle_file
    from quad_modelling.core.preprocess import resample_uniform
    from quad_modelling.core.windows import check_window_rate
    from quad_modelling.fanout import check_fanout_options, tty_progress
    from quad_modelling.io.loader import check_distinct_flights, check_topic_map_applies, load_flights

    output = Path(args.output)
    check_command_output(output, args.force, inputs=[*args.flights, *(args.val_flights or []), vehicle_file(args.vehicle),
                                             topic_map_file(args.topic_map)])  # fail before minutes of training
    if output.suffix != ".npz":
        raise ConfigError(f"-o {output}: a model file is an .npz archive; name it MODEL.npz")
    if args.hybrid and args.direct:
        raise ConfigError("--hybrid and --direct: choose one model to train")
    if args.direct and args.val_flights:
        raise ConfigError("--val-flights: the direct model's fit is closed-form, with no validation; pass those flights as training flights")
    check_distinct_inputs(args.flights, "FLIGHT", args.val_flights or [], "--val-flights")
    check_distinct_inputs(args.val_flights or [], "--val-flights")
    check_topic_map_applies(args.topic_map, [*args.flights, *(args.val_flights or [])])
    kind = "hybrid" if args.hybrid else "direct" if args.direct else "narx"
    check_model_options(args, kind)
    config, rollout = (hybrid_config(args), None) if args.hybrid else (None, None) if args.direct else training_configs(args)
    check_fanout_options(args.jobs, args.scheduler)
    given = load_vehicle(args.vehicle) if args.vehicle else None  # once for every flight
    paths = [*args.flights, *(args.val_flights or [])]
    logs, _ = load_flights(paths, given, jobs=args.jobs, scheduler=args.scheduler,
                           progress=None if args.quiet else tty_progress("train: read", len(paths)), topic_map=args.topic_map)
    named = [(log.meta.source, log.fingerprint()) for log in logs]
    check_distinct_flights(named[: len(args.flights)], "FLIGHT", named[len(args.flights):], "--val-flights")
    check_distinct_flights(named[len(args.flights):], "--val-flights")
    for log in logs:  # windows and rollout segments are in samples: a flight no window can score is refused for its rate
        check_window_rate(log)
    # rows of one period, as evaluate scores them: a dropped row is filled, a longer hole marked as a gap (it was one row)
    logs = [resample_uniform(log) for log in logs]
    print_flight_warnings(logs)
    spans = training_spans(logs, args)
    val_flights = list(range(len(args.flights), len(logs))) if args.val_flights else None
    started = time.perf_counter()
    progress = not args.quiet and sys.stderr.isatty()
    if args.hybrid or args.direct:
        warn_starting_values(given or load_vehicle(logs[0].meta.vehicle), kind)
    if args.hybrid:
        from quad_modelling.core.training.hybrid import train_hybrid_on_flights

        model = train_hybrid_on_flights(logs, spans, given or load_vehicle(logs[0].meta.vehicle), config, args.seed, progress, val_flights)
        samples = model.training["samples"]
    elif args.direct:
        from quad_modelling.core.training.direct import train_direct

        model = train_direct(logs, spans, given or load_vehicle(logs[0].meta.vehicle))
        samples = model.training["samples"]
    else:
        model = train_narx_on_flights(logs, spans, config, args.seed, progress, rollout, args.val_fraction, val_flights)
        samples = model.training["samples"]
    elapsed = time.perf_counter() - started
    model.save(output, args.force)
    record = model.training  # the flights trained on, held-back validation flights not: the NARX's segments, else "flights"
    trained = len({seg["source"] for seg in record.get("segments", ())}) or len(record.get("flights") or args.flights)
    images = len(model.training.get("mirror_images") or ())
    mirrored = f" and their {images} mirror images" if images else ""
    print(f"trained {kind} model on {samples} samples of {trained} flight(s){mirrored} in {elapsed:.1f} s -> {output}")
    weights = model.training.get("weights") if kind == "narx" else None
    if weights and samples * len(NARX_OUTPUTS) < weights:  # fewer numbers to fit than weights: it can memorise them
        print(f"warning: {samples} training rows x {len(NARX_OUTPUTS)} outputs for {weights} weights: the NARX can learn these rows "
              "by heart; give longer or more flights (or --preset/--train spans that keep more of them)", file=sys.stderr)
    if "rollout" in getattr(model, "training", {}):
        r = model.training["rollout"]
        in_sample = kind == "hybrid" and not model.training.get("validation_flights")  # one flight: its own windows
        judged = (f"{'training' if in_sample else 'validation'} loss {r['val_loss'][0]:.4g} -> {r['val_loss'][r['best_epoch']]:.4g} "
                  f"on {r['val_windows']} windows" + (" (one flight, none held back: in-sample)" if in_sample else "")
                  if r["val_windows"] else f"no validation window (--val-fraction 0, or a held-back part shorter than one): stopped on the training "
                  f"loss, {r['val_loss'][0]:.4g} -> {r['val_loss'][r['best_epoch']]:.4g}")
        print(f"rollout fine-tuning: best epoch {r['best_epoch']} of {r['epochs_run']} "
              f"({'stopped early' if r['stopped_early'] else 'epoch limit'}), {judged}")
    if args.direct:
        print(f"vertical map (down velocity): {model.training['vertical_map']}")
    print(f"evaluate it with: quad-modelling evaluate ... --model {kind}:{output}")
    return 0
