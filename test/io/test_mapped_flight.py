"""The streamed assembly of a topic map's streams (FlightAssembler): own rates and phases, cuts, gaps, clocks.

Fed directly with numbers (no bag): PX4 streams at their own rates, each on its own phase, with signals whose
linear interpolation is exact, so every aligned row is known.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import DataError
from quad_modelling.io import mapped_flight
from quad_modelling.io.mapped_flight import FlightAssembler, readers_for
from quad_modelling.io.topic_maps import load_topic_map

ODOM, MOTORS, IMU, BATTERY = ("/fmu/out/vehicle_odometry", "/fmu/out/actuator_motors", "/fmu/out/sensor_combined",
                              "/fmu/out/battery_status")
RATES = {ODOM: 30.0, MOTORS: 200.0, IMU: 250.0, BATTERY: 10.0}
PHASE_NS = {ODOM: 3_100_000, MOTORS: 0, IMU: 1_700_000, BATTERY: 40_000_000}


def _values(path: str, t: float) -> float:
    """Every signal linear in t [s] (exact under linear interpolation); the attitude level, yaw 0."""
    return {"position[0]": 2.0 * t, "position[1]": -t, "position[2]": -1.0, "q[0]": 1.0, "q[1]": 0.0, "q[2]": 0.0, "q[3]": 0.0,
            "velocity[0]": 2.0, "velocity[1]": -1.0, "velocity[2]": 0.0, "accelerometer_m_s2[0]": 0.1 * t,
            "accelerometer_m_s2[1]": 0.0, "accelerometer_m_s2[2]": -9.8, "gyro_rad[0]": 0.0, "gyro_rad[1]": 0.0,
            "gyro_rad[2]": 0.01 * t, "voltage_v": 16.0 - 0.01 * t}.get(path, 0.5)


def _assemble(duration_s=4.0, skip=lambda topic, ns: False, offset_ns=None, values=_values):
    """Messages of the four streams in stamp order -> (FlightLog, the motor stamps fed) for vehicle px4_iris;
    ``values(path, t, topic)`` the numbers of each message (default: :func:`_values`)."""
    topic_map = load_topic_map("px4")
    sources = topic_map.sources(RATES)
    readers = readers_for(topic_map, sources, "test")
    events = []
    for topic, rate in RATES.items():
        n = int(duration_s * rate)
        stamps = 10**9 + PHASE_NS[topic] + np.round(np.arange(n) * 1e9 / rate).astype(np.int64) + (offset_ns or {}).get(topic, 0)
        events += [(int(ns), topic) for ns in stamps if not skip(topic, ns)]
    events.sort()
    motors = np.array([ns for ns, topic in events if topic == MOTORS])
    assembler = FlightAssembler(topic_map, sources, readers, load_vehicle("px4_iris"), "test", capacity=len(motors))
    for ns, topic in events:
        t = (ns - 10**9) / 1e9
        assembler.add(topic, ns, [values(p, t) if values is _values else values(p, t, topic) for p in readers[topic].paths])
    return assembler.finish(), motors


def test_streams_on_their_own_rates_are_aligned_on_the_commands():
    log, motors = _assemble()
    odom_first = 10**9 + PHASE_NS[ODOM]
    odom_last = odom_first + round(119 * 1e9 / 30)
    inside = motors[(motors >= odom_first) & (motors <= odom_last) & (motors >= 10**9 + PHASE_NS[IMU])]
    np.testing.assert_array_equal(np.round(log.t * 1e9).astype(np.int64), inside)  # rows: the motor stamps all cover
    t = (inside - 10**9) / 1e9
    np.testing.assert_allclose(log.pos_n[:, 0], 2 * t, atol=1e-12)
    np.testing.assert_allclose(log.pos_n[:, 1], -t, atol=1e-12)
    np.testing.assert_allclose(log.vel_n, np.tile([2.0, -1.0, 0.0], (len(t), 1)), atol=1e-12)
    np.testing.assert_allclose(log.acc_b[:, 0], 0.1 * t, atol=1e-12)
    np.testing.assert_allclose(log.gyro_b[:, 2], 0.01 * t, atol=1e-12)
    np.testing.assert_allclose(log.u, 0.5)
    np.testing.assert_allclose(log.vbat, np.clip(16.0 - 0.01 * t, 16.0 - 0.01 * 3.94, 16.0 - 0.01 * 0.04), atol=1e-12)
    assert log.meta.notes["sources"]["position"].endswith("30.0 Hz") and "measurement_gaps" not in log.meta.notes


def _stamps(duration_s: float = 4.0) -> list[tuple[int, str]]:
    """(stamp [ns], topic) of the four streams at their own rates and phases, in stamp order."""
    events = []
    for topic, rate in RATES.items():
        stamps = 10**9 + PHASE_NS[topic] + np.round(np.arange(int(duration_s * rate)) * 1e9 / rate).astype(np.int64)
        events += [(int(ns), topic) for ns in stamps]
    return sorted(events)


def _feed(events, capacity: int):
    """The flight of ``events`` (stamp given [ns], true time [ns], topic), fed in their order, for px4_iris."""
    topic_map = load_topic_map("px4")
    sources = topic_map.sources(RATES)
    readers = readers_for(topic_map, sources, "test")
    assembler = FlightAssembler(topic_map, sources, readers, load_vehicle("px4_iris"), "test", capacity=capacity)
    for stamp, true_ns, topic in events:
        assembler.add(topic, stamp, [_values(p, (true_ns - 10**9) / 1e9) for p in readers[topic].paths])
    return assembler.finish()


def _odometry_not_finite(until_s: float, also_at_s: float | None = None):
    """Values whose odometry velocity is NaN before ``until_s`` [s] (an estimator not yet valid) and at ``also_at_s``."""
    def values(path, t, topic):
        late = also_at_s is not None and abs(t - also_at_s) < 0.01
        return float("nan") if topic == ODOM and path == "velocity[0]" and (t < until_s or late) else _values(path, t)
    return values


def test_leading_odometry_without_a_finite_velocity_is_skipped_and_noted():
    log, motors = _assemble(values=_odometry_not_finite(1.0))
    first_valid_odom = 10**9 + PHASE_NS[ODOM] + round(30 * 1e9 / 30)  # the 31st message, at 1.0031 s
    assert round(log.t[0] * 1e9) >= first_valid_odom  # the rows begin where the odometry is valid
    assert round(log.t[0] * 1e9) == motors[motors >= first_valid_odom][0]
    np.testing.assert_allclose(log.vel_n[:, 0], 2.0, atol=1e-12)
    assert log.meta.notes["leading_not_finite"].startswith(f"{ODOM}: the first 30 messages skipped")


def test_a_not_finite_field_after_valid_messages_is_refused_naming_the_message():
    with pytest.raises(DataError, match=rf"test: topic {ODOM} message 60 field velocity\[0\] is not finite \(after 30 valid"):
        _assemble(values=_odometry_not_finite(1.0, also_at_s=2.0031))
    with pytest.raises(DataError, match=rf"topic {ODOM}: none of its 120 messages has every mapped field .* finite"):
        _assemble(values=_odometry_not_finite(10.0))


def test_a_single_stamp_far_ahead_costs_that_message_not_the_flight():
    """One odometry stamp 10 s in the future (a bad timestamp_sample) was refused as 'stamps go back' at the good
    message after it; the live nodes' stamp gate drops it, and so does the reader: the flight is the one without it."""
    clean, _ = _assemble()
    bad_ns = 10**9 + PHASE_NS[ODOM] + round(60 * 1e9 / 30)  # the 61st odometry message

    def shifted(topic, ns):
        return topic == ODOM and ns == bad_ns

    events = [(ns + (10 * 10**9 if shifted(topic, ns) else 0), ns, topic) for ns, topic in _stamps()]  # arrival order
    log = _feed(events, capacity=sum(1 for _, topic in _stamps() if topic == MOTORS))
    assert log.meta.notes["stamp_outliers"] == f"{ODOM}: 1 message(s) whose stamp lay off the stream's time dropped"
    np.testing.assert_array_equal(log.t, clean.t)
    np.testing.assert_allclose(log.pos_n, clean.pos_n, atol=1e-12)  # linear signals: one sample fewer changes nothing


def test_a_stamp_within_a_microsecond_of_the_last_is_a_repeat():
    """Two command stamps 128 ns apart (a burst) were two rows of one float64 time, refused as 'time is not strictly
    increasing'; they are one stamp, the first message kept, as an exact repeat is."""
    clean, motors = _assemble()
    events = sorted([*_stamps(), (int(motors[100]) + 128, MOTORS)])  # the burst's second message
    log = _feed([(ns, ns, topic) for ns, topic in events], capacity=len(motors) + 1)
    np.testing.assert_array_equal(log.t, clean.t)


def test_small_batches_give_the_same_flight(monkeypatch):
    whole, _ = _assemble()
    monkeypatch.setattr(mapped_flight, "EMIT_ROWS", 7)
    batched, _ = _assemble()
    for field in ("t", "u", "pos_n", "vel_n", "euler", "acc_b", "gyro_b", "vbat"):
        np.testing.assert_array_equal(getattr(batched, field), getattr(whole, field))


def test_a_stream_gap_longer_than_the_live_rule_is_marked():
    """sensor_combined silent for 0.2 s (> 50 ms, the live coverage rule's longest gap): marked, windows left out."""
    log, _ = _assemble(skip=lambda topic, ns: topic == IMU and 2.0e9 < ns - 10**9 < 2.2e9)
    (gap,) = log.meta.notes["measurement_gaps"]
    assert gap["topic"] == IMU and gap["fields"] == ["acc_b", "gyro_b"] and 0.19 < gap["end_s"] - gap["start_s"] < 0.21


def test_a_stream_that_stops_early_cuts_the_flight_there(monkeypatch):
    stops = lambda topic, ns: topic == ODOM and ns - 10**9 > 2.5e9  # noqa: E731
    log, _ = _assemble(skip=stops)
    assert 2.46 < log.t[-1] - 1.0 <= 2.47 and "1.53 s outside" in log.meta.notes["time_base"]  # 3.995 s of motors, 2.46 s kept
    monkeypatch.setattr(mapped_flight, "MAX_PENDING_S", 0.5)  # held rows decided on the way: the same flight
    monkeypatch.setattr(mapped_flight, "EMIT_ROWS", 16)
    early, _ = _assemble(skip=stops)
    np.testing.assert_array_equal(early.t, log.t)
    np.testing.assert_array_equal(early.pos_n, log.pos_n)


@pytest.mark.parametrize("held_s", [60.0, 0.5])
def test_a_stream_on_another_clock_is_refused(monkeypatch, held_s):
    monkeypatch.setattr(mapped_flight, "MAX_PENDING_S", held_s)
    monkeypatch.setattr(mapped_flight, "EMIT_ROWS", 16)
    with pytest.raises(DataError, match=rf"topic {IMU} stamps span -\d+\.\d+\.\.-\d+\.\d+ s, topic {MOTORS} 1\.000\.\.\d\.\d+ s: "
                                        "stamps from another clock"):
        _assemble(offset_ns={IMU: -100 * 10**9})


@pytest.mark.parametrize("held_s", [60.0, 0.5])
def test_a_late_or_pausing_battery_bounds_nothing_and_is_noted(monkeypatch, held_s):
    """The battery (optional, slow) starts 2.9 s late, then pauses 2.5 s: every row kept, its readings held before its
    first and interpolated through the pause, both said; the rows decided on the way (held_s 0.5) give the same."""
    monkeypatch.setattr(mapped_flight, "MAX_PENDING_S", held_s)
    monkeypatch.setattr(mapped_flight, "EMIT_ROWS", 16)
    reference, _ = _assemble(duration_s=8.0)
    log, _ = _assemble(duration_s=8.0, skip=lambda topic, ns: topic == BATTERY and (ns < 3.94e9 or 5.0e9 < ns < 7.5e9))
    np.testing.assert_array_equal(log.t, reference.t)
    t = log.t - 1.0
    first, last = 2.94, 7.94  # the battery's first and last readings [s from the motors' first stamp]
    np.testing.assert_allclose(log.vbat, 16.0 - 0.01 * np.clip(t, first, last), atol=1e-12)
    assert log.meta.notes["battery"] == (f"{BATTERY}: starts 2.9 s after the first row (its first reading held before); "
                                         "1 pause(s) longer than 2 s interpolated (longest 2.6 s from 3.9 s into the flight)")


def test_battery_readings_at_zero_volts_or_not_finite_are_skipped_not_refused():
    def values(path, t, topic):
        if path == "voltage_v" and 1.0 < t < 1.5:
            return 0.0 if t < 1.25 else float("nan")  # a monitor that dropped out
        return _values(path, t)
    log, _ = _assemble(values=values)
    t = log.t - 1.0
    np.testing.assert_allclose(log.vbat, 16.0 - 0.01 * np.clip(t, 0.04, 3.94), atol=1e-12)  # linear through the dropout
    assert log.meta.notes["battery"] == f"{BATTERY}: 5 of 40 readings at or below 0 V or not finite skipped (a battery not connected)"


def test_a_battery_instance_at_zero_volts_is_not_the_one_read():
    """PX4's unused battery slot (0 V) seen first: the first instance with a usable reading is read."""
    topic_map = load_topic_map("px4")
    reader = readers_for(topic_map, topic_map.sources(RATES), "test")[BATTERY]
    seen = [(0, 0.0), (1, 15.9), (0, 0.0), (1, 15.8)]
    kept = [reader.keep(SimpleNamespace(id=which), [volts]) for which, volts in seen]
    assert kept == [False, True, False, True] and reader.chosen == 1 and reader.instances == {0: 2, 1: 2}


def test_commands_in_another_unit_of_the_same_dimension_are_converted_not_range_mapped():
    """PX4 PWM pulse widths (us, range 900..2000) for a vehicle taking seconds (0.001..0.002 s): 1500 us is 0.0015 s,
    not the 0.00155 s of the linear range map; a vehicle in a unit of another kind still gets the range map."""
    source = load_topic_map("px4").sources({"/fmu/out/actuator_outputs": "", "/fmu/out/vehicle_odometry": ""})["commands"]
    in_seconds = dataclasses.replace(load_vehicle("px4_iris_pwm"), input_unit="s", input_min=0.001, input_max=0.002)
    pulses = np.array([[900.0, 1500.0, 2000.0, 1000.0]])
    np.testing.assert_allclose(mapped_flight.commands_in_vehicle_unit(pulses, source, in_seconds, "t"), pulses * 1e-6)
    normalised = load_vehicle("px4_iris")
    np.testing.assert_allclose(mapped_flight.commands_in_vehicle_unit(pulses, source, normalised, "t"), (pulses - 900) / 1100)
