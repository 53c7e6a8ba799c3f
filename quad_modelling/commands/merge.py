"""``quad-modelling merge``: one evaluation of all flights from the results of several ``evaluate`` runs (#19)."""

from __future__ import annotations

import argparse
from pathlib import Path

from quad_modelling.atomic import atomic_output
from quad_modelling.commands import check_command_output
from quad_modelling.io.reports.evaluation import headline_scores, windows_text, write_report
from quad_modelling.io.results import merge_results

NAME = "merge"
HELP = "merge the results.json of several evaluate runs into the numbers of one evaluation over all their flights"
DESCRIPTION = """\
Merge evaluation results: each RESULTS_DIR is an output directory of `quad-modelling evaluate`
(its results.json stores, next to the averages, the statistics they are computed from: window
counts, sums of the per-window RMS and TIC, multi-step start counts and MAE sums per horizon).
The merge adds them in the order given, as one evaluation of all the flights does, so OUTDIR
receives the results.json and tables.md of one `evaluate` over every flight (no figures: the
inputs keep no flight data). The inputs are read one at a time.

The inputs must share the vehicle (every constant), models, spans, windows, trim, smoothing and horizons; a
missing, foreign or incompatible results.json is a one-line error naming it.

examples:
  quad-modelling evaluate flight1.csv.gz --preset short -o r1
  quad-modelling evaluate flight2.csv.gz --preset short -o r2
  quad-modelling merge r1 r2 -o all
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="RESULTS_DIR", help="output directories of quad-modelling evaluate (or their results.json)")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="new output directory")
    parser.add_argument("--force", action="store_true", help="overwrite an existing OUTDIR")


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    check_command_output(output, args.force, inputs=args.inputs, directory=True, markers=("results.json",))
    result = merge_results(args.inputs)
    stats = result.statistics
    with atomic_output(output, args.force) as tmp:
        files = write_report(result, tmp, title=f"Evaluation of {', '.join(stats.models)} on vehicle {stats.vehicle} "
                                                f"(merged from {len(args.inputs)} results)")
    data = result.to_json()
    used = [f for f in result.flights if not f.get("skipped")]
    print(f"{len(used)} flight(s) from {len(args.inputs)} results, {windows_text(data)} -> {output}/ ({', '.join(files)})")
    for line in headline_scores(data, stats.models):
        print(line)
    return 0
