"""``quad-modelling simulate``: writes a readable thesis log (or bag) that records its own answer."""

import numpy as np

from quad_modelling.cli import main
from quad_modelling.core.effect_names import SIM_EFFECTS
from quad_modelling.io.matlog import read_matlog


def test_simulate_writes_a_thesis_log_with_effects_and_seed(tmp_path, capsys):
    path = tmp_path / "flight.mat"
    args = ["simulate", "-o", str(path), "--duration", "12", "--seed", "3", "--effects", "wind,battery"]
    assert main(args) == 0
    assert "seed 3" in capsys.readouterr().out
    log = read_matlog(path)
    assert log.meta.vehicle == "linkquad" and len(log) == 1200
    assert log.meta.notes["seed"] == 3
    assert log.meta.notes["effects"] == ["battery", "wind"]
    assert set(log.meta.notes["effect_parameters"]) == {"battery", "wind"}
    assert log.vbat is not None and log.omega is not None
    log.check_input_range(0.0009, 0.0021, "s")
    # same command, --force: the identical flight
    assert main(args) == 2
    assert "exists" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0
    assert read_matlog(path).allclose(log, rtol=0.0, atol=0.0)


def test_simulate_crazyflie_all_and_none(tmp_path):
    assert main(["simulate", "-o", str(tmp_path / "cf.mat"), "--vehicle", "crazyflie21", "--effects", "all", "--duration", "8"]) == 0
    log = read_matlog(tmp_path / "cf.mat")
    assert log.meta.notes["effects"] == list(SIM_EFFECTS)
    assert log.u.max() <= 65535 and log.u.min() >= 0
    assert main(["simulate", "-o", str(tmp_path / "none.mat"), "--effects", "none", "--duration", "8"]) == 0
    assert read_matlog(tmp_path / "none.mat").meta.notes["effects"] == []


def test_simulate_rejects_bad_options_with_one_line(tmp_path, capsys):
    assert main(["simulate", "-o", str(tmp_path / "x.mat"), "--effects", "rotor_drag,flapping"]) == 2
    assert "unknown simulator effect 'flapping'" in capsys.readouterr().err
    assert main(["simulate", "-o", str(tmp_path / "x.txt")]) == 2
    assert ".mat" in capsys.readouterr().err
    assert main(["simulate", "-o", str(tmp_path / "x.mat"), "--duration", "1"]) == 2
    assert "at least" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_simulate_bag(tmp_path):
    from quad_modelling.io.bag_io import read_bag

    bag = tmp_path / "sim_bag"
    assert main(["simulate", "-o", str(bag), "--bag", "--duration", "6", "--seed", "1"]) == 0
    log = read_bag(bag)
    assert len(log) == 600
    assert np.all(np.isfinite(log.pos_n))
    assert log.u.max() <= 0.0021


def test_a_flight_too_short_for_its_script_is_said(tmp_path, capsys):
    """--duration 5 is allowed (short flights serve tests) but never leaves the ground: one warning says so and how
    long a flight needs; a 14 s flight takes off, hovers and lands without a word."""
    assert main(["simulate", "-o", str(tmp_path / "short.mat"), "--duration", "5"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["warning: a 5 s flight never leaves the ground (its descent starts at -3 s, the climb ends at 6 s): "
                   "fly at least 14 s for a take-off, a hover and a landing"]
    # 10 s: the descent starts as the vehicle lifts; it climbs to 0.49 m (it was said never to leave the ground)
    assert main(["simulate", "-o", str(tmp_path / "ten.mat"), "--duration", "10"]) == 0
    assert capsys.readouterr().err.startswith("warning: a 10 s flight lands before it reaches the hover height")
    heights = -read_matlog(tmp_path / "ten.mat").pos_n[:, 2]
    assert heights.min() < 0.13 and heights.max() > 0.4  # rests at 0.12 m, then leaves the ground
    assert main(["simulate", "-o", str(tmp_path / "enough.mat"), "--duration", "14"]) == 0
    assert "warning" not in capsys.readouterr().err
    log = read_matlog(tmp_path / "enough.mat")
    assert -log.pos_n[:, 2].min() > 1.0  # the LinkQuad's 1.1 m hover height reached
