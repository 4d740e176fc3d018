"""Issue 34.1: the monitor never releases an arm it has not checked, over real DDS.

A ``monitor_node`` whose model cannot be loaded exits (status 2, one line) without publishing
anything; one with a model starts with an active stop (``kind: not_ready``) and releases it
only after k* + 1 consecutive ticks checked to the horizon, all conformant, on both inputs.
Before: a missing model was logged and the node published ``active: false`` ("monitor started:
no safe stop active") at once, which released a controller waiting for the monitor; an input
that never arrived left a diagnostics warning and no stop.
"""
import math
import time

import pytest

from helpers import HISTORY, HORIZON, JOINTS, stamps, stream, write_model
from reachset_ros import processes
from reachset_ros.nodes.common import MONITOR_NOT_READY, MONITOR_STARTED

pytestmark = pytest.mark.dds   # real DDS participants / node processes


def start_monitor(bus, d, **params):
    """A monitor_node process with the test model, its inputs matched; ``(proc, window_dir)``."""
    windows = d / "windows"
    proc = processes.start("monitor_node", {"model_file": str(write_model(d / "m.yaml")), "max_missing_ticks": 10000,
                                            "window_dir": str(windows), **params}, d)
    # matched endpoints, not the graph: the ticks' statuses are counted from the first
    assert bus.wait(lambda: bus.js.get_subscription_count() and bus.pi.get_subscription_count()
                    and bus.status_matched(), 30), proc.log.read_text()
    assert bus.wait(lambda: any(s.kind == "not_ready" for s in list(bus.stops)), 30), proc.log.read_text()
    return proc, windows


def assert_never_released(bus):
    """Every /safe_stop received is the start-up stop: active, ``not_ready``, ``not ready: ...``."""
    stops = list(bus.stops)
    assert stops and all(s.active and s.kind == "not_ready" and s.reason.startswith(MONITOR_NOT_READY)
                         and not s.window_bag for s in stops), [(s.active, s.kind, s.reason) for s in stops]


@pytest.mark.parametrize("case", ["empty", "missing", "refused"])
def test_a_monitor_without_a_loadable_model_exits_2_and_publishes_nothing(bus, tmp_path, case):
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: nonsense\n")
    model = {"empty": "", "missing": str(tmp_path / "none.yaml"), "refused": str(bad)}[case]
    bus.clear()
    proc = processes.start("monitor_node", {"model_file": model, "window_dir": str(tmp_path / "w")}, tmp_path)
    try:
        assert proc.proc.wait(timeout=60) == 2, proc.log.read_text()[-1500:]
    finally:
        processes.stop([proc])
    errors = [line for line in proc.log.read_text().splitlines() if "error:" in line]
    assert len(errors) == 1 and "model_file" in errors[0], proc.log.read_text()[-1500:]
    assert case != "missing" or "none.yaml" in errors[0]
    assert "[guarantee G12: " in errors[0]           # the refusal names the row it protects
    time.sleep(1.0)             # a latched message would reach the bus' transient-local reader
    assert not bus.stops, [(s.active, s.reason) for s in bus.stops]


def test_an_input_that_never_arrives_keeps_the_start_up_stop(bus, tmp_path):
    """Only /joint_states (a remapped /plant_input): no tick, the stop stays ``not_ready``,
    /diagnostics names the missing topic, a reset is refused even with ``reset_clean_ticks`` 0,
    and no offending window is written (nothing offended)."""
    bus.clear()
    proc, windows = start_monitor(bus, tmp_path, reset_clean_ticks=0)
    try:
        n = 400
        Y, _ = stream(n, seed=4)
        for t, y in zip(stamps(n), Y):
            bus.send_y(t, JOINTS, y)
            time.sleep(0.002)
        name = "reachset_ros: conformance monitor"
        assert bus.wait(lambda: name in bus.diags and "/plant_input (never received)" in bus.diags[name][1], 30), \
            bus.diags.get(name)
        assert bus.diags[name][1].startswith(MONITOR_NOT_READY)
        r = bus.call_trigger("/monitor_node/reset")
        assert not r.success and MONITOR_NOT_READY in r.message, r.message
        time.sleep(0.5)
        assert not bus.status                       # nothing paired, nothing checked
        assert_never_released(bus)
        assert not windows.exists() or not any(windows.iterdir())
        assert proc.alive()
    finally:
        processes.stop([proc])


def test_the_start_up_stop_is_released_after_k_star_plus_one_checked_ticks(bus, tmp_path):
    """Both inputs, conformant: the ticks' ``safe_stop_active`` is true up to and including the
    (k*+1)-th tick checked to the horizon, false from the next; the release names itself
    (:data:`MONITOR_STARTED`)."""
    bus.clear()
    proc, windows = start_monitor(bus, tmp_path)
    try:
        n = HISTORY + 2 * HORIZON + 40
        Y, U = stream(n, seed=5)
        bus.send_ticks(stamps(n), Y, U)
        assert bus.wait(lambda: len(bus.status) >= n, 30), len(bus.status)
        full = HORIZON + 1                           # test cases checked at a tick checked to k*
        stopped = [s for s in bus.status if s.safe_stop_active]
        assert [s.active_test_cases for s in stopped].count(full) == HORIZON + 1
        assert stopped == bus.status[:len(stopped)] and len(stopped) < n
        assert all(s.active_test_cases == full for s in bus.status[len(stopped):])
        assert bus.wait(lambda: not bus.stops[-1].active, 10)
        release = bus.stops[-1]
        assert release.reason == MONITOR_STARTED and release.kind == "reset"
        assert [s.kind for s in bus.stops if s.active] and all(s.kind == "not_ready" for s in bus.stops if s.active)
        assert not windows.exists() or not any(windows.iterdir())
    finally:
        processes.stop([proc])


def test_a_fault_before_the_release_latches_a_stop_only_a_reset_clears(bus, tmp_path):
    """A non-finite sample while not ready replaces the start-up stop with its own (latched,
    its window written); clean ticks afterwards do not release it."""
    bus.clear()
    proc, windows = start_monitor(bus, tmp_path)
    try:
        n = 2 * (HISTORY + HORIZON + 1)
        Y, U = stream(n, seed=6)
        ts = stamps(n)
        bus.send_ticks(ts[:10], Y[:10], U[:10])
        # the ten ticks checked first (the topics are not ordered against each other: a NaN
        # /joint_states read before their /plant_input would find no window to write)
        assert bus.wait(lambda: len(bus.statuses([ts[0], ts[9]])) >= 10, 20), len(bus.status)
        y = list(Y[10])
        y[0] = math.nan
        bus.send_y(ts[10], JOINTS, y)
        assert bus.wait(lambda: any(s.kind == "invalid_sample" for s in list(bus.stops)), 20)
        bus.send_ticks(ts[11:], Y[11:], U[11:])
        assert bus.wait(lambda: len(bus.status) >= n - 11, 30), len(bus.status)
        time.sleep(0.5)
        assert bus.stops[-1].active and bus.stops[-1].kind == "invalid_sample" and bus.stops[-1].window_bag
        assert not any(not s.active for s in bus.stops)
    finally:
        processes.stop([proc])


def test_the_controller_holds_the_start_up_stop_with_the_drives_not_the_brakes(bus):
    """The ticks that release the start-up stop must check the modelled plant: the controller
    holds the arm through it with the braking law and the drives (category 2), no brake, as
    while it waits for the monitor's state; a stop a check latched brakes (category 1). Before:
    category 1, a brake engaging on a joint not quite at rest was a violation at step 1 of
    the held arm's first test cases (the closed-loop test in test_nodes.py)."""
    from rclpy.parameter import Parameter
    from reachset_msgs.msg import JointEstimate, SafeStop
    from reachset_ros.nodes.common import to_stamp
    from reachset_ros.nodes.controller_node import ControllerNode
    over = {"joints": JOINTS, "u_max": [26.0, 26.0], "omega": [10.0], "zeta": [1.0], "allow_uncertified": True,
            "reference_timeout": 0.0, "stop_category": 1}
    node = ControllerNode(parameter_overrides=[Parameter(k, value=v) for k, v in over.items()])
    ts = stamps(40)

    def held(lo, hi):
        for t in ts[lo:hi]:
            e = JointEstimate(name=JOINTS, position=[0.3, -0.4], velocity=[0.0, 0.0], disturbance=[0.0, 0.0])
            to_stamp(e.header.stamp, t)
            node.on_estimate(e)
    try:
        node.on_safe_stop(SafeStop(active=True, kind="not_ready", reason=f"{MONITOR_NOT_READY} test"))
        held(0, 20)                                        # at rest for 20 ticks (brakes: after 5)
        assert node.braking() and node.stop is not None and not node.stop.engaged.any()
        node.on_safe_stop(SafeStop(active=True, kind="violation", reason="test"))
        held(20, 40)
        assert node.stop.engaged.all()
    finally:
        node.destroy_node()


def call_stop(bus, caller, reason, timeout=15.0):
    """The monitor's ``~/stop`` (reachset_msgs/ResetStop: caller, reason); its response."""
    import rclpy
    from reachset_msgs.srv import ResetStop
    cli = bus.caller.create_client(ResetStop, "/monitor_node/stop")
    try:
        assert cli.wait_for_service(timeout_sec=timeout), "/monitor_node/stop not available"
        fut = cli.call_async(ResetStop.Request(caller=caller, reason=reason))
        rclpy.spin_until_future_complete(bus.caller, fut, timeout_sec=timeout)
        assert fut.done(), "/monitor_node/stop did not answer"
        return fut.result()
    finally:
        bus.caller.destroy_client(cli)


def test_a_manual_stop_before_the_release_latches_and_only_the_audited_reset_clears_it(bus, tmp_path):
    """Issue 36.2: ``~/stop`` replaces the start-up stop with a latched stop of kind ``manual``
    (the reason and the caller in it, a PRIVILEGED line); the clean ticks that would have
    released the start-up stop do not release it; the audited reset does. Before there was no
    ``~/stop`` (the call finds no service)."""
    bus.clear()
    proc, _ = start_monitor(bus, tmp_path, reset_clean_ticks=0)
    try:
        r = call_stop(bus, "test_operator", "cell door open")
        assert r.success and "latched" in r.message, r.message
        assert bus.wait(lambda: any(s.active and s.kind == "manual" for s in list(bus.stops)), 20)
        stop = next(s for s in list(bus.stops) if s.kind == "manual")
        assert "cell door open" in stop.reason and "test_operator" in stop.reason
        n = 2 * (HISTORY + HORIZON + 1)
        Y, U = stream(n, seed=8)
        bus.send_ticks(stamps(n), Y, U)
        assert bus.wait(lambda: len(bus.status) >= n - 5, 30), len(bus.status)
        time.sleep(0.5)
        assert bus.stops[-1].active and bus.stops[-1].kind == "manual"     # not released by clean ticks
        assert not any(not s.active for s in list(bus.stops))
        r = bus.call_trigger("/monitor_node/reset")
        assert r.success, r.message
        assert bus.wait(lambda: not bus.stops[-1].active and bus.stops[-1].kind == "reset", 20)
        log = proc.log.read_text()
        assert "PRIVILEGED manual safe stop through ~/stop: caller test_operator; reason 'cell door open'" in log
    finally:
        processes.stop([proc])
