"""The monitor's core without ROS (:class:`~reachset_ros.conformance.monitor_core.MonitorCore`):
the exact accounting of bad input, faults, gaps, coverage and stuck sensors (docs/reliability.md,
"Nodes"); the same cases through real processes are in test/nodes/test_monitor_node_faults.py.

Stamps increase across the whole test session (:func:`helpers.stamps`).
"""
import math

import numpy as np
import pytest

from helpers import DT_NS, HISTORY, HORIZON, JOINTS, stamps, stream, write_model
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.watches import FaultEvent, TickEvent
from reachset_ros.errors import ReachsetError
from reachset_ros.conformance.monitor_core import MonitorCore


# ============================================================ MonitorCore (no ROS)
@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return write_model(tmp_path_factory.mktemp("model") / "m.yaml")


def feed(core, ts, Y, U, drop_y=(), drop_u=()):
    """Feed ticks (y then u per tick); returns the events."""
    ev = []
    for k, t in enumerate(ts):
        if k not in drop_y:
            ev += core.add_y(t, JOINTS, list(Y[k]))
        if k not in drop_u:
            ev += core.add_u(t, JOINTS, list(U[k]))
    return ev


def ticks_of(events):
    return [e for e in events if isinstance(e, TickEvent)]


def faults_of(events):
    return [e for e in events if isinstance(e, FaultEvent)]


def test_core_clean_stream_is_conformant_and_pairs_by_stamp_and_name(model):
    """Reference run: every tick checked and conformant; pairing ignores arrival order and
    the order of names (u arrives first, names reversed)."""
    core = MonitorCore(mdl.load(model))
    Y, U = stream(400, seed=4)
    ts = stamps(400)
    ev = []
    for k, t in enumerate(ts):
        ev += core.add_u(t, JOINTS[::-1], [U[k, 1], U[k, 0]])
        ev += core.add_y(t, JOINTS, list(Y[k]))
    assert not faults_of(ev)
    assert [e.stamp for e in ticks_of(ev)] == ts
    assert all(s == "ok" for e in ev for s in e.result["status"])
    assert core.counters["ticks"] == 400 and core.counters["gaps"] == 0
    # the same data in stamp order but all of /plant_input first (a burst from one side)
    core2 = MonitorCore(mdl.load(model))
    ts2 = stamps(40)
    ev2 = [e for k, t in enumerate(ts2) for e in core2.add_u(t, JOINTS, list(U[k]))]
    assert ev2 == [] and len(core2.pending) == 40
    for k, t in enumerate(ts2):
        ev2 += core2.add_y(t, JOINTS, list(Y[k]))
    assert [e.stamp for e in ticks_of(ev2)] == ts2 and not core2.pending


@pytest.mark.parametrize("case, kind, joint, words", [
    ("nan_y", "invalid_sample", "arm_2_joint", "non-finite"),
    ("inf_u", "invalid_sample", "arm_1_joint", "non-finite"),
    ("short_positions", "invalid_sample", "", "2 names but 1 values"),
    ("missing_joint", "name_mismatch", "arm_2_joint", "lacks joint arm_2_joint"),
    ("unknown_names", "name_mismatch", "arm_1_joint", "lacks joint arm_1_joint"),
    ("duplicate_name", "name_mismatch", "arm_1_joint", "names joint arm_1_joint twice"),
    ("stamp_backwards", "stamp_backwards", "", "stamp went backwards"),
])
def test_core_bad_sample_is_a_fault_with_its_reason(model, case, kind, joint, words):
    core = MonitorCore(mdl.load(model))
    Y, U = stream(80, seed=1)
    ts = stamps(80)
    ev = feed(core, ts[:60], Y, U)
    assert not faults_of(ev)
    t = ts[60]
    names, y, u = list(JOINTS), list(Y[60]), list(U[60])
    if case == "nan_y":
        y[1] = math.nan
    elif case == "inf_u":
        u[0] = math.inf
    elif case == "short_positions":
        y = y[:1]
    elif case == "missing_joint":
        names, y = [JOINTS[0], "gripper_joint"], y
    elif case == "unknown_names":
        names = ["a", "b"]
    elif case == "duplicate_name":
        names = [JOINTS[0], JOINTS[0], JOINTS[1]]
        y = [y[0], y[0], y[1]]
    elif case == "stamp_backwards":
        t = ts[30]
    ev = core.add_y(t, names, y) + core.add_u(ts[60], JOINTS, u)
    f = faults_of(ev)
    assert len(f) == 1, ev
    stamp, fkind, reason, fjoint = f[0].stamp, f[0].kind, f[0].reason, f[0].joint
    assert (stamp, fkind, fjoint) == (t, kind, joint) and words in reason, f[0]
    # the core goes on: later ticks are processed (after a gap where the tick was rejected)
    ev = feed(core, ts[62:80], Y[62:], U[62:])
    assert not faults_of(ev) and len(ticks_of(ev)) == 18
    assert ticks_of(ev)[-1].stamp == ts[79]


def test_core_non_finite_half_tick_is_a_fault_without_its_pair(model):
    """Issue 17 (the fault campaign): a NaN /joint_states sample is a fault when it arrives,
    not only once its /plant_input pairs with it: on the running loop the observer skips the
    sample, no /plant_input ever comes for its stamp, and the stop used to come only from the
    missing-data watchdog 0.5 s later. The same for a non-finite /plant_input."""
    for half in ("y", "u"):
        core = MonitorCore(mdl.load(model))
        Y, U = stream(80, seed=1)
        ts = stamps(80)
        assert not faults_of(feed(core, ts[:60], Y, U))
        v = list((Y if half == "y" else U)[60])
        v[1] = math.nan
        f = faults_of(core.add_y(ts[60], JOINTS, v) if half == "y" else core.add_u(ts[60], JOINTS, v))
        assert len(f) == 1 and f[0].kind == "invalid_sample" and f[0].joint == JOINTS[1], f
        assert f[0].stamp == ts[60] and "non-finite" in f[0].reason
        assert core.counters["invalid_" + half] == 1


def test_core_after_a_clock_jump_back_messages_of_checked_ticks_are_stale(model):
    """The source's clock jumps back: one stamp_backwards fault; the following messages
    (on the new clock, older than the last checked tick) are skipped and counted."""
    core = MonitorCore(mdl.load(model))
    Y, U = stream(60, seed=14)
    ts = stamps(60)
    ev = feed(core, ts[:50], Y, U)
    ev = feed(core, ts[10:20], Y[10:], U[10:])
    f = faults_of(ev)
    assert [e.kind for e in f] == ["stamp_backwards", "stamp_backwards"]   # one per topic
    assert not ticks_of(ev)
    assert (core.counters["stale_y"], core.counters["stale_u"]) == (9, 9)
    ev = feed(core, ts[50:], Y[50:], U[50:])          # back on the old clock, after the last tick
    assert not faults_of(ev) and len(ticks_of(ev)) == 10


def test_core_extra_names_are_ignored_and_counted(model):
    core = MonitorCore(mdl.load(model))
    Y, U = stream(50, seed=2)
    ts = stamps(50)
    ev = []
    for k, t in enumerate(ts):
        ev += core.add_y(t, ["gripper_joint", JOINTS[1], JOINTS[0]], [123.0, Y[k, 1], Y[k, 0]])
        ev += core.add_u(t, JOINTS + ["other"], list(U[k]) + [math.nan])
    assert not faults_of(ev) and len(ticks_of(ev)) == 50
    assert all(s == "ok" for e in ev for s in e.result["status"])
    assert core.counters["extra_names_y"] == 50 and core.counters["extra_names_u"] == 50


def test_core_repeated_and_stale_stamps_are_skipped_and_counted(model):
    core = MonitorCore(mdl.load(model))
    Y, U = stream(60, seed=3)
    ts = stamps(60)
    ev = feed(core, ts[:40], Y, U)
    # the same /joint_states sample again (a driver republishing): skipped, counted
    ev += core.add_y(ts[39], JOINTS, list(Y[39]))
    assert core.counters["duplicate_y"] == 1
    # a repeated stamp inside a pending tick keeps the first sample
    ev += core.add_y(ts[40], JOINTS, list(Y[40]))
    ev += core.add_y(ts[40], JOINTS, [9.0, 9.0])
    ev += core.add_u(ts[40], JOINTS, list(U[40]))
    assert core.counters["duplicate_y"] == 2
    ev += feed(core, ts[41:60], Y[41:], U[41:])
    assert not faults_of(ev) and len(ticks_of(ev)) == 60
    assert all(s == "ok" for e in ev for s in e.result["status"])


def test_core_dropped_messages_are_counted_gaps(model):
    """A lost /joint_states, a lost /plant_input, three lost ticks: the half ticks are
    dropped (counted), the test cases restart after each gap (as `reachset check` does), no
    false verdict, and ticks + missing ticks account for every tick of the span."""
    core = MonitorCore(mdl.load(model))
    Y, U = stream(300, seed=5)
    ts = stamps(300)
    ev = feed(core, ts, Y, U, drop_y={100, 200, 201, 202}, drop_u={150, 200, 201, 202})
    ticks = ticks_of(ev)
    assert not faults_of(ev)
    assert len(ticks) == 295
    assert all(s in ("ok", "gap_reset") for e in ticks for s in e.result["status"])
    assert [e.result["status"][0] for e in ticks if e.stamp in (ts[101], ts[151], ts[203])] == ["gap_reset"] * 3
    c = core.counters
    assert (c["dropped_incomplete"], c["gaps"], c["missing_ticks"]) == (2, 3, 5)
    assert c["ticks"] + c["missing_ticks"] == 300
    # right after a gap nothing spans it: the first test case starts history+1 ticks later
    after = next(e for e in ticks if e.stamp == ts[203])
    assert max(after.result["checked"]) == 0


def test_core_burst_larger_than_pending_drops_oldest_counted(model):
    """All /plant_input of 200 ticks, then all /joint_states: only max_pending ticks can
    wait; the rest are dropped and counted, the remaining ones are checked."""
    core = MonitorCore(mdl.load(model))
    Y, U = stream(200, seed=6)
    ts = stamps(200)
    ev = [e for k, t in enumerate(ts) for e in core.add_u(t, JOINTS, list(U[k]))]
    assert len(core.pending) == core.max_pending == 2 * (HORIZON + 1)
    for k, t in enumerate(ts):
        ev += core.add_y(t, JOINTS, list(Y[k]))
    ticks = ticks_of(ev)
    assert not faults_of(ev)
    assert [e.stamp for e in ticks] == ts[200 - core.max_pending:]
    c = core.counters
    # the oldest u-only ticks left the queue, then their y halves (older than all waiting
    # ticks) were dropped on arrival: both counted; the newest ticks were all completed
    assert c["dropped_incomplete"] == 2 * (200 - core.max_pending)
    assert c["ticks"] == core.max_pending and not core.pending




def test_core_clean_stream_warm_up_is_not_conformant_nor_a_fault(model):
    """A normal 250 Hz stream: the first ``history`` ticks check nothing and are not
    conformant (but no violation: margin +inf), every later tick is; no coverage fault."""
    core = MonitorCore(mdl.load(model))
    Y, U = stream(400, seed=4)
    ticks = ticks_of(feed(core, stamps(400), Y, U))
    assert len(ticks) == 400 and not core.counters["coverage_faults"]
    assert [e.conformant for e in ticks] == [False] * HISTORY + [True] * (400 - HISTORY)
    assert all(max(e.result["checked"]) == 0 and min(e.result["margin"]) > 0 and e.longest == -1
               for e in ticks[:HISTORY])
    assert [e.longest for e in ticks[HISTORY:HISTORY + HORIZON + 2]] == list(range(HORIZON + 1)) + [HORIZON]
    assert core.coverage.share == (400 - HISTORY - HORIZON) / 400


@pytest.mark.parametrize("case", ["125Hz", "300Hz", "every_4th_lost", "every_8th_lost"])
def test_core_stream_that_cannot_form_the_test_cases_is_a_coverage_fault(model, case):
    """A stream whose period is not the model's 4 ms (125 Hz: every step a gap; 300 Hz: no
    gap, the wrong time grid), or whose losses keep every test case short of k*, ends in a
    ``coverage`` fault within the missing-data limit (after the warm-up that the checks
    need) that names the measured period; no tick at which nothing was checked is conformant.
    The lossy-link rule is off here (``gap_window`` 0): these are the rules that hold
    without it (it is tested below)."""
    mm = 25                                        # max_missing_ticks, the default
    core = MonitorCore(mdl.load(model), gap_window=0)
    n = 400
    Y, U = stream(n, seed=4)
    base = stamps(3 * n)[0]
    step = {"125Hz": 2 * DT_NS, "300Hz": 3_333_333}.get(case, DT_NS)
    ts = [base + k * step for k in range(n)]
    lost = {"every_4th_lost": set(range(3, n, 4)), "every_8th_lost": set(range(7, n, 8))}.get(case, set())
    ev = feed(core, ts, Y, U, drop_y=lost, drop_u=lost)
    f = faults_of(ev)
    assert f and all(e.kind == "coverage" for e in f), f
    first = f[0]
    ticks = [e for e in ticks_of(ev) if e.stamp <= first.stamp]
    assert not [e for e in ticks if e.conformant and max(e.result["checked"]) == 0]
    assert all(min(e.result["margin"]) >= 0 for e in ticks)        # no violation was claimed
    late = first.stamp - ts[0]
    if case == "125Hz":
        # nothing is ever checked: never conformant; the fault within the limit after the warm-up
        assert not any(e.conformant for e in ticks) and all(e.longest == -1 for e in ticks)
        assert late <= (HISTORY + mm) * DT_NS + step, late
        assert "nothing checked" in first.reason and "measured stream period 8 ms" in first.reason, first.reason
    elif case == "300Hz":
        assert late <= (HISTORY + mm) * DT_NS, late
        assert "measured stream period 3.333 ms" in first.reason and "dt 4 ms" in first.reason, first.reason
    elif case == "every_4th_lost":
        # segments of 3 ticks: no test case can start, nothing is ever checked
        assert not any(e.conformant for e in ticks)
        assert late <= (HISTORY + mm) * DT_NS + 2 * DT_NS, late
        assert "nothing checked" in first.reason and "gaps" in first.reason, first.reason
    else:
        # segments of 7 ticks: steps 0..3 are checked, never k*; conformant only where checked
        assert max(e.longest for e in ticks) == 3
        assert all(e.conformant == (e.longest >= 0) for e in ticks)
        assert late <= (HISTORY + HORIZON + mm) * DT_NS + 2 * DT_NS, late
        assert f"no test case reached the horizon k*={HORIZON}" in first.reason, first.reason
        assert "longest step checked 3 of 25" in first.reason and "measured stream period 4 ms" in first.reason


@pytest.mark.parametrize("case", ["half_lost", "every_8th_lost", "125Hz", "one_in_200_lost"])
def test_core_samples_lost_again_within_the_gap_window_is_a_coverage_fault(model, case):
    """The lossy-link rule (``gap_window``, 25 ticks by default): samples lost again within
    25 ticks of the previous loss end in a ``coverage`` fault at the second loss, where the
    horizon rule alone waits for the warm-up, k* and the missing-data limit (the fault
    campaign's link loss: 1.04 s); one loss in 200 ticks is no fault."""
    core = MonitorCore(mdl.load(model))
    n = 600
    Y, U = stream(n, seed=6)
    base = stamps(3 * n)[0]
    step = 2 * DT_NS if case == "125Hz" else DT_NS
    ts = [base + k * step for k in range(n)]
    rng = np.random.default_rng(3)
    lost = {"half_lost": {k for k in range(100, n) if rng.random() < 0.5},
            "every_8th_lost": set(range(107, n, 8)), "one_in_200_lost": set(range(150, n, 200))}.get(case, set())
    ev = feed(core, ts, Y, U, drop_y=lost, drop_u=lost)
    f = faults_of(ev)
    if case == "one_in_200_lost":
        assert not f and len(ticks_of(ev)) == n - len(lost)
        return
    assert f and f[0].kind == "coverage", f
    losses = sorted(lost) or [0, 1]       # 125 Hz: the steps into ticks 1 and 2 are gaps
    # the tick after the second loss (runs of lost samples count once: a gap is one stamp step)
    gaps = [k for k in losses if k - 1 not in lost]
    second = next(k for k in range(gaps[1] + 1, n) if k not in lost)
    assert f[0].stamp == ts[second], (f[0].stamp - ts[0], ts[second] - ts[0])
    assert "samples lost again" in f[0].reason and "25-tick window" in f[0].reason, f[0].reason
    if case == "125Hz":
        assert "measured stream period 8 ms" in f[0].reason, f[0].reason
    # the same stream without the rule: the horizon rule, much later
    old = faults_of(feed(MonitorCore(mdl.load(model), gap_window=0), ts, Y, U, drop_y=lost, drop_u=lost))
    assert not old or old[0].stamp - ts[second] >= HISTORY * DT_NS, (old[0].stamp - ts[0], f[0].stamp - ts[0])


def feed_with_reference(core, ts, Y, U, qd, refs=True):
    """Feed ticks as the running system does: /joint_states, then /reference (the reference
    node answers each sample, stamped with its stamp), then /plant_input."""
    ev = []
    for k, t in enumerate(ts):
        ev += core.add_y(t, JOINTS, list(Y[k]))
        if refs:
            core.add_reference(t, JOINTS[::-1], list(qd[k][::-1]))     # any order of names
        ev += core.add_u(t, JOINTS, list(U[k]))
    return ev


@pytest.mark.parametrize("case", ["moving", "at_rest", "no_reference", "slow", "off"])
def test_core_a_reading_repeated_while_the_reference_moves_is_a_stuck_sensor(model, case):
    """The stuck-sensor rule (``stuck_ticks`` 5, ``stuck_speed`` 0.05 rad/s): joint 2's
    reading frozen at tick 300 while its reference moves at 0.1 rad/s is an
    ``invalid_sample`` fault at the fifth repeat (20 ms), long before the sets see it (the
    stream's sets are wide: no violation in the 200 ticks after); the same readings while
    the reference rests (a quantized encoder at rest repeats itself) or moves slower than
    0.05 rad/s, without any /reference, or with the rule off are no fault."""
    kw = {"stuck_ticks": 0} if case == "off" else {}
    core = MonitorCore(mdl.load(model), **kw)
    n = 500
    Y, U = stream(n, seed=7)
    Y[300:, 1] = Y[300, 1]                                     # the sensor freezes
    speed = {"at_rest": 0.0, "slow": 0.049}.get(case, 0.1)
    qd = np.tile([0.3, speed], (n, 1))
    ts = stamps(n)
    ev = feed_with_reference(core, ts, Y, U, qd, refs=case != "no_reference")
    f = faults_of(ev)
    if case != "moving":
        assert not [e for e in f if "stuck" in e.reason], f
        if case == "no_reference":
            assert core.stuck.unreferenced == n
        return
    assert f and f[0].kind == "invalid_sample" and f[0].joint == JOINTS[1], f
    assert f[0].stamp == ts[305], (f[0].stamp - ts[300]) / DT_NS
    assert "repeated 5 times in a row, the last 5 (20 ms)" in f[0].reason and "stuck sensor" in f[0].reason, f[0].reason
    # joint 1's reading never repeats: the fault names joint 2 only, and the sets saw nothing
    assert all(e.joint == JOINTS[1] for e in f)
    assert not [e for e in ticks_of(ev) if "violation" in e.result["status"]]


def test_core_stuck_rule_needs_every_tick_referenced_and_no_gap(model):
    """A run of repeats broken by a gap starts anew, and a tick whose reference is missing is
    not established: the fault comes only once 5 repeats are all referenced."""
    core = MonitorCore(mdl.load(model))
    n = 400
    Y, U = stream(n, seed=8)
    Y[200:, 0] = Y[200, 0]
    qd = np.tile([0.2, 0.2], (n, 1))
    ts = stamps(n)
    ev = []
    for k, t in enumerate(ts):
        if k == 203:
            continue                                       # a lost tick: the run starts again at 204
        ev += core.add_y(t, JOINTS, list(Y[k]))
        if k != 207:                                       # this tick's reference is lost
            core.add_reference(t, JOINTS, list(qd[k]))
        ev += core.add_u(t, JOINTS, list(U[k]))
    f = [e for e in faults_of(ev) if "stuck" in e.reason]
    # repeats from 205 on (204 follows the gap); 5 referenced repeats in a row: 208..213
    assert f and f[0].stamp == ts[213], (f[0].stamp - ts[200]) / DT_NS
    assert "repeated 9 times in a row, the last 5 (20 ms)" in f[0].reason, f[0].reason


def test_core_a_single_gap_is_no_coverage_fault(model):
    """One loss of 24 ticks (under the missing-data limit of 25) restarts the test cases but
    is no coverage fault; nor is a pause longer than the limit (the watchdog's business)."""
    core = MonitorCore(mdl.load(model))                # max_missing_ticks 25
    Y, U = stream(600, seed=5)
    ts = stamps(600)
    ev = feed(core, ts, Y, U, drop_y=set(range(100, 124)) | set(range(300, 500)),
              drop_u=set(range(100, 124)) | set(range(300, 500)))
    assert not faults_of(ev) and len(ticks_of(ev)) == 600 - 224


def test_core_joint_list_must_be_in_the_model(model):
    with pytest.raises(ReachsetError, match="arm_3_joint is not in the model"):
        MonitorCore(mdl.load(model), ["arm_1_joint", "arm_3_joint"])
    with pytest.raises(ReachsetError, match="twice"):
        MonitorCore(mdl.load(model), ["arm_1_joint", "arm_1_joint"])


def test_core_stamps_that_jump_forward_again_and_again_are_a_coverage_fault(model):
    """Issue 34.8: a source clock that jumps 0.504 s forward every 20 ticks while samples keep
    coming (the wall-time watchdog quiet). Each jump is longer than the missing-data limit and
    restarted the coverage watch, so no test case ever reached k* (25 here) and no stop came.
    Now the ticks received without a test case at k* count across the jumps: a ``coverage``
    fault within the warm-up plus the missing-data limit, in ticks; a single jump is not one."""
    mm = 25
    core = MonitorCore(mdl.load(model), gap_window=0)
    n = 200
    Y, U = stream(n, seed=4)
    base = stamps(3 * n + 2000)[0]
    ts = [base + k * DT_NS + (k // 20) * 126 * DT_NS for k in range(n)]       # +0.504 s every 20 ticks
    f = faults_of(feed(core, ts, Y, U))
    assert f and f[0].kind == "coverage", f
    assert "stamp steps longer than" in f[0].reason and "missing-data limit" in f[0].reason, f[0].reason
    assert ts.index(f[0].stamp) <= HISTORY + HORIZON + mm + 1
    # one jump, then a steady stream: the test cases reach k* again, no fault
    core = MonitorCore(mdl.load(model), gap_window=0)
    base = stamps(3 * n + 2000)[0]
    ts = [base + k * DT_NS + (126 * DT_NS if k >= 20 else 0) for k in range(n)]
    assert not faults_of(feed(core, ts, Y, U))
