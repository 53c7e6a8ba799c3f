"""Onboard predictor + ground evaluator: run-bag split over two network namespaces ("drone": replay and predictor,
"ground": evaluator) joined by a link with 50 ms delay and 5 % loss each way (test/ros/impaired_link.py), discovery
SUBNET and a user Fast DDS profile (UDPv4 only, so no shared memory bypasses the link; merged with the nodes'
heartbeat). No scored window is lost and every RMS/TIC equals the single-host run exactly.

Needs root and iproute2 to create the namespaces; skipped with the reason elsewhere."""

import json
import os
import shutil
import signal
import subprocess
import sys

import pytest

from test.conftest import REPO
from test.io.test_dds_profile import USER_PROFILE

pytestmark = pytest.mark.slow  # two network namespaces, two DDS graphs over a lossy link (about 40 s): `make test-slow`

BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"
RUN_BAG = [sys.executable, "-m", "quad_modelling.cli", "run-bag", str(BAG), "--models", "naive", "--window", "5", "--no-figures",
           "--no-multistep"]


def _namespaces_unavailable() -> str | None:
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "no ip (iproute2) to create network namespaces"
    if not os.path.exists("/dev/net/tun"):
        return "no /dev/net/tun for the link's TAP devices"
    probe = f"qm-probe-{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot create a network namespace: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def _stop(proc: subprocess.Popen) -> None:
    """SIGTERM (run-bag stops its nodes and removes its staging), SIGKILL after 20 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.exclusive  # a real-time graph over a lossy link: a window came in late while a --validate ran beside it
def test_drone_and_ground_over_a_lossy_delayed_link_score_what_one_host_scores(tmp_path):
    reason = _namespaces_unavailable()
    if reason:
        pytest.skip(reason)
    from test.ros.impaired_link import ImpairedLink

    env = {**os.environ, "PYTHONPATH": str(REPO)}
    single = subprocess.run([*RUN_BAG, "-o", str(tmp_path / "single")], env=env, capture_output=True, text=True, timeout=120)
    assert single.returncode == 0, single.stderr
    profile = tmp_path / "udp_only.xml"
    profile.write_text(USER_PROFILE)
    # TMPDIR: the merged profile (<tmp>/quad_modelling_fastdds_<hash>.xml) goes with the test's files; the domain is set,
    # so no domain lock file is looked for there.
    env.update(ROS_DOMAIN_ID="42", FASTRTPS_DEFAULT_PROFILES_FILE=str(profile), TMPDIR=str(tmp_path))
    split = [*RUN_BAG, "--discovery", "subnet", "--remote-timeout", "30", "--timeout", "80"]
    with ImpairedLink(("ground", "drone"), delay_s=0.05, loss=0.05, seed=1) as link:
        for name in ("ground", "drone"):  # nothing else to send to: loopback and the link
            links = subprocess.run(["ip", "-n", link.namespace(name), "-o", "link"], capture_output=True, text=True).stdout
            assert [line.split(":")[1].strip().split("@")[0] for line in links.splitlines()] == ["lo", f"qm{name[0]}{os.getpid()}"[:15]]
        procs = {}
        try:
            for name, nodes in (("drone", "replay,predictors"), ("ground", "evaluator")):
                procs[name] = subprocess.Popen(link.exec(name) + [*split, "--nodes", nodes, "-o", str(tmp_path / name)], env=env,
                                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            outputs = {name: proc.communicate(timeout=85)[0] for name, proc in procs.items()}
        finally:
            for proc in procs.values():
                _stop(proc)
    assert [procs["drone"].returncode, procs["ground"].returncode] == [0, 0], outputs
    assert "expecting /quad/evaluator on another host (ROS_DOMAIN_ID 42, discovery SUBNET)" in outputs["drone"]
    assert "the evaluator on the other host writes the results" in outputs["drone"]
    assert not (tmp_path / "drone" / "results.json").exists() and (tmp_path / "drone" / "logs" / "replay.log").is_file()
    merged = list(tmp_path.glob("quad_modelling_fastdds_*.xml"))  # the user's profile was merged, once for both hosts
    assert len(merged) == 1 and "added data_writer/times/heartbeatPeriod" in merged[0].read_text()
    # The link carried the graph and was impaired: every frame crossed it with 50 ms delay, about 5 % dropped each way.
    for direction, stats in link.stats.items():
        assert stats["frames"] > 2000 and 0.03 < stats["dropped"] / stats["frames"] < 0.07, (direction, stats)
    ground = json.loads((tmp_path / "ground" / "results.json").read_text())
    one_host = json.loads((tmp_path / "single" / "results.json").read_text())
    # 42.3 s at 5 s windows: windows 0-7 scored, the partial window 8 marked (input ended), on both.
    # (the marked windows first: a failure shows their reasons; a reader matched late once cost window 0 its first poses)
    assert [(m["model"], m["window"], m["reason"]) for m in ground["live"]["marked"]] == [
        (m["model"], m["window"], m["reason"]) for m in one_host["live"]["marked"]]
    assert [(m["model"], m["window"]) for m in ground["live"]["marked"]] == [("naive", 8), ("dummy", 8)]
    assert ground["windows"] == one_host["windows"] == {"naive": {"live": 8}, "dummy": {"live": 8}}
    assert ground["live"]["marked"] == one_host["live"]["marked"]
    assert ground["models"] == one_host["models"]  # every RMS and TIC of every variable, exactly
    # Nothing lost over the impaired link: the ground's evaluator received every sample, as the single host's did (each
    # host compares the nodes it started: the predictors' counts are the drone's, which exited 0 without a loss line).
    samples = {name: result["live"].pop("samples") for name, result in (("ground", ground), ("single", one_host))}
    assert samples["ground"]["loss"] == samples["single"]["loss"] == [] and "sample loss" not in outputs["drone"]
    assert list(samples["ground"]["received"]) == ["evaluator"]
    assert samples["ground"]["received"]["evaluator"] == samples["single"]["received"]["evaluator"]
    assert ground["live"] == one_host["live"]  # every window, scored or marked, with its numbers
