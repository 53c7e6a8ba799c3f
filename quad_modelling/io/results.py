"""Evaluation results read back: results.json of ``evaluate`` directories, and their exact merge.

``quad-modelling merge`` reads the ``statistics`` of each directory's results.json
(:mod:`quad_modelling.core.evaluation.statistics`) one directory at a time, in the order given, and
merges them with the same function an evaluation of all their flights runs: the merged averages are
the numbers of one ``evaluate`` over every flight (bit for bit when each directory holds the
evaluation of consecutive flights evaluated one by one, see the statistics module). Only what makes
the numbers comparable is checked: the same vehicle, models, spans, windows, trim, smoothing and
horizons; anything else is one :class:`~quad_modelling.errors.DataError` naming the file and field.
"""

from __future__ import annotations

import dataclasses

import json
import stat
from collections.abc import Iterator, Sequence
from pathlib import Path

from quad_modelling.core.evaluation.statistics import EvaluationStatistics
from quad_modelling.core.evaluation.windowed import EvaluationResult, result_from_statistics
from quad_modelling.core.input_files import check_regular_file, input_path_mode
from quad_modelling.core.windows import EvaluationConfig
from quad_modelling.errors import ConfigError, DataError

RESULTS_FILE = "results.json"

MAX_RESULTS_BYTES = 256 << 20
"""Largest results.json read [bytes]: a per-flight file is a few kB to a few MB."""


def results_file(directory: str | Path) -> Path:
    """The results.json of an ``evaluate`` output directory (or the file itself); DataError when missing."""
    path = Path(directory)
    mode = input_path_mode(path, "results directory", DataError)
    path = path / RESULTS_FILE if mode is not None and stat.S_ISDIR(mode) else path
    if input_path_mode(path, "results file", DataError) is None:
        raise DataError(f"{directory}: no {RESULTS_FILE} (not an output directory of quad-modelling evaluate)")
    check_regular_file(path, "results file", DataError)
    if path.stat().st_size > MAX_RESULTS_BYTES:
        raise DataError(f"{path}: {path.stat().st_size} bytes, more than the {MAX_RESULTS_BYTES >> 20} MiB a results.json may hold")
    return path


def read_results(directory: str | Path) -> tuple[Path, dict, EvaluationStatistics, EvaluationConfig]:
    """(file, document, statistics, configuration) of one results.json; DataError naming the file when it is not
    JSON, not an evaluation's, or has no statistics (a run-bag result or one written before they were stored)."""
    path = results_file(directory)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DataError(f"{path}: not a JSON document ({type(err).__name__}: {err})") from err
    except RecursionError as err:
        raise DataError(f"{path}: nests deeper than JSON can be read") from err
    if not isinstance(document, dict) or not {"models", "config"} <= set(document):
        raise DataError(f"{path}: not the results.json of quad-modelling evaluate (no 'models' and 'config')")
    if "statistics" not in document:
        raise DataError(f"{path}: holds averages only, no 'statistics' to merge (written by an older version); "
                        f"re-run quad-modelling evaluate (or run-bag) on its flights")
    if "live" in document and not (document["config"].get("train") and document["config"].get("eval")):
        raise DataError(f"{path}: a run-bag result without both --train and --eval (its span is live:0:inf); merge takes "
                        "evaluations over train and eval spans: re-run run-bag with --train and --eval")
    statistics = EvaluationStatistics.from_json(document["statistics"], f"{path}: statistics")
    try:
        config = EvaluationConfig.from_dict(document["config"], f"{path}: config")
    except ConfigError as err:
        raise DataError(str(err)) from err
    return path, document, statistics, config


def _same(name: str, first, other, first_path: Path, other_path: Path) -> None:
    """DataError (one line) when ``other`` differs from ``first``: for a configuration (a dataclass) the fields that
    differ, with both values, not the two whole configurations."""
    if first == other:
        return
    if dataclasses.is_dataclass(first) and type(first) is type(other):
        fields = [f.name for f in dataclasses.fields(first) if getattr(first, f.name) != getattr(other, f.name)]
        what = "; ".join(f"{f} {getattr(other, f)!r} (there {getattr(first, f)!r})" for f in fields)
    else:
        what = f"{other} (there {first})"
    raise DataError(f"{other_path}: {name} differs from {first_path}'s: {what}; only evaluations with the same vehicle, "
                    f"models, spans and configuration can be merged")


def merge_results(directories: Sequence[str | Path]) -> EvaluationResult:
    """One evaluation of every flight of ``directories`` (their results.json statistics merged in the order
    given, one file held at a time); the flights list is the inputs' lists in order."""
    total: EvaluationStatistics | None = None
    flights: list[dict] = []
    seen_flights: dict[tuple, tuple] = {}
    first = None
    for path, document, statistics, config in _each(directories):
        if first is None:
            first = (path, config, statistics)
            total = statistics.empty_like([s.name for s in config.spans()])
        first_path, first_config, first_stats = first
        _same("vehicle", first_stats.vehicle, statistics.vehicle, first_path, path)
        difference = first_stats.vehicle_difference(statistics)
        if difference:
            raise DataError(f"{path}: vehicle constants differ from {first_path}'s ({difference}): evaluations run with different "
                            "vehicle files do not merge; evaluate every flight with one --vehicle")
        _same("models", first_stats.models, statistics.models, first_path, path)  # before their files: a model both hold
        model = first_stats.model_file_difference(statistics)
        if model:
            raise DataError(f"{path}: model {model} was loaded from another file than in {first_path} (its contents differ); "
                            "evaluations of different model files do not merge")
        _same("configuration", first_config, config, first_path, path)
        _same("multi-step table", first_stats.multistep is not None, statistics.multistep is not None, first_path, path)
        scored = [f for f in document["config"].get("flights", []) if isinstance(f, dict) and not f.get("skipped")]
        for flight in scored:  # the same flight in two results would count twice
            key = _flight_key(flight)
            if key in seen_flights:
                name, where = seen_flights[key]
                raise DataError(f"{path}: flight {flight.get('source')} ({flight.get('duration_s')} s) is also in {where}"
                                + (f" (as {name})" if name != flight.get("source") else "")
                                + "; its windows would count twice: merge results of different flights")
            seen_flights[key] = (flight.get("source"), f"{path}")
        total.merge(statistics)
        flights.extend(document["config"].get("flights", []))
    if first is None:
        raise ConfigError("merge needs at least one results directory")
    return result_from_statistics(total, first[1], flights)


def _flight_key(flight: dict) -> tuple:
    """What makes two scored flights one: the digest of its numbers (:meth:`FlightLog.fingerprint
    <quad_modelling.core.flight_log.FlightLog.fingerprint>`: the same flight under another path is one, two flights
    of one name are two); results written before it carry none: the source as given, duration and rate."""
    if flight.get("fingerprint"):
        return ("fingerprint", flight["fingerprint"])
    return (str(flight.get("source")), flight.get("duration_s"), flight.get("sample_rate_hz"))


def _each(directories: Sequence[str | Path]) -> Iterator[tuple[Path, dict, EvaluationStatistics, EvaluationConfig]]:
    seen: dict[Path, str] = {}
    for directory in directories:
        path, document, statistics, config = read_results(directory)
        if path.resolve() in seen:
            raise DataError(f"{directory}: given twice (also as {seen[path.resolve()]}); its flights would count twice")
        seen[path.resolve()] = str(directory)
        yield path, document, statistics, config
