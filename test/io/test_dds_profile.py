"""A user's Fast DDS profile file merged with the project's writer settings: theirs kept, ours only where they set nothing."""

import xml.etree.ElementTree as ET

import pytest

from quad_modelling.errors import ConfigError
from quad_modelling.io.dds_profile import merge_profiles, profile_with_defaults
from test.conftest import REPO

OURS = REPO / "config" / "fastdds.xml"
NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}

USER_PROFILE = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <transport_descriptors>
      <transport_descriptor><transport_id>udp_only</transport_id><type>UDPv4</type></transport_descriptor>
    </transport_descriptors>
    <participant profile_name="my_participant" is_default_profile="true">
      <rtps>
        <userTransports><transport_id>udp_only</transport_id></userTransports>
        <useBuiltinTransports>false</useBuiltinTransports>
      </rtps>
    </participant>
    <data_writer profile_name="my_writer" is_default_profile="true">
      <times><initialHeartbeatDelay><sec>0</sec><nanosec>12000000</nanosec></initialHeartbeatDelay></times>
      <qos><data_sharing><kind>OFF</kind></data_sharing></qos>
    </data_writer>
    <data_reader profile_name="my_reader" is_default_profile="true">
      <qos><data_sharing><kind>OFF</kind></data_sharing></qos>
    </data_reader>
  </profiles>
</dds>
"""


def test_user_profile_keeps_its_profiles_and_gains_only_the_heartbeat_it_lacks():
    merged, added = merge_profiles(USER_PROFILE, OURS.read_text(), "mine.xml")
    assert added == ["data_writer/times/heartbeatPeriod"]
    root = ET.fromstring(merged)
    profiles = root.find("f:profiles", NS)
    assert [(p.tag.split("}")[1], p.get("profile_name")) for p in profiles] == [
        ("transport_descriptors", None), ("participant", "my_participant"), ("data_writer", "my_writer"), ("data_reader", "my_reader")]
    participant = profiles.find("f:participant", NS)
    assert participant.find("f:rtps/f:useBuiltinTransports", NS).text == "false"
    assert participant.find("f:rtps/f:userTransports/f:transport_id", NS).text == "udp_only"
    writer = profiles.find("f:data_writer", NS)
    times = writer.find("f:times", NS)
    assert int(times.find("f:initialHeartbeatDelay/f:nanosec", NS).text) == 12_000_000  # theirs, kept
    assert int(times.find("f:heartbeatPeriod/f:sec", NS).text) == 0
    assert int(times.find("f:heartbeatPeriod/f:nanosec", NS).text) == 50_000_000  # ours, added
    assert writer.find("f:qos/f:data_sharing/f:kind", NS).text == "OFF"
    assert len(profiles.findall("f:data_writer", NS)) == 1  # one default writer: theirs, completed
    assert "merged by quad_modelling from mine.xml: added data_writer/times/heartbeatPeriod" in merged


def test_user_heartbeat_wins_and_the_file_is_used_as_is(tmp_path):
    theirs = USER_PROFILE.replace("<times>", "<times><heartbeatPeriod><sec>1</sec><nanosec>0</nanosec></heartbeatPeriod>")
    assert merge_profiles(theirs, OURS.read_text()) == (None, [])
    mine = tmp_path / "mine.xml"
    mine.write_text(theirs)
    assert profile_with_defaults(mine, OURS, directory=tmp_path / "nowhere") == mine  # nothing written


def test_profile_without_a_default_writer_gets_ours_and_the_merge_file_is_shared(tmp_path):
    bare = """<profiles><participant profile_name="p" is_default_profile="true"><domainId>7</domainId></participant>
    <data_writer profile_name="named_only"><qos/></data_writer></profiles>"""  # no namespace, bare <profiles> root
    mine = tmp_path / "mine.xml"
    mine.write_text(bare)
    first = profile_with_defaults(mine, OURS, directory=tmp_path)
    assert first.parent == tmp_path and first.name.startswith("quad_modelling_fastdds_")
    assert profile_with_defaults(mine, OURS, directory=tmp_path) == first  # same input, same file, written once
    root = ET.parse(first).getroot()
    assert root.tag == "profiles" and root.find("participant/domainId").text == "7"
    writers = {w.get("profile_name"): w for w in root.findall("data_writer")}
    assert list(writers) == ["named_only", "quad_modelling_writer"]
    assert writers["quad_modelling_writer"].get("is_default_profile") == "true"
    assert writers["quad_modelling_writer"].find("times/heartbeatPeriod/nanosec").text == "50000000"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([first.name, "mine.xml"])  # no staging left


def test_unreadable_or_foreign_profile_is_one_config_error(tmp_path):
    broken = tmp_path / "broken.xml"
    broken.write_text("<dds><profiles>")
    with pytest.raises(ConfigError, match="broken.xml: not a readable Fast DDS XML profile file"):
        profile_with_defaults(broken, OURS, directory=tmp_path)
    with pytest.raises(ConfigError, match=r"root element <html> is not a Fast DDS profile file"):
        merge_profiles("<html/>", OURS.read_text(), "page.xml")
