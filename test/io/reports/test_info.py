"""The info listing of a bag: one aligned line per topic, whatever the length of its type's name."""

from quad_modelling.io.bag_io import BagSummary, TopicSummary
from quad_modelling.io.reports.info import bag_text


def test_topic_lines_stay_aligned_with_a_long_message_type():
    """crazyflie_interfaces/msg/LogDataGeneric (38 characters) pushed its line's count and rate out of their columns."""
    topics = (TopicSummary("/cf1/log_motors", "crazyflie_interfaces/msg/LogDataGeneric", 4000, 0.0, 40.0),
              TopicSummary("/cf1/pose", "geometry_msgs/msg/PoseStamped", 4000, 0.0, 40.0))
    lines = bag_text(BagSummary("bag", "mcap", 40.0, 0.0, 40.0, 8000, topics, {})).splitlines()
    table = lines[lines.index("") + 1:]
    assert table[0].split() == ["topic", "type", "count", "rate", "Hz", "span", "s"]
    assert len({len(line) for line in table}) == 1  # every line as long as the header: the columns line up
    assert {line.index("4000") for line in table[1:]} == {table[0].index("count") + 1}
