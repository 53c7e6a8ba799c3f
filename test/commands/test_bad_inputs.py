"""The bad-input corpus: what a user can get wrong, each through the real CLI entry point.

Every case must end with exit code 2 and exactly one line on stderr naming the file, field, flag
or row at fault, no traceback, every file under the work directory byte-identical afterwards (the
inputs untouched, no partial output, no staging directory left). Each case runs under an alarm:
a hang fails the case instead of hanging CI. The inputs are built in a temporary directory from
the test fixtures (never from ../shared).
"""

from __future__ import annotations

import gzip
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from quad_modelling.cli import main
from quad_modelling.core.vehicle import vehicle_dir
from quad_modelling.io.bag_io import write_bag
from quad_modelling.io.matlog import write_matlog
from test.conftest import FIXTURES, REPO, synthetic_log
from test.io.test_bag_io import STAMPS, _imu, _motor, _odom, _write_raw_bag

CASE_TIMEOUT_S = 60
"""Longest a case may take; a hang becomes a failure (SIGALRM)."""

NANOBENCH = FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz"


class CaseTimeout(Exception):
    pass


@pytest.fixture(autouse=True)
def alarm():
    def expire(signum, frame):
        raise CaseTimeout(f"case took longer than {CASE_TIMEOUT_S} s: a hang")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(CASE_TIMEOUT_S)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


# ---- the inputs ------------------------------------------------------------------------------------------------


GROUND_TERM = ("effects:\n  ground_effect:\n    enabled: true\n"
               "    coefficient: {{value: {c}, unit: {unit}, bounds: [0, 0.01], source: test, status: identified}}\n"
               "    offset: {{value: 0.05, unit: m, bounds: [0, 0.5], source: test, status: {status}}}\n")
EFFECT_SECTIONS = {
    "effect_unknown": "effects:\n  wind: {enabled: true}\n",
    "effect_unit": GROUND_TERM.format(c=0.001, unit="mm", status="identified"),
    "effect_bounds": GROUND_TERM.format(c=0.5, unit="m2", status="identified"),
    "effect_unidentified": GROUND_TERM.format(c=0.001, unit="m2", status="not identified"),
}
"""Vehicle files whose effects section a user got wrong (appended to the LinkQuad config)."""


def _vehicle_text(**values) -> str:
    """The shipped LinkQuad config with some constants' values replaced (text substitution: the file as a user edits it)."""
    text = (vehicle_dir() / "linkquad.yaml").read_text()
    for key, value in values.items():
        text, count = re.subn(rf"(\n\s*{key}:\s*\{{value:)\s*[^,]+", rf"\g<1> {value}", text)
        assert count == 1, key
    return text


def _npy_header_only(shape, dtype="<f8") -> bytes:
    """An .npy member whose header declares ``shape`` but which holds no data."""
    header = repr({"descr": dtype, "fortran_order": False, "shape": shape}).encode()
    header += b" " * (63 - (10 + len(header)) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """One directory with every bad (and a few good) inputs; cases never modify it (that is asserted)."""
    d = tmp_path_factory.mktemp("corpus")
    (d / "work" / "sub").mkdir(parents=True)
    write_matlog(synthetic_log(vehicle="linkquad", n=2000), d / "flight.mat")
    write_bag(synthetic_log(vehicle="linkquad", n=2000), d / "bag")
    shutil.copy(NANOBENCH, d / "nanobench.csv.gz")
    lines = gzip.open(NANOBENCH, "rt").read().splitlines()
    header = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:50]]
    (d / "missing_px.csv").write_text("\n".join(",".join(c for i, c in enumerate(r) if i != header.index("px"))
                                                 for r in [header, *rows]) + "\n")
    rows[20][header.index("t")] = "1e300"
    (d / "t1e300.csv").write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")
    jumped = [line.split(",") for line in lines[1:50]]
    for row in jumped[30:]:  # every stamp after row 30 1e9 s on: a 745 GiB uniform grid (session 44)
        row[header.index("t")] = repr(float(row[header.index("t")]) + 1e9)
    (d / "t_jump.csv").write_text("\n".join(",".join(r) for r in [header, *jumped]) + "\n")
    (d / "extra_cell.csv").write_text("\n".join([lines[0], *lines[1:20], lines[20] + ",1.0", *lines[21:50]]) + "\n")
    os.mkfifo(d / "fifo.csv")
    os.mkfifo(d / "fifo.yaml")
    os.mkfifo(d / "fifo.npz")
    (d / "zero.csv").symlink_to("/dev/zero")
    (d / "in_link.mat").symlink_to(d / "flight.mat")
    # vehicles
    (d / "latin1.yaml").write_bytes(_vehicle_text().replace("Table", "T\xe4ble").encode("latin-1"))
    bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join([f'*{chr(97 + i)}'] * 9)}]\n" for i in range(9))
    (d / "bomb.yaml").write_text(bomb)
    (d / "nan_mass.yaml").write_text(_vehicle_text(mass=".nan"))
    (d / "renamed.yaml").write_text(_vehicle_text() + "name: other\n")  # an appended key: PyYAML kept the last silently
    (d / "inf_thrust.yaml").write_text(_vehicle_text(rotor_thrust_constant=".inf"))
    (d / "heavy.yaml").write_text(_vehicle_text(mass="1.0e6"))
    (d / "tiny.yaml").write_text(_vehicle_text(mass="1.0e-300"))
    (d / "huge.yaml").write_text(_vehicle_text() + "#" * (2 << 20) + "\n")
    (d / "linkquad_copy.yaml").write_text(_vehicle_text())
    # vehicles with a faulty effects section (the physics model's optional terms)
    for name, section in EFFECT_SECTIONS.items():
        (d / f"{name}.yaml").write_text(_vehicle_text() + section)
    # mappings
    mapping = (REPO / "config" / "mappings" / "example_lab.yaml").read_text()
    (d / "map_columns.yaml").write_text(mapping.replace("columns: [1, 2, 3, 4]", "columns: [a, b, c, d]"))
    (d / "map_unit.yaml").write_text(mapping.replace("{variable: pos, unit: m,", "{variable: pos, unit: deg,"))
    (d / "map_bomb.yaml").write_text(bomb)
    # model files
    (d / "text.npz").write_text("weights: 1 2 3\n")
    with zipfile.ZipFile(d / "petabytes.npz", "w") as z:
        z.writestr("header.npy", _npy_header_only((2**50,)))
    with zipfile.ZipFile(d / "zipbomb.npz", "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("w_u.npy", b"\0" * (65 << 20))
    header = {"format": "quad_modelling.narx", "format_version": 1, "kind": "narx", "vehicle": "linkquad",
              "variables": [], "outputs": [], "config": {}, "dt": "fast", "training": {}}
    np.savez(d / "header_types.npz", header=np.array(json.dumps(header)))
    # bags with a damaged time base
    _write_raw_bag(d / "imu_clock", {"motor_input": [(s, _motor(s)) for s in STAMPS], "mocap/odom": [(s, _odom(s)) for s in STAMPS],
                                     "imu": [(s + 100_000_000_000, _imu(s + 100_000_000_000)) for s in STAMPS]})
    stamps = [1_000_000_000 + 10_000_000 * k for k in range(1000)]
    _write_raw_bag(d / "mocap_gap", {"motor_input": [(s, _motor(s)) for s in stamps],
                                     "mocap/odom": [(s, _odom(s)) for s in stamps if not 2_000_000_000 < s < 8_680_000_000],
                                     "imu": [(s, _imu(s)) for s in stamps]})
    damaged = d / "damaged"
    shutil.copytree(d / "bag", damaged)
    mcap = next(damaged.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    return d


def _snapshot(root: Path) -> dict[str, str]:
    """Every entry under ``root`` (hidden staging included) with the hash of a regular file's bytes."""
    found = {}
    for path in sorted(root.rglob("*")):
        key = str(path.relative_to(root))
        if path.is_symlink() or not path.is_file():
            found[key] = "link" if path.is_symlink() else "dir" if path.is_dir() else "special"
        else:
            found[key] = hashlib.sha256(path.read_bytes()).hexdigest()
    return found


# ---- the corpus: (id, argv with {d} for the inputs directory, what the one line must say) --------------------

LONG_NAME = "{d}/" + "n" * 300
"""An input whose last name is longer than the 255 bytes a Linux file system allows (ENAMETOOLONG)."""

DEEP_PATH = "{d}/" + "/".join(["p" * 200] * 25)
"""An input path of 25 names of 200 bytes: longer than the 4096 bytes of PATH_MAX (ENAMETOOLONG)."""

NEGATIVE_DROP = ("--drop '-5:0': START -5 is negative; --drop START:END gives the seconds dropped at take-off and at "
                 "landing, each >= 0, e.g. 30:22 (0:0 drops nothing)")
"""The one line of a negative --drop start, on every verb that takes --drop."""

CORPUS = [
    # outputs: never an input, never '', . or .., never a name the file system cannot hold
    ("o-empty", ["convert", "{d}/flight.mat", "-o", ""], "-o '': the output must name a new file or directory, not ''"),
    ("o-dot", ["convert", "{d}/flight.mat", "-o", ".", "--force"], "the output must name a new file or directory, not '.'"),
    ("o-dotdot", ["convert", "{d}/flight.mat", "-o", "..", "--force"], "the output must name a new file or directory, not '..'"),
    ("o-long-name", ["convert", "{d}/flight.mat", "-o", "{d}/work/" + "x" * 300], "output name is 300 bytes long; the file system allows 241 here"),
    ("convert-onto-input", ["convert", "{d}/flight.mat", "-o", "{d}/flight.mat", "--force"], "the output is the input {d}/flight.mat; choose another output (refused even with --force)"),
    ("convert-into-input", ["convert", "{d}/bag", "-o", "{d}/bag/inner.mat", "--force"], "the output lies inside the input {d}/bag"),
    ("convert-via-symlink", ["convert", "{d}/in_link.mat", "-o", "{d}/flight.mat", "--force"], "the output is the input {d}/in_link.mat"),
    ("evaluate-onto-bag", ["evaluate", "{d}/bag", "--preset", "short", "-o", "{d}/bag", "--force"], "-o {d}/bag: the output is the input {d}/bag"),
    ("evaluate-contains-input", ["evaluate", "{d}/bag", "--preset", "short", "-o", "{d}", "--force"], "the output contains the input {d}/bag"),
    ("evaluate-onto-model", ["evaluate", "{d}/bag", "--model", "narx:{d}/text.npz", "-o", "{d}/text.npz", "--force"], "the output is the input {d}/text.npz"),
    ("train-onto-bag", ["train", "{d}/bag", "--preset", "short", "-o", "{d}/bag", "--force"], "the output is the input {d}/bag"),
    ("identify-onto-flight", ["identify", "{d}/flight.mat", "-o", "{d}/flight.mat", "--force"], "the output is the input {d}/flight.mat"),
    ("identify-onto-vehicle", ["identify", "{d}/flight.mat", "--vehicle", "{d}/linkquad_copy.yaml", "-o", "{d}/linkquad_copy.yaml", "--force"],
     "the output is the input {d}/linkquad_copy.yaml"),
    ("diagnose-onto-test", ["diagnose", "--train", "{d}/flight.mat", "--test", "{d}/bag", "-o", "{d}/bag", "--force"], "the output is the input {d}/bag"),
    ("run-bag-onto-bag", ["run-bag", "{d}/bag", "-o", "{d}/bag", "--force"], "the output is the input {d}/bag"),
    ("run-bag-onto-direct-model", ["run-bag", "{d}/bag", "--models", "direct:{d}/text.npz", "-o", "{d}/text.npz", "--force"],
     "the output is the input {d}/text.npz"),
    # numbers
    ("window-nan", ["evaluate", "{d}/flight.mat", "--window", "nan", "-o", "{d}/work/out"], "--window nan: must be a finite number"),
    ("window-inf", ["evaluate", "{d}/flight.mat", "--window", "inf", "-o", "{d}/work/out"], "--window inf: must be a finite number"),
    # a negative bound after its flag: argparse read '-5:0' as an option ("argument --drop: expected one argument")
    *[(f"drop-negative-{verb}", [verb, *inputs, "--drop", "-5:0", "-o", out], NEGATIVE_DROP) for verb, inputs, out in [
        ("evaluate", ["{d}/flight.mat"], "{d}/work/out"), ("train", ["{d}/flight.mat"], "{d}/work/m.npz"),
        ("identify", ["{d}/flight.mat"], "{d}/work/v.yaml"),
        ("diagnose", ["--train", "{d}/flight.mat", "--test", "{d}/bag"], "{d}/work/d")]],
    ("drop-negative-end", ["evaluate", "{d}/flight.mat", "--drop", "5:-1", "-o", "{d}/work/out"], "--drop '5:-1': END -1 is negative"),
    ("train-span-negative", ["evaluate", "{d}/flight.mat", "--train", "-5:10", "-o", "{d}/work/out"],
     "span train '-5:10': bound '-5' is negative; e.g. 30:150, 0%:60% or 20:inf"),
    ("simulate-duration-minus-inf", ["simulate", "--duration", "-inf", "-o", "{d}/work/s.mat"], "--duration -inf: must be at least 5 s"),
    ("simulate-duration-abbreviated", ["simulate", "--dur", "-5", "-o", "{d}/work/s.mat"], "--duration -5: must be at least 5 s"),
    ("warm-inf", ["identify", "{d}/flight.mat", "--warm", "inf", "-o", "{d}/work/v.yaml"], "--warm inf: must be a finite number"),
    ("train-seed-negative", ["train", "{d}/flight.mat", "--seed", "-1", "-o", "{d}/work/m.npz"], "--seed -1: must be a whole number in 0..4294967295"),
    ("train-seed-huge", ["train", "{d}/flight.mat", "--seed", "99999999999999999999", "-o", "{d}/work/m.npz"],
     "--seed 99999999999999999999: must be a whole number in 0..4294967295"),
    ("vehicle-mass-tiny", ["evaluate", "{d}/flight.mat", "--vehicle", "{d}/tiny.yaml", "-o", "{d}/work/out"],
     "constants.mass.value must lie in (1e-05, 1000) kg, got 1e-300"),
    ("train-epochs-huge", ["train", "{d}/flight.mat", "--epochs", "1000000000", "-o", "{d}/work/m.npz"], "--epochs 1000000000: must lie in [0, 10000]"),
    ("simulate-duration-inf", ["simulate", "--duration", "inf", "-o", "{d}/work/s.mat"], "--duration inf: must be at least 5 s and at most 3600 s"),
    ("simulate-duration-1e9", ["simulate", "--duration", "1e9", "-o", "{d}/work/s.mat"], "--duration 1e+09: must be at least 5 s and at most 3600 s"),
    ("simulate-duration-nan", ["simulate", "--duration", "nan", "-o", "{d}/work/s.mat"], "--duration nan: must be at least 5 s and at most 3600 s"),
    ("diagnose-validate-short-duration", ["diagnose", "--validate", "--vehicle", "crazyflie21", "--seeds", "0", "--duration", "20",
                                          "--jobs", "1", "--quiet", "-o", "{d}/work/v"],
     "--validate --duration 20: the simulated flights leave the diagnosis nothing to work on (no usable training window"),
    ("diagnose-validate-duration", ["diagnose", "--validate", "--duration", "1e9", "-o", "{d}/work/v"], "simulation duration must be at least 5 s and at most 3600 s, got 1e+09"),
    ("diagnose-smooth-nyquist", ["diagnose", "--base", "greybox", "--train", "{d}/flight.mat", "--test", "{d}/flight.mat", "--smooth", "80", "-o", "{d}/work/d"],
     "--smooth 80 Hz: must be below 40 Hz, 0.8 x the Nyquist frequency 50 Hz of {d}/flight.mat (100 Hz samples)"),
    ("diagnose-smooth-capped", ["diagnose", "--base", "greybox", "--train", "{d}/flight.mat", "--test", "{d}/flight.mat", "--smooth", "45", "-o", "{d}/work/d"],
     "--smooth 45 Hz: must be below 40 Hz, 0.8 x the Nyquist frequency 50 Hz of {d}/flight.mat (100 Hz samples)"),
    ("diagnose-smooth-tiny", ["diagnose", "--base", "greybox", "--train", "{d}/flight.mat", "--test", "{d}/flight.mat", "--smooth", "1e-6", "-o", "{d}/work/d"],
     "--smooth 1e-06 Hz: must be at least 1 / --window = 0.2 Hz (a window holds less than one period of a slower cutoff)"),
    ("evaluate-window-huge", ["evaluate", "{d}/flight.mat", "--window", "1e10", "-o", "{d}/work/e"],
     "--window 1e+10 s: must be at most 1e+06 s (11.6 days)"),
    ("evaluate-drop-huge", ["evaluate", "{d}/flight.mat", "--drop", "99999999999999999999:0", "-o", "{d}/work/e"],
     "--drop start 1e+20 s: must be at most 1e+06 s (11.6 days)"),
    ("identify-effects-blank", ["identify", "{d}/flight.mat", "--effects", "", "-o", "{d}/work/v.yaml"],
     "--effects '': name the terms to fit (e.g. battery,motor_imbalance), or leave --effects out for none"),
    ("evaluate-drop-blank", ["evaluate", "{d}/flight.mat", "--drop", "", "-o", "{d}/work/e"], "--drop '': expected START:END seconds"),
    ("diagnose-validate-seeds-twice", ["diagnose", "--validate", "--seeds", "1,1", "-o", "{d}/work/v"],
     "--seeds '1,1': 1 given more than once; name each item once"),
    ("diagnose-validate-seeds-empty-entry", ["diagnose", "--validate", "--seeds", "1,,2", "-o", "{d}/work/v"],
     "--seeds '1,,2': an empty entry (a comma too many?); name each item once"),
    ("diagnose-validate-pairs-blank", ["diagnose", "--validate", "--pairs", "", "-o", "{d}/work/v"],
     "--pairs '': an empty list; name each item once"),
    ("diagnose-validate-disturbance-blank", ["diagnose", "--validate", "--disturbance", ",", "-o", "{d}/work/v"],
     "--disturbance ',': an empty list; name each item once"),
    ("info-bag-vehicle-unknown", ["info", "{d}/bag", "--vehicle", "nosuch"], "nosuch"),
    ("info-bag-vehicle-other", ["info", "{d}/bag", "--vehicle", "crazyflie21"], "was converted for vehicle linkquad; info reports"),
    ("run-bag-rate-tiny", ["run-bag", "{d}/bag", "--rate", "1e-300", "-o", "{d}/work/r"],
     "s, longer than --timeout 900 s (raise --timeout, or --rate 0: paced by the nodes)"),
    ("run-bag-rate-huge", ["run-bag", "{d}/bag", "--rate", "1e308", "-o", "{d}/work/r"],
     "--rate 1e+308: must be >= 0 and at most 1e+06"),
    ("evaluate-horizons-negative", ["evaluate", "{d}/flight.mat", "--horizons", "-1", "-o", "{d}/work/e"],
     "--horizons -1: give positive step counts"),
    ("diagnose-seeds-negative", ["diagnose", "--validate", "--seeds", "0,-1", "-o", "{d}/work/v"], "--seeds -1: must be a whole number in 0..4294967295"),
    ("diagnose-seeds-huge", ["diagnose", "--validate", "--seeds", "99999999999999999999", "-o", "{d}/work/v"],
     "--seeds 99999999999999999999: must be a whole number in 0..4294967295"),
    ("simulate-seed-huge", ["simulate", "--seed", "99999999999999999999", "-o", "{d}/work/s.mat"],
     "--seed 99999999999999999999: must be a whole number in 0..4294967295"),
    ("simulate-seed-negative", ["simulate", "--seed", "-3", "-o", "{d}/work/s.mat"], "--seed -3: must be a whole number in 0..4294967295"),
    ("run-bag-models-empty-entry", ["run-bag", "{d}/bag", "--models", "greybox,,naive", "-o", "{d}/work/live"],
     "--models 'greybox,,naive': an empty entry in the list (a comma too many?)"),
    ("vehicle-empty", ["evaluate", "{d}/flight.mat", "--vehicle", "", "-o", "{d}/work/out"], "--vehicle '': names nothing"),
    ("topic-map-empty", ["info", "{d}/bag", "--topic-map", " "], "--topic-map ' ': names nothing"),
    ("run-bag-model-name", ["run-bag", "{d}/bag", "--models", "Bad-Name=greybox", "-o", "{d}/work/live"],
     "model name 'Bad-Name' must be letters, digits and '_', not starting with a digit"),
    ("run-bag-baseline-name", ["run-bag", "{d}/bag", "--models", "naive=greybox", "-o", "{d}/work/live"],
     "naive is the name of a baseline every evaluation holds; name the greybox model otherwise"),
    ("run-bag-timeout-nan", ["run-bag", "{d}/bag", "--timeout", "nan", "-o", "{d}/work/live"], "--timeout nan: must be a finite number"),
    ("run-bag-rate-inf", ["run-bag", "{d}/bag", "--rate", "inf", "-o", "{d}/work/live"], "--rate inf: must be a finite number"),
    ("namespace-space", ["convert", "{d}/flight.mat", "--namespace", "/quad drone/1", "-o", "{d}/work/b"],
     "--namespace '/quad drone/1': not a valid ROS 2 namespace: token 'quad drone' must be letters, digits and '_', not starting with a digit"),
    ("namespace-relative", ["convert", "{d}/flight.mat", "--namespace", "quad", "-o", "{d}/work/b"], "not a valid ROS 2 namespace: must start with '/'"),
    ("mistyped-flag", ["evaluate", "{d}/flight.mat", "--windw", "3", "-o", "{d}/work/out"],
     "quad-modelling evaluate: error: unrecognized arguments: --windw 3 (see quad-modelling evaluate --help)"),
    ("float-for-int", ["train", "{d}/flight.mat", "--seed", "1.5", "-o", "{d}/work/m.npz"], "argument --seed: invalid int value: '1.5'"),
    # vehicle configs
    ("vehicle-not-utf8", ["convert", "{d}/flight.mat", "--vehicle", "{d}/latin1.yaml", "-o", "{d}/work/b"], "{d}/latin1.yaml: vehicle config is not UTF-8 text (byte "),
    ("vehicle-alias-bomb", ["convert", "{d}/flight.mat", "--vehicle", "{d}/bomb.yaml", "-o", "{d}/work/b"], "{d}/bomb.yaml: vehicle config expands (through YAML aliases) to more than 100000 nodes"),
    ("vehicle-key-twice", ["evaluate", "{d}/flight.mat", "--vehicle", "{d}/renamed.yaml", "-o", "{d}/work/out"],
     "{d}/renamed.yaml: vehicle config holds key 'name' at lines 15 and "),
    ("vehicle-nan-mass", ["identify", "{d}/flight.mat", "--vehicle", "{d}/nan_mass.yaml", "-o", "{d}/work/v.yaml"], "{d}/nan_mass.yaml: constants.mass.value must be a finite number, got nan"),
    ("vehicle-inf-thrust", ["identify", "{d}/flight.mat", "--vehicle", "{d}/inf_thrust.yaml", "-o", "{d}/work/v.yaml"], "constants.rotor_thrust_constant.value must be a finite number, got inf"),
    ("vehicle-out-of-range", ["evaluate", "{d}/flight.mat", "--vehicle", "{d}/heavy.yaml", "-o", "{d}/work/out"], "constants.mass.value must lie in (1e-05, 1000) kg, got 1e+06"),
    ("vehicle-too-large", ["evaluate", "{d}/flight.mat", "--vehicle", "{d}/huge.yaml", "-o", "{d}/work/out"], "bytes, larger than the 1048576 read"),
    ("vehicle-fifo", ["evaluate", "{d}/flight.mat", "--vehicle", "{d}/fifo.yaml", "-o", "{d}/work/out"], "{d}/fifo.yaml: is a FIFO, not a regular file; give the vehicle config as a file"),
    # mapping files
    ("mapping-columns", ["convert", "{d}/flight.mat", "--mapping", "{d}/map_columns.yaml", "-o", "{d}/work/b"],
     "field 'u': 'columns' must list 4 non-negative 0-based column numbers, got ['a', 'b', 'c', 'd']"),
    ("mapping-unit-dimension", ["convert", "{d}/flight.mat", "--mapping", "{d}/map_unit.yaml", "-o", "{d}/work/b"],
     "field 'pos_n' unit 'deg' is a rad unit; pos_n needs one of ['m', 'mm']"),
    ("mapping-alias-bomb", ["info", "{d}/flight.mat", "--mapping", "{d}/map_bomb.yaml"], "{d}/map_bomb.yaml: mapping file expands (through YAML aliases) to more than 100000 nodes"),
    ("info-mapping-on-bag", ["info", "{d}/bag", "--mapping", "{d}/map_unit.yaml"], "a mapping applies to .mat logs only"),
    # model files
    ("model-text-file", ["evaluate", "{d}/flight.mat", "--model", "narx:{d}/text.npz", "-o", "{d}/work/out"],
     "{d}/text.npz: not a readable model file: not an .npz (zip) archive; expected a file written by quad-modelling train"),
    ("model-petabyte-header", ["evaluate", "{d}/flight.mat", "--model", "narx:{d}/petabytes.npz", "-o", "{d}/work/out"],
     "member header.npy declares a (1125899906842624,) float64 array (9007199254740992 bytes) but holds 0; corrupt model file"),
    ("model-zip-bomb", ["evaluate", "{d}/flight.mat", "--model", "narx:{d}/zipbomb.npz", "-o", "{d}/work/out"],
     "member w_u.npy inflates to 68157440 bytes, more than the 67108864 a model array may have"),
    ("model-header-types", ["evaluate", "{d}/flight.mat", "--model", "narx:{d}/header_types.npz", "-o", "{d}/work/out"],
     "header field 'dt' is str 'fast', expected int or float"),
    ("model-fifo", ["evaluate", "{d}/flight.mat", "--model", "narx:{d}/fifo.npz", "-o", "{d}/work/out"], "{d}/fifo.npz: is a FIFO, not a regular file"),
    ("convert-mapping-for-a-csv", ["convert", "{d}/missing_px.csv", "--mapping", "{d}/nosuch.yaml", "-o", "{d}/work/b"],
     "--mapping {d}/nosuch.yaml: a mapping applies to .mat logs only, and no input is one ({d}/missing_px.csv is a nanobench input)"),
    ("convert-format-bag-on-a-csv", ["convert", "{d}/missing_px.csv", "--format", "bag", "-o", "{d}/work/b"],
     "{d}/missing_px.csv: --format bag reads a bag directory (or its .mcap file); this is a file"),
    # a flight given twice would count twice
    ("evaluate-flight-twice", ["evaluate", "{d}/flight.mat", "../../flight.mat", "-o", "{d}/work/out"],
     "FLIGHT ../../flight.mat: given twice (also as {d}/flight.mat); every flight counts once, give it once"),
    ("identify-flight-twice", ["identify", "{d}/flight.mat", "{d}/flight.mat", "-o", "{d}/work/v.yaml"], "given twice"),
    ("train-val-is-train", ["train", "{d}/flight.mat", "--val-flights", "{d}/flight.mat", "-o", "{d}/work/m.npz"],
     "--val-flights {d}/flight.mat: also a FLIGHT ({d}/flight.mat); a flight is one or the other"),
    ("diagnose-train-twice", ["diagnose", "--train", "{d}/flight.mat", "{d}/flight.mat", "--test", "{d}/flight.mat",
                              "-o", "{d}/work/diag"], "--train {d}/flight.mat: given twice"),
    # flights
    ("flight-fifo", ["convert", "{d}/fifo.csv", "-o", "{d}/work/b"], "{d}/fifo.csv: is a FIFO, not a regular file; give the flight file as a file"),
    ("flight-device", ["info", "{d}/zero.csv"], "{d}/zero.csv: is a device, not a regular file"),
    ("csv-missing-column", ["convert", "{d}/missing_px.csv", "-o", "{d}/work/b"], "{d}/missing_px.csv: missing NanoBench column(s) ['px']"),
    ("csv-t-1e300", ["convert", "{d}/t1e300.csv", "-o", "{d}/work/b"], "{d}/t1e300.csv: time at sample 21 of 49 is 1e+300 s, beyond ±9.223e+09 s (int64 nanosecond stamps): corrupt time base"),
    ("bag-imu-other-clock", ["convert", "{d}/imu_clock", "-o", "{d}/work/b.mat"], "topic /quad/imu stamps are offset by +100.000 s from /quad/motor_input"),
    # a motion-capture dropout is marked, not refused (test/commands/test_measurement_gaps.py); only a .mat output cannot keep it
    ("bag-mocap-gap-to-mat", ["convert", "{d}/mocap_gap", "-o", "{d}/work/b.mat"],
     "{d}/mocap_gap has measurement gaps (/quad/mocap/odom 1.00..7.68 s): a .mat log has one time base; convert to a bag"),
    ("run-bag-damaged", ["run-bag", "{d}/damaged", "-o", "{d}/work/live"], "{d}/damaged: not a readable rosbag2 bag"),
    # the graph ran, scored nothing and exited 0
    ("run-bag-no-window", ["run-bag", "{d}/bag", "--window", "1000", "-o", "{d}/work/live"], "{d}/bag: no 1000 s window fits any span"),
    ("effects-unknown-term", ["evaluate", "{d}/flight.mat", "--vehicle", "{d}/effect_unknown.yaml", "-o", "{d}/work/e"],
     "{d}/effect_unknown.yaml: effects.wind: unknown physics-model term; known: ground_effect"),
    ("effects-wrong-unit", ["identify", "{d}/flight.mat", "--vehicle", "{d}/effect_unit.yaml", "-o", "{d}/work/v.yaml"],
     "{d}/effect_unit.yaml: effects.ground_effect.coefficient.unit must be 'm2', got 'mm'"),
    ("effects-out-of-bounds", ["identify", "{d}/flight.mat", "--vehicle", "{d}/effect_bounds.yaml", "-o", "{d}/work/v.yaml"],
     "{d}/effect_bounds.yaml: effects.ground_effect.coefficient.value 0.5 m2 lies outside its bounds [0, 0.01]"),
    ("effects-never-identified", ["evaluate", "{d}/flight.mat", "--vehicle", "{d}/effect_unidentified.yaml", "-o", "{d}/work/e"],
     "effects.ground_effect.offset: ground_effect is switched on but this parameter was never identified"),
    ("identify-effects-twice", ["identify", "{d}/flight.mat", "--effects", "battery,ground_effect,battery", "-o", "{d}/work/v.yaml"],
     "--effects: battery named more than once"),
    ("identify-effects-unknown", ["identify", "{d}/flight.mat", "--effects", "wind", "-o", "{d}/work/v.yaml"],
     "--effects: unknown physics-model term 'wind'"),
    ("identify-effects-unfittable", ["identify", "{d}/flight.mat", "--effects", "disturbance_observer", "-o", "{d}/work/v.yaml"],
     "--effects: identify cannot fit disturbance_observer yet"),
    ("run-bag-imu-other-clock", ["run-bag", "{d}/imu_clock", "-o", "{d}/work/live"], "topic /quad/imu stamps are offset by +100.000 s"),
    # paths longer than the file system allows (a name over NAME_MAX, a path over PATH_MAX), on every verb that takes one
    *[(f"path-too-long-{case}", argv, f"{what} path is too long for the file system (longest name {name} bytes") for case, argv, what, name in [
        ("convert", ["convert", LONG_NAME + ".csv", "-o", "{d}/work/b"], "flight file", 304),
        ("info", ["info", LONG_NAME], "flight file", 300),
        ("evaluate", ["evaluate", DEEP_PATH + ".mat", "-o", "{d}/work/out"], "flight file", 204),
        ("identify", ["identify", LONG_NAME + ".mat", "-o", "{d}/work/v.yaml"], "flight file", 304),
        ("train", ["train", DEEP_PATH + ".csv", "-o", "{d}/work/m.npz"], "flight file", 204),
        ("diagnose", ["diagnose", "--train", "{d}/flight.mat", "--test", LONG_NAME + ".mat", "-o", "{d}/work/d"], "flight file", 304),
        ("run-bag", ["run-bag", DEEP_PATH, "-o", "{d}/work/live"], "bag", 200),
        ("merge", ["merge", LONG_NAME, "{d}/bag", "-o", "{d}/work/m"], "results directory", 300),
        ("vehicle", ["evaluate", "{d}/flight.mat", "--vehicle", LONG_NAME + ".yaml", "-o", "{d}/work/out"], "vehicle config", 305),
        ("mapping", ["convert", "{d}/flight.mat", "--mapping", DEEP_PATH + ".yaml", "-o", "{d}/work/b"], "mapping file", 205),
        ("model", ["evaluate", "{d}/flight.mat", "--model", f"narx:{LONG_NAME}.npz", "-o", "{d}/work/out"], "model file", 304),
    ]],
    ("output-parent-missing", ["simulate", "-o", "{d}/nowhere/s.mat"], "-o {d}/nowhere/s.mat: its parent directory {d}/nowhere does not exist"),
    ("identify-not-yaml", ["identify", "{d}/flight.mat", "-o", "{d}/work/v.txt"], "-o {d}/work/v.txt: a vehicle file is YAML"),
    ("evaluate-warm-0", ["evaluate", "{d}/flight.mat", "--warm", "0", "-o", "{d}/work/e"], "need window_s > warm_s > 0 (--window, --warm)"),
    # a warm start or window of too few rows was named as a model's "warm start of 1 samples" or "no window fits"
    ("evaluate-warm-under-2-rows", ["evaluate", "{d}/flight.mat", "--warm", "0.001", "-o", "{d}/work/e"],
     "--warm 0.001: 0 row(s) of {d}/flight.mat at 100 Hz; a warm start holds at least 2 rows (0.02 s)"),
    ("identify-window-of-the-warm-rows", ["identify", "{d}/flight.mat", "--preset", "short", "--window", "0.021", "--warm", "0.02",
                                          "-o", "{d}/work/v.yaml"],
     "--window 0.021: 2 row(s) of {d}/flight.mat at 100 Hz or fewer; a window holds at least 2 rows more than its --warm 0.02 s"),
    ("train-val-fraction-all", ["train", "{d}/flight.mat", "--preset", "short", "--val-fraction", "0.999", "-o", "{d}/work/m.npz"],
     "--val-fraction 0.999 of the one flight {d}/flight.mat leaves "),
    ("evaluate-horizons-repeated", ["evaluate", "{d}/flight.mat", "--horizons", "1,1,10", "-o", "{d}/work/e"],
     "--horizons 1,1,10: give each step count once, in increasing order"),
    ("info-time-jump", ["info", "{d}/t_jump.csv"], "t_jump.csv: the time jumps by 1e+09 s after sample 30"),
    ("convert-extra-cell", ["convert", "{d}/extra_cell.csv", "-o", "{d}/work/b"],
     "extra_cell.csv: data row 20 (line 21 of the file) has 53 values, the header 52 columns: a cell more than the header"),
    ("evaluate-horizons-huge", ["evaluate", "{d}/flight.mat", "--horizons", "1,99999999999999999999", "-o", "{d}/work/e"],
     "--horizons 1,99999999999999999999: at most 1000000 steps"),
    ("bag-named-mat", ["simulate", "-o", "{d}/work/s.mat", "--bag", "--duration", "5"], "-o {d}/work/s.mat: an MCAP bag is a directory; a name ending in .mat"),
    ("bag-named-csv", ["convert", "{d}/flight.mat", "-o", "{d}/work/s.csv"], "-o {d}/work/s.csv: an MCAP bag is a directory; a name ending in .csv"),
    ("path-too-long-output-dir", ["simulate", "-o", DEEP_PATH + "/s.mat"], "bytes): output directory path cannot be looked up (File name too long)"),
]


@pytest.mark.parametrize(("argv", "expected"), [case[1:] for case in CORPUS], ids=[case[0] for case in CORPUS])
def test_bad_input_is_one_line_exit_2_and_changes_nothing(inputs, monkeypatch, capsys, argv, expected):
    monkeypatch.chdir(inputs / "work" / "sub")
    before = _snapshot(inputs)
    try:
        code = main([a.replace("{d}", str(inputs)) for a in argv])
    except SystemExit as exit_:  # argparse's errors exit, as the console script does
        code = exit_.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "Traceback" not in err and re.match(r"^quad-modelling( [a-z-]+)?: error: ", lines[0]), err
    assert expected.replace("{d}", str(inputs)) in lines[0]
    assert lines[0].count(str(inputs / "missing_px.csv")) <= 1  # the file is named once
    assert _snapshot(inputs) == before  # inputs byte-identical; no partial output, no staging left


def test_the_corpus_covers_at_least_40_bad_inputs():
    assert len(CORPUS) >= 40 and len({case[0] for case in CORPUS}) == len(CORPUS)


def test_a_foreign_mat_log_can_be_inspected_with_its_mapping(tmp_path, capsys):
    import scipy.io

    log = synthetic_log(vehicle="linkquad")
    scipy.io.savemat(tmp_path / "lab.mat", {
        "T": log.t, "PWM": np.column_stack([np.zeros(len(log)), log.u * 1e6]), "ax": log.acc_b[:, 0] / 9.80665,
        "ay": -log.acc_b[:, 1] / 9.80665, "az": -log.acc_b[:, 2] / 9.80665, "gyro": np.rad2deg(log.gyro_b * [1, -1, -1]),
        "pos": log.pos_n[:, [1, 0, 2]] * [1, 1, -1], "vel": log.vel_n[:, [1, 0, 2]] * [1, 1, -1], "att": np.rad2deg(log.euler),
        "battery_voltage": log.vbat,
    })
    mapping = REPO / "config" / "mappings" / "example_lab.yaml"
    assert main(["info", str(tmp_path / "lab.mat"), "--mapping", str(mapping), "--vehicle", "linkquad", "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["samples"] == 400 and document["vehicle"] == "linkquad"


# ---- disk full: one line, no partial output ----------------------------------------------------------------------


def test_disk_full_while_writing_a_mat_log_is_one_line_and_leaves_nothing(tmp_path, monkeypatch, capsys):
    import errno

    import scipy.io

    write_matlog(synthetic_log(vehicle="linkquad"), tmp_path / "flight.mat")
    before = _snapshot(tmp_path)

    def full(stream, *args, **kwargs):
        stream.write(b"MATLAB 5.0 partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(scipy.io, "savemat", full)
    assert main(["convert", str(tmp_path / "flight.mat"), "-o", str(tmp_path / "copy.mat")]) == 2
    err = capsys.readouterr().err
    assert err == f"quad-modelling convert: error: {tmp_path}/copy.mat: cannot write the output (No space left on device); nothing was written\n"
    assert _snapshot(tmp_path) == before


def test_disk_full_while_writing_a_bag_is_one_line_and_leaves_nothing(tmp_path, monkeypatch, capsys):
    import errno

    from quad_modelling.io import bag_io

    shutil.copy(NANOBENCH, tmp_path / "flight.csv.gz")
    before = _snapshot(tmp_path)
    calls = []

    def full(self, *args, **kwargs):
        calls.append(1)
        if len(calls) > 100:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return original(self, *args, **kwargs)

    original = bag_io.Writer.write
    monkeypatch.setattr(bag_io.Writer, "write", full)
    assert main(["convert", str(tmp_path / "flight.csv.gz"), "-o", str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err
    assert err == f"quad-modelling convert: error: {tmp_path}/bag: cannot write the output (No space left on device); nothing was written\n"
    assert _snapshot(tmp_path) == before


# ---- signals: SIGTERM removes the staging ------------------------------------------------------------------------


def test_sigterm_during_convert_leaves_no_staging_and_no_output(tmp_path):
    for k in range(12):
        shutil.copy(NANOBENCH, tmp_path / f"flight{k}.csv.gz")
    before = _snapshot(tmp_path)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "quad_modelling.cli", "convert", *sorted(str(p) for p in tmp_path.glob("*.csv.gz")),
                             "-o", str(tmp_path / "bags")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 50
        while not any(tmp_path.glob(".bags.tmp-*/bags/flight0")) and time.monotonic() < deadline:  # staging holds a bag
            time.sleep(0.02)
        assert proc.poll() is None, "convert finished before it could be interrupted"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143
    assert err.strip().splitlines()[-1] == "quad-modelling convert: interrupted (SIGTERM)" and "Traceback" not in err
    assert _snapshot(tmp_path) == before  # no bags/, no .bags.tmp-*


def test_a_ctrl_c_while_the_verbs_import_is_one_line_and_exit_130(monkeypatch, capsys):
    """The verbs' modules (numpy, scipy, torch) import before the signal handlers: a Ctrl-C then was a traceback."""
    from quad_modelling import cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["info", "x"]) == 130
    assert capsys.readouterr().err == "quad-modelling: interrupted while starting (SIGINT)\n"


def test_the_shipped_configuration_is_never_an_output_even_with_force(tmp_path, capsys):
    """A vehicle named by the flight (not by --vehicle) or the default a --vehicle-from-log copies its guesses from
    was no input of the check: `identify -o config/vehicles/linkquad.yaml --force` rewrote the shipped file (review)."""
    before = {p.name: p.read_bytes() for p in vehicle_dir().glob("*.yaml")}
    mat = tmp_path / "flight.mat"
    write_matlog(synthetic_log(n=400), mat)
    ulog = REPO / "test" / "data" / "px4" / "sample_px4_events.ulg"
    runs = [["identify", str(mat), "--preset", "short", "-o", str(vehicle_dir() / "linkquad.yaml"), "--force"],
            ["convert", str(ulog), "--vehicle-from-log", str(vehicle_dir() / "px4_iris.yaml"), "-o", str(tmp_path / "bag"), "--force"],
            ["evaluate", str(mat), "-o", str(vehicle_dir().parent), "--force"]]
    for argv in runs:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "the shipped configuration" in err[0] and "refused even with --force" in err[0], err
    assert {p.name: p.read_bytes() for p in vehicle_dir().glob("*.yaml")} == before
    assert not (tmp_path / "bag").exists()


def test_convert_of_several_flights_reruns_with_force_and_evaluate_does_not_replace_a_bag(tmp_path, capsys):
    """convert of several inputs writes a directory of bags: its --force re-run was refused (no marker at its top);
    evaluate -o RECORDING --force replaced a bag (any verb took a bag's metadata.yaml for its own output)."""
    flights = []
    for seed in (1, 2):
        flights.append(tmp_path / f"f{seed}.mat")
        write_matlog(synthetic_log(n=400, seed=seed), flights[-1])
    out = tmp_path / "bags"
    assert main(["convert", *map(str, flights), "-o", str(out)]) == 0
    assert main(["convert", *map(str, flights), "-o", str(out), "--force"]) == 0
    capsys.readouterr()
    recording = out / "f1"
    assert main(["evaluate", str(flights[0]), "--preset", "short", "-o", str(recording), "--force"]) == 2
    assert "is no earlier output of this command (none of results.json)" in capsys.readouterr().err
    assert (recording / "metadata.yaml").is_file()
