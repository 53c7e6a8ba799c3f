"""The package builds with colcon and its executables run as `ros2 run` would run them."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from test.conftest import REPO

VENV_BIN = Path(sys.executable).parent


@pytest.mark.slow
def test_colcon_build_installs_runnable_executables(tmp_path):
    env = {**os.environ, "PATH": f"{VENV_BIN}:{os.environ['PATH']}"}
    build = subprocess.run(
        [str(VENV_BIN / "colcon"), "--log-base", str(tmp_path / "log"), "build", "--base-paths", str(REPO),
         "--packages-select", "quad_modelling", "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    lib = tmp_path / "install" / "quad_modelling" / "lib" / "quad_modelling"
    share = tmp_path / "install" / "quad_modelling" / "share" / "quad_modelling"
    assert (lib / "quad-modelling").is_file() and os.access(lib / "quad-modelling", os.X_OK)
    node_executables = ("replay", "predictor", "greybox_predictor", "narx_predictor", "evaluator")
    for name in node_executables:
        assert (lib / name).is_file() and os.access(lib / name, os.X_OK), name
    assert sorted(p.name for p in (share / "config").glob("*.yaml")) == [
        "evaluator.yaml", "greybox_predictor.yaml", "narx_predictor.yaml", "replay.yaml"]
    assert (share / "config" / "fastdds.xml").is_file()  # the nodes' DDS profile (nodes.common.use_dds_profile)
    assert (share / "launch" / "replay_evaluation.launch.py").is_file()
    assert (share / "package.xml").is_file()
    assert sorted(p.name for p in (share / "config" / "vehicles").iterdir()) == ["crazyflie21.yaml", "linkquad.yaml", "px4_iris.yaml", "px4_iris_pwm.yaml"]

    bag = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
    script = (
        f"source {tmp_path}/install/setup.bash && "
        f"{lib}/quad-modelling info {bag} && "
        "python -c 'import quad_modelling.core.vehicle as v; print(v.__file__); print(v.vehicle_dir()); print(v.load_vehicle(\"linkquad\").mass)'"
    )
    run = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    assert any(line.startswith("/quad/motor_input") and "4227" in line for line in lines)
    module_file, vehicles, mass = lines[-3:]
    assert module_file.startswith(str(tmp_path / "install"))  # the installed copy, not the source tree
    assert vehicles == str(share / "config" / "vehicles")
    assert float(mass) == 1.2

    # the node executables start as `ros2 run` starts them (a bad parameter: exit 2 with the reason)
    node = subprocess.run(["bash", "-c", f"source {tmp_path}/install/setup.bash && {lib}/replay --ros-args -p bag:={tmp_path}/nope"],
                          cwd=tmp_path, env={**env, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, capture_output=True, text=True, timeout=120)
    assert node.returncode == 2 and "no such bag" in node.stderr, node.stdout + node.stderr
