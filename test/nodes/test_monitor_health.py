"""The controller's deadline on the monitor's verdicts (issue 34.2) and the one release that
clears a stop of its own (issue 34.9): :mod:`reachset_ros.nodes.monitor_health`, pure logic.
The nodes over DDS: test_controller_node_faults.py::TestMonitorStalled and
test_lifecycle.py::test_lifecycle_transitions_never_clear_a_stop_of_the_controllers_own."""
from reachset_msgs.msg import SafeStop

from reachset_ros.nodes.common import MONITOR_STARTED
from reachset_ros.nodes.monitor_health import VerdictDeadline, is_audited_reset

DT = 4_000_000


def test_the_newest_verdict_may_trail_the_tick_by_at_most_the_limit_in_stamps():
    d = VerdictDeadline(max_lag_ns=10 * DT, first_timeout_s=1.0)
    t0 = 10**18
    d.verdict(t0 - DT)
    for k in range(11):                  # 10 ticks ahead of the first tick tracked: allowed
        assert d.check(t0 + k * DT, wall=0.0) is None
    assert "monitor_verdict_ticks" in d.check(t0 + 11 * DT, wall=0.0)
    d.verdict(t0 + 5 * DT)               # the monitor catches up
    assert d.check(t0 + 15 * DT, wall=0.0) is None
    assert d.check(t0 + 16 * DT, wall=0.0) is not None
    assert d.lag_max_ns == 11 * DT
    # wall time plays no part once a verdict came: a slow machine's loop slows its stamps too
    assert d.check(t0 + 15 * DT, wall=1e6) is None


def test_a_stop_restarts_the_deadline_from_the_next_tracked_tick():
    d = VerdictDeadline(max_lag_ns=10 * DT, first_timeout_s=1.0)
    t0 = 10**18
    d.verdict(t0)
    assert d.check(t0 + 5 * DT, wall=0.0) is None
    d.pause()                            # braking for a while: the monitor checks the held arm or not
    assert d.check(t0 + 100 * DT, wall=0.0) is None      # the first tick tracked again
    assert d.check(t0 + 110 * DT, wall=0.0) is None
    assert d.check(t0 + 111 * DT, wall=0.0) is not None


def test_before_the_first_verdict_a_wall_time_allowance_and_a_new_clock_forgets_old_verdicts():
    d = VerdictDeadline(max_lag_ns=10 * DT, first_timeout_s=2.0)
    t0 = 10**18
    assert d.check(t0, wall=100.0) is None
    assert d.check(t0 + 1000 * DT, wall=101.9) is None
    assert "monitor_first_verdict_timeout" in d.check(t0 + 1001 * DT, wall=102.1)
    d = VerdictDeadline(max_lag_ns=10 * DT, first_timeout_s=2.0)
    d.verdict(t0)
    assert d.check(t0 + DT, wall=0.0) is None
    # a clock 10 s back (a restarted simulation): the old verdict covers nothing on it
    t1 = t0 - 10**10
    assert d.check(t1, wall=5.0) is None and d.newest_ns is None
    assert d.check(t1 + 1000 * DT, wall=7.5) is not None


def test_only_the_audited_reset_clears_a_stop_of_the_controllers_own():
    assert is_audited_reset(SafeStop(active=False, kind="reset", reason="reset through ~/reset"))
    assert is_audited_reset(SafeStop(active=False, kind="reset", reason="reset through ~/reset_stop by op: ok"))
    for reason in (MONITOR_STARTED, "monitor_node lifecycle: active: checking", "test: reset", ""):
        assert not is_audited_reset(SafeStop(active=False, kind="reset", reason=reason))
    assert not is_audited_reset(SafeStop(active=True, kind="manual", reason="reset through ~/reset"))
