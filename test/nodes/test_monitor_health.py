"""The controller's deadline on the monitor's verdicts (issue 34.2) and the one release that
clears a stop of its own (issue 34.9): :mod:`reachset_ros.nodes.monitor_health`, pure logic.
The nodes over DDS: test_controller_node_faults.py::TestMonitorStalled and
test_lifecycle.py::test_lifecycle_transitions_never_clear_a_stop_of_the_controllers_own."""
from reachset_msgs.msg import SafeStop

from reachset_ros.nodes.common import MONITOR_STARTED
from reachset_ros.nodes.monitor_health import VerdictDeadline, is_audited_reset

DT = 4_000_000


def test_the_newest_verdict_may_trail_the_tick_by_at_most_the_limit_in_stamps():
    d = VerdictDeadline(max_lag_ns=10 * DT)
    t0 = 10**18
    d.verdict(t0 - DT)
    for k in range(11):                  # 10 ticks ahead of the first tick tracked: allowed
        assert d.check(t0 + k * DT) is None
    assert "monitor_verdict_ticks" in d.check(t0 + 11 * DT)
    d.verdict(t0 + 5 * DT)               # the monitor catches up
    assert d.check(t0 + 15 * DT) is None
    assert d.check(t0 + 16 * DT) is not None
    assert d.lag_max_ns == 11 * DT


def test_a_stop_restarts_the_deadline_from_the_next_tracked_tick():
    d = VerdictDeadline(max_lag_ns=10 * DT)
    t0 = 10**18
    d.verdict(t0)
    assert d.check(t0 + 5 * DT) is None
    d.pause()                            # braking for a while: the monitor checks the held arm or not
    assert d.check(t0 + 100 * DT) is None      # the first tick tracked again
    assert d.check(t0 + 110 * DT) is None
    assert d.check(t0 + 111 * DT) is not None


def test_no_deadline_before_the_first_verdict_and_a_new_clock_forgets_old_verdicts():
    d = VerdictDeadline(max_lag_ns=10 * DT)
    t0 = 10**18
    assert d.check(t0) is None and d.check(t0 + 10**6 * DT) is None     # a monitor that never checked
    d = VerdictDeadline(max_lag_ns=10 * DT)
    d.verdict(t0)
    assert d.check(t0 + DT) is None
    # a clock 10 s back (a restarted simulation): the old verdict covers nothing on it
    t1 = t0 - 10**10
    assert d.check(t1) is None and d.newest_ns is None
    d.verdict(t1 + DT)
    assert d.check(t1 + 11 * DT) is None
    assert d.check(t1 + 12 * DT) is not None


def test_a_stamp_jump_forward_beyond_the_limit_is_a_stop():
    d = VerdictDeadline(max_lag_ns=10 * DT)
    t0 = 10**18
    d.verdict(t0)
    assert d.check(t0 + DT) is None
    assert d.check(t0 + 500 * DT) is not None


def test_only_the_audited_reset_clears_a_stop_of_the_controllers_own():
    assert is_audited_reset(SafeStop(active=False, kind="reset", reason="reset through ~/reset"))
    assert is_audited_reset(SafeStop(active=False, kind="reset", reason="reset through ~/reset_stop by op: ok"))
    for reason in (MONITOR_STARTED, "monitor_node lifecycle: active: checking", "test: reset", ""):
        assert not is_audited_reset(SafeStop(active=False, kind="reset", reason=reason))
    assert not is_audited_reset(SafeStop(active=True, kind="manual", reason="reset through ~/reset"))
