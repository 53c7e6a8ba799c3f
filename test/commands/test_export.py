"""``quad-modelling export``: CasADi files that casadi loads, and each bad input one line, exit 2, nothing written."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import casadi
import numpy as np
import pytest
import yaml

from quad_modelling.cli import main
from quad_modelling.core.physics.parameters import PhysicsParameters
from quad_modelling.core.physics.rigid_body import GRAVITY
from quad_modelling.core.vehicle import load_vehicle, vehicle_dir
from test.core.export.vehicles import crazyflie_document, random_hybrid, vehicle_of, write_vehicle


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """An identified Crazyflie (every term on), one never identified, one with a broken identification record, a hybrid
    of each vehicle, and a work directory."""
    d = tmp_path_factory.mktemp("export")
    write_vehicle(crazyflie_document(cg_offset=False), d / "cf.yaml")  # a level hover holds
    write_vehicle(crazyflie_document(identified=False), d / "cf_starting_values.yaml")
    broken = crazyflie_document()
    broken["identification"]["constants"] = ["rotor_delay"]
    write_vehicle(broken, d / "cf_bad_record.yaml")
    other = crazyflie_document(cg_offset=False)  # identified again: another delay than the hybrids were trained with
    other["constants"]["rotor_delay"]["value"] = other["identification"]["constants"]["rotor_delay"]["value"] = 0.031
    write_vehicle(other, d / "cf_reidentified.yaml")
    random_hybrid(vehicle_of(crazyflie_document())).save(d / "hybrid.npz")
    linkquad = load_vehicle("linkquad")
    random_hybrid(linkquad).save(d / "linkquad_hybrid.npz")
    (d / "work").mkdir()
    (d / "work" / "taken").mkdir()
    return d


def _snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(root.rglob("*"))}


def test_export_writes_functions_casadi_loads_and_their_layout(inputs, tmp_path, capsys):
    out = tmp_path / "cf_model"
    assert main(["export", str(inputs / "cf.yaml"), "--format", "casadi", "-o", str(out)]) == 0
    assert f"{out}: physics model of crazyflie21 (terms on: ground_effect, battery, motor_imbalance, gyroscopic)" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["F.casadi", "F_disturbed.casadi", "f.casadi", "f_disturbed.casadi", "layout.yaml"]
    layout = yaml.safe_load((out / "layout.yaml").read_text())
    assert [s["name"] for s in layout["state"][:3]] == ["pos_n_x", "pos_n_y", "pos_n_z"] and len(layout["state"]) == 22
    assert [i["name"] for i in layout["input"]] == ["u_1", "u_2", "u_3", "u_4", "battery_voltage"]
    p = PhysicsParameters.from_vehicle(vehicle_of(crazyflie_document(cg_offset=False)))
    assert layout["constants"]["rotor_delay_s"] == p.delay and layout["constants"]["input_max"] == 65535.0
    step = casadi.Function.load(str(out / "F.casadi"))
    assert step.name_in() == ["x", "u", "dt"] and step.size1_in(0) == 22 and step.size1_in(1) == 5
    hover = np.zeros(22)
    hover[[6, 10, 14]] = 1.0
    hover[2] = -20.0  # high up: ground effect 1e-7 of the thrust
    hover[18:] = p.hover_rotor_speed(GRAVITY)
    after = np.asarray(step(hover, [*(p.hover_command(GRAVITY) / np.asarray(p.motor_gains)), p.battery[1]], 0.01)).ravel()
    assert np.abs(after - hover).max() < 1e-6  # the loaded step holds the hover it was built around


def test_export_of_a_hybrid_adds_the_logged_commands_and_its_command_filters_to_the_input(inputs, tmp_path):
    out = tmp_path / "cf_hybrid"
    assert main(["export", str(inputs / "cf.yaml"), "--model", f"hybrid:{inputs / 'hybrid.npz'}", "--format", "casadi", "-o", str(out)]) == 0
    layout = yaml.safe_load((out / "layout.yaml").read_text())
    assert layout["model"] == f"hybrid:{inputs / 'hybrid.npz'}" and layout["format_version"] == 2
    filters = [f"u_filtered_{ms}ms_{i}" for ms in (30, 100, 300) for i in range(1, 5)]
    assert [i["name"] for i in layout["input"]][4:] == ["u_logged_1", "u_logged_2", "u_logged_3", "u_logged_4", *filters, "battery_voltage"]
    assert casadi.Function.load(str(out / "f_disturbed.casadi")).size1_in(1) == 9 + 12


BAD = [
    ("unknown-format", ["{d}/cf.yaml", "--format", "onnx", "-o", "{d}/work/out"], "--format onnx: unknown export format; known: casadi"),
    ("unknown-model", ["{d}/cf.yaml", "--model", "narx:{d}/hybrid.npz", "--format", "casadi", "-o", "{d}/work/out"],
     "--model narx:{d}/hybrid.npz: export takes physics or hybrid:FILE"),
    ("never-identified", ["{d}/cf_starting_values.yaml", "--format", "casadi", "-o", "{d}/work/out"],
     "{d}/cf_starting_values.yaml: never identified: the physics constants "),
    ("identification-record-not-a-mapping", ["{d}/cf_bad_record.yaml", "--format", "casadi", "-o", "{d}/work/out"],
     "{d}/cf_bad_record.yaml: identification.constants must be a mapping of constant names"),
    ("no-physics-constants", ["px4_iris", "--format", "casadi", "-o", "{d}/work/out"],
     f"{vehicle_dir() / 'px4_iris.yaml'}: the physics model needs the vehicle constants "),
    ("hybrid-of-another-vehicle", ["{d}/cf.yaml", "--model", "hybrid:{d}/linkquad_hybrid.npz", "--format", "casadi", "-o", "{d}/work/out"],
     "{d}/linkquad_hybrid.npz: model was trained for vehicle 'linkquad', not 'crazyflie21'"),
    ("hybrid-of-other-constants", ["{d}/cf_reidentified.yaml", "--model", "hybrid:{d}/hybrid.npz", "--format", "casadi", "-o", "{d}/work/out"],
     "{d}/hybrid.npz: the hybrid was trained with other physics constants than {d}/cf_reidentified.yaml holds; export takes a "
     "hybrid of the identified vehicle it exports: retrain it, `quad-modelling train FLIGHTS --hybrid --vehicle {d}/cf_reidentified.yaml"),
    ("output-is-the-vehicle", ["{d}/cf.yaml", "--format", "casadi", "-o", "{d}/cf.yaml", "--force"],
     "-o {d}/cf.yaml: the output is the input {d}/cf.yaml"),
    ("output-is-the-model", ["{d}/cf.yaml", "--model", "hybrid:{d}/hybrid.npz", "--format", "casadi", "-o", "{d}/hybrid.npz", "--force"],
     "-o {d}/hybrid.npz: the output is the input {d}/hybrid.npz"),
    ("output-exists", ["{d}/cf.yaml", "--format", "casadi", "-o", "{d}/work/taken"], "{d}/work/taken: exists; pass --force to overwrite"),
    # the last --model was exported, the hybrid before it dropped without a word
    ("two-models", ["{d}/cf.yaml", "--model", "hybrid:{d}/hybrid.npz", "--model", "physics", "--format", "casadi", "-o", "{d}/work/out"],
     "--model given 2 times (hybrid:{d}/hybrid.npz, physics): export writes one model; run it once per model"),
]


@pytest.mark.parametrize(("argv", "expected"), [case[1:] for case in BAD], ids=[case[0] for case in BAD])
def test_bad_export_input_is_one_line_exit_2_and_writes_nothing(inputs, capsys, argv, expected):
    before = _snapshot(inputs)
    code = main(["export", *(a.replace("{d}", str(inputs)) for a in argv)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert re.match(r"^quad-modelling export: error: ", lines[0]) and expected.replace("{d}", str(inputs)) in lines[0], lines[0]
    assert _snapshot(inputs) == before  # nothing written, no staging left, inputs untouched


def test_export_warns_when_the_model_cannot_hover_within_its_commands(inputs, tmp_path, capsys):
    """Identified motor gains far from 1 can put a motor's hover command beyond the command range (0.818 / 1.34 / 0.83
    / 1.01 on two NanoBench flights: 69802 > 65535); the export is written, with one warning naming the motors."""
    doc = crazyflie_document(cg_offset=False)
    doc["effects"]["motor_imbalance"]["gain_2"]["value"] = 0.55
    vehicle = write_vehicle(doc, tmp_path / "weak_motor.yaml")
    out = tmp_path / "weak_model"
    assert main(["export", str(vehicle), "--format", "casadi", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    hover = yaml.safe_load((out / "layout.yaml").read_text())["constants"]["hover_commands"]
    assert hover[1] > 65535.0 and max(hover[0], hover[2], hover[3]) < 65535.0
    warnings = captured.err.strip().splitlines()
    assert len(warnings) == 1 and warnings[0].startswith("warning: the model's level hover needs commands outside [0, 65535] on motor(s) 2 ")
    assert warnings[0].endswith("check the identified motor gains and CG offset (identify's AT BOUND flags)")
    doc["effects"]["motor_imbalance"]["gain_2"]["value"] = 1.0
    doc["constants"]["rotor_thrust_constant"]["value"] /= 4  # every motor short: the thrust constant, not the gains
    assert main(["export", str(write_vehicle(doc, tmp_path / "weak_rotors.yaml")), "--format", "casadi", "-o", str(tmp_path / "m2")]) == 0
    warnings = capsys.readouterr().err.strip().splitlines()
    assert len(warnings) == 1 and "on motor(s) 1, 2, 3, 4 " in warnings[0], warnings
    assert warnings[0].endswith("check the identified thrust constant k_f, the rotor speed map and the mass (identify's AT BOUND flags)")


def test_a_cg_offset_beyond_the_rotors_is_one_line_naming_the_vehicle(tmp_path, capsys):
    doc = crazyflie_document()
    doc["effects"]["motor_imbalance"]["cg_offset_x"].update(value=0.04, bounds=[-0.1, 0.1])  # rotors at x = +-32.5 mm
    vehicle = write_vehicle(doc, tmp_path / "offset.yaml")
    assert main(["export", str(vehicle), "--format", "casadi", "-o", str(tmp_path / "out")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{vehicle}: no level hover: the CG offset (0.04, -0.001) m lies beyond the rotors" in line and "np.float64" not in line, line
    assert not (tmp_path / "out").exists()
