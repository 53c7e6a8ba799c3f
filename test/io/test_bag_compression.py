"""Bags are written with zstd-compressed MCAP chunks: smaller, and read back exactly as written uncompressed."""

import numpy as np
import pytest
from mcap.reader import make_reader

from quad_modelling.io.bag_io import BagRecorder, read_bag, read_recorded, write_bag
from test.conftest import REPO

BAG = REPO / "bags" / "nanobench_B7_oval_medium_rep2"


def _size(bag) -> int:
    return sum(f.stat().st_size for f in bag.iterdir())


@pytest.mark.slow
def test_zstd_bag_is_a_fifth_of_the_size_and_reads_back_the_same_messages(tmp_path):
    flight = read_bag(BAG)  # the bundled 42 s flight, 16,908 messages
    plain = write_bag(flight, tmp_path / "plain", compress=False)
    packed = write_bag(flight, tmp_path / "packed")
    assert _size(packed) < 0.2 * _size(plain)  # 1.08 MB against 6.10 MB here
    assert read_recorded(packed) == read_recorded(plain)  # every message, byte for byte
    again = read_bag(packed)
    for field in ("t", "u", "acc_b", "gyro_b", "pos_n", "vel_n", "euler", "vbat"):
        assert np.array_equal(getattr(again, field), getattr(read_bag(plain), field)), field
    with open(packed / "packed.mcap", "rb") as handle:  # the mcap library (Foxglove's reader) decompresses the chunks
        reader = make_reader(handle)
        assert {c.compression for c in reader.get_summary().chunk_indexes} == {"zstd"}
        assert sum(1 for _ in reader.iter_messages()) == len(read_recorded(plain))
    with open(plain / "plain.mcap", "rb") as handle:
        assert {c.compression for c in make_reader(handle).get_summary().chunk_indexes} == {""}


def test_recorder_stages_the_bag_and_abort_leaves_nothing(tmp_path):
    raw = read_recorded(BAG)[:300]
    recorder = BagRecorder(tmp_path / "rec", custom_data={"quad_modelling.vehicle": "crazyflie21"})
    for m in reversed(raw):  # out of time order, as a live node receives predictions and measurements
        recorder.write(f"/quad/{m.topic}", {"motor_input": "sensor_msgs/msg/JointState", "mocap/odom": "nav_msgs/msg/Odometry",
                                            "imu": "sensor_msgs/msg/Imu", "battery": "sensor_msgs/msg/BatteryState"}[m.topic],
                       m.stamp_ns, m.raw)
    assert not (tmp_path / "rec").exists()  # staged until closed
    assert recorder.close() == tmp_path / "rec"
    assert read_recorded(tmp_path / "rec") == raw  # readers put them back in stamp order
    dropped = BagRecorder(tmp_path / "dropped")
    dropped.write("/quad/imu", "sensor_msgs/msg/Imu", raw[2].stamp_ns, raw[2].raw)
    dropped.abort()
    assert [p.name for p in tmp_path.iterdir()] == ["rec"]  # no staging directory, no bag


def test_a_corrupt_zstd_chunk_is_one_bag_error(tmp_path):
    import pytest

    from quad_modelling.errors import BagError
    from test.conftest import synthetic_log

    bag = write_bag(synthetic_log(n=50), tmp_path / "bag")
    mcap = bag / "bag.mcap"
    with open(mcap, "rb") as handle:
        start = make_reader(handle).get_summary().chunk_indexes[0].chunk_start_offset
    data = bytearray(mcap.read_bytes())
    # chunk record: opcode, length, start/end time, uncompressed size, crc, "zstd" (4 + 4 bytes), records length
    payload = start + 1 + 8 + 8 + 8 + 8 + 4 + 8 + 8
    assert data[payload:payload + 4] == b"\x28\xb5\x2f\xfd"  # the zstd frame magic
    data[payload:payload + 4] = b"\0\0\0\0"
    mcap.write_bytes(bytes(data))
    for read in (read_bag, read_recorded):
        with pytest.raises(BagError, match="corrupt or truncated bag"):
            read(bag)
