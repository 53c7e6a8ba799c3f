"""One entry point to read any supported flight file: :func:`load_flight`; several at once: :func:`load_flights`."""

from __future__ import annotations

import stat
from pathlib import Path
from typing import NamedTuple

from quad_modelling.core.consistency import consistency_warnings
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.input_files import check_regular_file, input_path_mode, read_yaml
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle
from quad_modelling.errors import BagError, ConfigError, DataError, QuadModellingError
from quad_modelling.fanout import map_flights

FORMATS = ("thesis-mat", "nanobench", "px4-ulog", "bag")


def detect_format(path: str | Path) -> str:
    """``thesis-mat`` for .mat, ``nanobench`` for .csv/.csv.gz, ``px4-ulog`` for .ulg, ``bag`` for a rosbag2 directory or .mcap."""
    path = Path(path)
    name = path.name.lower()
    mode = input_path_mode(path, "flight file", DataError)
    if (mode is not None and stat.S_ISDIR(mode)) or name.endswith(".mcap"):
        return "bag"
    if name.endswith(".mat"):
        return "thesis-mat"
    if name.endswith(".csv") or name.endswith(".csv.gz"):
        return "nanobench"
    if name.endswith(".ulg"):
        return "px4-ulog"
    if mode is None:
        raise DataError(f"{path}: no such file or directory")
    raise DataError(f"{path}: cannot tell the format from the name (expected .mat, .csv, .csv.gz, .ulg or a bag directory)")


def bag_directory(path: Path) -> Path:
    """The bag directory a bag input names: the directory itself, or the directory of the .mcap file named when the
    bag's ``metadata.yaml`` lists that file among its ``relative_file_paths`` (the reader reads the files listed,
    not the one named: another file there would be read in its place). BagError in one line otherwise."""
    if path.is_dir():
        return path
    bag = path.parent
    if not (bag / "metadata.yaml").is_file():
        raise BagError(f"{path}: no metadata.yaml beside it: a rosbag2 bag is a directory of metadata.yaml and its .mcap file(s)")
    try:
        document = read_yaml(bag / "metadata.yaml", "bag metadata")
    except ConfigError as err:
        raise BagError(f"{bag}: not a readable rosbag2 bag: {err}") from err
    information = document.get("rosbag2_bagfile_information") if isinstance(document, dict) else None
    files = information.get("relative_file_paths") if isinstance(information, dict) else None
    names = [Path(str(f)).name for f in files] if isinstance(files, list) else []
    if path.name not in names:
        raise BagError(f"{path}: not a file of the bag {bag} (its metadata.yaml lists {', '.join(names) or 'none'}); "
                       "give the bag directory or the file it lists")
    return bag


def input_format(path: str | Path, given: str = "auto") -> str:
    """The input format ``--format`` gives, or the one its name tells (``unknown`` when it tells none)."""
    if given != "auto":
        return given
    try:
        return detect_format(path)
    except DataError:
        return "unknown"


def check_topic_map_applies(topic_map: str | None, paths, given: str = "auto") -> None:
    """ConfigError (one line) when ``--topic-map`` is given and no input is a bag: a topic map reads bags only, and
    unread it would be ignored without a word (every verb that takes flights calls this)."""
    if not topic_map or not paths:
        return
    formats = [input_format(p, given) for p in paths]
    if "bag" not in formats:
        raise ConfigError(f"--topic-map {topic_map}: a topic map applies to bags only, and no input is one "
                          f"({paths[0]} is a {formats[0]} input)")


def load_flight(path: str | Path, vehicle: str | VehicleConfig | None = None, fmt: str = "auto",
                mapping_file: str | Path | None = None, topic_map: str | None = None) -> FlightLog:
    """Read a thesis .mat log, a NanoBench CSV, a PX4 ULog or a rosbag2 bag into a FlightLog.

    ``vehicle``: config name, YAML path or a loaded config (required for .mat files
    that do not name one; NanoBench defaults to crazyflie21, PX4 ULog to px4_iris or
    px4_iris_pwm by its motor-command topic, see :mod:`quad_modelling.io.ulog`). The vehicle config is
    loaded once per call, not at all when ``vehicle`` is a loaded config (a command
    reading many flights of one ``--vehicle`` loads it once). The returned log's
    ``meta.vehicle`` is the config's name. ``mapping_file``: YAML
    variable mapping for foreign .mat logs (see :mod:`quad_modelling.io.matlog`). ``topic_map``: for a bag, a
    topic map name or YAML file (``--topic-map``); None: the one built-in map the bag's topics match
    (:func:`~quad_modelling.io.topic_maps.choose_topic_map`; our own contract is the map ``quad``). A bag
    of another stack without a ``--vehicle`` is read for its map's ``default_vehicle``.
    """
    path = Path(path)
    fmt = detect_format(path) if fmt == "auto" else fmt
    if fmt not in FORMATS:
        raise DataError(f"{path}: unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    mode = input_path_mode(path, "flight file", DataError)
    if mode is None:
        raise DataError(f"{path}: no such file or directory")
    if not stat.S_ISDIR(mode):  # a FIFO or device would block or never end: refused before it is opened
        check_regular_file(path, "flight file", DataError)
    try:
        return _load(path, vehicle, fmt, mapping_file, topic_map)
    except QuadModellingError as err:
        if " ".join(str(path).splitlines()) in str(err):  # the error's one line (QuadModellingError) names the file
            raise
        hint = ("; the flight (or its topic map's default_vehicle) names it: pass its vehicle file with --vehicle FILE.yaml (for a bag of a PX4 log, the one "
                "`convert --vehicle-from-log` wrote)" if vehicle is None and str(err).startswith("unknown vehicle") else "")
        raise type(err)(f"{path}: {err}{hint}") from err  # e.g. an unknown vehicle the file names


def _load(path: Path, vehicle: str | VehicleConfig | None, fmt: str, mapping_file: str | Path | None,
          topic_map: str | None = None) -> FlightLog:
    config = vehicle if isinstance(vehicle, VehicleConfig) else None
    name = config.name if config is not None else vehicle
    if fmt == "thesis-mat":
        from quad_modelling.io.matlog import load_mapping, read_matlog

        mapping = load_mapping(mapping_file) if mapping_file else None
        log = read_matlog(path, vehicle=name, mapping=mapping)
    elif fmt == "nanobench":
        from quad_modelling.io.nanobench import read_nanobench

        config = config or load_vehicle(name or "crazyflie21")
        log = read_nanobench(path, vehicle=config)
    elif fmt == "px4-ulog":
        from quad_modelling.io.ulog import read_ulog

        log = read_ulog(path, vehicle=config or name)
    else:
        from quad_modelling.io.bag_io import read_bag, read_bag_metadata
        from quad_modelling.io.mapped_flight import read_mapped_bag
        from quad_modelling.io.topic_maps import choose_topic_map

        if not path.is_dir() and path.suffix != ".mcap":  # --format bag on a file: not the parent directory's fault
            raise DataError(f"{path}: --format bag reads a bag directory (or its .mcap file); this is a file")
        bag = bag_directory(path)
        metadata = read_bag_metadata(bag)
        chosen = choose_topic_map(metadata.topics, str(bag), topic_map)
        if chosen.is_contract:
            log = read_bag(bag, vehicle=name, namespace=chosen.namespace)
        else:  # the vehicle: --vehicle, else the one the bag records (a bag we wrote), else the map's default
            recorded = name or metadata.vehicle or chosen.default_vehicle
            if config is None and not recorded:
                raise DataError(f"{bag}: neither the bag nor topic map {chosen.name} names a vehicle; pass --vehicle NAME")
            config = config or load_vehicle(recorded)
            log = read_mapped_bag(bag, chosen, config)
    config = config or load_vehicle(vehicle if vehicle is not None else log.meta.vehicle)  # a --vehicle FILE of any name
    if fmt == "thesis-mat" and mapping_file:  # a mapping names the commands' unit: it must be the vehicle's kind
        from quad_modelling.io.matlog import commands_in_vehicle_unit

        log.u = commands_in_vehicle_unit(log.u, mapping["u"].unit, config, f"{path} (mapping {mapping_file})")
    # The log names its airframe (config name), not the file its constants came from:
    # --vehicle FILE picks constants for a command, the flight stays the same vehicle.
    log.meta.vehicle = config.name
    if fmt != "nanobench":  # the NanoBench reader saturates with its column names
        log.saturate_inputs(config.input_min, config.input_max, config.input_unit)
    # Formats other tools write are checked for unit and frame mistakes (a map's bag as it is assembled, its warnings
    # naming the map: io.mapped_flight); our own bags and .mat logs are what convert and simulate wrote.
    if fmt in ("nanobench", "px4-ulog") or (fmt == "thesis-mat" and mapping_file):
        for warning in consistency_warnings(log, config.input_min, config.input_max):
            log.warn(warning)
    return log


class LoadedFlight(NamedTuple):
    """One path's outcome: the flight, or (``--skip-bad``) None and the message of the file left out."""

    log: FlightLog | None
    skipped: str | None


def load_flight_or_skip(path: str | Path, vehicle: VehicleConfig | None = None, skip_bad: bool = False,
                        topic_map: str | None = None) -> LoadedFlight:
    """:func:`load_flight`; with ``skip_bad`` a file that cannot be read is a :class:`LoadedFlight` with its message
    instead of the error (the per-flight task of :func:`load_flights`, run where the flight is)."""
    try:
        return LoadedFlight(load_flight(path, vehicle=vehicle, topic_map=topic_map), None)
    except QuadModellingError as err:
        if not skip_bad:
            raise
        return LoadedFlight(None, str(err))


def load_flights(paths, vehicle: str | VehicleConfig | None = None, skip_bad: bool = False, jobs: int | None = None,
                 scheduler: str | None = None, progress=None, topic_map: str | None = None) -> tuple[list[FlightLog], list[str]]:
    """Read every path with :func:`load_flight`; returns the flights (in the order of ``paths``) and the messages
    of the files left out.

    A ``vehicle`` given by name or file is loaded once for all the flights. ``jobs``/``scheduler``: read the
    files on Dask workers (:func:`quad_modelling.fanout.map_flights`; ``progress(index, path, loaded)`` per file read).
    ``topic_map``: as :func:`load_flight` (``--topic-map``), for every bag among the paths.

    A file that cannot be read raises its :class:`~quad_modelling.errors.QuadModellingError`, or, with
    ``skip_bad``, is left out and its message returned (the ``--skip-bad`` of the commands)."""
    given = load_vehicle(vehicle) if vehicle is not None and not isinstance(vehicle, VehicleConfig) else vehicle
    loaded = map_flights(load_flight_or_skip, [str(p) for p in paths], given, skip_bad, topic_map, jobs=jobs, scheduler=scheduler,
                         progress=progress)
    return [one.log for one in loaded if one.log is not None], [one.skipped for one in loaded if one.log is None]


def check_distinct_flights(named, flag: str = "FLIGHT", other=(), other_flag: str = "") -> None:
    """ConfigError (one line) when two of ``named`` ((source, :meth:`~quad_modelling.core.flight_log.FlightLog.fingerprint`)
    pairs) are one flight -- the same recorded numbers under another path, name or format (a bag and the CSV it was
    converted from): its windows would count twice -- or one is also among ``other`` (``other_flag``'s)."""
    seen: dict[str, str] = {}
    for source, print_ in named:
        if print_ in seen:
            raise ConfigError(f"{flag} {source}: the same flight as {seen[print_]} (the same recorded numbers); every flight "
                              "counts once, give it once")
        seen[print_] = source
    for source, print_ in other:
        if print_ in seen:
            raise ConfigError(f"{other_flag} {source}: the same flight as the {flag} {seen[print_]}; a flight is one or the other")
