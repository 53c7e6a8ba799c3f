import dataclasses

import numpy as np
import pytest

from quad_modelling.core import flight_log
from quad_modelling.core.flight_log import FlightLog
from quad_modelling.errors import DataError
from test.conftest import synthetic_log


def _fields(log: FlightLog) -> dict:
    return {f.name: getattr(log, f.name) for f in dataclasses.fields(log)}


def test_valid_log_reports_rate_and_duration(flight):
    assert len(flight) == 400
    assert flight.sample_rate == pytest.approx(100.0)
    assert flight.duration == pytest.approx(3.99)
    part = flight.slice(100, 200)
    assert len(part) == 100 and part.t[0] == flight.t[100]
    assert part.vbat.shape == (100,)


def test_nan_is_rejected_with_field_row_and_time(flight):
    fields = _fields(flight)
    fields["vel_n"] = fields["vel_n"].copy()
    fields["vel_n"][123, 2] = np.nan
    with pytest.raises(DataError, match=r"synthetic: field vel_n column 2 \(down\) is not finite at sample 124 of 400 \(t=1\.230 s into the flight\)"):
        FlightLog(**fields)


def test_non_monotonic_time_names_the_row(flight):
    fields = _fields(flight)
    fields["t"] = fields["t"].copy()
    fields["t"][50] = fields["t"][49]
    with pytest.raises(DataError, match="time is not strictly increasing at sample 51 of 400"):
        FlightLog(**fields)


def test_wrong_shape_names_the_field(flight):
    fields = _fields(flight)
    fields["u"] = fields["u"][:, :3]
    with pytest.raises(DataError, match=r"field u has shape \(400, 3\), expected \(400, 4\)"):
        FlightLog(**fields)


def test_angles_in_degrees_are_caught(flight):
    fields = _fields(flight)
    fields["euler"] = np.rad2deg(fields["euler"]) * 10  # roll up to 57 'rad': degrees mistaken for radians
    with pytest.raises(DataError, match="field euler column 0 .* wrong unit"):
        FlightLog(**fields)


def test_input_range_check_names_command_row_and_time():
    log = synthetic_log()
    log.u[77, 2] = 70000.0
    with pytest.raises(DataError, match=r"engine command u3 row 77 \(t=5\.770 s\) is 70000.*\[0, 65535\]"):
        log.check_input_range(0, 65535, "PWM")


def test_allclose_detects_a_difference(flight):
    other = flight.slice(0, len(flight))
    assert flight.allclose(other)
    other.pos_n[3, 1] += 1e-3
    assert not flight.allclose(other)


def test_implausible_position_and_velocity_are_refused(flight):
    fields = _fields(flight)
    fields["pos_n"] = fields["pos_n"].copy()
    fields["pos_n"][42, 1] = 1e30
    with pytest.raises(DataError, match=r"synthetic: field pos_n column 1 \(east\) at sample 43 of 400 \(t=0\.420 s into the flight\) is 1e\+30, beyond ±1e\+05 m \(no local frame is that large\)"):
        FlightLog(**fields)
    fields = _fields(flight)
    fields["vel_n"] = fields["vel_n"].copy() * 1000.0  # mm/s read as m/s
    fields["vel_n"][7, 0] = -350.0
    with pytest.raises(DataError, match=r"synthetic: field vel_n column \d \(\w+\) at sample \d+ of \d+ \(t=[0-9.]+ s into the flight\) is .*, beyond ±200 m/s \(faster than any multirotor\)"):
        FlightLog(**fields)
    fields = _fields(flight)
    fields["pos_n"] = fields["pos_n"] + 9.0e4  # a PX4 local frame 90 km from its origin is still a flight
    assert len(FlightLog(**fields)) == 400


@pytest.mark.parametrize("field, row, column, value", [
    ("t", 1, None, np.nan), ("t", 0, None, 1e12), ("t", 1, None, -1.0), ("u", 0, 2, np.inf), ("acc_b", 1, 2, 300.0),
    ("gyro_b", 0, 0, -40.0), ("pos_n", 1, 1, 1e30), ("vel_n", 0, 2, np.nan), ("euler", 1, 1, 4.0), ("vbat", 1, None, np.nan),
    ("omega", 0, 3, -np.inf),
])
def test_a_short_log_is_screened_and_refused_as_the_full_checks_refuse_it(flight, field, row, column, value, monkeypatch):
    """A log of up to SCREENED_ROWS rows passes one stacked check; a bad value there fails it and the per-field checks
    name it: the same message as with the screen off. A valid short log passes (the yaw may exceed π)."""
    fields = {name: (value_.copy() if isinstance(value_, np.ndarray) else value_) for name, value_ in _fields(flight.slice(10, 12)).items()}
    fields["omega"] = np.full((2, 4), 2000.0)
    fields["euler"][:, 2] += 40.0  # a continuous yaw after many turns
    assert len(FlightLog(**fields)) == 2
    if column is None:
        fields[field][row] = value
    else:
        fields[field][row, column] = value
    with pytest.raises(DataError) as screened:
        FlightLog(**fields)
    monkeypatch.setattr(flight_log, "SCREENED_ROWS", 0)
    with pytest.raises(DataError) as checked:
        FlightLog(**fields)
    assert str(screened.value) == str(checked.value)
    assert f"sample {row + 1} of 2" in str(screened.value) or "strictly increasing at sample 2" in str(screened.value)
