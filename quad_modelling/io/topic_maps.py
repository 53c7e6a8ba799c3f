"""Topic maps: which topic and message field of a recording gives which flight field (DESIGN 5a).

A topic map is a YAML document (the shipped ones: ``config/topic_maps/*.yaml``, documented in
docs/formats.md)::

    name: px4
    default_vehicle: px4_iris              # when neither --vehicle nor the bag names one
    topics:                                # every topic the map reads
      /fmu/out/vehicle_odometry: {type: px4_msgs/msg/VehicleOdometry, stamp: timestamp_sample, stamp_unit: us}
      /fmu/out/battery_status: {type: px4_msgs/msg/BatteryStatus, stamp: timestamp, stamp_unit: us,
                                instance: id, optional: true}
      /{robot}/log_imu: {type: crazyflie_interfaces/msg/LogDataGeneric, stamp: header.stamp,
                         vars: [acc.x, acc.y, acc.z, gyro.x, gyro.y, gyro.z]}
    fields:                                # flight field -> source (or a list of alternatives, first present wins)
      position: {topic: /fmu/out/vehicle_odometry, fields: ["position[0]", "position[1]", "position[2]"],
                 unit: m, frame: NED}

Flight fields (:data:`FLIGHT_FIELDS`): ``commands`` (4, the vehicle's input unit, see below),
``position`` (3, world ``ENU``/``NED``), ``attitude`` (4, quaternion, ``order`` ``xyzw``/``wxyz``,
frame ``ENU/FLU`` or ``NED/FRD`` = the body-to-world rotation), ``velocity`` (3, world ``ENU``/``NED`` or
body ``FLU``/``FRD``), ``acc`` (3, specific force, body ``FLU``/``FRD``), ``gyro`` (3, body rates) and
``battery`` (1, voltage). The first four are required; the others are read when their topic is in the
bag. Units come from :data:`~quad_modelling.core.frames.UNIT_FACTORS` (``m``, ``mm``, ``m/s``,
``m/s2``, ``g``, ``rad/s``, ``deg/s``, ``V``) and must have the field's dimension.

Commands: ``unit`` is the unit the commands are in (``normalised``, ``PWM``, ``us``, ...; ``vehicle``: the
vehicle's own input unit, as the project's contract) and ``range: [low, high]`` what they span. A vehicle
taking that unit gets them as they are, one taking a unit of the same kind converted (``us`` for a vehicle in
``s``); any other vehicle gets them mapped linearly from ``range`` onto its
input range ``[inputs.min, inputs.max]``, so a PX4 ``actuator_motors`` recording (0..1) is read for a
vehicle in PWM or in normalised units alike.

Message field paths: attributes and indexes, ``pose.position.x``, ``q[0]``; ``values[acc.x]`` indexes a
sequence by the topic's ``vars`` (crazyswarm2 log blocks publish their values in the order of the block's
vars). Stamps: ``stamp`` is a builtin_interfaces/Time field (``header.stamp``) or an integer field with its
``stamp_unit`` (``s``, ``ms``, ``us``, ``ns``). ``instance``: a field telling apart several publishers of
one topic (PX4 multi-instance topics, as ULog instance 0): the first instance seen is read, the notes say
how many there were. ``frame_field`` and ``frames``: a message field naming each message's frame (PX4's
``velocity_frame: 1 NED, 3 body FRD``) and its values' frames, each the source's ``frame`` or a body frame rotated into
it by the same message's attitude; a value not listed is refused (:mod:`quad_modelling.io.field_conversion`).
``{robot}`` in a topic name stands for one ROS name token (the crazyswarm2 robot
name); a bag of several robots is named with ``--topic-map crazyswarm2:cf231``.

This module holds the definitions, their validation (one line naming file and key), the choice of a map
for a bag's topics (:func:`choose_topic_map`, namespaces included) and the check of a map's paths against the
message definitions a bag stores (:func:`check_map_fields`); :mod:`quad_modelling.io.mapped_flight` reads the
messages, :mod:`quad_modelling.io.field_conversion` converts their numbers.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path

from quad_modelling.core import frames
from quad_modelling.core.input_files import read_yaml, yaml_number
from quad_modelling.core.vehicle import config_dir
from quad_modelling.errors import BagError, ConfigError
from quad_modelling.io.topics import check_namespace

CONTRACT_MAP = "quad"
CONTRACT_NAMESPACE = "/quad"
"""The namespace of the contract map's topics as shipped (``io.topics.DEFAULT_NAMESPACE``)."""
CONTRACT_COMMANDS = "/motor_input"
"""The contract's command topic, relative to its namespace: what tells a bag's contract namespace."""
"""The project's own contract (DESIGN 5a): read by :func:`quad_modelling.io.bag_io.read_bag`, bit for bit as before maps."""

ROBOT = "{robot}"
"""Placeholder for one ROS name token in a topic name (the crazyswarm2 robot name)."""

FLIGHT_FIELDS = {
    # field: (components, SI unit the field's unit must have (None: see module doc), frames, required)
    "commands": (4, None, (), True),
    "position": (3, "m", ("ENU", "NED"), True),
    "attitude": (4, None, ("ENU/FLU", "NED/FRD"), True),
    "velocity": (3, "m/s", ("ENU", "NED", "FLU", "FRD"), True),
    "acc": (3, "m/s2", ("FLU", "FRD"), False),
    "gyro": (3, "rad/s", ("FLU", "FRD"), False),
    "battery": (1, "V", (), False),
}
"""The flight fields a map can give (module doc)."""

QUATERNION_ORDERS = ("xyzw", "wxyz")
STAMP_UNITS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
"""Integer stamp units and their nanoseconds."""

COMMAND_UNITS = ("vehicle", "normalised", *frames.UNIT_FACTORS)
"""Units a map's commands may be in: the vehicle's own, normalised (0..1 ratio) or a unit of UNIT_FACTORS."""

_STEP = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[[^\]]+\])*)$")
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
TOPIC_KEYS = {"type", "stamp", "stamp_unit", "vars", "instance", "optional"}
SOURCE_KEYS = {"topic", "fields", "unit", "frame", "order", "range", "frame_field", "frames"}
WORLD_FRAMES, BODY_FRAMES = ("ENU", "NED"), ("FLU", "FRD")


def topic_maps_dir():
    """Where the shipped topic maps are: ``config/topic_maps``."""
    return config_dir() / "topic_maps"


@dataclass(frozen=True)
class TopicSpec:
    """One topic a map reads: its message type, stamp field and unit, log-block vars, instance field."""

    name: str
    msgtype: str
    stamp: str
    stamp_unit: str | None
    """None: ``stamp`` is a builtin_interfaces/Time; else the integer field's unit (:data:`STAMP_UNITS`)."""
    vars: tuple[str, ...] | None = None
    instance: str | None = None
    optional: bool = False


@dataclass(frozen=True)
class FieldSource:
    """Where one flight field comes from: topic, message field paths (one per component), unit, frame, order, range."""

    field: str
    topic: str
    paths: tuple[str, ...]
    unit: str | None = None
    frame: str | None = None
    order: str = "xyzw"
    range: tuple[float, float] | None = None
    frame_field: str | None = None
    """The message field naming each message's frame (``frames``: its values -> frames), or None: always ``frame``."""
    frames: tuple[tuple[int, str], ...] = ()


@dataclass(frozen=True)
class TopicMap:
    """A validated topic map (module doc). ``fields``: flight field -> its sources, the first present in a bag wins."""

    name: str
    description: str
    origin: str
    topics: dict[str, TopicSpec]
    fields: dict[str, tuple[FieldSource, ...]]
    default_vehicle: str | None = None

    @property
    def is_contract(self) -> bool:
        return self.name == CONTRACT_MAP and self.origin == "built-in"

    @property
    def namespace(self) -> str:
        """The contract's topic namespace (``/quad`` unless :meth:`in_namespace` moved it); ``/quad`` for other maps."""
        motor = next((name for name in self.topics if name.endswith(CONTRACT_COMMANDS)), None)
        return motor[: -len(CONTRACT_COMMANDS)] or "/" if self.is_contract and motor else CONTRACT_NAMESPACE

    def in_namespace(self, namespace: str) -> TopicMap:
        """The map with its topics under ``namespace``: the contract's ``/quad`` replaced (a bag written by ``convert
        --namespace``), any other map's topics prefixed (PX4's multi-vehicle ``/px4_1/fmu/out/...``)."""
        def sub(name: str) -> str:
            rest = name[len(CONTRACT_NAMESPACE):] if self.is_contract else name
            return namespace.rstrip("/") + rest
        return replace(self, topics={sub(n): replace(t, name=sub(n)) for n, t in self.topics.items()},
                       fields={f: tuple(replace(s, topic=sub(s.topic)) for s in sources) for f, sources in self.fields.items()})

    def namespaces(self, bag_topics) -> list[str]:
        """The namespaces under which ``bag_topics`` hold one of the map's command topics (``/a/b/motor_input`` ->
        ``/a/b`` for the contract, whose own namespace is ``/quad``; ``/px4_1/fmu/out/actuator_motors`` -> ``/px4_1``)."""
        if self.is_contract:
            return contract_namespaces(bag_topics)
        commands = [s.topic for s in self.fields.get("commands", ())]
        found = {t[: -len(c)] for t in bag_topics for c in commands if t.endswith(c) and len(t) > len(c)}
        return sorted(ns for ns in found if ns.startswith("/") and not ns.endswith("/"))

    @property
    def has_robot(self) -> bool:
        return any(ROBOT in name for name in self.topics)

    def bind(self, robot: str) -> TopicMap:
        """The map with ``{robot}`` replaced by ``robot`` in every topic name."""
        def sub(name: str) -> str:
            return name.replace(ROBOT, robot)
        return replace(self, topics={sub(n): replace(t, name=sub(n)) for n, t in self.topics.items()},
                       fields={f: tuple(replace(s, topic=sub(s.topic)) for s in sources) for f, sources in self.fields.items()})

    def robots(self, bag_topics) -> list[str]:
        """The robot names for which some topic of the map is in ``bag_topics`` (maps with ``{robot}``)."""
        found = set()
        for pattern in self.topics:
            if ROBOT in pattern:
                regex = re.compile("^" + re.escape(pattern).replace(re.escape(ROBOT), f"({_TOKEN})") + "$")
                found.update(m.group(1) for m in map(regex.match, bag_topics) if m)
        return sorted(found)

    def sources(self, bag_topics) -> dict[str, FieldSource]:
        """Flight field -> the source read from a bag with ``bag_topics`` (the first alternative whose topic is there);
        a required field without one is missing from the result (:meth:`missing`)."""
        present = set(bag_topics)
        chosen = {}
        for field, alternatives in self.fields.items():
            source = next((s for s in alternatives if s.topic in present), None)
            if source is not None:
                chosen[field] = source
        return chosen

    def missing(self, bag_topics) -> list[str]:
        """What a bag with ``bag_topics`` lacks for this map: per field without a present source (unless all its topics
        are optional), ``position from /topic (pkg/msg/Type)`` (alternatives joined by ``or``)."""
        chosen = self.sources(bag_topics)
        out = []
        for field, alternatives in self.fields.items():
            if field not in chosen and not all(self.topics[s.topic].optional for s in alternatives):
                out.append(f"{field} from " + " or ".join(dict.fromkeys(f"{s.topic} ({self.topics[s.topic].msgtype})" for s in alternatives)))
        return list(dict.fromkeys(out))


def _need(doc: dict, key: str, where: str):
    if key not in doc:
        raise ConfigError(f"{where}: missing key {key!r}")
    return doc[key]


def _check_mapping(doc, here: str, shape: str, known) -> None:
    """ConfigError naming ``here`` unless ``doc`` is a mapping with only ``known`` keys (``shape`` shows them)."""
    if not isinstance(doc, dict):
        raise ConfigError(f"{here}: must be a mapping {shape}, got {type(doc).__name__}")
    unknown = sorted(set(map(str, doc)) - known)
    if unknown:
        raise ConfigError(f"{here}: unknown key(s) {unknown}; known: {sorted(known)}")


def _topic_spec(name: str, doc, where: str) -> TopicSpec:
    here = f"{where}: topics.{name}"
    _check_mapping(doc, here, "{type, stamp, ...}", TOPIC_KEYS)
    if not re.fullmatch(r"(/(\{robot\}|" + _TOKEN + "))+", name):
        raise ConfigError(f"{here}: not an absolute ROS 2 topic name (e.g. /fmu/out/vehicle_odometry or /{{robot}}/pose)")
    msgtype = str(_need(doc, "type", here))
    if not re.fullmatch(rf"{_TOKEN}/msg/{_TOKEN}", msgtype):
        raise ConfigError(f"{here}: type {msgtype!r} is not a ROS 2 message type (package/msg/Name)")
    unit = doc.get("stamp_unit")
    if unit is not None and unit not in STAMP_UNITS:
        raise ConfigError(f"{here}: unknown stamp_unit {unit!r}; known: {', '.join(STAMP_UNITS)} (none: a builtin_interfaces/Time stamp)")
    variables = doc.get("vars")
    if variables is not None and (not isinstance(variables, list) or not variables or len(set(map(str, variables))) != len(variables)):
        raise ConfigError(f"{here}: vars must be a non-empty list of distinct log variable names")
    instance = doc.get("instance")
    optional = doc.get("optional", False)
    if not isinstance(optional, bool):  # bool("false") is True: a quoted or misspelt value would flip it
        raise ConfigError(f"{here}: optional must be true or false, got {optional!r}")
    return TopicSpec(name, msgtype, str(_need(doc, "stamp", here)), unit, tuple(map(str, variables)) if variables else None,
                     str(instance) if instance is not None else None, optional)


def parse_path(path: str, spec: TopicSpec, where: str) -> list[tuple[str, object]]:
    """``pose.position.x`` / ``q[0]`` / ``values[acc.x]`` -> steps ``("attr", name)``, ``("index", i)``; a name in
    brackets is looked up in the topic's ``vars``. ConfigError naming the path when it cannot be parsed."""
    steps: list[tuple[str, object]] = []
    text = path
    # split on dots outside brackets
    parts, depth, current = [], 0, ""
    for char in text:
        depth += char == "["
        depth -= char == "]"
        if char == "." and depth == 0:
            parts.append(current)
            current = ""
        else:
            current += char
    parts.append(current)
    for part in parts:
        match = _STEP.match(part)
        if not match:
            raise ConfigError(f"{where}: field {path!r} of topic {spec.name}: cannot parse {part!r} (expected name, name[0] or values[var])")
        steps.append(("attr", match.group(1)))
        for index in re.findall(r"\[([^\]]+)\]", match.group(2)):
            if index.isdigit():
                steps.append(("index", int(index)))
            elif spec.vars and index in spec.vars:
                steps.append(("index", spec.vars.index(index)))
            else:
                raise ConfigError(f"{where}: field {path!r}: {index!r} is not in the vars of topic {spec.name} "
                                  f"({list(spec.vars) if spec.vars else 'none given'})")
    return steps


def _field_source(field: str, doc, topics: dict[str, TopicSpec], where: str) -> FieldSource:
    here = f"{where}: fields.{field}"
    _check_mapping(doc, here, "{topic, fields, unit, frame}", SOURCE_KEYS)
    components, si_unit, known_frames, _ = FLIGHT_FIELDS[field]
    topic = str(_need(doc, "topic", here))
    if topic not in topics:
        raise ConfigError(f"{here}: topic {topic} is not declared under topics (declared: {', '.join(topics)})")
    paths = _need(doc, "fields", here)
    if not isinstance(paths, list) or len(paths) != components:
        raise ConfigError(f"{here}: fields must list {components} message field(s), one per component, got {paths!r}")
    for path in paths:
        parse_path(str(path), topics[topic], here)
    unit = doc.get("unit")
    if field == "commands":
        if unit not in COMMAND_UNITS:
            raise ConfigError(f"{here}: unknown unit {unit!r}; known: {', '.join(COMMAND_UNITS)}")
    elif field != "attitude":
        if unit not in frames.UNIT_FACTORS or frames.UNIT_FACTORS[unit][0] != si_unit:
            known = [u for u, (si, _) in frames.UNIT_FACTORS.items() if si == si_unit]
            raise ConfigError(f"{here}: unknown unit {unit!r} for {field}; known: {', '.join(known)}")
    frame = doc.get("frame")
    if known_frames and frame not in known_frames:
        raise ConfigError(f"{here}: unknown frame {frame!r}; known: {', '.join(known_frames)}")
    if field == "attitude" and "order" not in doc:  # xyzw (ROS) and wxyz (PX4) both occur: no silent default
        raise ConfigError(f"{here}: give the quaternion's order (xyzw: geometry_msgs; wxyz: PX4)")
    order = str(doc.get("order", "xyzw"))
    if order not in QUATERNION_ORDERS:
        raise ConfigError(f"{here}: unknown quaternion order {order!r}; known: {', '.join(QUATERNION_ORDERS)}")
    span = doc.get("range")
    if span is not None:
        try:
            low, high = (yaml_number(v) for v in span)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{here}: range must be [low, high], got {span!r}") from err
        if not (math.isfinite(low) and math.isfinite(high) and math.isfinite(high - low)):
            raise ConfigError(f"{here}: range [{low:g}, {high:g}] must be finite numbers")
        if not high > low:
            raise ConfigError(f"{here}: range [{low:g}, {high:g}] must have high > low")
        span = (low, high)
    frame_field, listed = _frame_field(doc, field, frame, known_frames, topics[topic], here)
    return FieldSource(field, topic, tuple(map(str, paths)), unit, frame, order, span, frame_field, listed)


def _frame_field(doc: dict, field: str, frame, known_frames, spec: TopicSpec, here: str) -> tuple[str | None, tuple]:
    """A source's ``frame_field`` and ``frames`` (module doc): the field's path and ((value, frame), ...), each frame
    the source's ``frame`` or a body frame rotated into its world ``frame``; (None, ()) when not given."""
    if "frame_field" not in doc and "frames" not in doc:
        return None, ()
    path, listed = str(_need(doc, "frame_field", here)), _need(doc, "frames", here)
    parse_path(path, spec, here)
    if not isinstance(listed, dict) or not listed or any(type(v) is not int for v in listed):
        raise ConfigError(f"{here}: frames must map the integer values of {path} onto frames, e.g. {{1: NED, 3: FRD}}, got {listed!r}")
    allowed = [frame, *(f for f in known_frames if f in BODY_FRAMES and frame in WORLD_FRAMES)]
    wrong = sorted({str(f) for f in listed.values()} - set(allowed))
    if wrong:
        raise ConfigError(f"{here}: frames {wrong}: a message's frame must be the field's frame {frame} or a body frame "
                          f"rotated into it (known: {', '.join(allowed)})")
    return path, tuple((v, str(f)) for v, f in listed.items())


def topic_map_from_dict(doc, origin: str) -> TopicMap:
    """Validate a parsed topic map document (module doc); ConfigError in one line naming ``origin`` and the key."""
    if not isinstance(doc, dict):
        raise ConfigError(f"{origin}: a topic map must be a mapping with name, topics and fields")
    unknown = sorted(set(map(str, doc)) - {"name", "description", "default_vehicle", "topics", "fields"})
    if unknown:
        raise ConfigError(f"{origin}: unknown key(s) {unknown}; known: name, description, default_vehicle, topics, fields")
    topics_doc, fields_doc = _need(doc, "topics", origin), _need(doc, "fields", origin)
    if not isinstance(topics_doc, dict) or not topics_doc:
        raise ConfigError(f"{origin}: topics must be a mapping of topic name -> {{type, stamp, ...}}")
    if not isinstance(fields_doc, dict):
        raise ConfigError(f"{origin}: fields must be a mapping of flight field -> source")
    topics = {str(name): _topic_spec(str(name), spec, origin) for name, spec in topics_doc.items()}
    unknown = sorted(set(map(str, fields_doc)) - set(FLIGHT_FIELDS))
    if unknown:
        raise ConfigError(f"{origin}: unknown flight field(s) {unknown}; known: {', '.join(FLIGHT_FIELDS)}")
    missing = [f for f, (_, _, _, required) in FLIGHT_FIELDS.items() if required and f not in fields_doc]
    if missing:
        raise ConfigError(f"{origin}: the map gives no {', '.join(missing)} (required: commands, position, attitude, velocity)")
    fields = {}
    for field, entry in fields_doc.items():
        alternatives = entry if isinstance(entry, list) else [entry]
        if not alternatives:
            raise ConfigError(f"{origin}: fields.{field} lists no source")
        fields[str(field)] = tuple(_field_source(str(field), alt, topics, origin) for alt in alternatives)
    name = str(_need(doc, "name", origin))
    default_vehicle = doc.get("default_vehicle")
    return TopicMap(name, str(doc.get("description", "")), origin, topics, fields, str(default_vehicle) if default_vehicle else None)


def builtin_names() -> list[str]:
    """The shipped maps' names (``config/topic_maps/*.yaml``), the contract first."""
    names = sorted(p.stem for p in topic_maps_dir().glob("*.yaml"))
    return sorted(names, key=lambda n: n != CONTRACT_MAP)


def load_topic_map(name_or_path: str) -> TopicMap:
    """A shipped map by name (``px4``, ``crazyswarm2``, ``quad``; ``crazyswarm2:cf231`` binds the robot) or a YAML file."""
    text = str(name_or_path)
    if _names_file(text):
        file, _, robot = text.rpartition(":") if re.search(r"\.ya?ml:[^/:]+$", text) else (text, "", "")
        topic_map = topic_map_from_dict(read_yaml(Path(file), "topic map"), file)
        if robot:  # FILE.yaml:ROBOT, as a built-in map's NAME:ROBOT
            if not re.fullmatch(_TOKEN, robot) or not topic_map.has_robot:
                raise ConfigError(f"--topic-map {text}: {robot!r} is not a robot name for map {file} (maps with {ROBOT} "
                                  "topics take FILE.yaml:ROBOT)")
            topic_map = topic_map.bind(robot)
        return topic_map
    name, _, robot = text.partition(":")
    path = topic_maps_dir() / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"--topic-map {text}: no such built-in map; known: {', '.join(builtin_names())} (or a YAML file)")
    topic_map = replace(topic_map_from_dict(read_yaml(path, "topic map"), str(path)), origin="built-in")
    if robot.startswith("/") or (robot and topic_map.is_contract):  # quad:/my_drone/cf1, px4:/px4_1: under a namespace
        try:
            return topic_map.in_namespace(check_namespace(robot))
        except ConfigError as err:
            raise ConfigError(f"--topic-map {text}: {err} (a map takes NAME:/NAMESPACE)") from err
    if robot:
        if not re.fullmatch(_TOKEN, robot) or not topic_map.has_robot:
            raise ConfigError(f"--topic-map {text}: {robot!r} is not a robot name for map {name} (maps with {ROBOT} topics take NAME:ROBOT)")
        topic_map = topic_map.bind(robot)
    return topic_map


def bind_robot(topic_map: TopicMap, bag_topics, where: str) -> TopicMap:
    """``topic_map`` with its ``{robot}`` bound to the one robot whose topics the bag has; BagError for none or several."""
    if not topic_map.has_robot:
        return topic_map
    robots = topic_map.robots(bag_topics)
    if len(robots) != 1:
        found = f"robots {', '.join(robots)}" if robots else "no robot"
        named = topic_map.name if topic_map.origin == "built-in" else topic_map.origin  # a YAML map: its file
        raise BagError(f"{where}: topic map {topic_map.name} reads one robot's topics; the bag has {found} "
                       f"(name one with --topic-map {named}:ROBOT)")
    return topic_map.bind(robots[0])


def choose_topic_map(bag_topics, where: str, requested: str | None = None) -> TopicMap:
    """The map to read a bag whose topics are ``bag_topics`` with: ``requested`` (name or YAML) when given, else the one
    built-in map whose required topics the bag has. BagError listing the topics found and the maps tried when no map
    or several match."""
    bag_topics = sorted(bag_topics)
    if requested:
        topic_map = load_topic_map(requested)
        named = ":" in str(requested) and not _names_file(str(requested))  # quad:/cf1: the namespace given, not searched
        namespaces = topic_map.namespaces(bag_topics) if topic_map.origin == "built-in" and not (topic_map.has_robot or named) else []
        if topic_map.missing(bag_topics) and len(namespaces) == 1:  # --topic-map px4, one /px4_1
            topic_map = topic_map.in_namespace(namespaces[0])
        elif topic_map.missing(bag_topics) and namespaces:
            raise BagError(f"{where}: the bag holds the topics of map {topic_map.name} under several namespaces; name one "
                           f"with --topic-map {' or '.join(f'{topic_map.name}:{ns}' for ns in namespaces)}")
        return bind_robot(topic_map, bag_topics, where)
    matching, tried = [], []
    for name in builtin_names():
        topic_map = load_topic_map(name)
        robots = topic_map.robots(bag_topics) if topic_map.has_robot else [None]
        candidates = [(f"{name}:{r}" if r else name, topic_map.bind(r) if r else topic_map) for r in robots] or [(name, topic_map)]
        if not topic_map.has_robot:  # under a namespace: convert --namespace, PX4's multi-vehicle /px4_N
            candidates += [(f"{name}:{ns}", topic_map.in_namespace(ns)) for ns in topic_map.namespaces(bag_topics)
                           if not (topic_map.is_contract and ns == CONTRACT_NAMESPACE)]
        hits = [(label, c) for label, c in candidates if not c.missing(bag_topics)]
        matching += hits
        if not hits:
            missing = candidates[0][1].missing(bag_topics)
            tried.append(f"{name} (needs {', '.join(missing)})")
    if len(matching) == 1:
        return matching[0][1]
    if not matching:
        raise BagError(f"{where}: no topic map matches the bag's topics {bag_topics}; maps tried: {'; '.join(tried)}; "
                       "name a map or a YAML file with --topic-map (docs/formats.md)")
    raise BagError(f"{where}: the bag's topics match several topic maps; choose one with --topic-map "
                   f"{' or '.join(label for label, _ in matching)}")


def contract_namespaces(bag_topics) -> list[str]:
    """The namespaces under which ``bag_topics`` hold the contract's command topic (``/a/b/motor_input`` -> ``/a/b``)."""
    return sorted({t[: -len(CONTRACT_COMMANDS)] or "/" for t in bag_topics if t.endswith(CONTRACT_COMMANDS)})


def add_topic_map_argument(parser) -> None:
    """``--topic-map NAME|YAML`` for every command that reads flights (the one definition of the option)."""
    parser.add_argument("--topic-map", metavar="NAME|YAML", default=None,
                        help="how to read a bag of another stack: a built-in topic map (px4, crazyswarm2, crazyswarm2:ROBOT, quad) "
                             "or a YAML map (docs/formats.md); default: the one built-in map the bag's topics match")


def _names_file(text: str) -> bool:
    """Whether a ``--topic-map`` value is a file: a YAML name (``maps/x.yaml``, ``maps/x.yaml:ROBOT``), or a path (a
    ``/`` before any ``:``; ``quad:/ns`` is the contract map in a namespace)."""
    return text.endswith((".yaml", ".yml")) or re.search(r"\.ya?ml:[^/:]+$", text) is not None or "/" in text.partition(":")[0]


def topic_map_file(value: str | None) -> str | None:
    """The YAML file a ``--topic-map`` value names (an input of the command), None for a built-in name."""
    if not value or not _names_file(value):
        return None
    return value.rpartition(":")[0] if re.search(r"\.ya?ml:[^/:]+$", value) else value


# --- static check of a map against the message definitions ------------------------------------

@dataclass(frozen=True)
class FieldType:
    """One message field as a definition gives it: a nested message type, or a base type; array length or sequence."""

    nested: str | None
    base: str | None
    length: int | None = None
    sequence: bool = False


NUMERIC = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "octet"}
TIME_TYPE = "builtin_interfaces/msg/Time"


def check_path(path: str, spec: TopicSpec, fields_of, where: str, stamp: bool = False) -> None:
    """ConfigError naming the field, the topic and its message type unless ``path`` reaches a number (``stamp``: a
    number or a builtin_interfaces/Time) in ``spec.msgtype``; ``fields_of(msgtype)`` -> {name: FieldType}."""
    msgtype = spec.msgtype
    current: FieldType | None = None
    what = f"{where}: field {path!r} of topic {spec.name} ({spec.msgtype})"
    steps = parse_path(path, spec, where)
    for kind, value in steps:
        if kind == "attr":
            if current is not None:
                if current.nested is None or current.length is not None or current.sequence:
                    raise ConfigError(f"{what}: {value!r} follows a field that is not a message")
                msgtype = current.nested
            known = fields_of(msgtype)
            if value not in known:
                raise ConfigError(f"{what}: {msgtype} has no field {value!r} (fields: {', '.join(known)})")
            current = known[value]
        else:
            if current is None or (current.length is None and not current.sequence):
                raise ConfigError(f"{what}: [{value}] indexes a field that is not an array")
            if current.length is not None and value >= current.length:
                raise ConfigError(f"{what}: index {value} is beyond the field's {current.length} elements")
            current = FieldType(current.nested, current.base)
    if current is None or current.length is not None or current.sequence:
        raise ConfigError(f"{what}: does not name one number")
    if current.base in NUMERIC and not (stamp and spec.stamp_unit is None):
        return
    if stamp and spec.stamp_unit is None and current.nested == TIME_TYPE:
        return
    expected = "a builtin_interfaces/Time (or give stamp_unit for an integer stamp)" if stamp and spec.stamp_unit is None else "a number"
    raise ConfigError(f"{what}: is {current.base or current.nested}, not {expected}")


def check_map_fields(topic_map: TopicMap, sources: dict[str, FieldSource], fields_of, where: str) -> None:
    """Every stamp, instance and field path the ``sources`` read exists in the topics' message definitions."""
    for topic in dict.fromkeys(s.topic for s in sources.values()):
        spec = topic_map.topics[topic]
        check_path(spec.stamp, spec, fields_of, where, stamp=True)
        if spec.instance:
            check_path(spec.instance, spec, fields_of, where)
    for source in sources.values():
        for path in (*source.paths, *([source.frame_field] if source.frame_field else [])):
            check_path(path, topic_map.topics[source.topic], fields_of, where)


def fields_of_store(store):
    """``fields_of(msgtype)`` -> {name: FieldType} from a type store's definitions (the map's static check)."""
    from rosbags.typesys.store import Nodetype

    def describe(kind, detail) -> FieldType:
        if kind == Nodetype.NAME:
            return FieldType(detail, None)
        if kind == Nodetype.BASE:
            return FieldType(None, detail[0])
        (element_kind, element_detail), size = detail
        element = describe(element_kind, element_detail)
        return FieldType(element.nested, element.base, size if kind == Nodetype.ARRAY else None, kind == Nodetype.SEQUENCE)

    def fields_of(msgtype: str) -> dict:
        if msgtype not in store.fielddefs:
            return {}
        return {name: describe(kind, detail) for name, (kind, detail) in store.fielddefs[msgtype][1]}
    return fields_of
