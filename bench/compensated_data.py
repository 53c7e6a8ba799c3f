"""NanoBench flights with the motor columns mapped through the Crazyflie firmware's battery compensation.

The Crazyflie firmware (bitcraze/crazyflie-firmware, ``motors.c``, ``motorsCompensateBatteryVoltage``, built with
``CONFIG_ENABLE_THRUST_BAT_COMPENSATED``; whether the NanoBench build (2025.12.1) had it is not recorded, the flights'
response is the evidence: docs/models.md) takes the power distribution's motor value as a *thrust request*
(65536 = 60 g), turns it into a motor voltage with a quadratic fitted by Bitcraze,

    T = u / 65536 * 60 g,   V_motor = -0.0006239 T^2 + 0.088 T   [V],

and sets the PWM duty V_motor / V_bat: the motor sees V_motor whatever the battery. If the NanoBench ``motor_motor_m*``
columns log that request (not the duty), the rotor answers V_motor(u), concave in u: at the flights' hover (u ~ 59000)
its slope is 0.38 of the secant's, so a model linear in u over-predicts every differential (roll/pitch) command by
~2.5x and the fit inflates the inertias by as much (docs/models.md, "Why the fit needs 5x inertia").

``compensated_copy`` writes a copy of a NanoBench directory whose motor columns are the duty the same motor voltage
takes at a fixed reference battery, u' = 65535 V_motor(u) / V_REF: the input of the vehicle file's speed map
(Foerster 2015, rotor speed vs PWM duty), no parameter fitted to the flights. Values outside 0..65535 (a quirk of
B9_trefoil_fast_rep2) are left as logged, for the reader to report as before; an extrapolated motor tail (the same
flight) is cut as the reader cuts it.
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np

FULL_SCALE_GRAMS = 60.0
"""Thrust request at 65536 [g] (Crazyflie firmware motors.c: "Ithrust is thrust mapped for 65536 <==> 60 grams")."""

VOLTAGE_POLYNOMIAL = (-0.0006239, 0.088)
"""V_motor = a T^2 + b T [V], T [g] (Crazyflie firmware motors.c, Bitcraze's thrust stand fit without its constant)."""

V_REF = 3.7
"""Reference battery voltage [V] of the equivalent duty: a 1S LiPo's nominal (firmware comment: 3.7 V mid-charge);
an assumption, the speed map's test-stand supply is not documented."""

MOTOR_COLUMNS = ("motor_motor_m1", "motor_motor_m2", "motor_motor_m3", "motor_motor_m4")
INPUT_MAX = 65535.0


def motor_voltage(request):
    """V_motor [V] of thrust requests ``request`` (0..65535): the firmware's compensation polynomial."""
    thrust = np.asarray(request, dtype=float) / 65536.0 * FULL_SCALE_GRAMS
    a, b = VOLTAGE_POLYNOMIAL
    return a * thrust**2 + b * thrust


def equivalent_duty(request):
    """u' = 65535 V_motor(u) / V_REF: the PWM duty at V_REF giving the motor the voltage the firmware gives it;
    values outside 0..65535 pass unchanged."""
    request = np.asarray(request, dtype=float)
    inside = (request >= 0.0) & (request <= INPUT_MAX)
    return np.where(inside, INPUT_MAX * motor_voltage(request) / V_REF, request)


def _recorded_rows(header: list[str], body: list[list[str]]) -> int:
    """Rows before the extrapolated motor tail the NanoBench reader cuts (io/nanobench.py): the copy drops it too,
    since the mapped tail is no longer a straight line for the reader to find."""
    from quad_modelling.io.nanobench import _recorded_rows as reader_rows

    def number(text: str) -> float:
        try:
            return float(text)
        except ValueError:
            return float("nan")

    motors = np.array([[number(row[header.index(c)]) for c in MOTOR_COLUMNS] for row in body])
    t = np.array([number(row[header.index("t")]) for row in body])
    return reader_rows(motors, t)


def compensated_copy(source: Path, target: Path) -> list[Path]:
    """Copy every ``*.csv.gz`` of ``source`` into ``target`` with :data:`MOTOR_COLUMNS` mapped by
    :func:`equivalent_duty` (metadata, README and LICENSE copied as they are); returns the flights written."""
    import csv

    target.mkdir(parents=True, exist_ok=True)
    written = []
    for path in sorted(source.iterdir()):
        if path.name.endswith(".csv.gz"):
            with gzip.open(path, "rt", newline="") as handle:
                rows = list(csv.reader(handle))
            header, body = rows[0], rows[1:]
            body = body[:_recorded_rows(header, body)]
            for column in MOTOR_COLUMNS:
                i = header.index(column)
                for row in body:
                    if i < len(row) and row[i].strip():
                        try:
                            row[i] = f"{float(equivalent_duty(float(row[i]))):.9f}"
                        except ValueError:
                            pass  # a non-number stays for the reader to report
            with gzip.open(target / path.name, "wt", newline="") as out:
                csv.writer(out, lineterminator="\n").writerows([header] + body)
            written.append(target / path.name)
        elif path.is_file():
            shutil.copy2(path, target / path.name)
    return written
