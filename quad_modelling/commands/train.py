"""``quad-modelling train``: train the NARX (or hybrid greybox+NARX) model on flights."""

from __future__ import annotations

import argparse
import sys
import time

from quad_modelling.errors import ConfigError

MAX_EPOCHS = 10_000
"""Most training epochs (L-BFGS steps; the thesis used 25)."""

MAX_HIDDEN = 1000
"""Most sigmoid units per net (the thesis used 10)."""

MAX_DELAYS = 1000
"""Most delayed outputs or input taps (10 s at 100 Hz; the thesis used 20)."""

NAME = "train"
HELP = "train the NARX blackbox model (or the hybrid greybox+NARX model) and write a model file"
DESCRIPTION = """\
Train the thesis's NARX model (chapter 4: six nets for the X/Y/Z velocities and roll/pitch/yaw
rates, 10 sigmoid hidden units, 20 delayed outputs, 25 epochs, 10 dB noise on the rates) on the
training span of one or more flights, and write it as an .npz model file (no pickle) that
`quad-modelling evaluate --model narx:MODEL` and the NARX predictor node load. With --hybrid,
train the residual nets of the hybrid model (linear greybox + NARX on its residual) instead;
evaluate it with --model hybrid:MODEL.

Spans follow the evaluation: take-off/landing are dropped (--drop, thesis 30:22 s) and --train
A:B is seconds from each flight's start (thesis 30:150) or percent of the flying part
(0%:60%, --preset short for ~40 s NanoBench flights).

example:
  quad-modelling train bags/nanobench_B7_oval_medium_rep2 --preset short -o narx.npz
  quad-modelling train flight1.mat flight2.mat --vehicle linkquad --train 30:150 -o narx.npz
  quad-modelling train bags/nanobench_B7_oval_medium_rep2 --preset short --hybrid -o hybrid.npz
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("flights", metavar="BAG", nargs="+", help="flights: MCAP bag directories, thesis .mat logs or NanoBench .csv.gz")
    parser.add_argument("-o", "--output", required=True, metavar="MODEL", help="model file to write (.npz)")
    parser.add_argument("--vehicle", help="vehicle config name or YAML (default: the one the flight names)")
    parser.add_argument("--preset", choices=("thesis", "short"), default="thesis",
                        help="span preset: thesis (drop 30:22 s, train 30:150) or short (drop 5:5 s, train 0%%:60%%)")
    parser.add_argument("--train", metavar="A:B", help="training span (seconds, or percent of the flying part)")
    parser.add_argument("--drop", metavar="A:B", help="seconds dropped at take-off:landing")
    parser.add_argument("--epochs", type=int, default=25, help="training epochs (L-BFGS steps; thesis 25)")
    parser.add_argument("--hidden", type=int, default=10, help="sigmoid units per net (thesis 10)")
    parser.add_argument("--delays", type=int, default=20, help="delayed outputs fed back (thesis 20 = 0.2 s at 100 Hz)")
    parser.add_argument("--input-delays", type=int, default=20, help="engine-command taps u(t)..u(t-N+1) (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (weights init, noise)")
    parser.add_argument("--hybrid", action="store_true", help="train the hybrid model's residual nets on the greybox")
    parser.add_argument("--force", action="store_true", help="overwrite an existing model file")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def training_spans(logs, args) -> list[tuple[float, float]]:
    """Training span [s from each flight's start] per flight, as the evaluation computes it."""
    from quad_modelling.core.windows import EvaluationConfig

    config = EvaluationConfig.from_options(args.preset, args.drop, train=args.train)
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


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from quad_modelling.atomic import check_output
    from quad_modelling.commands.evaluate import print_gap_warnings
    from quad_modelling.core.models.narx import NarxConfig
    from quad_modelling.core.models.narx_training import train_narx_on_flights
    from quad_modelling.core.vehicle import load_vehicle, vehicle_file
    from quad_modelling.io.loader import load_flight

    output = Path(args.output)
    check_output(output, args.force, inputs=[*args.flights, vehicle_file(args.vehicle)])  # fail before minutes of training
    if args.seed < 0:
        raise ConfigError(f"--seed {args.seed}: must be a non-negative integer")
    if not (0 <= args.epochs <= MAX_EPOCHS and 1 <= args.hidden <= MAX_HIDDEN and 1 <= args.delays <= MAX_DELAYS
            and 1 <= args.input_delays <= MAX_DELAYS):
        raise ConfigError(f"--epochs must lie in [0, {MAX_EPOCHS}], --hidden in [1, {MAX_HIDDEN}], "
                          f"--delays and --input-delays in [1, {MAX_DELAYS}]")
    config = NarxConfig(hidden=args.hidden, output_delays=args.delays, input_delays=tuple(range(args.input_delays)), epochs=args.epochs)
    given = load_vehicle(args.vehicle) if args.vehicle else None  # once for every flight
    logs = [load_flight(path, given) for path in args.flights]
    print_gap_warnings(logs)
    spans = training_spans(logs, args)
    started = time.perf_counter()
    progress = not args.quiet and sys.stderr.isatty()
    if args.hybrid:
        from quad_modelling.core.models.hybrid import train_hybrid_on_flights

        model = train_hybrid_on_flights(logs, spans, given or load_vehicle(logs[0].meta.vehicle), config, args.seed, progress)
        samples = model.residual.training["samples"]
    else:
        model = train_narx_on_flights(logs, spans, config, args.seed, progress)
        samples = model.training["samples"]
    elapsed = time.perf_counter() - started
    model.save(output, args.force)
    kind = "hybrid" if args.hybrid else "narx"
    print(f"trained {kind} model on {samples} samples of {len(logs)} flight(s) in {elapsed:.1f} s -> {output}")
    print(f"evaluate it with: quad-modelling evaluate ... --model {kind}:{output}")
    return 0
