"""The launch file and config/*.yaml name executables and parameters that exist."""

import ast
import os
import re
from pathlib import Path

import pytest
import yaml

from quad_modelling.errors import ConfigError
from quad_modelling.nodes.evaluator_node import EVALUATOR_PARAMETERS
from quad_modelling.nodes.predictor_node import predictor_parameters
from quad_modelling.nodes.replay_node import REPLAY_PARAMETERS
from test.conftest import REPO

DECLARED = {
    "replay": {p.name for p in REPLAY_PARAMETERS},
    "evaluator": {p.name for p in EVALUATOR_PARAMETERS},
    "greybox_predictor": {p.name for p in predictor_parameters("greybox")},
    "narx_predictor": {p.name for p in predictor_parameters("narx")},
}


def entry_points() -> set[str]:
    text = (REPO / "setup.py").read_text()
    return set(re.findall(r'"([\w-]+) = quad_modelling\.', text))


def test_config_files_set_exactly_the_declared_parameters():
    for node, names in DECLARED.items():
        doc = yaml.safe_load((REPO / "config" / f"{node}.yaml").read_text())
        assert list(doc) == ["/**"]  # any node name, any namespace
        assert set(doc["/**"]["ros__parameters"]) == names, node


def test_launch_file_compiles_and_names_existing_executables_and_parameters():
    source = (REPO / "launch" / "replay_evaluation.launch.py").read_text()
    tree = ast.parse(source)
    compile(source, "replay_evaluation.launch.py", "exec")
    nodes = [call for call in ast.walk(tree) if isinstance(call, ast.Call) and getattr(call.func, "id", None) == "Node"]
    assert len(nodes) == 4
    executables = entry_points()
    for call in nodes:
        kw = {k.arg: k.value for k in call.keywords}
        executable = kw["executable"].value
        assert executable in executables and executable in DECLARED
        keys = {k.value for d in ast.walk(kw["parameters"]) if isinstance(d, ast.Dict) for k in d.keys}
        common = {"window_s", "vehicle"} if executable != "replay" else set()
        assert keys - common <= DECLARED[executable], (executable, keys - DECLARED[executable])
        yaml_files = [c.value for c in ast.walk(kw["parameters"]) if isinstance(c, ast.Constant) and str(c.value).endswith(".yaml")]
        assert yaml_files == [f"{executable}.yaml"]


def test_nodes_use_the_shipped_dds_profile_unless_the_environment_names_one(monkeypatch, tmp_path):
    import xml.etree.ElementTree as ET

    from quad_modelling.nodes.common import DDS_PROFILE_ENV, use_dds_profile

    monkeypatch.delenv(DDS_PROFILE_ENV, raising=False)
    shipped = use_dds_profile()
    assert shipped == str(REPO / "config" / "fastdds.xml") and os.environ[DDS_PROFILE_ENV] == shipped
    ns = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    writer = ET.parse(shipped).getroot().find("f:profiles/f:data_writer", ns)
    assert writer.get("is_default_profile") == "true"
    period = writer.find("f:times/f:heartbeatPeriod", ns)
    assert int(period.find("f:sec", ns).text) == 0 and int(period.find("f:nanosec", ns).text) == 50_000_000  # 50 ms, not 3 s
    mine = tmp_path / "mine.xml"  # a user's profile that sets its own heartbeat: used as is
    mine.write_text(Path(shipped).read_text().replace("50000000", "20000000"))
    monkeypatch.setenv(DDS_PROFILE_ENV, str(mine))
    assert use_dds_profile() == str(mine)
    monkeypatch.setenv(DDS_PROFILE_ENV, str(tmp_path / "missing.xml"))
    with pytest.raises(ConfigError, match="FASTRTPS_DEFAULT_PROFILES_FILE=.*missing.xml'?: cannot read the Fast DDS profile"):
        use_dds_profile()


FAST_DDS_LOADS = """
import rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("profile_check")
node.create_publisher(String, "profile_check", 10)
node.destroy_node()
rclpy.shutdown()
"""


def test_fast_dds_loads_a_merged_user_profile_without_parser_errors(tmp_path):
    """The merge of a user's profile (participant + transports + their default writer) is a file Fast DDS parses:
    it prints '[XMLPARSER Error]' lines for an element it rejects (as it does for the unmerged broken one)."""
    import subprocess
    import sys

    from quad_modelling.io.dds_profile import profile_with_defaults
    from test.io.test_dds_profile import USER_PROFILE

    mine = tmp_path / "mine.xml"
    mine.write_text(USER_PROFILE)
    merged = profile_with_defaults(mine, REPO / "config" / "fastdds.xml", directory=tmp_path)
    broken = tmp_path / "broken.xml"
    broken.write_text(USER_PROFILE.replace("<qos><data_sharing>", "<data_sharing>").replace("</data_sharing></qos>", "</data_sharing>"))
    for profile, errors in ((merged, False), (broken, True)):
        run = subprocess.run([sys.executable, "-c", FAST_DDS_LOADS], env={**os.environ, "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)},
                             capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        assert ("XMLPARSER" in run.stdout + run.stderr) is errors, (profile, run.stdout + run.stderr)
