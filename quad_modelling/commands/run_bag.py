"""``quad-modelling run-bag``: the live graph (replay, predictors, evaluator) on one bag, over real DDS."""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from quad_modelling.atomic import atomic_output, name_final_paths
from quad_modelling.commands import check_command_output
from quad_modelling.core.models.registry import MODEL_FILE_KINDS, baseline_name_clash, named_spec
from quad_modelling.core.windows import MAX_SECONDS, EvaluationConfig, check_window_rate, seconds_spans, spans_without_a_window
from quad_modelling.errors import ConfigError, QuadModellingError
from quad_modelling.io.topic_maps import add_topic_map_argument
from quad_modelling.nodes.domains import DISCOVERY_MODES, ros_environment
from quad_modelling.nodes.executors import EXECUTORS

NAME = "run-bag"
HELP = "replay a bag through the live predictor and evaluator nodes (separate processes, real DDS)"
DESCRIPTION = """\
Start the ROS 2 graph of the node suite on one MCAP bag: the evaluator, one predictor per model and the replay, each
its own process talking over DDS (--discovery localhost, the default: loopback only; a ROS_DOMAIN_ID of its own
unless the environment sets one). Waits until the replay has played the bag and the evaluator acknowledged the last
sample, stops the nodes (SIGINT, then terminate), and prints the RMS/TIC tables. Then the multi-step table (IDSIA:
MAE at 1/10/50 steps, SimErr, ratio to naive) of the same models on the bag, each predicting with its live form from
every start (the code the predictor nodes run, called in-process); --no-multistep skips it.

Half a graph per host: --nodes names the nodes started here (replay, predictors, evaluator; default all); the others
are expected on another host in the same ROS_DOMAIN_ID (set it, the same on every host) with --discovery subnet
(multicast, plus ROS_STATIC_PEERS if set) or env (your ROS_AUTOMATIC_DISCOVERY_RANGE / ROS_STATIC_PEERS as they
are). run-bag waits --remote-timeout for them, starts the replay last, and ends when the replay (here, or announcing
replay/done from there) has finished; every host runs it on the same BAG and --models. A Fast DDS profile of yours
(FASTRTPS_DEFAULT_PROFILES_FILE) is kept, with the nodes' writer heartbeat added where it sets none.

Models: comma-separated specs (naive, greybox, greybox:euler, narx:MODEL.npz, ...); NAME=SPEC gives a spec another
topic name (two NARX files: a=narx:a.npz,b=narx:b.npz). Spans: --train and --eval in seconds from the first sample
(multiples of --window are best: only windows entirely inside a span are scored; a span holding no whole window of
the bag is warned about before any node starts); without them one span live:0:inf.

OUTDIR receives (on the evaluator's host) results.json (as quad-modelling evaluate, plus every live window, scored
or marked), tables.md, figures, params.yaml (the nodes' parameters) and logs/<node>.log; with --record also record/,
one MCAP bag of everything the evaluator received and published.

Every node subscribes reliable and transient-local (parameter qos: replay): at --rate 0 the replay is paced on the
evaluator's acknowledgements and loses nothing, not even to a late discovery; a faster --rate can overrun the nodes' keep-last
queues: samples received against replayed, per stream, in a warning line each and results.json live.samples, exit code 1.
SIGINT/SIGTERM stop every node (each one's process group) and remove the staging directory.

examples:
  quad-modelling run-bag bags/nanobench_B7_oval_medium_rep2 --models naive -o live
  quad-modelling run-bag BAG --models greybox --nodes replay,predictors --discovery subnet -o drone    (onboard)
  quad-modelling run-bag BAG --models greybox --nodes evaluator --discovery subnet -o ground           (ground)
  quad-modelling run-bag bags/nanobench_B7_oval_medium_rep2 --models greybox --record -o recorded
  quad-modelling run-bag bags/flight --models greybox,narx:narx.npz --train 30:150 --eval 150:190 --rate 0 -o flight_live
"""

STOP_TIMEOUT_S = 30.0
"""How long a node may take to exit after SIGINT (the evaluator writes its report then) [s]."""


class NodeFailedError(QuadModellingError, RuntimeError):
    """A node of the graph died, a node expected on another host never appeared, or the run did not finish in time."""


NODE_GROUPS = ("replay", "predictors", "evaluator")
"""``--nodes``: the parts of the graph one run-bag can start (``predictors`` = one per model)."""


def parse_nodes(text: str) -> tuple[str, ...]:
    """``replay,evaluator`` -> the groups of :data:`NODE_GROUPS` to start here, in that order; ConfigError naming the
    valid names for an unknown or empty list."""
    given = [item.strip() for item in text.split(",") if item.strip()]
    unknown = [item for item in given if item not in NODE_GROUPS]
    if unknown or not given:
        what = f"unknown node {unknown[0]!r}" if unknown else "no node named"
        raise ConfigError(f"--nodes {text!r}: {what}; valid: {', '.join(NODE_GROUPS)} (comma-separated)")
    return tuple(group for group in NODE_GROUPS if group in given)


@dataclass
class ModelEntry:
    name: str
    spec: str


RUN_BAG_MARKERS = ("results.json", "params.yaml")
"""What marks an earlier run-bag output (--force replaces it): its results, or the params.yaml every run writes (a run
without the evaluator, ``--nodes replay,predictors``, writes no results)."""
MAX_RATE = 1.0e6
"""The fastest replay ``--rate``: a million times real time (a 220 s flight in 0.22 ms of wall time) is far beyond what
any graph keeps up with; the replay node's clock arithmetic overflowed at 1e308."""


def parse_models(text: str) -> list[ModelEntry]:
    """``naive,greybox,b=narx:b.npz`` -> entries; ConfigError for empty or duplicate names."""
    entries = []
    items = [s.strip() for s in text.split(",")]
    if len(items) > 1 and not all(items):  # as --effects: 'greybox,,naive' is a typo, not two models
        raise ConfigError(f"--models {text!r}: an empty entry in the list (a comma too many?); name each model once")
    for item in filter(None, items):
        name, spec = named_spec(item, "--models")
        entries.append(ModelEntry(name or spec.partition(":")[0].strip(), spec))
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", entries[-1].name):  # a spec's kind names its node
            raise ConfigError(f"--models {text!r}: bad entry {item!r}; expected SPEC or NAME=SPEC")
        if baseline_name_clash(entries[-1].name, spec):  # naive:foo would take the baseline's name and topics
            raise ConfigError(f"--models {text!r}: {baseline_name_clash(entries[-1].name, spec)}")
    if not entries:
        raise ConfigError("--models: give at least one model spec")
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise ConfigError(f"--models {text!r}: model names {names} repeat; name them NAME=SPEC")
    return entries


def span_list(args: argparse.Namespace) -> list[str]:
    """The evaluator's ``spans`` (``NAME:A:B``) of --train/--eval, or ``live:0:inf``; ConfigError when malformed."""
    spans = [f"train:{args.train}"] if args.train else []
    spans += [f"eval:{args.eval}"] if args.eval else []
    spans = spans or ["live:0:inf"]
    return [span.name + ":" + span.text() for span in seconds_spans(spans)]


class RemoteNodes:
    """What this run-bag sees of the nodes it expects on other hosts: their names in the ROS graph and the
    replay's ``replay/done``. One rclpy context and node (``run_bag_<pid>``) of this process, created with the
    nodes' environment ``env`` (domain, discovery, Fast DDS profile)."""

    def __init__(self, env: dict):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rosgraph_msgs.msg import Clock

        from quad_modelling.io import topics
        from quad_modelling.nodes.common import latched_qos

        saved = dict(os.environ)
        os.environ.update(env)  # read by rcl/Fast DDS while the context and participant are created
        try:
            self.context = Context()
            rclpy.init(context=self.context, domain_id=int(env["ROS_DOMAIN_ID"]))
            self.node = rclpy.create_node(f"run_bag_{os.getpid()}", namespace=topics.DEFAULT_NAMESPACE, context=self.context,
                                          enable_rosout=False, start_parameter_services=False)
        finally:
            os.environ.clear()
            os.environ.update(saved)
        self.done_ns: int | None = None
        self.node.create_subscription(Clock, topics.DONE_TOPIC, self._on_done, latched_qos())
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _on_done(self, msg) -> None:
        from quad_modelling.io.topics import stamp_ns

        self.done_ns = stamp_ns(msg.clock)

    def spin(self, seconds: float) -> None:
        """Handle what arrived, waiting up to ``seconds`` [s]."""
        self.executor.spin_once(timeout_sec=seconds)

    def missing(self, names: list[str]) -> list[str]:
        """Those of the fully qualified node ``names`` (``/quad/evaluator``) not in the graph now."""
        present = {f"{ns.rstrip('/')}/{name}" for name, ns in self.node.get_node_names_and_namespaces()}
        return [n for n in names if n not in present]

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


class Graph:
    """The node processes, their log files and how to stop them."""

    def __init__(self, workdir: Path, params_file: Path, env: dict):
        self.workdir = workdir
        self.params_file = params_file
        self.env = env
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}

    def start(self, name: str, module: str, remap_name: str | None = None) -> None:
        """Start node ``name`` (``python -m quad_modelling.nodes.<module>``, node name ``remap_name``) with its log file."""
        log = self.workdir / "logs" / f"{name}.log"
        self.logs[name] = log
        argv = [sys.executable, "-m", f"quad_modelling.nodes.{module}", "--ros-args", "--params-file", str(self.params_file)]
        if remap_name:
            argv += ["-r", f"__node:={remap_name}"]
        with log.open("w") as handle:
            self.procs[name] = subprocess.Popen(argv, stdout=handle, stderr=subprocess.STDOUT, env=self.env,
                                                stdin=subprocess.DEVNULL, start_new_session=True)

    def tail(self, name: str, lines: int = 12) -> str:
        try:
            text = self.logs[name].read_text(errors="replace").splitlines()
        except OSError:
            return "(no log)"
        return "\n".join("    " + line for line in text[-lines:])

    def dead(self, exclude: tuple[str, ...] = ()) -> list[str]:
        return [n for n, p in self.procs.items() if n not in exclude and p.poll() is not None]

    def stop(self, names: list[str] | None = None, timeout: float = STOP_TIMEOUT_S) -> None:
        names = [n for n in (names or list(self.procs)) if self.procs[n].poll() is None]
        for n in names:
            self._signal(n, signal.SIGINT)
        deadline = time.monotonic() + timeout
        for n in names:
            try:
                self.procs[n].wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                self._signal(n, signal.SIGTERM)
                try:
                    self.procs[n].wait(5)
                except subprocess.TimeoutExpired:
                    self._signal(n, signal.SIGKILL)
                    self.procs[n].wait()

    def _signal(self, name: str, signum: int) -> None:
        """``signum`` to the node's process group (each node is a session of its own: its children too)."""
        proc = self.procs[name]
        try:
            os.killpg(proc.pid, signum)
        except ProcessLookupError:
            pass
        except PermissionError:
            proc.send_signal(signum)


RECORD_NAME = "record"
"""The recording's bag directory inside OUTDIR (``--record``)."""

REPLAY_PATIENCE_S = 60.0
"""How long [wall s] the evaluator waits for a lagging predictor before marking its window, in run-bag."""


TRUTH_NOTES_NAME = "truth_notes.json"
"""The bag's simulator notes, written for the ``truth`` model's predictor nodes (their windows carry no notes)."""


def is_truth(m: ModelEntry) -> bool:
    """The ``truth`` model (:mod:`quad_modelling.core.sim.truth_model`): its nodes need the bag's simulator notes."""
    return m.spec.partition(":")[0].strip() == "truth"


def live_spec(m: ModelEntry, truth_notes: Path | None) -> str:
    """The spec a predictor node runs: ``truth`` gets the notes file (``truth:NOTES.json``), unless its spec names one."""
    kind, _, arg = m.spec.partition(":")
    if not is_truth(m) or truth_notes is None or any(part.endswith(".json") for part in arg.split(",")):
        return m.spec
    return f"{kind}:{','.join([str(truth_notes), *([arg] if arg else [])])}"


def node_parameters(args, models: list[ModelEntry], vehicle: str, spans: list[str], report_dir: Path,
                    record: Path | None = None, truth_notes: Path | None = None, battery: bool = False) -> dict:
    """Every node's parameters (one params file; every host of a split graph writes the same but its report paths).
    Subscriptions are reliable: the paced replay is lossless. The evaluator waits for the models' publishers and the
    replay for its subscribers and first acknowledgement as long as run-bag waits for remote nodes."""
    common = {"vehicle": vehicle, "window_s": float(args.window), "warm_s": float(args.warm), "executor": args.executor,
              "qos": "replay"}
    params = {
        # A replayed bag waits for slow predictors (a busy machine) instead of marking their windows:
        # run-bag itself reports a predictor that dies.
        "/quad/evaluator": {"ros__parameters": {**common, "models": [m.name for m in models], "spans": spans,
                                                "output_dir": str(report_dir), "force": True, "figures": not args.no_figures,
                                                "stale_model_s": REPLAY_PATIENCE_S, "close_grace_s": REPLAY_PATIENCE_S,
                                                "ready_timeout_s": float(args.remote_timeout),
                                                "record": str(record) if record else ""}},
        "/quad/replay": {"ros__parameters": {"bag": str(Path(args.bag).resolve()), "rate": float(args.rate),
                                             "executor": args.executor, "vehicle": vehicle,
                                             "startup_timeout_s": float(args.remote_timeout),
                                             "wait_for_subscribers": len(models) + 1}},
    }
    for m in models:
        node = {**common, "model": live_spec(m, truth_notes), "model_name": m.name}
        if is_truth(m) and battery:  # the battery effect's ESC scaling reads the logged voltage
            node["battery_topic"] = "battery"
        params[f"/quad/{m.name}_predictor"] = {"ros__parameters": node}
    return params


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="rosbag2 bag directory: the topic contract, or another stack's topics (--topic-map)")
    parser.add_argument("--models", default="naive", metavar="SPEC,...", help="models to run live (default naive)")
    parser.add_argument("--vehicle", metavar="NAME|FILE", help="vehicle config (default: the one the bag names)")
    add_topic_map_argument(parser)
    parser.add_argument("--rate", type=float, default=0.0, metavar="R",
                        help="real-time factor of the replay; 0 = as fast as the graph keeps up without loss (default); "
                             "> 0 can lose samples on a busy machine: each stream's loss one warning line, exit code 1")
    parser.add_argument("--window", type=float, default=EvaluationConfig.window_s, metavar="SECONDS",
                        help=f"window length (default {EvaluationConfig.window_s:g})")
    parser.add_argument("--warm", type=float, default=EvaluationConfig.warm_s, metavar="SECONDS",
                        help=f"warm start (default {EvaluationConfig.warm_s:g})")
    parser.add_argument("--train", metavar="A:B", help="training span, seconds from the first sample")
    parser.add_argument("--eval", metavar="C:D", help="evaluation span, seconds from the first sample")
    parser.add_argument("--timeout", type=float, default=900.0, metavar="SECONDS", help="give up after this long (default 900)")
    parser.add_argument("--no-figures", action="store_true", help="skip the figures")
    parser.add_argument("--no-multistep", action="store_true", help="skip the multi-step table")
    parser.add_argument("--nodes", default=",".join(NODE_GROUPS), metavar="NODE,...",
                        help="nodes started here, of replay, predictors, evaluator (default all); the others are expected on "
                             "another host in the same ROS_DOMAIN_ID")
    parser.add_argument("--discovery", choices=DISCOVERY_MODES, default="localhost",
                        help="localhost (default: loopback only), subnet (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET; "
                             "ROS_STATIC_PEERS kept) or env (your ROS_AUTOMATIC_DISCOVERY_RANGE / ROS_STATIC_PEERS as set)")
    parser.add_argument("--remote-timeout", type=float, default=60.0, metavar="SECONDS",
                        help="wait this long for the nodes expected on another host (default 60)")
    parser.add_argument("--executor", choices=EXECUTORS, default="events",
                        help="rclpy executor of every node: events (EventsExecutor, default) or single (SingleThreadedExecutor)")
    parser.add_argument("--record", action="store_true",
                        help="also record measurements, predictions and evaluation into OUTDIR/record (one MCAP bag, zstd "
                             "chunks; open it in Foxglove with config/foxglove_layout.json)")
    parser.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="new output directory")
    parser.add_argument("--force", action="store_true", help="overwrite an existing OUTDIR")


def run(args: argparse.Namespace) -> int:
    """Replay a contract bag through the live graph; a bag of another stack (a topic map other than ``quad``) is read
    through its map and written as a contract bag in a temporary directory first (the replay publishes the contract)."""
    import tempfile

    from quad_modelling.commands.evaluate import print_flight_warnings
    from quad_modelling.core.vehicle import vehicle_file
    from quad_modelling.io.bag_io import read_bag_metadata, write_bag
    from quad_modelling.io.loader import load_flight
    from quad_modelling.io.topic_maps import CONTRACT_NAMESPACE, choose_topic_map, topic_map_file

    check_command_output(Path(args.output), args.force, inputs=[args.bag, vehicle_file(args.vehicle), topic_map_file(args.topic_map)],
                         markers=RUN_BAG_MARKERS)
    chosen = choose_topic_map(read_bag_metadata(args.bag).topics, str(args.bag), args.topic_map)
    if chosen.is_contract and chosen.namespace == CONTRACT_NAMESPACE:
        return _run(args)
    flight = load_flight(args.bag, vehicle=args.vehicle, topic_map=args.topic_map)
    print_flight_warnings([flight])  # as evaluate prints them for this bag (the contract bag names a temporary path)
    if flight.acc_b is None or flight.gyro_b is None:  # the live nodes start from imu messages
        imu = " or ".join(dict.fromkeys(s.topic for f in ("acc", "gyro") for s in chosen.fields.get(f, ()))) or "no topic"
        raise ConfigError(f"{args.bag}: run-bag needs an IMU (the live nodes start from imu messages); topic map {chosen.name} "
                          f"reads it from {imu}, which the bag lacks; evaluate it offline with quad-modelling evaluate")
    with tempfile.TemporaryDirectory(prefix="quad_run_bag_") as staging:
        converted = write_bag(flight, Path(staging) / "contract_bag")
        print(f"{args.bag}: read through topic map {chosen.name} ({len(flight)} samples); replaying it in the topic contract", flush=True)
        return _run(argparse.Namespace(**{**vars(args), "bag": str(converted), "source_bag": args.bag,
                                          "vehicle": args.vehicle or flight.meta.vehicle}), warned=True)


def _run(args: argparse.Namespace, warned: bool = False) -> int:
    from quad_modelling.commands.evaluate import print_flight_warnings
    from quad_modelling.core.vehicle import load_vehicle, vehicle_file
    from quad_modelling.io.bag_io import read_bag_metadata
    from quad_modelling.io.loader import load_flight
    from quad_modelling.io.reports.evaluation import live_summary_table, multistep_lines
    from quad_modelling.nodes.model_factory import make_streaming_predictor

    output = Path(args.output)
    models = parse_models(args.models)
    here = parse_nodes(args.nodes)
    remote = tuple(group for group in NODE_GROUPS if group not in here)
    model_files = [m.spec.partition(":")[2] for m in models if m.spec.partition(":")[0] in MODEL_FILE_KINDS]
    check_command_output(output, args.force, inputs=[args.bag, vehicle_file(args.vehicle), *model_files], directory=True,
                         markers=RUN_BAG_MARKERS)
    for flag, value in (("--rate", args.rate), ("--window", args.window), ("--warm", args.warm), ("--timeout", args.timeout),
                        ("--remote-timeout", args.remote_timeout)):
        if not math.isfinite(value):
            raise ConfigError(f"{flag} {value}: must be a finite number")
    if not 0 <= args.rate <= MAX_RATE:  # 1e308 failed inside the replay node, in five lines of its log (review)
        raise ConfigError(f"--rate {args.rate:g}: must be >= 0 and at most {MAX_RATE:g} (times real time; 0 = paced, lossless)")
    if not 0 < args.warm < args.window <= MAX_SECONDS:  # checked before any node starts (the evaluator's config is later)
        raise ConfigError(f"--window {args.window:g} / --warm {args.warm:g}: need 0 < warm < window <= {MAX_SECONDS:g} s")
    for flag, value in (("--timeout", args.timeout), ("--remote-timeout", args.remote_timeout)):
        if not value > 0:
            raise ConfigError(f"{flag} {value}: must be a positive number of seconds")
    if args.record and "evaluator" not in here:
        raise ConfigError(f"--record with --nodes {','.join(here)}: the evaluator records; pass --record on its host")
    spans = span_list(args)
    bag = read_bag_metadata(args.bag)  # metadata.yaml only: the replay node reads the messages
    bag.require_live_topics()
    vehicle_name = args.vehicle or bag.vehicle
    if not vehicle_name:
        raise ConfigError(f"{args.bag}: the bag names no vehicle; pass --vehicle NAME")
    vehicle = load_vehicle(vehicle_name)
    flight = load_flight(args.bag, vehicle=vehicle, fmt="bag")  # the whole bag before any node starts: a damaged bag is one line
    if not warned:  # a bag of another stack: run printed them as read through its map
        print_flight_warnings([flight])  # as evaluate prints them, once
    check_window_rate(flight)  # the evaluator would mark every window of a flight this slow
    if args.rate > 0 and flight.duration / args.rate > args.timeout:  # 1e-300 was accepted, then timed out (review)
        raise ConfigError(f"--rate {args.rate:g}: the {flight.duration:.1f} s flight would replay for {flight.duration / args.rate:.3g} s, "
                          f"longer than --timeout {args.timeout:g} s (raise --timeout, or --rate 0: paced by the nodes)")
    empty = spans_without_a_window(spans, flight.duration, float(args.window))
    if len(empty) == len(seconds_spans(spans)):  # the graph would run and score nothing (evaluate refuses it so)
        raise ConfigError(f"{args.bag}: no {float(args.window):g} s window fits any span ({empty[0]}"
                          f"{f'; and {len(empty) - 1} more' if len(empty) > 1 else ''}): use a shorter --window or other spans")
    for note in empty:
        print(f"warning: {args.bag}: {note}", file=sys.stderr)
    for m in models:  # fail fast, in this process, on an unknown model or a bad model file
        check = getattr(make_streaming_predictor(m.spec, vehicle), "check_flight", None)
        if check is not None:
            check(flight)  # a model that cannot predict this bag (truth without simulator notes): one line naming it
    env = ros_environment(args.discovery, remote)
    local_nodes = graph_nodes(here, models)
    remote_nodes = [f"/quad/{n}" for n in graph_nodes(remote, models)]
    if remote:
        print(f"starting {', '.join(local_nodes)} here; expecting {', '.join(remote_nodes)} on another host "
              f"(ROS_DOMAIN_ID {env['ROS_DOMAIN_ID']}, discovery {env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', 'default')}"
              f"{', static peers ' + env['ROS_STATIC_PEERS'] if env.get('ROS_STATIC_PEERS') else ''})", flush=True)
    started = time.monotonic()
    with atomic_output(output, args.force, markers=RUN_BAG_MARKERS) as tmp:
        tmp.mkdir()
        (tmp / "logs").mkdir()
        report_dir = tmp / "report"
        params_file = tmp / "params.yaml"
        record = tmp / RECORD_NAME if args.record else None
        truth_notes = None
        if any(is_truth(m) for m in models):
            truth_notes = tmp / TRUTH_NOTES_NAME
            truth_notes.write_text(json.dumps(flight.meta.notes))
        params_file.write_text(yaml.safe_dump(node_parameters(args, models, vehicle_name, spans, report_dir, record, truth_notes,
                                                              flight.vbat is not None), sort_keys=False))
        graph = Graph(tmp, params_file, env)
        watch = RemoteNodes(env) if remote else None
        try:
            if "evaluator" in here:
                graph.start("evaluator", "evaluator_node")
            if "predictors" in here:
                for m in models:
                    graph.start(f"{m.name}_predictor", "predictor_node", remap_name=f"{m.name}_predictor")
            if watch is not None:
                _wait_for_remote(graph, watch, remote_nodes, args.remote_timeout, env)
            if "replay" in here:
                graph.start("replay", "replay_node")
                _wait_for_replay(graph, args.timeout, started)
            else:
                _wait_for_remote_replay(graph, watch, args.timeout, started)
            graph.stop([n for n in graph.procs if n != "evaluator"])
            graph.stop(["evaluator"] if "evaluator" in graph.procs else [])
        finally:
            graph.stop()
            if watch is not None:
                watch.close()
        failed = {n: p.returncode for n, p in graph.procs.items() if p.returncode not in (0, -signal.SIGINT)}
        if failed:
            name = next(iter(failed))
            raise _failure(graph, name, f"node {name} exited with code {failed[name]}")
        if "evaluator" in here:
            if not (report_dir / "results.json").is_file():
                raise _failure(graph, "evaluator", "the evaluator wrote no results")
            if record is not None and not (record / "metadata.yaml").is_file():
                raise _failure(graph, "evaluator", "the evaluator wrote no recording")
        samples = sample_counts(args.bag, graph, report_dir / "results.json")
        if "evaluator" in here:
            complete_results(report_dir, flight, models, vehicle, args, samples)
            for item in report_dir.iterdir():
                shutil.move(str(item), tmp / item.name)
            report_dir.rmdir()
        name_final_paths([params_file, *sorted((tmp / "logs").glob("*.log"))], {report_dir: output, tmp: output})
    # samples lost (--rate > 0 on a busy machine): a line per stream; output written, exit 1 as --skip-bad (docs/cli.md)
    lost = "".join(f"warning: sample loss: {line}\n" for line in samples["loss"])
    if "evaluator" not in here:
        print(lost, end="", file=sys.stderr, flush=True)
        print(f"{', '.join(local_nodes)} done in {time.monotonic() - started:.1f} s (ROS_DOMAIN_ID {env['ROS_DOMAIN_ID']}); "
              f"the evaluator on the other host writes the results; logs in {output}/logs/")
        return 1 if lost else 0
    elapsed = time.monotonic() - started
    results = json.loads((output / "results.json").read_text())
    print(live_summary_table(results, [m.name for m in models]))
    for line in ["", *multistep_lines(results.get("horizons") or {}, align=True)]:
        print(line, flush=True)
    print(lost, end="", file=sys.stderr, flush=True)
    print(f"\n{bag.duration_s:.1f} s of flight replayed in {elapsed:.1f} s (ROS_DOMAIN_ID {env['ROS_DOMAIN_ID']}); "
          f"results in {output}/ (results.json, tables.md, logs/)"
          + (f"; samples lost on {len(samples['loss'])} stream(s): the live scores rest on incomplete input" if lost else ""))
    return 1 if lost else 0


def sample_counts(bag: str, graph: Graph, results_file: Path) -> dict:
    """results.json ``live.samples`` (:func:`~quad_modelling.io.reports.evaluation.sample_accounting`): what the replay
    plays of ``bag`` and each local predictor published, against what the nodes started here received (the evaluator's
    ``results_file``, when it ran here, and the predictors' exit summaries in their logs)."""
    from quad_modelling.io.reports.evaluation import sample_accounting
    from quad_modelling.nodes.replay_node import played_counts

    evaluator = json.loads(results_file.read_text())["live"].get("received") if results_file.is_file() else None
    logs = {name: log.read_text(errors="replace") for name, log in graph.logs.items() if name.endswith("_predictor")}
    return sample_accounting(played_counts(bag), evaluator, logs)


def _failure(graph: Graph, name: str, what: str) -> NodeFailedError:
    """Print the node's log tail on stderr (the output directory is not kept on failure) and
    return the one-line error: what happened and the node's last log line."""
    tail = graph.tail(name)
    print(f"--- last lines of the {name} log ---\n{tail}\n---", file=sys.stderr)
    last = next((line.strip() for line in reversed(tail.splitlines()) if line.strip()), "(empty log)")
    return NodeFailedError(f"{what}; its last log line: {last}")


def graph_nodes(groups: tuple[str, ...], models: list[ModelEntry]) -> list[str]:
    """The node names of ``groups`` (:data:`NODE_GROUPS`): ``evaluator``, ``<model>_predictor``..., ``replay``."""
    names = ["evaluator"] if "evaluator" in groups else []
    names += [f"{m.name}_predictor" for m in models] if "predictors" in groups else []
    return names + (["replay"] if "replay" in groups else [])


def _wait_for_remote(graph: Graph, watch: RemoteNodes, names: list[str], timeout: float, env: dict) -> None:
    """Wait until every node of ``names`` (fully qualified) is in the graph; NodeFailedError naming those that never
    appeared within ``timeout`` [s], or a local node that died meanwhile."""
    deadline = time.monotonic() + timeout
    missing = watch.missing(names)
    while missing:
        dead = graph.dead()
        if dead:
            raise _failure(graph, dead[0], f"node {dead[0]} died early (exit code {graph.procs[dead[0]].returncode})")
        if time.monotonic() > deadline:
            peers = env.get("ROS_STATIC_PEERS")
            raise NodeFailedError(
                f"{', '.join(missing)} never appeared within --remote-timeout {timeout:g} s (ROS_DOMAIN_ID {env['ROS_DOMAIN_ID']}, "
                f"discovery {env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', 'default')}{', static peers ' + peers if peers else ''}); "
                "start run-bag with the other --nodes on the other host, in the same domain, with a discovery that reaches it")
        watch.spin(0.1)
        missing = watch.missing(names)
    print(f"{', '.join(names)} found on another host", flush=True)


def _wait_for_remote_replay(graph: Graph, watch: RemoteNodes, timeout: float, started: float) -> None:
    """Wait for the remote replay's ``replay/done``, while every local node lives and ``timeout`` [s] allows."""
    while watch.done_ns is None:
        dead = graph.dead()
        if dead:
            raise _failure(graph, dead[0], f"node {dead[0]} died early (exit code {graph.procs[dead[0]].returncode})")
        if time.monotonic() - started > timeout:
            raise NodeFailedError(f"the replay on the other host did not announce its end (replay/done) within --timeout {timeout:g} s")
        watch.spin(0.1)


def _wait_for_replay(graph: Graph, timeout: float, started: float) -> None:
    replay = graph.procs["replay"]
    while replay.poll() is None:
        dead = graph.dead(exclude=("replay",))
        if dead:
            raise _failure(graph, dead[0], f"node {dead[0]} died early (exit code {graph.procs[dead[0]].returncode})")
        if time.monotonic() - started > timeout:
            raise _failure(graph, "replay", f"run did not finish within --timeout {timeout:g} s")
        time.sleep(0.1)
    if replay.returncode != 0:
        raise _failure(graph, "replay", f"replay exited with code {replay.returncode}")


def complete_results(report_dir: Path, flight, models: list[ModelEntry], vehicle, args: argparse.Namespace, samples: dict) -> None:
    """Add to the evaluator's results.json the flight (fingerprint: ``merge`` tells flights apart) and the spec of each
    named model (as evaluate's), the samples sent and received per stream (``live.samples``: :func:`sample_counts`)
    and, unless --no-multistep, the multi-step table of every model (its sums in ``statistics``), each model's live
    form from every start of the --eval span (the whole bag without one); tables.md written again. With --train and
    --eval it is the results.json ``evaluate BAG --drop 0:0`` writes, for ``merge``."""
    from quad_modelling.core.evaluation.multistep import flight_multistep_sums, multistep_table
    from quad_modelling.core.models.base import DummyPredictor
    from quad_modelling.core.preprocess import resample_uniform
    from quad_modelling.io.reports.evaluation import tables_text
    from quad_modelling.io.reports.formatting import json_text
    from quad_modelling.nodes.model_factory import make_streaming_predictor

    results_file = report_dir / "results.json"
    results = json.loads(results_file.read_text())
    named = {m.name: m.spec for m in models if m.name != m.spec.partition(":")[0]}  # given as NAME=SPEC
    results["config"]["flights"] = [{"source": str(getattr(args, "source_bag", args.bag)), "live": True, "duration_s": flight.duration,
                                     "sample_rate_hz": flight.sample_rate, "fingerprint": flight.fingerprint()}]
    if results.get("statistics") is not None and named:
        results["statistics"]["model_specs"] = named
    results["live"]["samples"] = samples
    if not args.no_multistep:
        predictors = []
        for m in models:
            predictor = make_streaming_predictor(m.spec, vehicle)
            predictor.name = m.name  # the topic name the tables use
            predictors.append(predictor)
        config = EvaluationConfig(drop_start=0.0, drop_end=0.0, train=args.train or "0:inf", eval=args.eval or "0:inf",
                                  window_s=float(args.window), warm_s=float(args.warm))
        baseline = [] if "dummy" in [m.name for m in models] else [DummyPredictor()]  # listed as not multi-step, as offline
        sums = flight_multistep_sums(resample_uniform(flight), predictors + baseline, vehicle, config)
        results["horizons"] = multistep_table(sums, config)
        if not args.eval:
            results["horizons"]["span"] = "live (whole bag)"
        results["config"]["horizons"] = list(config.horizons)
        if results.get("statistics") is not None:  # as evaluate's: merge reads them
            results["statistics"].update(multistep=sums.to_json(), durations_s=[flight.duration])
    results_file.write_text(json_text(results))
    title = f"Live evaluation of {', '.join(m.name for m in models)} on vehicle {vehicle.name}"
    (report_dir / "tables.md").write_text(tables_text(results, title, named))
