"""PX4 ULog flights (``*.ulg``, read with pyulog) into a FlightLog.

PX4 logs in the internal convention already: local frame NED, body FRD,
quaternions ``q[0..3]`` = (w, x, y, z) of R_NED←FRD, SI units. Topics used
(instance 0 of each; see *Multi-instance topics*):

=========  ==========================================  ===================  ===================
field      topic.fields                                time stamp           when absent
=========  ==========================================  ===================  ===================
u          actuator_motors.control[0..3] (0..1)        timestamp            actuator_outputs
u          actuator_outputs.output[motor channels]     timestamp            refused
           (PWM pulse width [us])
pos_n      vehicle_local_position.x, y, z [m]          timestamp_sample     vehicle_odometry
vel_n      vehicle_local_position.vx, vy, vz [m/s]     timestamp_sample     vehicle_odometry
pos/vel    vehicle_odometry.position, velocity         timestamp_sample     refused
           (pose_frame 1 = NED; velocity_frame 1 = NED,
           3 = body FRD: rotated by the message's q)
euler      vehicle_attitude.q[0..3] (w, x, y, z)       timestamp_sample     refused
acc_b      sensor_combined.accelerometer_m_s2 [m/s²]   timestamp + accelerometer_timestamp_relative
gyro_b     sensor_combined.gyro_rad [rad/s]            timestamp            refused
vbat       battery_status.voltage_v [V]                timestamp            left out
           (lowest connected instance; held at its ends)
armed      vehicle_status.arming_state == 2            timestamp            actuator_armed.armed
=========  ==========================================  ===================  ===================

``vehicle_angular_velocity`` (filtered, bias-corrected rates) is not used:
``sensor_combined`` carries the raw gyro, the measurement the thesis compares with.

Time base: the motor-command topic's own stamps, so no command is invented;
every other stream is interpolated onto it, linearly per component (attitude:
spherical linear interpolation of the quaternion, then ZYX Euler angles with
the yaw unwrapped). Rows outside the span every used stream covers are cut (no
extrapolation); a gap longer than :data:`MAX_INTERPOLATION_GAP_S` of a
kinematic stream (position, attitude, IMU) around a kept row is marked, not
bridged: ``meta.notes["measurement_gaps"]`` and a warning name the topic and
times, and no window or training segment uses a row inside it
(:func:`quad_modelling.core.preprocess.mark_measurement_gaps`). Streams faster
than the base are point-sampled, not averaged.

Disarmed stretches: rows before the first and after the last armed sample are
dropped (seconds said in ``meta.notes["disarmed"]``); a log that is never armed
(on the ground, motors at their disarmed value) is kept whole and marked so.

Motor commands: PX4 ``actuator_motors`` marks a stopped motor with NaN; a NaN
in the four used channels is read as 0 (stopped) and counted in the notes.
``actuator_outputs`` channels are the ones whose ``PWM_MAIN_FUNCn`` is Motor 1..4
(101..104); without those parameters (older PX4) the first four outputs. The
PWM range comes from ``PWM_MAIN_MINn/MAXn``, ``PWM_MAIN_MIN/MAX`` or
``HIL_ACT_MINn/MAXn``, whichever the log has, and is recorded in the notes.
Only four-rotor vehicles are read: the rotor count comes from
``CA_ROTOR_COUNT``, else ``MAV_TYPE``, else the non-NaN ``actuator_motors``
channels; any other count (hexa, octo, VTOL with a pusher) is refused in one
line naming the count and where it came from.

Multi-instance topics: instance 0 is used and ``meta.notes["instances"]``
says how many were logged; ``battery_status``: the lowest instance that measured
a pack (PX4 logs every battery slot, an unused one at 0 V, not connected).
Appended data and logging dropouts are noted.

Battery: optional and slow, it does not bound the flight. Its readings at 0 V,
not connected or not finite are skipped, the rest interpolated, the first and
last held beyond them; ``meta.notes["battery"]`` says what was skipped, a late
start or early end and pauses longer than
:data:`~quad_modelling.core.alignment.BATTERY_PAUSE_S`
(:func:`~quad_modelling.core.alignment.battery_on_rows`).

Default vehicle (``vehicle=None``): ``px4_iris`` for ``actuator_motors`` logs,
``px4_iris_pwm`` for PWM logs (``config/vehicles/``). A vehicle whose input
unit does not match the command source is refused (``vehicle`` may be a loaded
VehicleConfig).

Vehicle from the log (:func:`vehicle_from_ulog`, ``convert --vehicle-from-log``):
a vehicle document started from the log's parameters. Motor k = ``CA_ROTOR(k-1)``
(the order of ``actuator_motors.control`` and of the outputs whose function is
Motor k); positions ``CA_ROTORn_PX/PY`` (body FRD [m]) symmetrised to one arm
length (:func:`symmetric_frame`); spins from the sign of ``CA_ROTORn_KM`` (PX4:
positive = counter-clockwise seen from above); input range 0..1 ``normalised``
for ``actuator_motors``, for ``actuator_outputs`` the disarmed pulse
(``PWM_MAIN_DISn``, ``PWM_MAIN_DISARM``, else PX4's default 900 us) to the PWM
maximum, in ``us``. Mass, inertia and motor constants are not in a log: copied
from the default vehicle of the command source and marked as guesses. A log
without ``CA_ROTORn`` parameters (PX4 before the control allocator) takes the
default vehicle's frame, marked and warned as a guess.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from quad_modelling.core import frames
from quad_modelling.core.alignment import battery_on_rows, usable_voltages
from quad_modelling.core.flight_log import FlightLog, FlightMeta
from quad_modelling.core.preprocess import (
    MAX_INTERPOLATION_GAP_S,
    MeasurementGap,
    interpolation_gaps,
    mark_measurement_gaps,
)
from quad_modelling.core.vehicle import VehicleConfig, load_vehicle
from quad_modelling.errors import DataError, reason

ROTORS = 4
"""Rotor count the FlightLog and the vehicle configs hold."""

POSE_FRAME_NED, VELOCITY_FRAME_NED, VELOCITY_FRAME_BODY_FRD = 1, 1, 3
"""vehicle_odometry.pose_frame / velocity_frame values read (PX4 msg/VehicleOdometry.msg: POSE_FRAME_NED = 1,
VELOCITY_FRAME_NED = 1, VELOCITY_FRAME_BODY_FRD = 3; FRD = 2 is earth-fixed with an arbitrary heading: refused)."""

ARMING_STATE_ARMED = 2
"""vehicle_status.arming_state value of an armed vehicle (PX4 msg/VehicleStatus.msg)."""

RELATIVE_TIMESTAMP_INVALID = 0x7FFFFFFF
"""sensor_combined.accelerometer_timestamp_relative when no accelerometer sample came with the gyro
(PX4 msg/SensorCombined.msg)."""

MOTOR_FUNCTION_FIRST = 101
"""PWM_MAIN_FUNCn value of "Motor 1" (PX4 output functions; Motor k = 100 + k)."""

ROTORS_OF_MAV_TYPE = {1: 0, 2: 4, 3: 2, 4: 1, 13: 6, 14: 8, 15: 3, 19: 4, 20: 4, 21: 4, 22: 4, 23: 4, 24: 4, 25: 4}
"""Rotor count per MAVLink MAV_TYPE (common.xml): 2 quadrotor, 13 hexa, 14 octo, 15 tri, 3 coaxial,
4 helicopter, 1 fixed wing; 19-25 are VTOL types, refused below whatever their lift rotor count."""

VTOL_MAV_TYPES = range(19, 26)

MOTOR_UNITS = {"actuator_motors": "normalised", "actuator_outputs": "us"}
"""Input unit (vehicle ``inputs.unit``) of each motor-command source."""

DEFAULT_VEHICLES = {"actuator_motors": "px4_iris", "actuator_outputs": "px4_iris_pwm"}


TOPICS = (
    "actuator_motors", "actuator_outputs", "vehicle_local_position", "vehicle_odometry", "vehicle_attitude",
    "sensor_combined", "vehicle_angular_velocity", "battery_status", "vehicle_status", "actuator_armed",
)
"""Every topic the reader looks at."""

Topics = dict[str, dict[str, np.ndarray]]
"""Topic name -> field name -> values (one instance per topic), as pyulog's ``data`` dicts."""


def read_ulog(path: str | Path, vehicle: str | VehicleConfig | None = None) -> FlightLog:
    """Read a PX4 .ulg file into a FlightLog (see module doc); DataError names file and topic."""
    where = str(path)
    ulog, said, cut_at, read_to = open_ulog(path, TOPICS)
    topics, notes = topics_of(ulog.data_list)
    size = Path(path).stat().st_size
    if cut_at is None and read_to < size and not getattr(ulog, "file_corruption", False):
        # pyulog takes a message it cannot unpack (a damaged size field: a 0-byte data message) for the file's end
        last_s = (ulog.last_timestamp - ulog.start_timestamp) * 1e-6
        notes["warnings"] = [*notes.get("warnings", []), f"{where}: pyulog stopped at a message it could not unpack near "
                             f"byte {read_to} of {size} (the file is damaged there); the rest of the file is not read, "
                             f"read up to {last_s:.2f} s into the log"]
    if cut_at is not None and not getattr(ulog, "file_corruption", False):  # power lost, a copy stopped early (a damaged
        # file is said below: pyulog's resync reads its end in chunks)
        last_s = (ulog.last_timestamp - ulog.start_timestamp) * 1e-6
        notes["warnings"] = [*notes.get("warnings", []), f"{where}: the file ends inside a message at byte {cut_at} of "
                             f"{size} (cut short: power lost, or an incomplete copy?); read up to there, {last_s:.2f} s "
                             "into the log"]
    if said.getvalue().strip():
        notes["pyulog"] = " ".join(sorted(set(said.getvalue().split("\n")) - {""}))
    if getattr(ulog, "file_corruption", False):  # pyulog skipped a damaged part: its messages are lost, say so
        notes["warnings"] = [*notes.get("warnings", []), f"{where}: pyulog found the file damaged and skipped the damaged part (its messages are lost; "
                             f"notes.pyulog has what it said)"]
    if ulog.has_data_appended:
        notes["appended_data"] = "yes (read by pyulog after the regular data)"
    if ulog.dropouts:
        notes["dropouts"] = f"{len(ulog.dropouts)} logging dropouts, {sum(d.duration for d in ulog.dropouts)} ms in total"
    return flight_from_topics(topics, ulog.initial_parameters, where, vehicle=vehicle, notes=notes)


class CutShortWatch(io.BufferedReader):
    """The file as pyulog reads it, noting where it ends inside a message.

    pyulog reads each message as a 3-byte header (size, type) then ``size`` bytes, and stops without a word at a
    message the file ends inside (its comment: "File is most likely cut") -- a log whose writer lost power. A read
    that returns part of a header, or less body than the header before it announced, is that place: ``cut_at``
    [byte offset of the cut message]. A file cut exactly between two messages looks complete. ``read_to`` is the
    furthest byte read: short of the file's size when pyulog stopped early (it ends its reading at any
    ``struct.error``, a message it could not unpack among them)."""

    def __init__(self, path: str | Path):
        super().__init__(io.FileIO(str(path), "rb"))
        self.cut_at: int | None = None
        self.read_to = 0
        self._after_header = False

    def read(self, size: int | None = -1) -> bytes:
        start = self.tell()
        data = super().read(size)
        if size is not None and size > 0 and self.cut_at is None:
            if size == 3 and 0 < len(data) < 3:  # inside a message header
                self.cut_at = start
            elif self._after_header and len(data) < size:  # inside the body a whole header announced
                self.cut_at = start - 3
        self._after_header = size == 3 and len(data) == 3  # (pyulog's resync reads 512-byte chunks: never judged)
        self.read_to = max(self.read_to, start + len(data))
        return data


def open_ulog(path: str | Path, topics) -> tuple:
    """(pyulog ULog holding ``topics``, what pyulog printed, the byte offset the file is cut at or None, the furthest
    byte read); DataError naming the file when unreadable."""
    from pyulog import ULog

    said = io.StringIO()  # pyulog prints its corruption notices: kept in the notes, off the user's terminal
    watch = None
    try:
        with contextlib.redirect_stdout(said):
            watch = CutShortWatch(path)
            return ULog(watch, message_name_filter_list=list(topics)), said, watch.cut_at, watch.read_to
    except FileNotFoundError as err:
        raise DataError(f"{path}: no such file") from err
    except Exception as err:  # pyulog raises bare Exception/struct.error/IndexError on bad files
        raise DataError(f"{path}: not a readable ULog file ({reason(err)})") from err
    finally:
        if watch is not None:
            watch.close()  # pyulog closes it after a whole read, not after raising


def connected_battery(data) -> bool:
    """Whether a ``battery_status`` instance measured a pack: a reading connected (where the field is logged),
    finite and above 0 V (:func:`~quad_modelling.core.alignment.usable_voltages`). PX4 logs every
    battery slot; an unused one reports 0 V, ``connected`` false."""
    ok = usable_voltages(data.get("voltage_v", []))
    if "connected" in data:
        ok &= np.asarray(data["connected"]) != 0
    return bool(ok.any())


def topics_of(data_list) -> tuple[Topics, dict]:
    """Instance 0 of each topic of pyulog ``data_list`` (``battery_status``: the lowest instance that measured a pack,
    :func:`connected_battery`), and a note naming multi-instance topics and the instance used."""
    instances: dict[str, int] = {}
    topics: Topics = {}
    batteries = sorted((d for d in data_list if d.name == "battery_status"), key=lambda d: d.multi_id)
    battery = next((d for d in batteries if connected_battery(d.data)), batteries[0] if batteries else None)
    for dataset in data_list:
        instances[dataset.name] = instances.get(dataset.name, 0) + 1
        if dataset is battery or (dataset.multi_id == 0 and dataset.name != "battery_status"):
            topics[dataset.name] = dataset.data
    multi = {name: count for name, count in instances.items() if count > 1 and name in topics}
    used = {name: battery.multi_id if name == "battery_status" else 0 for name in multi}
    notes = {"instances": {name: f"{count} instances logged, instance {used[name]} used"
                           + (" (the lowest connected)" if name == "battery_status" else "")
                           for name, count in sorted(multi.items())}} if multi else {}
    return topics, notes


def _need(topics: Topics, topic: str, fields: list[str], where: str) -> list[np.ndarray]:
    data = topics[topic]
    missing = [f for f in fields if f not in data]
    if missing:
        raise DataError(f"{where}: topic {topic} lacks field(s) {', '.join(missing)}")
    return [np.asarray(data[f], dtype=float) for f in fields]


def _time(topics: Topics, topic: str, where: str, field: str = "timestamp_sample") -> np.ndarray:
    """The topic's stamps [s] (``field`` when logged, else ``timestamp``), checked non-decreasing."""
    data = topics[topic]
    stamp = np.asarray(data[field] if field in data else data["timestamp"], dtype=np.int64)
    if np.any(np.diff(stamp) < 0):
        k = int(np.argmax(np.diff(stamp) < 0)) + 1
        raise DataError(f"{where}: topic {topic} time stamps go backwards at sample {k}")
    return stamp * 1e-6


def rate_hz(t: np.ndarray) -> float:
    """Mean logging rate [Hz] of stamps ``t`` [s]: (samples - 1) / span."""
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    return (len(t) - 1) / span if span > 0 else 0.0


def rotor_count(topics: Topics, params: dict, where: str) -> tuple[int, str]:
    """(rotor count, where it came from); DataError when it cannot be told."""
    if "CA_ROTOR_COUNT" in params:
        count = params["CA_ROTOR_COUNT"]
        if not np.isfinite(count) or count != int(count):
            raise DataError(f"{where}: parameter CA_ROTOR_COUNT is {count:g}, not a rotor count")
        return int(count), "CA_ROTOR_COUNT"
    mav_type = params.get("MAV_TYPE")
    if mav_type in VTOL_MAV_TYPES:
        raise DataError(f"{where}: MAV_TYPE {mav_type} is a VTOL airframe; only plain quadrotors are read")
    if mav_type in ROTORS_OF_MAV_TYPE:
        return ROTORS_OF_MAV_TYPE[mav_type], f"MAV_TYPE {mav_type}"
    if "actuator_motors" in topics:
        channels = [k for k in topics["actuator_motors"] if k.startswith("control[")]
        used = [k for k in channels if not np.isnan(np.asarray(topics["actuator_motors"][k], dtype=float)).all()]
        return len(used), "actuator_motors channels not all NaN"
    raise DataError(f"{where}: cannot tell the rotor count (no CA_ROTOR_COUNT, MAV_TYPE or actuator_motors)")


def pwm_range(params: dict, channels: list[int]) -> tuple[float, float, str] | None:
    """(min, max, parameter names) of the PWM outputs ``channels`` (0-based), or None when not logged."""
    for prefix in ("PWM_MAIN", "HIL_ACT"):
        low = [params.get(f"{prefix}_MIN{c + 1}") for c in channels]
        high = [params.get(f"{prefix}_MAX{c + 1}") for c in channels]
        if None not in low and None not in high:
            return float(min(low)), float(max(high)), f"{prefix}_MINn/MAXn"
    if "PWM_MAIN_MIN" in params and "PWM_MAIN_MAX" in params:
        return float(params["PWM_MAIN_MIN"]), float(params["PWM_MAIN_MAX"]), "PWM_MAIN_MIN/MAX"
    return None


def four_rotors(topics: Topics, params: dict, where: str) -> str:
    """The rotor-count note ("4 (CA_ROTOR_COUNT)"); DataError naming the count and its source unless 4."""
    count, counted_by = rotor_count(topics, params, where)
    if count != ROTORS:
        raise DataError(f"{where}: {count} rotors ({counted_by}); only {ROTORS}-rotor vehicles are read")
    return f"{count} ({counted_by})"


def motor_channels(params: dict) -> tuple[list[int], str]:
    """(0-based actuator_outputs channels of Motor 1..4, note): those whose PWM_MAIN_FUNCn is Motor k, else 0..3."""
    functions = {c: params.get(f"PWM_MAIN_FUNC{c + 1}") for c in range(16)}
    functions = {c: f for c, f in functions.items() if f is not None and np.isfinite(f)}  # a damaged value names no motor
    by_motor = {int(f) - MOTOR_FUNCTION_FIRST: c for c, f in functions.items() if f is not None and 0 <= int(f) - MOTOR_FUNCTION_FIRST < ROTORS}
    if len(by_motor) == ROTORS:
        channels = [by_motor[k] for k in range(ROTORS)]
        return channels, f"outputs {channels} (PWM_MAIN_FUNCn = Motor 1..4)"
    return list(range(ROTORS)), "outputs [0, 1, 2, 3] (no PWM_MAIN_FUNCn naming the motors: first four)"


def motor_commands(topics: Topics, params: dict, where: str, prefer: str | None = None) -> tuple[str, np.ndarray, np.ndarray, dict]:
    """(source topic, stamps [s], (N, 4) commands as logged, notes) of the four motors: from ``actuator_motors``, else
    ``actuator_outputs``; ``prefer`` one of them when the log holds both (the one in the vehicle's input unit)."""
    notes: dict = {"rotor_count": four_rotors(topics, params, where)}
    if "actuator_motors" in topics and not (prefer == "actuator_outputs" and "actuator_outputs" in topics):
        topic = "actuator_motors"
        u = np.column_stack(_need(topics, topic, [f"control[{i}]" for i in range(ROTORS)], where))
        stopped = np.isnan(u)
        if stopped.any():
            notes["motor_nan"] = f"{int(stopped.sum())} NaN commands (PX4: motor stopped) read as 0"
            u = np.where(stopped, 0.0, u)
    elif "actuator_outputs" in topics:
        topic = "actuator_outputs"
        channels, notes["motor_channels"] = motor_channels(params)
        u = np.column_stack(_need(topics, topic, [f"output[{c}]" for c in channels], where))
        found = pwm_range(params, channels)
        notes["pwm_range"] = f"{found[0]:g}..{found[1]:g} us ({found[2]})" if found else "not in the log's parameters"
    else:
        raise DataError(f"{where}: no motor commands: neither actuator_motors nor actuator_outputs was logged")
    return topic, _time(topics, topic, where, field="timestamp"), u, notes


def position_velocity(topics: Topics, where: str) -> tuple[str, np.ndarray, np.ndarray, list[str]]:
    """(source topic, stamps [s], (n, 6) NED position [m] and velocity [m/s], warnings). ``vehicle_odometry`` (the
    fallback): each message's ``pose_frame`` / ``velocity_frame`` is read where its numbers are finite (PX4 marks
    invalid numbers NaN and their frame means nothing there, as the bag reader's topic maps); a velocity frame that
    changes within the log is read message by message and warned about."""
    if "vehicle_local_position" in topics:
        topic = "vehicle_local_position"
        return topic, _time(topics, topic, where), np.column_stack(_need(topics, topic, ["x", "y", "z", "vx", "vy", "vz"], where)), []
    if "vehicle_odometry" not in topics:
        raise DataError(f"{where}: no position: neither vehicle_local_position nor vehicle_odometry was logged")
    topic = "vehicle_odometry"
    pose_frame, velocity_frame = (np.asarray(a) for a in _need(topics, topic, ["pose_frame", "velocity_frame"], where))
    values = np.column_stack(_need(topics, topic, [f"position[{i}]" for i in range(3)] + [f"velocity[{i}]" for i in range(3)], where))
    pose_named = pose_frame[np.all(np.isfinite(values[:, :3]), axis=1)]
    velocity_named = velocity_frame[np.all(np.isfinite(values[:, 3:]), axis=1)]
    if np.any(pose_named != POSE_FRAME_NED) or np.any(~np.isin(velocity_named, (VELOCITY_FRAME_NED, VELOCITY_FRAME_BODY_FRD))):
        raise DataError(f"{where}: topic vehicle_odometry: pose_frame {sorted({int(f) for f in pose_named})}, velocity_frame "
                        f"{sorted({int(f) for f in velocity_named})} (messages with finite numbers); read are pose_frame 1 "
                        "(NED) and velocity_frame 1 (NED) or 3 (body FRD): an FRD-referenced odometry (frame 2) has no known heading")
    warnings = []
    if len(set(velocity_named.tolist())) > 1:
        counts = "; ".join(f"{int(f)} = {name} in {int(np.sum(velocity_named == f))} messages"
                           for f, name in ((VELOCITY_FRAME_NED, "NED"), (VELOCITY_FRAME_BODY_FRD, "FRD (body, rotated into NED)")))
        warnings.append(f"{where}: velocity from vehicle_odometry velocity_frame {counts}: the frame changes within the "
                        "recording, each message read in its own frame")
    body = velocity_frame == VELOCITY_FRAME_BODY_FRD
    if body.any():  # v_N = R v_B with the message's own attitude q (w, x, y, z) of R_NED<-FRD; NaN without a valid q
        w, x, y, z = (np.asarray(c, dtype=float)[body] for c in _need(topics, topic, [f"q[{i}]" for i in range(4)], where))
        quat, rows = np.column_stack([x, y, z, w]), np.flatnonzero(body)
        valid = np.all(np.isfinite(quat), axis=1) & (np.linalg.norm(np.nan_to_num(quat), axis=1) > 0)
        values[rows[~valid], 3:6] = np.nan  # PX4's "attitude not valid": no frame to read the velocity in
        values[rows[valid], 3:6] = np.einsum("nij,nj->ni", frames.quat_to_matrix(quat[valid]), values[rows[valid], 3:6])
    return topic, _time(topics, topic, where), values, warnings


def imu(topics: Topics, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(accel stamps [s], specific force FRD [m/s²], gyro stamps [s], rates FRD [rad/s]) from sensor_combined."""
    if "sensor_combined" not in topics:
        raise DataError(f"{where}: no accelerometer: sensor_combined was not logged")
    topic = "sensor_combined"
    gyro_t = _time(topics, topic, where, field="timestamp")
    acc = np.column_stack(_need(topics, topic, [f"accelerometer_m_s2[{i}]" for i in range(3)], where))
    gyro = np.column_stack(_need(topics, topic, [f"gyro_rad[{i}]" for i in range(3)], where))
    relative = np.asarray(topics[topic].get("accelerometer_timestamp_relative", np.zeros(len(gyro_t))), dtype=np.int64)
    acc_t = gyro_t + np.where(relative == RELATIVE_TIMESTAMP_INVALID, 0, relative) * 1e-6
    if np.any(np.diff(acc_t) < 0):
        acc_t = gyro_t  # relative stamps out of order: the gyro's stamp is the sample's (PX4 SensorCombined.msg)
    return acc_t, acc, gyro_t, gyro


def armed_at(topics: Topics, t: np.ndarray) -> tuple[np.ndarray | None, str]:
    """Armed flag per base time (last state logged at or before it; disarmed before the first)."""
    if "vehicle_status" in topics and "arming_state" in topics["vehicle_status"]:
        topic, armed = "vehicle_status", np.asarray(topics["vehicle_status"]["arming_state"]) == ARMING_STATE_ARMED
    elif "actuator_armed" in topics and "armed" in topics["actuator_armed"]:
        topic, armed = "actuator_armed", np.asarray(topics["actuator_armed"]["armed"]).astype(bool)
    else:
        return None, "no vehicle_status or actuator_armed: nothing dropped"
    stamps = np.asarray(topics[topic]["timestamp"], dtype=np.int64) * 1e-6
    index = np.searchsorted(stamps, t, side="right") - 1
    return np.where(index >= 0, armed[np.clip(index, 0, None)], False), topic


def linear(source_t: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Each column of ``values`` (stamps ``source_t``) linearly interpolated at ``t``; repeated stamps keep the last."""
    keep = np.append(np.diff(source_t) > 0, True)
    source_t, values = source_t[keep], values[keep]
    return np.column_stack([np.interp(t, source_t, column) for column in np.atleast_2d(values.T)])


def attitude(source_t: np.ndarray, quat_wxyz: np.ndarray, t: np.ndarray, where: str) -> np.ndarray:
    """Euler (φ, θ, ψ) [rad] at ``t`` from PX4 quaternions (w, x, y, z) of R_NED←FRD by slerp; yaw unwrapped. Only
    the samples the slerp at ``t`` reads are checked (PX4 logs NaN before its estimator is aligned, before arming)."""
    first = max(int(np.searchsorted(source_t, t[0], side="right")) - 1, 0)  # the last sample at or before t[0] ...
    last = min(int(np.searchsorted(source_t, t[-1], side="right")), len(source_t) - 1)  # ... the first after t[-1]
    bad_quaternion = frames.non_unit_quaternion(quat_wxyz[first:last + 1])
    if bad_quaternion:
        row, norm = bad_quaternion
        raise DataError(f"{where}: topic vehicle_attitude q at sample {first + row} has norm {norm:.3f}, not 1")
    source_t, quat_wxyz = source_t[first:last + 1], quat_wxyz[first:last + 1]
    keep = np.append(np.diff(source_t) > 0, True)
    rotations = Rotation.from_quat(quat_wxyz[keep], scalar_first=True)
    euler = frames.rotation_to_euler_ned(Slerp(source_t[keep], rotations)(t))
    euler[:, 2] = frames.unwrap_angles(euler[:, 2])
    return euler


def flight_from_topics(topics: Topics, params: dict, where: str, vehicle: str | VehicleConfig | None = None,
                       notes: dict | None = None) -> FlightLog:
    """Map PX4 topics (instance 0, pyulog field names) and parameters onto one FlightLog (module doc)."""
    notes = {"format": "px4-ulog", **(notes or {})}
    required = {"motor commands": ("actuator_motors", "actuator_outputs"), "position": ("vehicle_local_position", "vehicle_odometry"),
                "attitude": ("vehicle_attitude",), "accelerometer": ("sensor_combined",)}
    missing = [" or ".join(names) for names in required.values() if not any(n in topics for n in names)]
    if missing:
        found = sorted(n for n in topics if n in TOPICS)
        raise DataError(f"{where}: missing PX4 topic(s) {'; '.join(missing)} (found: {', '.join(found) or 'none'})")
    given = vehicle if isinstance(vehicle, VehicleConfig) else load_vehicle(vehicle) if vehicle else None
    prefer = next((topic for topic, unit in MOTOR_UNITS.items() if given is not None and unit == given.input_unit), None)
    motor_topic, t, u, motor_notes = motor_commands(topics, params, where, prefer)  # a PWM vehicle: actuator_outputs if logged
    notes.update(motor_notes)
    config = given or load_vehicle(DEFAULT_VEHICLES[motor_topic])
    if config.input_unit != MOTOR_UNITS[motor_topic]:
        raise DataError(
            f"{where}: motor commands come from {motor_topic} ({MOTOR_UNITS[motor_topic]}) but vehicle "
            f"{config.name} takes {config.input_unit}; use vehicle {DEFAULT_VEHICLES[motor_topic]} or one in {MOTOR_UNITS[motor_topic]}"
        )
    keep = np.append(np.diff(t) > 0, True)
    t, u = t[keep], u[keep]
    pos_topic, pos_t, pos_vel, frame_warnings = position_velocity(topics, where)
    if frame_warnings:
        notes["warnings"] = [*notes.get("warnings", []), *frame_warnings]
    att_t = _time(topics, "vehicle_attitude", where)
    quat = np.column_stack(_need(topics, "vehicle_attitude", [f"q[{i}]" for i in range(4)], where))
    acc_t, acc, gyro_t, gyro = imu(topics, where)
    streams = {pos_topic: pos_t, "vehicle_attitude": att_t, "sensor_combined": acc_t}
    battery = None
    if "battery_status" in topics and "voltage_v" in topics["battery_status"]:
        volts = np.asarray(topics["battery_status"]["voltage_v"], dtype=float)
        if "connected" in topics["battery_status"]:
            volts = np.where(np.asarray(topics["battery_status"]["connected"]) != 0, volts, 0.0)
        battery = (_time(topics, "battery_status", where, field="timestamp"), volts)
    start = max(t[0], *(s[0] for s in streams.values()), gyro_t[0])
    end = min(t[-1], *(s[-1] for s in streams.values()), gyro_t[-1])
    inside = (t >= start) & (t <= end)
    if inside.sum() < 2:
        raise DataError(f"{where}: the topics {', '.join([motor_topic, *streams])} share no common time span")
    cut = float(t[-1] - t[0]) - float(t[inside][-1] - t[inside][0])
    t, u = t[inside], u[inside]
    armed, armed_from = armed_at(topics, t)
    if armed is None:
        notes["disarmed"] = armed_from
    elif not armed.any():
        notes["disarmed"] = f"never armed ({armed_from}): the whole log is kept, motors at their disarmed value"
    else:
        first, last = int(np.argmax(armed)), len(armed) - 1 - int(np.argmax(armed[::-1]))
        inner = float(np.sum(np.diff(t[first:last + 1])[~armed[first:last]]))
        notes["disarmed"] = (
            f"dropped {t[first] - t[0]:.2f} s before arming and {t[-1] - t[last]:.2f} s after disarming ({armed_from})"
            + (f"; {inner:.2f} s disarmed inside the armed span kept" if inner > 0 else "")
        )
        t, u = t[first:last + 1], u[first:last + 1]
    gap_fields = {pos_topic: ("pos_n", "vel_n"), "vehicle_attitude": ("euler",), "sensor_combined": ("acc_b", "gyro_b")}
    gaps = {MeasurementGap(topic, a, b, gap_fields[topic])
            for topic, stamps in (*streams.items(), ("sensor_combined", gyro_t))
            for a, b in interpolation_gaps(stamps, t, MAX_INTERPOLATION_GAP_S)}
    rates = {motor_topic: rate_hz(t), **{name: rate_hz(stamps) for name, stamps in streams.items()}}
    notes["time_base"] = f"{motor_topic} stamps, {rates[motor_topic]:.1f} Hz; {cut:.2f} s outside the span all streams cover cut"
    notes["sources"] = {
        "u": f"{motor_topic} ({MOTOR_UNITS[motor_topic]}), {rates[motor_topic]:.1f} Hz, not interpolated",
        "pos_n, vel_n": f"{pos_topic}, {rates[pos_topic]:.1f} Hz, linear",
        "euler": f"vehicle_attitude q, {rates['vehicle_attitude']:.1f} Hz, slerp",
        "acc_b, gyro_b": f"sensor_combined, {rates['sensor_combined']:.1f} Hz, linear",
    }
    vbat = None
    if battery:
        vbat, battery_note = battery_on_rows(*battery, t)
        if vbat is not None:
            notes["sources"]["vbat"] = f"battery_status voltage_v, {rate_hz(battery[0]):.1f} Hz, linear, held at its ends"
        if battery_note:
            notes["battery"] = battery_note
    notes["interpolated"] = sorted([*(name for name in rates if name != motor_topic), *(["battery_status"] if vbat is not None else [])])
    log = FlightLog(
        t=t,
        u=u,
        acc_b=linear(acc_t, acc, t),
        gyro_b=linear(gyro_t, gyro, t),
        pos_n=linear(pos_t, pos_vel[:, :3], t),
        vel_n=linear(pos_t, pos_vel[:, 3:], t),
        euler=attitude(att_t, quat, t, where),
        vbat=vbat,
        meta=FlightMeta(vehicle=config.name, source=where, notes=notes),
    )
    mark_measurement_gaps(log, list(gaps), MAX_INTERPOLATION_GAP_S)
    return log


