"""A topic map field's numbers -> the FlightLog field (offline and live alike), the frame each message names included.

:func:`convert_field` converts one field's (n, k) numbers on the flight's rows, in the map's unit and frame, to the
FlightLog's (NED/FRD, SI). A source with a ``frame_field`` (:mod:`quad_modelling.io.topic_maps`; PX4's
``VehicleOdometry.velocity_frame`` and ``pose_frame``) has the frame of each message's numbers named by the message:
:class:`MessageFrames` reads it per message (called by :class:`~quad_modelling.io.mapped_flight.TopicReader`), refuses
a value the map does not list in one line naming the bag, topic, message and field, and rotates the numbers of a
body-frame message (PX4 ``VELOCITY_FRAME_BODY_FRD``) into the field's world ``frame`` with the attitude quaternion of
the same message. A recording whose frame changes is so read message by message, each in its own frame, and said
(:func:`frame_notes`). Every rotation and axis change through :mod:`quad_modelling.core.frames`.
"""

from __future__ import annotations

import math

import numpy as np

from quad_modelling.core import frames
from quad_modelling.errors import ConfigError, DataError
from quad_modelling.io.topic_maps import BODY_FRAMES, WORLD_FRAMES, FieldSource, TopicMap


def attitude_euler(quat: np.ndarray, source: FieldSource) -> np.ndarray:
    """(n, 4) quaternions in the map's order and frame -> Euler (φ, θ, ψ) NED/FRD [rad], yaw not unwrapped."""
    xyzw = quat if source.order == "xyzw" else quat[:, [1, 2, 3, 0]]
    if source.frame == "ENU/FLU":
        return frames.quat_enu_to_euler_ned(xyzw)
    return frames.quat_ned_to_euler_ned(xyzw)


def body_to_world(vectors: np.ndarray, body: str, world: str, euler: np.ndarray) -> np.ndarray:
    """(n, 3) body vectors (``FRD`` or ``FLU``, any unit) -> the ``world`` frame (``NED`` or ``ENU``) with the attitudes
    ``euler`` (n, 3) NED/FRD [rad] at the same rows: v_N = R v_B (:func:`~quad_modelling.core.frames.body_to_nav`)."""
    ned = frames.body_to_nav(frames.flu_to_frd(vectors) if body == "FLU" else vectors, euler)
    return frames.ned_to_enu(ned) if world == "ENU" else ned


def convert_field(source: FieldSource, values: np.ndarray, euler: np.ndarray | None = None) -> np.ndarray:
    """(n, k) numbers of one non-command field, as the map gives them -> the FlightLog field (NED/FRD, SI).

    position -> pos_n [m]; velocity -> vel_n [m/s] (a body-frame velocity rotated by ``euler``, the attitude at
    the same rows); attitude -> euler [rad]; acc -> acc_b [m/s²]; gyro -> gyro_b [rad/s]; battery -> vbat [V].
    """
    if source.field == "attitude":
        return attitude_euler(values, source)
    si = frames.to_si(values, source.unit)
    if source.field == "battery":
        return si[:, 0]
    if source.field == "velocity" and source.frame in BODY_FRAMES:
        return body_to_world(si, source.frame, "NED", euler)
    if source.frame == "ENU":
        return frames.enu_to_ned(si)
    return frames.flu_to_frd(si) if source.frame == "FLU" else si


class MessageFrames:
    """The frames one topic's messages name for the map fields they give (the sources with a ``frame_field``).

    :meth:`apply` takes a message's frame field values (one per source, in :attr:`sources` order) and its numbers (the
    topic reader's ``paths``): a value the map does not list is a DataError; the numbers of a body-frame message are
    rotated in place into the source's ``frame`` with the message's own ``attitude`` quaternion. :attr:`seen` counts
    the messages of each (field, value); a message whose numbers of a field are not finite names no frame for it (PX4
    marks invalid numbers NaN): it is skipped or refused by the not-finite rule, as any other.
    """

    def __init__(self, topic: str, sources: list[FieldSource], attitude: FieldSource | None, paths: list[str],
                 map_name: str, where: str):
        self.topic, self.sources, self.attitude, self.map_name, self.where = topic, sources, attitude, map_name, where
        self._columns = [[paths.index(p) for p in s.paths] for s in sources]
        self._quat = [paths.index(p) for p in attitude.paths] if attitude is not None else []
        self._frames = [dict(s.frames) for s in sources]
        self.seen: dict[str, dict] = {s.field: {} for s in sources}  # field -> {frame field value: messages}

    def apply(self, codes: list, values: list[float], index: int) -> None:
        """Check message ``index``'s frame ``codes`` and rotate its body-frame numbers in ``values`` (class doc)."""
        for source, code, columns, listed in zip(self.sources, codes, self._columns, self._frames):
            numbers = [values[i] for i in columns]
            if not all(map(math.isfinite, numbers)):
                continue
            frame = listed.get(code)
            if frame is None:
                known = ", ".join(f"{v} = {f}" + (" (body)" if f in BODY_FRAMES else " (world)" if f in WORLD_FRAMES else "")
                                  for v, f in source.frames)
                raise DataError(f"{self.where}: topic {self.topic} message {index}: {source.frame_field} is {code}; topic map "
                                f"{self.map_name} reads {source.field} only with {source.frame_field} {known}")
            seen = self.seen[source.field]
            seen[code] = seen.get(code, 0) + 1
            if frame == source.frame:
                continue
            quat = np.array([[values[i] for i in self._quat]])
            if not np.isfinite(quat).all():  # no attitude (PX4: q[0] NaN): the numbers neither, skipped or refused so
                rotated = [math.nan] * len(columns)
            elif frames.non_unit_quaternion(quat):
                raise DataError(f"{self.where}: topic {self.topic} message {index} has an attitude quaternion of norm "
                                f"{np.linalg.norm(quat):.3g}, not 1: its {source.field} in {frame} cannot be rotated")
            else:
                rotated = body_to_world(np.array([numbers]), frame, source.frame, attitude_euler(quat, self.attitude))[0]
            for i, value in zip(columns, rotated):
                values[i] = float(value)

    def notes(self) -> dict[str, tuple[str, int]]:
        """Field -> (the frames its messages named: ``/topic velocity_frame 3 = FRD (body, rotated into NED by each
        message's attitude) in 1000 messages``, the number of different ones)."""
        out = {}
        for source, listed in zip(self.sources, self._frames):
            named = [f"{code} = {listed[code]}" + (f" (body, rotated into {source.frame} by each message's attitude)"
                                                    if listed[code] != source.frame else "") + f" in {n} messages"
                     for code, n in self.seen[source.field].items()]
            out[source.field] = (f"{self.topic} {source.frame_field} " + "; ".join(named or ["none finite"]), len(named))
        return out


def message_frames(topic_map: TopicMap, sources: dict[str, FieldSource], topic: str, paths: list[str], where: str) -> MessageFrames | None:
    """The :class:`MessageFrames` of ``topic`` (None when no chosen source on it has a ``frame_field``); ConfigError when
    a source lists a body frame and the map's attitude is not read from the same topic (each message is rotated by
    its own attitude)."""
    framed = [s for s in sources.values() if s.topic == topic and s.frame_field]
    if not framed:
        return None
    attitude = sources.get("attitude")
    rotating = next((s for s in framed if any(f != s.frame for _, f in s.frames)), None)
    if rotating is not None and (attitude is None or attitude.topic != topic):
        raise ConfigError(f"{where}: topic map {topic_map.name}: fields.{rotating.field} lists body frames, rotated by the attitude "
                          f"of the same message, but the attitude is read from {attitude.topic if attitude else 'no topic'}, not {topic}")
    return MessageFrames(topic, framed, attitude if rotating is not None else None, paths, topic_map.name, where)


def frame_notes(readers) -> tuple[dict, list[str]]:
    """(notes, warnings) of the topic readers' :class:`MessageFrames`: ``notes["frames"]``, field -> the frames its
    messages named; a warning per field whose messages named several frames (each read in its own, not mixed)."""
    notes, warnings = {}, []
    for framed in (reader.frames for reader in readers.values() if reader.frames is not None):
        for field, (text, count) in framed.notes().items():
            notes[field] = text
            if count > 1:
                warnings.append(f"{framed.where}: {field} from {text}: the frame changes within the recording, each message "
                                "read in its own frame")
    return ({"frames": notes} if notes else {}), warnings
