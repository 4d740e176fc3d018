"""The validated envelope at a real ``monitor_node`` process over DDS (issue 37.2): outside it the
monitor warns on ``/diagnostics`` (``outside_envelope: warn``, the default) or stops
(``stop``); a violation's stop reason says whether the data were inside it."""
import time

import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from helpers import JOINTS, stamps, stream, write_envelope_model
from reachset_ros import processes

pytestmark = pytest.mark.dds   # real DDS participants / node processes

MONITOR = "reachset_ros: conformance monitor"


@pytest.fixture(scope="module")
def mon(bus, tmp_path_factory):
    """A monitor_node with a model whose envelope was fitted on :func:`helpers.stream` data; and
    a second model, the same envelope with sets so tight that the same data violate them."""
    d = tmp_path_factory.mktemp("monitor_envelope")
    path = write_envelope_model(d / "m.yaml")
    tight = write_envelope_model(d / "tight.yaml", alpha_w=(1e-4, 0.0))
    proc = processes.start("monitor_node", {"model_file": str(path), "max_missing_ticks": 10000,
                                            "reset_clean_ticks": 0, "window_dir": str(d / "windows")}, d)
    try:
        assert bus.wait(lambda: bus.js.get_subscription_count() and bus.pi.get_subscription_count()
                        and bus.status_matched(), 30), proc.log.read_text()
        bus.clear()
        bus.make_ready()
        yield proc, path, tight
    finally:
        processes.stop([proc])


def reset(bus):
    assert bus.call_trigger("/monitor_node/reset").success
    assert bus.wait(lambda: bus.stops and not bus.stops[-1].active)
    bus.clear()


def test_outside_the_envelope_warns_by_default_and_stops_when_asked(bus, mon):
    proc, _, _ = mon
    reset(bus)
    Y, U = stream(200, seed=12)
    ts = stamps(200)
    bus.send_ticks(ts, Y + 1.0, U)              # a pose 1 rad away from every training position
    assert bus.wait(lambda: len(bus.statuses(ts)) == 200), len(bus.statuses(ts))
    assert not bus.active_stops()               # warn: no stop, the data are conformant
    t = time.monotonic()
    c = bus.counters(MONITOR, newer_than=t)
    level, message, values, _ = bus.diags[MONITOR]
    assert values["envelope"] == "recorded" and values["outside_envelope"] == "warn"
    assert values["outside_envelope_joints"] == ",".join(JOINTS) and c["outside_envelope_ticks"] >= 200
    assert level == DiagnosticStatus.WARN and "outside the validated envelope" in message, (level, message)
    ok, why = bus.set_params("monitor_node", {"outside_envelope": "halt"})
    assert not ok and "outside_envelope must be 'warn' or 'stop'" in why
    ok, why = bus.set_params("monitor_node", {"outside_envelope": "stop"})
    assert ok, why
    try:
        reset(bus)
        Y, U = stream(200, seed=13)
        ts = stamps(200)
        bus.send_ticks(ts[:100], Y[:100], U[:100])          # inside: no stop
        assert bus.wait(lambda: len(bus.statuses(ts[:100])) == 100)
        assert not bus.active_stops()
        bus.send_ticks(ts[100:], Y[100:] + 1.0, U[100:])    # jumps out (and violates: a 1 rad step)
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert stop.kind == "violation" and "OUTSIDE the validated envelope" in stop.reason, stop.reason
        reset(bus)
        ts = stamps(200)
        bus.send_ticks(ts, Y + 1.0, U)                       # outside from the start: no violation
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert (stop.kind, stop.joint) == ("outside_envelope", JOINTS[0]), (stop.kind, stop.reason)
        assert "outside the validated envelope" in stop.reason
    finally:
        assert bus.set_params("monitor_node", {"outside_envelope": "warn"})[0]
    assert proc.alive()


def test_a_violation_inside_the_envelope_says_so(bus, mon):
    proc, path, tight = mon
    ok, why = bus.set_params("monitor_node", {"model_file": str(tight)})
    assert ok, why
    try:
        reset(bus)
        Y, U = stream(300, seed=12)
        ts = stamps(300)
        bus.send_ticks(ts, Y, U)                 # data of the validated kind, sets too tight for them
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert stop.kind == "violation", stop.reason
        assert "inside the validated envelope (motion of the kind the model was validated on)" in stop.reason
    finally:
        assert bus.set_params("monitor_node", {"model_file": str(path)})[0]
    assert proc.alive()


def test_in_stop_mode_a_reset_waits_until_the_data_are_back_inside(bus, mon):
    """With ``outside_envelope: stop`` a tick outside the envelope does not count towards the
    clean ticks a reset needs: a reset while the data are still outside is refused, naming the
    envelope, instead of being granted and followed by a new stop at the next tick. Before: the
    outside ticks were conformant, so they counted, and the reset was granted."""
    from helpers import HISTORY, HORIZON
    proc, _, _ = mon
    reset(bus)                                            # the previous test's stop, any data
    ok, why = bus.set_params("monitor_node", {"outside_envelope": "stop", "reset_clean_ticks": -1})
    assert ok, why
    try:
        n = 4 * (HISTORY + HORIZON + 1)
        Y, U = stream(n, seed=14)
        ts = stamps(2 * n)
        bus.send_ticks(ts[:n], Y + 1.0, U)                # outside from the start, conformant
        assert bus.wait(lambda: len(bus.statuses(ts[:n])) == n)
        stops = bus.active_stops()
        assert stops and stops[0].kind == "outside_envelope", [s.kind for s in stops]
        r = bus.call_trigger("/monitor_node/reset")
        assert not r.success and "outside the validated envelope" in r.message, r.message
        Y2, U2 = stream(n, seed=15)
        bus.send_ticks(ts[n:], Y2, U2)                    # back inside (the jump back is a violation)
        assert bus.wait(lambda: len(bus.statuses(ts[n:])) == n)
        r = bus.call_trigger("/monitor_node/reset")
        assert r.success, r.message
        assert bus.wait(lambda: bus.stops and not bus.stops[-1].active)
        bus.clear()
    finally:
        assert bus.set_params("monitor_node", {"outside_envelope": "warn", "reset_clean_ticks": 0})[0]
    assert proc.alive()
