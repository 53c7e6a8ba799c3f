"""Node plumbing: the window clock's last warm row, and run_node's GC freeze."""

import gc

from quad_modelling.core.windows import WindowClock
from quad_modelling.nodes.common import run_node


def test_last_warm_row_is_the_one_whose_successor_falls_past_the_warm_start():
    clock = WindowClock(window_s=5.0, warm_s=0.2, sample_period_s=0.0025)  # 400 Hz: warm rows 0..79
    clock.origin_ns = 1_000_000_000
    positions = [clock.locate(clock.origin_ns + row * 2_500_000 + jitter)[1] for row, jitter in
                 [(78, 0), (79, 0), (79, 40_000), (79, -40_000), (80, 0)]]
    assert [clock.is_warm(p) for p in positions] == [True, True, True, True, False]
    assert [clock.is_last_warm(p) for p in positions] == [False, True, True, True, False]  # 40 µs jitter: same answer
    unknown = WindowClock(window_s=5.0, warm_s=0.2)
    unknown.origin_ns = 0
    assert not unknown.is_last_warm(unknown.locate(79 * 2_500_000)[1])  # no period yet: only a row past warm_s tells


def test_run_node_freezes_what_the_node_built_before_it_spins():
    seen = {}

    class Node:
        def run(self):
            seen["frozen"] = gc.get_freeze_count()

        def finish(self):
            pass

        def destroy_node(self):
            pass

    try:
        assert run_node(Node, []) == 0
    finally:
        gc.unfreeze()
    assert seen["frozen"] > 1000  # the node, rclpy and the modules imported so far


def test_realtime_priority_zero_puts_every_thread_back_under_normal_scheduling():
    """The benchmark harness relies on it: a process left under SCHED_FIFO hands it to every process it starts."""
    import os
    import threading

    from quad_modelling.nodes.common import set_realtime_priority

    stop = threading.Event()
    worker = threading.Thread(target=stop.wait)
    worker.start()
    try:
        refused = set_realtime_priority(2)
        threads = [int(t) for t in os.listdir("/proc/self/task")]
        if refused is None:
            assert {os.sched_getscheduler(t) for t in threads} == {os.SCHED_FIFO}
        else:
            assert "not permitted" in refused
        assert set_realtime_priority(0) is None
        assert {os.sched_getscheduler(t) for t in threads} == {os.SCHED_OTHER}
    finally:
        set_realtime_priority(0)
        stop.set()
        worker.join()


def test_both_nodes_name_stream_faults_from_the_one_vocabulary():
    """Every per-stream fault of the predictor and the evaluator is ``stream_fault(kind, stream)`` with a kind of
    STREAM_FAULTS and a stream of STREAMS (or a model's prediction stream): no node spells one of its own."""
    import re

    import pytest

    from quad_modelling.nodes.common import STREAM_FAULTS, STREAMS, stream_fault
    from test.conftest import REPO

    assert STREAMS == ("motor_input", "mocap_odom", "imu", "battery")
    assert stream_fault("stamp_outlier", "imu") == "stamp_outlier_imu" and stream_fault("clock_jump", "motor_input") == "clock_jump_motor_input"
    with pytest.raises(ValueError, match="fault kind 'outlier_stamp' is not in the vocabulary"):
        stream_fault("outlier_stamp", "imu")
    for node in ("predictor_node", "evaluator_node"):
        source = (REPO / "quad_modelling" / "nodes" / f"{node}.py").read_text()
        kinds = re.findall(r"faults\.report\(\s*(.+?),", source)
        assert len(kinds) > 10, node
        for kind in kinds:
            literal = re.fullmatch(r'f?"([^"]*)"', kind)
            if literal is None:
                assert kind.startswith("stream_fault(") or kind in ("event[1]",), (node, kind)
                continue
            text = literal.group(1)
            assert "{" not in text.replace("{model}", ""), (node, kind)  # no per-stream name built by hand (a model's own may be)
            assert not any(text.endswith(f"_{s}") for s in STREAMS + ("odom", "motor")), (node, kind)  # a stream's own name
            assert text not in {f"{k}_{s}" for k in STREAM_FAULTS for s in STREAMS}, (node, kind)


def test_a_second_signal_while_a_node_writes_what_it_owes_is_ignored():
    """The evaluator drawing its figures after Ctrl-C took a SIGTERM (ros2 launch, systemd) as a KeyboardInterrupt
    inside matplotlib: a traceback, exit 130, no results. Now the end is decided once: finish runs to its end."""
    import os
    import signal
    import time

    seen = {}

    class Node:
        def run(self):
            raise KeyboardInterrupt  # the first Ctrl-C ends the spin

        def finish(self):
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # delivered here, in the middle of writing
            seen["finished"] = True

        def destroy_node(self):
            seen["destroyed"] = True

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        assert run_node(Node, []) == 0
    finally:
        gc.unfreeze()
    assert seen == {"finished": True, "destroyed": True}
    assert {s: signal.getsignal(s) for s in before} == before  # the caller's handlers back
