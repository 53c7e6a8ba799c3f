"""Recording what a node receives and publishes into one MCAP bag (evaluator parameter ``record``).

The bag is written by :class:`quad_modelling.io.bag_io.BagRecorder` (zstd chunks, staged and
renamed when the node finishes). A received message goes in as the CDR bytes that arrived
(``raw=True`` subscriptions: what the publisher sent, as ``ros2 bag record`` stores it), a
message the node publishes itself as the type store serialises it
(:func:`~quad_modelling.io.bag_io.serialize_as`), on its fully qualified topic name (``/quad/motor_input``, ``/quad/greybox/odom``, ``/quad/evaluation``),
at the bag time of its header stamp, so measured and predicted samples of one instant line up
in Foxglove (``config/foxglove_layout.json``) and PlotJuggler. The bag names the vehicle in its
custom data, as converted bags do, so ``quad-modelling evaluate``/``info`` read it too.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from quad_modelling.errors import QuadModellingError
from quad_modelling.io import topics
from quad_modelling.io.bag_io import SOURCE_KEY, VEHICLE_KEY, BagRecorder, serialize_as
from quad_modelling.nodes.common import BadParameter


def message_type_name(kind: type) -> str:
    """rclpy's ``sensor_msgs.msg.Imu`` -> ``sensor_msgs/msg/Imu`` (the bag's type name)."""
    return f"{kind.__module__.split('.')[0]}/msg/{kind.__name__}"


class TopicRecorder:
    """One node's recording: :meth:`add` a message as it is received or published."""

    def __init__(self, path: str, force: bool, source: str):
        self.bag = BagRecorder(path, force, custom_data={SOURCE_KEY: source})
        self._types: dict[type, str] = {}

    def set_vehicle(self, name: str) -> None:
        """The vehicle the recorded flight was flown with (custom data, as converted bags)."""
        self.bag.set_custom_data(VEHICLE_KEY, name)

    def add(self, topic: str, msg, ns: int | None = None) -> None:
        """Record ``msg`` (one the node publishes) on the absolute ``topic`` at ``ns`` (default: its header stamp)."""
        name = self.type_name(type(msg))
        stamp = topics.stamp_ns(msg.header.stamp) if ns is None else ns
        self.bag.write(topic, name, stamp, serialize_as(msg, name))

    def add_raw(self, topic: str, msgtype: str, raw: bytes) -> None:
        """Record a message as received (CDR bytes, from a ``raw=True`` subscription) at its header stamp."""
        self.bag.write(topic, msgtype, topics.cdr_stamp_ns(raw), raw)

    def type_name(self, kind: type) -> str:
        name = self._types.get(kind)
        if name is None:
            name = self._types[kind] = message_type_name(kind)
        return name

    @property
    def count(self) -> int:
        return self.bag.count

    def close(self):
        return self.bag.close()

    def abort(self) -> None:
        self.bag.abort()


def open_recorder(node_name: str, record: str, output_dir: Path | None, force: bool, vehicle) -> TopicRecorder | None:
    """The recording of parameter ``record`` ('' = none): refused (:class:`BadParameter`) when the bag exists
    without ``force`` or lies in ``output_dir`` (which is replaced on each write)."""
    if not record:
        return None
    path = Path(record)
    if path.exists() and not force:
        raise BadParameter(f"{node_name}: parameter record={record!r} exists; set force:=true to replace it")
    if output_dir is not None and (path.resolve() == output_dir.resolve() or output_dir.resolve() in path.resolve().parents):
        raise BadParameter(f"{node_name}: parameter record={record!r} lies in output_dir (replaced on each write)")
    try:
        recorder = TopicRecorder(record, force, f"live recording by {node_name}")
    except QuadModellingError as err:
        raise BadParameter(f"{node_name}: parameter record={record!r}: {err}") from err
    if vehicle is not None:
        recorder.set_vehicle(vehicle.name)
    return recorder


def check_output_dir(node_name: str, output_dir: Path | None, force: bool, inputs=()) -> None:
    """Refuse (:class:`BadParameter`) an ``output_dir`` that exists without ``force``, that ``force`` may not replace
    (a regular file, a directory holding no earlier output, one holding an input: the CLI's rules,
    :func:`~quad_modelling.atomic.check_output`), whose parent is missing, or in which no directory can be made -- at
    start, not after the flight when the results are written (a session's results were lost there)."""
    from quad_modelling.atomic import check_output

    if output_dir is None:
        return
    where = f"{node_name}: parameter output_dir={str(output_dir)!r}"
    parent = output_dir.absolute().parent
    if output_dir.exists() and not force:
        raise BadParameter(f"{where} exists; set force:=true to replace it")
    if not parent.is_dir():
        raise BadParameter(f"{where}: its parent directory {str(parent)!r} does not exist")
    try:  # a directory can be made there (a read-only or special file system cannot)
        os.rmdir(tempfile.mkdtemp(prefix=".quad_write_check_", dir=parent))
    except OSError as err:
        raise BadParameter(f"{where}: cannot write in {str(parent)!r} ({err.strerror})") from err
    try:
        check_output(output_dir, force, inputs, flag="output_dir", directory=True)
    except QuadModellingError as err:
        raise BadParameter(f"{node_name}: parameter {err}") from err


def subscribe_recorded(node, recorder: TopicRecorder | None, kind, topic: str, callback, qos) -> None:
    """A data subscription of ``node``; with a ``recorder``, every message is received serialised, recorded as it came
    on its topic, then deserialised for ``callback``."""
    if recorder is None:
        node.create_subscription(kind, topic, callback, qos)
        return
    from rclpy.serialization import deserialize_message

    name, msgtype = node.resolve_topic_name(topic), recorder.type_name(kind)

    def recorded(data: bytes):
        recorder.add_raw(name, msgtype, data)
        callback(deserialize_message(data, kind))

    node.create_subscription(kind, topic, recorded, qos, raw=True)


def close_recording(say, recorder: TopicRecorder | None, refused: bool) -> None:
    """End a node's recording: written (``say`` the count, or why it could not be), or, for a refused run, removed."""
    if recorder is None:
        return
    if refused:
        recorder.abort()
        return
    try:
        say(f"recorded {recorder.count} messages in {recorder.close()}")
    except (QuadModellingError, OSError) as err:
        say(f"cannot write the recording: {err}", True)
