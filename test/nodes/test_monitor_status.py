"""Issue 38.4: the monitor node's whole tick, timed, and the status message built once.

:class:`~reachset_ros.nodes.monitor_status.StatusMessage` must give the values the per-tick
message of before gave (non-finite margins as +-1e300, the same arrays); the node must time
every tick's whole callback and report it on ``/diagnostics``. Before: a message built per
tick from Python lists (about 20 us of the tick), no whole-tick timing.
"""
import math
import time

import numpy as np
import pytest

from reachset_ros.nodes.monitor_status import StatusMessage, TickTimes


def reference_status(res, joints):
    """The message's arrays as the node built them before issue 38.4 (element by element)."""
    return {"margin": [float(x) if np.isfinite(x) else (1e300 if x > 0 else -1e300) for x in res["margin"]],
            "deviation": [float(x) for x in res["deviation"]], "tightest_step": [int(x) for x in res["step"]],
            "set_use": [float(x) for x in res["use"]], "active_test_cases": int(max(res["checked"])),
            "name": list(joints)}


@pytest.mark.parametrize("margin", [[0.5, -1e-9, 2.0], [np.inf, -np.inf, np.nan], [1e308, 1e308, 3.0]])
def test_status_message_equals_the_per_tick_message(margin):
    joints = ["a", "b", "c"]
    res = {"margin": np.array(margin), "deviation": np.array([1e-3, np.nan, 0.0]), "step": np.array([4, -1, 125]),
           "use": np.array([0.25, np.nan, 1.5]), "checked": np.array([126, 0, 7])}
    sm = StatusMessage()
    for stamp in (1_000_000_000 * 5 + 7, 4_000_000):       # twice: the message is reused
        m = sm.fill(stamp=stamp, result=res, conformant=False, stop_active=True, tick=9, horizon=125, joints=joints,
                    duration=1.5e-5, model_id="abc")
        want = reference_status(res, joints)
        for key in ("margin", "deviation", "set_use"):
            got = np.array(getattr(m, key))
            assert np.array_equal(got.view(np.int64), np.array(want[key]).view(np.int64)), key   # bits
        assert list(m.tightest_step) == want["tightest_step"] and list(m.name) == joints
        assert m.active_test_cases == want["active_test_cases"]
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == divmod(stamp, 1_000_000_000)
        assert (m.conformant, m.safe_stop_active, m.tick, m.horizon, m.check_duration, m.model_id) == \
            (False, True, 9, 125, 1.5e-5, "abc")
    assert all(math.isfinite(x) for x in m.margin)


def test_tick_times_summary_over_the_kept_ticks():
    t = TickTimes()
    assert t.summary() == {"tick_wall_ticks": 0} and TickTimes("x").summary() == {"x_ticks": 0}
    for ns in range(1, 101):
        t.add(ns * 1000)
    s = t.summary()
    assert s["tick_wall_ticks"] == 100 and float(s["tick_wall_us_max"]) == 100.0
    assert float(s["tick_wall_us_p50"]) == pytest.approx(50.5) and float(s["tick_wall_us_p99"]) == pytest.approx(99.01, abs=0.05)
    for _ in range(TickTimes.KEPT):                         # the ring keeps the last KEPT only
        t.add(7000)
    s = t.summary()
    assert float(s["tick_wall_us_max"]) == 7.0 and s["tick_wall_ticks"] == 100 + TickTimes.KEPT


@pytest.mark.dds
def test_the_node_times_each_whole_tick_and_publishes_the_same_status(tmp_path):
    """A real monitor node in this process (rclpy, its publishers over DDS), its callbacks
    given real messages: every completed tick is timed once (the callback that completed it),
    the diagnostics report it, and the status received is the tick's verdict."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from diagnostic_msgs.msg import DiagnosticArray
    from reachset_msgs.msg import ConformanceStatus, PlantInput
    from sensor_msgs.msg import JointState
    from helpers import JOINTS, stream, write_model
    from reachset_ros.nodes.common import STATUS_QOS
    rclpy.init(args=["--ros-args", "-p", f"model_file:={write_model(tmp_path / 'm.yaml')}",
                     "-p", "max_missing_ticks:=10000", "-p", f"window_dir:={tmp_path / 'w'}"])
    from reachset_ros.nodes.monitor_node import MonitorNode
    node, ear = MonitorNode(), Node("test_ear")
    got, diag = [], []
    sub = ear.create_subscription(ConformanceStatus, "conformance/status", got.append, STATUS_QOS)
    ear.create_subscription(DiagnosticArray, "diagnostics", diag.append, 10)
    ex = SingleThreadedExecutor()
    ex.add_node(ear)
    try:
        end = time.monotonic() + 30
        while not sub.get_publisher_count() or not node.status_pub.get_subscription_count():   # both ends matched
            ex.spin_once(timeout_sec=0.05)
            assert time.monotonic() < end
        Y, U = stream(200)
        for k in range(200):
            js = JointState(name=JOINTS, position=Y[k].tolist())
            js.header.stamp.sec, js.header.stamp.nanosec = 1000, 4_000_000 * k
            pi = PlantInput(name=JOINTS, acceleration=U[k].tolist())
            pi.header.stamp = js.header.stamp
            node.on_joint_states(js) if k % 2 else node.on_plant_input(pi)     # either half may complete it
            node.on_plant_input(pi) if k % 2 else node.on_joint_states(js)
        assert node.tick_times.count == node.statuses == 200
        node.publish_diagnostics()
        end = time.monotonic() + 30
        while (len(got) < 200 or not diag) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        values = {kv.key: kv.value for kv in diag[-1].status[0].values}
        for key in ("tick_wall", "publish_wall"):
            assert int(values[f"{key}_ticks"]) == 200 and 0 < float(values[f"{key}_us_p50"]) \
                <= float(values[f"{key}_us_p99"]) <= float(values[f"{key}_us_max"])
        last = got[-1]
        assert (last.header.stamp.sec, last.header.stamp.nanosec) == (1000, 4_000_000 * 199)
        assert last.conformant and list(last.name) == JOINTS and last.tick == 200
        assert all(math.isfinite(x) and x > 0 for x in last.margin)
    finally:
        ex.shutdown()
        ear.destroy_node()
        node.destroy_node()
        rclpy.shutdown()
