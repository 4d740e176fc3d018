"""Bad input, faults and parameter updates at the nodes (docs/reliability.md, "Nodes").

Two levels: :class:`MonitorCore` without ROS, for the exact accounting of each case, and
real ``monitor_node`` / ``controller_node`` processes over DDS fed by a test node, for the
behaviour a user sees (a latched ``/safe_stop`` with its reason, or a skip counted on
``/diagnostics``), each case ending with a check that the node still works.

Stamps increase across the whole module (:func:`stamps`): a monitor hearing an older
test's late message must never see a stamp going backwards by accident.
"""
import math
import os
import signal
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos import QoSProfile, ReliabilityPolicy
from reachset_msgs.msg import JointEstimate, JointReference, SafeStop

from helpers import HORIZON, JOINTS, Bus, stream, write_model
from reachset_ros import processes
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.watches import FaultEvent, TickEvent
from reachset_ros.errors import ReachsetError
from reachset_ros.nodes.common import MONITOR_STARTED, SAFE_STOP_QOS, stamp_ns, to_stamp
from reachset_ros.conformance.monitor_core import MonitorCore

DT_NS = 4_000_000
_next = [10**18]


def stamps(n):
    """Stamps for ``n`` ticks, later than any used before in this module."""
    t0 = _next[0]
    _next[0] += (n + 10_000) * DT_NS
    return [t0 + k * DT_NS for k in range(n)]


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


HISTORY = 3     # the fd estimator's history: ticks of a segment before its first test case


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


# ============================================================ real processes over DDS
def warm_up_then_conformant(st, segments=1):
    """Statuses of a clean stream: conformant, except at the first ``HISTORY`` ticks of each
    of its ``segments`` (after a start, reset or gap), where nothing was checked and the
    status says so (not conformant, no test case, tightest step -1, no violation). With
    ``segments=None`` only the rule is checked, not the count."""
    unchecked = [s for s in st if not s.active_test_cases]
    assert all(s.conformant for s in st if s.active_test_cases), "a checked tick not conformant"
    assert all(not s.conformant and set(s.tightest_step) == {-1} and min(s.margin) > 0 for s in unchecked)
    assert segments is None or len(unchecked) == HISTORY * segments, (len(unchecked), segments)
    return True


@pytest.fixture(scope="module")
def bus():
    rclpy.init()
    b = Bus()
    yield b
    b.close()
    rclpy.shutdown()


def corrupt(case, t_bad, t_old, y, u):
    """What to publish for a bad tick: (stamp, names of y, y values, u values)."""
    names, y, u = list(JOINTS), list(y), list(u)
    if case == "nan_y":
        y[1] = math.nan
    elif case == "inf_u":
        u[0] = math.inf
    elif case == "short_positions":
        y = y[:1]
    elif case == "missing_joint":
        names = [JOINTS[0], "gripper_joint"]
    elif case == "unknown_names":
        names = ["a", "b"]
    elif case == "duplicate_name":
        names, y = [JOINTS[0], JOINTS[0], JOINTS[1]], [y[0], y[0], y[1]]
    elif case == "stamp_backwards":
        return t_old, names, y, u
    return t_bad, names, y, u


BAD_CASES = [
    ("nan_y", "invalid_sample", "arm_2_joint", "non-finite"),
    ("inf_u", "invalid_sample", "arm_1_joint", "non-finite"),
    ("short_positions", "invalid_sample", "", "2 names but 1 values"),
    ("missing_joint", "name_mismatch", "arm_2_joint", "lacks joint arm_2_joint"),
    ("unknown_names", "name_mismatch", "arm_1_joint", "lacks joint arm_1_joint"),
    ("duplicate_name", "name_mismatch", "arm_1_joint", "names joint arm_1_joint twice"),
    ("stamp_backwards", "stamp_backwards", "", "/joint_states stamp went backwards"),
]


@pytest.fixture(scope="class")
def monitor(bus, tmp_path_factory):
    """A monitor_node process for one test class (the next class may start its own)."""
    d = tmp_path_factory.mktemp("monitor")
    path = write_model(d / "m.yaml")
    # reset_clean_ticks 0: the tests reset the latched stop as a set-up step, with no data
    # flowing; the rule that a reset waits until the stop's condition has cleared is tested
    # by TestResetNeedsClearedCondition
    proc = processes.start("monitor_node", {"model_file": str(path), "max_missing_ticks": 10000, "reset_clean_ticks": 0,
                                         "window_dir": str(d / "windows")}, d)
    try:
        assert bus.wait(lambda: bus.js.get_subscription_count() and bus.pi.get_subscription_count()
                        and bus.listener.count_publishers("/conformance/status"), 30), proc.log.read_text()
        yield proc, path, d
    finally:
        processes.stop([proc])


class TestMonitorNode:
    """One monitor_node process for the class, reset before each test."""

    @pytest.fixture
    def mon(self, monitor, bus):
        proc, path, d = monitor
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 10000,
                                                  "gap_window": MonitorCore.GAP_WINDOW})
        assert ok, why
        assert bus.call_trigger("/monitor_node/reset").success
        assert bus.wait(lambda: bus.stops and not bus.stops[-1].active)
        bus.clear()
        yield proc, path, d
        assert proc.alive(), proc.log.read_text()[-3000:]

    def alive_and_checking(self, bus, proc, seed=9):
        """The node answers its reset service and checks a fresh clean stream again."""
        assert proc.alive()
        assert bus.call_trigger("/monitor_node/reset").success
        Y, U = stream(40, seed)
        ts = stamps(40)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 40), len(bus.statuses(ts))
        st = bus.statuses(ts)
        assert all(not s.safe_stop_active for s in st) and warm_up_then_conformant(st)

    @pytest.mark.parametrize("case, kind, joint, words", BAD_CASES)
    def test_bad_sample_latches_safe_stop_with_reason(self, bus, mon, case, kind, joint, words):
        proc, _, _ = mon
        Y, U = stream(90, seed=1)
        ts = stamps(90)
        bus.send_ticks(ts[:60], Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts[:60])) == 60)
        t, names, y, u = corrupt(case, ts[60], ts[30], Y[60], U[60])
        bus.send_y(t, names, y)
        bus.send_u(ts[60], JOINTS, u)
        bus.send_ticks(ts[62:], Y[62:], U[62:])
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert (stamp_ns(stop.header.stamp), stop.kind, stop.joint) == (t, kind, joint), stop
        assert words in stop.reason, stop.reason
        # no verdict before it was wrong, none for the bad tick; checking went on afterwards
        assert bus.wait(lambda: len(bus.statuses(ts[62:])) == 28), len(bus.statuses(ts[62:]))
        assert warm_up_then_conformant(bus.statuses(ts[:60]))
        assert not [s for s in bus.statuses(ts) if stamp_ns(s.header.stamp) == ts[60]]
        assert all(s.safe_stop_active for s in bus.statuses(ts[62:]))
        assert warm_up_then_conformant(bus.statuses(ts[62:]))
        # first cause wins: later ones publish no other stop; the stop itself is repeated every
        # tick period until a reset (issue 17.2: bounded delivery)
        assert len(bus.distinct_active_stops()) == 1
        assert bus.wait(lambda: len(bus.active_stops()) >= 3)
        self.alive_and_checking(bus, proc)

    def test_violation_names_its_test_case_on_the_models_tick(self, bus, mon):
        """A violation's stop names joint, step k and the stamp where its test case began:
        k ticks of the model's dt (4 ms) before. (The node's ``dt`` parameter, the watchdog's
        tick, is read-only since issue 19.6 and never enters the test case's stamp.)"""
        Y, U = stream(80, seed=4)
        Y[60, 0] += 0.01                          # a jump no set of this model allows
        ts = stamps(80)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert (stop.kind, stop.joint, stamp_ns(stop.header.stamp)) == ("violation", JOINTS[0], ts[60]), stop
        assert stop.step >= 1 and stop.test_case_start_ns == ts[60] - stop.step * DT_NS, stop

    def test_a_stuck_sensor_while_the_reference_moves_latches_a_stop(self, bus, mon):
        """The stuck-sensor rule over DDS: /joint_states, /reference and /plant_input as the
        running system publishes them; joint 2's reading frozen at tick 60 while its reference
        moves at 0.1 rad/s latches an ``invalid_sample`` stop naming the joint at its fifth
        repeat (a reference that arrives after its tick was processed is used at the next
        tick, hence up to two ticks later); nothing stops while the readings change."""
        Y, U = stream(120, seed=12)
        Y[60:, 1] = Y[60, 1]
        ts = stamps(120)
        for k, t in enumerate(ts):
            bus.send_y(t, JOINTS, Y[k])
            r = JointReference(name=JOINTS, position=[0.0, 0.0], velocity=[0.3, 0.1], acceleration=[0.0, 0.0])
            to_stamp(r.header.stamp, t)
            bus.ref.publish(r)
            bus.send_u(t, JOINTS, U[k])
            time.sleep(0.002)
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert (stop.kind, stop.joint) == ("invalid_sample", JOINTS[1]), stop
        assert "stuck sensor" in stop.reason and "repeated" in stop.reason, stop.reason
        assert ts[65] <= stamp_ns(stop.header.stamp) <= ts[67], (stamp_ns(stop.header.stamp) - ts[60]) / DT_NS
        assert not [s for s in bus.statuses(ts[:60]) if not s.conformant and s.active_test_cases]

    def test_extra_names_are_ignored_and_counted(self, bus, mon):
        Y, U = stream(50, seed=2)
        ts = stamps(50)
        before = bus.counters()
        for k, t in enumerate(ts):
            bus.send_y(t, ["gripper_joint", JOINTS[1], JOINTS[0]], [123.0, Y[k, 1], Y[k, 0]])
            bus.send_u(t, JOINTS + ["other_joint"], list(U[k]) + [math.nan])
            time.sleep(0.002)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 50)
        assert warm_up_then_conformant(bus.statuses(ts)) and not bus.active_stops()

        def delta():
            c = bus.counters()
            return tuple(c.get(k, 0) - before.get(k, 0) for k in ("extra_names_y", "extra_names_u", "ticks"))
        assert bus.wait(lambda: delta() == (50, 50, 50)), delta()

    def test_repeated_stamps_are_skipped_and_counted(self, bus, mon):
        Y, U = stream(60, seed=3)
        ts = stamps(60)
        before = bus.counters()
        bus.send_ticks(ts[:40], Y, U)
        bus.send_y(ts[39], JOINTS, Y[39])          # the last sample again
        bus.send_u(ts[39], JOINTS, U[39])
        bus.send_y(ts[40], JOINTS, Y[40])
        bus.send_y(ts[40], JOINTS, [9.0, 9.0])     # a second, different sample at the same stamp
        bus.send_u(ts[40], JOINTS, U[40])
        bus.send_ticks(ts[41:], Y[41:], U[41:])
        assert bus.wait(lambda: len(bus.statuses(ts)) == 60), len(bus.statuses(ts))
        assert warm_up_then_conformant(bus.statuses(ts)) and not bus.active_stops()

        def delta():
            c = bus.counters()
            return tuple(c.get(k, 0) - before.get(k, 0) for k in ("duplicate_y", "duplicate_u", "ticks"))
        assert bus.wait(lambda: delta() == (2, 1, 60)), delta()

    def test_dropped_messages_are_counted_gaps(self, bus, mon):
        Y, U = stream(300, seed=5)
        ts = stamps(300)
        before = bus.counters()
        bus.send_ticks(ts, Y, U, drop_y={100, 200, 201, 202}, drop_u={150, 200, 201, 202})
        assert bus.wait(lambda: len(bus.statuses(ts)) == 295), len(bus.statuses(ts))
        got = [stamp_ns(s.header.stamp) for s in bus.statuses(ts)]
        assert got == [t for k, t in enumerate(ts) if k not in (100, 150, 200, 201, 202)]
        assert warm_up_then_conformant(bus.statuses(ts), segments=4) and not bus.active_stops()

        def delta():
            c = bus.counters()
            return tuple(c.get(k, 0) - before.get(k, 0) for k in ("ticks", "dropped_incomplete", "gaps",
                                                                    "missing_ticks"))
        assert bus.wait(lambda: delta() == (295, 2, 3, 5)), delta()

    def test_burst_every_processed_tick_has_a_status_and_losses_are_counted(self, bus, mon):
        """800 ticks published back to back, faster than the monitor checks them. The
        lossy-link rule is off here (``gap_window`` 0): ticks lost again within 25 ticks of
        each other are a coverage stop with it (``test_core_samples_lost_again_*``), which a
        burst that overflows the queues may cause; this test checks the accounting."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"gap_window": 0})
        assert ok, why
        n = 800
        Y, U = stream(n + 50, seed=7)
        ts = stamps(n + 50)
        before = bus.counters()
        bus.send_ticks(ts[:n], Y, U, pace=0)
        # then single ticks on the same grid until one is checked: both topics and the status
        # are ordered, so by then every tick of the burst that reached the monitor was checked
        # and its status is here
        for k in range(n, n + 50):
            bus.send_ticks(ts[k:k + 1], Y[k:k + 1], U[k:k + 1], pace=0)
            if bus.wait(lambda: bus.statuses(ts[n:]), 5.0):
                break
        st = bus.statuses(ts)
        got = [stamp_ns(s.header.stamp) for s in st]
        assert got and got[-1] >= ts[n]
        assert got == sorted(got) and len(set(got)) == len(got)
        assert warm_up_then_conformant(st, segments=None) and not bus.active_stops()
        # the diagnostics account for every tick between the first and the last checked one
        assert bus.wait(lambda: bus.counters()["ticks"] - before.get("ticks", 0) >= len(st))
        c = bus.counters()
        assert c["ticks"] - before.get("ticks", 0) == len(st), (c, before, len(st))
        missing = c.get("missing_ticks", 0) - before.get("missing_ticks", 0)
        print(f"burst of {n}: {len(st)} checked, {missing} missing in gaps, "
              f"{c.get('dropped_incomplete', 0) - before.get('dropped_incomplete', 0)} half ticks dropped")
        assert len(st) + missing == (got[-1] - got[0]) // DT_NS + 1
        # the tick counter in the statuses has no holes: each checked tick was published
        ticks = [s.tick for s in st]
        assert ticks == list(range(ticks[0], ticks[0] + len(ticks)))
        self.alive_and_checking(bus, proc)

    def test_plant_input_not_yet_arriving_is_reported_not_a_stop(self, bus, mon):
        """/joint_states flows, /plant_input has never come (a controller still starting):
        the monitor waits, says so on /diagnostics and counts the half ticks it drops; once
        /plant_input comes it checks every tick."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})
        assert ok, why
        before = bus.counters()
        Y, U = stream(700, seed=8)
        ts = stamps(700)
        t_start = time.monotonic()
        for k in range(500):                       # 1 s and more: five times the watchdog's limit
            bus.send_y(ts[k], JOINTS, Y[k])
            time.sleep(0.002)
        assert time.monotonic() - t_start > 1.0
        c = bus.counters()                          # a fresh /diagnostics message
        level, message = bus.diags["reachset_ros: conformance monitor"][:2]
        assert not bus.active_stops()
        assert (level, message) == (DiagnosticStatus.WARN, "waiting for /plant_input")
        assert c["dropped_incomplete"] - before.get("dropped_incomplete", 0) > 0
        assert c.get("ticks", 0) == before.get("ticks", 0)
        # the second half checks that every tick is checked, not the watchdog: give it 1 s, so
        # that a pause of this test's own Python publisher (a CI run saw one of 200 ms in the
        # full suite, with the loop's data intact) is not taken for the stream going silent
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 250})
        assert ok, why
        bus.send_ticks(ts[500:], Y[500:], U[500:])
        assert bus.wait(lambda: len(bus.statuses(ts)) == 200)
        assert warm_up_then_conformant(bus.statuses(ts)) and not bus.active_stops()
        self.alive_and_checking(bus, proc)

    def test_stamps_that_never_pair_are_missing_data(self, bus, mon):
        """Both topics arrive, but /plant_input is stamped half a period off (a controller
        stamping with its own clock): no tick ever completes, a safe stop says why."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})
        assert ok, why
        Y, U = stream(5000, seed=13)
        ts = stamps(5000)
        for k, t in enumerate(ts):
            bus.send_y(t, JOINTS, Y[k])
            bus.send_u(t + DT_NS // 2, JOINTS, U[k])
            time.sleep(0.002)
            if bus.active_stops():
                break
        stops = bus.active_stops()
        assert stops and stops[0].kind == "missing_data", stops
        assert "limit 200 ms" in stops[0].reason and "stamps do not pair" in stops[0].reason, stops[0].reason
        assert not bus.statuses(ts)
        self.alive_and_checking(bus, proc)

    def test_topic_going_silent_is_missing_data(self, bus, mon):
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})
        assert ok, why
        Y, U = stream(5000, seed=10)
        ts = stamps(5000)
        bus.send_ticks(ts[:100], Y, U)
        for k in range(100, 5000):
            bus.send_u(ts[k], JOINTS, U[k])      # /joint_states went silent
            time.sleep(0.002)
            if bus.active_stops():
                break
        stops = bus.active_stops()
        assert stops and stops[0].kind == "missing_data", stops
        assert "/joint_states silent for" in stops[0].reason, stops[0].reason
        assert bus.wait(lambda: len(bus.statuses(ts[:100])) == 100)
        assert warm_up_then_conformant(bus.statuses(ts[:100]))
        assert stamp_ns(stops[0].header.stamp) == ts[99]   # the last tick checked
        self.alive_and_checking(bus, proc)

    def test_stream_at_the_wrong_period_is_a_coverage_stop(self, bus, mon):
        """/joint_states and /plant_input at 125 Hz for a 4 ms model: every step is a gap, so
        nothing is ever checked. No status says conformant; a latched safe stop of kind
        ``coverage`` names the measured period, at the second step (the lossy-link rule:
        samples lost again within ``gap_window`` ticks; without it, within the missing-data
        limit after the warm-up, as the core's test checks); /diagnostics says nothing was
        checked."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})   # 200 ms: no watchdog stop on a stall
        assert ok, why
        Y, U = stream(200, seed=15)
        base = stamps(400)[0]
        ts = [base + 2 * DT_NS * k for k in range(200)]
        for k, t in enumerate(ts):
            bus.send_y(t, JOINTS, Y[k])
            bus.send_u(t, JOINTS, U[k])
            time.sleep(0.008)
            if bus.active_stops():
                break
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert stop.kind == "coverage" and "measured stream period 8 ms" in stop.reason, stop
        assert "samples lost again" in stop.reason and "dt of 4 ms" in stop.reason, stop.reason
        at = stamp_ns(stop.header.stamp)
        assert at == ts[2], (at - ts[0]) / 1e6
        assert bus.wait(lambda: bus.statuses([ts[0], at]) and stamp_ns(bus.statuses([ts[0], at])[-1].header.stamp) == at)
        st = bus.statuses(ts)
        assert st and not any(s.conformant for s in st), [s.conformant for s in st]
        assert all(s.active_test_cases == 0 and set(s.tightest_step) == {-1} for s in st)
        c = bus.counters(newer_than=time.monotonic())
        assert c["longest_step"] == -1 and c["unchecked_ticks"] >= len(st) and c["coverage_faults"] >= 1, c
        # latched: a late subscriber sees it
        late = []
        sub = bus.caller.create_subscription(SafeStop, "safe_stop", late.append, SAFE_STOP_QOS)
        try:
            end = time.monotonic() + 10
            while time.monotonic() < end and not late:
                rclpy.spin_once(bus.caller, timeout_sec=0.1)
            assert late and late[-1].active and late[-1].kind == "coverage"
        finally:
            bus.caller.destroy_subscription(sub)
        self.alive_and_checking(bus, proc)

    def test_bad_parameter_updates_are_refused_and_change_nothing(self, bus, mon, tmp_path):
        proc, path, _ = mon
        model_id = mdl.file_sha256(path)[:12]
        garbage = tmp_path / "garbage.yaml"
        garbage.write_text("format: [unclosed\n  {{ :\n")
        negative = tmp_path / "negative.yaml"
        negative.write_text(path.read_text().replace("- 0.15", "- -0.15", 1))
        assert negative.read_text() != path.read_text()
        other = write_model(tmp_path / "other.yaml", alpha_w=(0.3, 0.0))
        cases = [
            ({"model_file": str(tmp_path / "missing.yaml")}, "model file not found"),
            ({"model_file": str(garbage)}, "does not parse"),
            ({"model_file": str(negative)}, "negative scaling factor"),
            ({"model_file": ""}, "must not be empty"),
            ({"joints": ["arm_3_joint"]}, "arm_3_joint is not in the model"),
            ({"model_file": str(other), "joints": ["arm_1_joint", "arm_9_joint"]}, "arm_9_joint is not in the model"),
            ({"max_missing_ticks": 0}, "out of range"),
            ({"dt": math.nan}, "read-only"),       # read at start-up only (issue 19.6)
            ({"dt": -0.004}, "read-only"),
        ]
        for values, words in cases:
            ok, why = bus.set_params("monitor_node", values)
            assert not ok and words in why, (values, why)
        assert bus.get_param("monitor_node", "model_file") == str(path)
        assert bus.get_param("monitor_node", "joints") == [""]
        assert bus.get_param("monitor_node", "max_missing_ticks") == 10000
        # the running model is the one it had: same id, same verdicts
        Y, U = stream(60, seed=11)
        ts = stamps(60)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 60)
        assert all(s.model_id == model_id and list(s.name) == JOINTS for s in bus.statuses(ts))
        assert warm_up_then_conformant(bus.statuses(ts))
        assert not bus.active_stops()
        # a valid update is applied (the refusals above were not vacuous), and back
        ok, why = bus.set_params("monitor_node", {"model_file": str(other), "joints": ["arm_2_joint"]})
        assert ok, why
        ts = stamps(20)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 20)
        assert all(s.model_id == mdl.file_sha256(other)[:12] and list(s.name) == ["arm_2_joint"]
                   for s in bus.statuses(ts))
        ok, why = bus.set_params("monitor_node", {"model_file": str(path), "joints": [""]})
        assert ok, why
        self.alive_and_checking(bus, proc)


# ------------------------------------------------------------ controller_node
Q_TEST = np.array([0.1, -0.2])


def wait_exit(proc, timeout):
    end = time.monotonic() + timeout
    while proc.alive():
        if time.monotonic() > end:
            return False
        time.sleep(0.05)
    return True


def start_controller(d, model=None, u_max=(26.0, 26.0), wait_for_monitor=False, stop_category=2):
    """A controller_node for these tests: category 2 by default (the braking law's output is
    what they check; the holding brakes of category 1 are tested in test_stopping.py and
    test_nodes.py)."""
    params = {"joints": JOINTS, "u_max": list(u_max), "omega": [10.0], "zeta": [1.0],
              "wait_for_monitor": wait_for_monitor, "stop_category": stop_category,
              "allow_uncertified": model is None}
    if model is not None:
        params["model_file"] = str(model)
    return processes.start("controller_node", params, d)


def tracking_law(omega, zeta, q=Q_TEST, qd=(0.0, 0.0)):
    """The static law with the test's reference (q_d = qd_d = qdd_d = 0)."""
    return -np.asarray(omega) ** 2 * q - 2 * np.asarray(zeta) * np.asarray(omega) * np.asarray(qd)


def braking_law(q, qd, u_max):
    """docs of controller_node: hold at q + qd |qd| / u_max, PD (8 rad/s, damping 1) saturated to U_p."""
    q, qd = np.asarray(q), np.asarray(qd)
    q_hold = q + qd * np.abs(qd) / np.asarray(u_max)
    return np.clip(64.0 * (q_hold - q) - 16.0 * qd, -np.asarray(u_max), np.asarray(u_max))


def outputs(bus, ts):
    """The controller's /plant_input accelerations for the stamps ``ts`` (stamp -> array, joint order JOINTS)."""
    want = set(ts)
    out = {}
    for m in list(bus.inputs):
        t = stamp_ns(m.header.stamp)
        if t in want:
            idx = {n: i for i, n in enumerate(m.name)}
            out[t] = np.array([m.acceleration[idx[j]] for j in JOINTS])
    return out


def drive(bus, ts, q=Q_TEST, qd=(0.0, 0.0), reference=True, est_names=JOINTS, wait=True):
    """For each stamp: a reference (all zeros) then, 20 ms later, an estimate; returns the outputs."""
    for t in ts:
        if reference:
            r = JointReference(name=JOINTS, position=[0.0, 0.0], velocity=[0.0, 0.0], acceleration=[0.0, 0.0])
            to_stamp(r.header.stamp, t)
            bus.ref.publish(r)
            time.sleep(0.02)
        e = JointEstimate(name=list(est_names), position=[float(v) for v in q], velocity=[float(v) for v in qd],
                          disturbance=[0.0] * len(q))
        to_stamp(e.header.stamp, t)
        bus.est.publish(e)
    if wait:
        bus.wait(lambda: len(outputs(bus, ts)) == len(ts), 10)
    return outputs(bus, ts)


def assert_law(bus, expected, timeout=20.0):
    """Drive the controller (q = Q_TEST, qd = 0, reference 0) until it has computed three
    outputs with the reference; each must be ``expected``. A reference that arrives after
    its estimate is not used; that output is the hold law, u = 0 here, and is allowed."""
    end = time.monotonic() + timeout
    seen = 0
    while time.monotonic() < end and seen < 3:
        for u in drive(bus, stamps(3)).values():
            if np.all(u == 0.0):
                continue
            np.testing.assert_allclose(u, expected, rtol=0, atol=1e-9)
            seen += 1
    assert seen, f"no output computed with the reference within {timeout} s"


@pytest.fixture(scope="class")
def controller(bus, tmp_path_factory):
    """A controller_node process (with a model) for one test class."""
    d = tmp_path_factory.mktemp("controller")
    model = write_model(d / "m.yaml")
    proc = start_controller(d, model)
    try:
        assert bus.wait(lambda: bus.est.get_subscription_count() and bus.ref_subscribers()
                        and bus.listener.count_publishers("/plant_input") >= 1, 30), proc.log.read_text()
        yield proc, model, d
    finally:
        processes.stop([proc])


class TestControllerNode:
    def test_bad_parameter_updates_are_refused_and_change_nothing(self, bus, controller, tmp_path):
        proc, model, _ = controller
        bus.clear()
        assert_law(bus, tracking_law(10.0, 1.0))
        garbage = tmp_path / "garbage.yaml"
        garbage.write_text("joints: {arm_1_joint: [1, 2\n")
        negative = tmp_path / "negative.yaml"
        negative.write_text(model.read_text().replace("- 0.15", "- -0.15", 1))
        wide = write_model(tmp_path / "wide.yaml", alpha_w=(5.0, 50.0), alpha_v=(1e-2,))
        arm1_only = write_model(tmp_path / "arm1.yaml", joints=["arm_1_joint"])
        cases = [
            ({"omega": [math.nan]}, "gain omega must be a positive finite number"),
            ({"zeta": [-1.0]}, "gain zeta must be a positive finite number"),
            ({"omega": [0.0, 10.0]}, "gain omega must be a positive finite number"),
            ({"omega": [60.0]}, "closed loop unstable"),
            ({"omega": [10.0, 10.0, 10.0]}, "omega needs 1 or 2 values, got 3"),
            ({"eps": [math.inf]}, "gain eps must be a positive finite number"),
            ({"controller": "compensated"}, "needs the ESO"),
            ({"observer": "kalman"}, "observer must be hg or eso"),
            ({"u_max": [-26.0]}, "u_max must be finite and > 0"),
            ({"u_max": [26.0, math.nan]}, "u_max must be finite and > 0"),
            ({"u_max": [1.0]}, "leaves U_p = +-1"),
            ({"u_ff_bound": 30.0}, "leaves U_p = +-26"),
            ({"model_file": str(tmp_path / "missing.yaml")}, "model file not found"),
            ({"model_file": str(garbage)}, "does not parse"),
            ({"model_file": str(negative)}, "negative scaling factor"),
            ({"model_file": str(wide)}, "leaves U_p"),
            # a joint the new model does not cover still gets its stability check
            ({"model_file": str(arm1_only), "omega": [10.0, 300.0]}, "joint arm_2_joint: closed loop unstable"),
            ({"joints": ["arm_1_joint"]}, "read-only"),     # start-up only (issue 19.6)
        ]
        for values, words in cases:
            ok, why = bus.set_params("controller_node", values)
            assert not ok and words in why, (values, why)
        assert bus.get_param("controller_node", "omega") == [10.0]
        assert bus.get_param("controller_node", "u_max") == [26.0, 26.0]
        assert bus.get_param("controller_node", "model_file") == str(model)
        # the running law is unchanged; a valid change is applied (the refusals were not vacuous)
        bus.clear()
        assert_law(bus, tracking_law(10.0, 1.0))
        ok, why = bus.set_params("controller_node", {"omega": [12.0, 14.0]})
        assert ok, why
        assert_law(bus, tracking_law([12.0, 14.0], 1.0))
        ok, why = bus.set_params("controller_node", {"omega": [10.0]})
        assert ok, why
        assert proc.alive()

    def test_unusable_estimates_stop_with_brakes_references_ignored_counted(self, bus, controller):
        """An estimate the controller cannot use (a joint missing, a short array, a non-finite
        value) is a stop of the controller's own (issue 19.2; before: skipped, no output, the
        simulator stepping on a stale command): every holding brake engages on
        /brake_command, the effort holds the last usable position (u_p = 0), the diagnostics
        say why, and only a cleared /safe_stop gives control back. A reference it cannot use
        is treated as none (hold the measured position), counted."""
        from reachset_msgs.msg import BrakeCommand
        proc, _, _ = controller
        bus.clear()
        name = "reachset_ros: controller"
        before = bus.counters(name)
        brakes = []
        bsub = bus.listener.create_subscription(BrakeCommand, "brake_command", brakes.append,
                                                QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
        stop_pub = bus.caller.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
        try:
            assert bus.wait(lambda: proc.alive() and stop_pub.get_subscription_count() >= 1, 30)
            assert_law(bus, tracking_law(10.0, 1.0))
            assert bus.wait(lambda: any(not any(b.engage) for b in list(brakes)), 15)   # released while tracking
            bad = stamps(3)
            for t, est in zip(bad, [JointEstimate(name=[JOINTS[0]], position=[0.1], velocity=[0.0]),
                                    JointEstimate(name=JOINTS, position=[0.1, -0.2], velocity=[0.0]),
                                    JointEstimate(name=JOINTS, position=[0.1, math.nan], velocity=[0.0, 0.0])]):
                to_stamp(est.header.stamp, t)
                bus.est.publish(est)
            assert bus.wait(lambda: len(outputs(bus, bad)) == 3, 15), outputs(bus, bad)
            assert all(np.array_equal(u, [0.0, 0.0]) for u in outputs(bus, bad).values())
            assert bus.wait(lambda: any(stamp_ns(b.header.stamp) == bad[0] and all(b.engage) for b in list(brakes)))
            diag = bus.wait(lambda: "no usable estimate" in bus.diags.get(name, ("", "", {}, 0))[1], 15)
            assert diag, bus.diags.get(name)
            assert "no usable estimate" in proc.log.read_text()
            # still stopped: a good estimate gets the braking law, brakes stay engaged
            got = drive(bus, stamps(2))
            assert got and all(np.array_equal(u, [0.0, 0.0]) for u in got.values()), got
            # the reset (a cleared /safe_stop) releases the brakes and gives control back
            stop_pub.publish(SafeStop(active=False, kind="reset", reason="test: reset"))
            assert bus.wait(lambda: outputs_match(drive(bus, stamps(1)), tracking_law(10.0, 1.0)), 15)
            assert not any(list(brakes)[-1].engage)
        except BaseException:
            bus.caller.destroy_publisher(stop_pub)
            raise
        finally:
            bus.listener.destroy_subscription(bsub)
        try:
            self.references_treated_as_none(bus, proc, name, before)
        finally:
            # (the controller has heard from this "monitor": losing it is a stop, issue 17.2; this
            # is the class's last test, so that stop ends with the process)
            bus.caller.destroy_publisher(stop_pub)

    @staticmethod
    def references_treated_as_none(bus, proc, name, before):
        # references: a joint missing, a non-finite value, a short array -> treated as none:
        # hold the measured position (u = -2 zeta omega qd)
        qd = np.array([0.3, -0.1])
        refs = [JointReference(name=[JOINTS[1]], position=[0.0], velocity=[0.0], acceleration=[0.0]),
                JointReference(name=JOINTS, position=[0.0, 0.0], velocity=[0.0, 0.0], acceleration=[math.nan, 0.0]),
                JointReference(name=JOINTS, position=[0.0], velocity=[0.0, 0.0], acceleration=[0.0, 0.0])]
        for i, r in enumerate(refs):
            for _ in range(5):   # again if the estimate overtook the reference (then it was not read)
                t = stamps(1)[0]
                to_stamp(r.header.stamp, t)
                bus.ref.publish(r)
                time.sleep(0.05)
                got = drive(bus, [t], qd=qd, reference=False)
                np.testing.assert_allclose(got[t], -2 * 1.0 * 10.0 * qd, rtol=0, atol=1e-9)
                if bus.counters(name)["bad_reference"] - before["bad_reference"] == i + 1:
                    break
        c = bus.counters(name)
        assert c["bad_estimate"] - before["bad_estimate"] == 3, c
        assert c["bad_reference"] - before["bad_reference"] == 3, c
        assert c["callback_errors"] == 0 and proc.alive()
        assert_law(bus, tracking_law(10.0, 1.0))


class TestStopWithoutEstimates:
    def test_a_safe_stop_without_estimates_engages_every_brake(self, bus, controller):
        """Issue 17 (found by the fault campaign): the observer killed, the monitor's missing-data
        stop arrives, but the braking law has no estimate to act on. Before, the controller
        sent nothing and the drives held its last command; now every holding brake engages
        STOP_ESTIMATE_TIMEOUT after the last estimate, on /brake_command, which also says
        when braking began and which estimate the controller had when the stop arrived."""
        from reachset_msgs.msg import BrakeCommand
        proc, _, _ = controller
        bus.clear()
        brakes = []
        bsub = bus.listener.create_subscription(BrakeCommand, "brake_command", brakes.append,
                                                QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
        stop_pub = bus.caller.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
        try:
            assert bus.wait(lambda: proc.alive() and stop_pub.get_subscription_count() >= 1, 30)
            stop_pub.publish(SafeStop(active=False, kind="reset", reason="test: no stop"))
            assert_law(bus, tracking_law(10.0, 1.0))       # tracking
            ts = stamps(2)
            assert len(drive(bus, ts)) == 2                  # the newest estimate and command: ts[-1]
            assert not any(list(brakes)[-1].engage) and list(brakes)[-1].braking_since_ns == 0
            stop = SafeStop(active=True, kind="missing_data", reason="test: the observer died")
            to_stamp(stop.header.stamp, ts[-1])
            stop_pub.publish(stop)          # and no estimate comes any more
            assert bus.wait(lambda: any(all(b.engage) for b in list(brakes)), 15), list(brakes)[-3:]
            b = next(b for b in list(brakes) if all(b.engage))
            assert "no estimate" in b.reason and b.stop_received_ns == ts[-1] and b.braking_since_ns == ts[-1], b
            assert "safe stop without estimates" in proc.log.read_text()
        finally:
            stop_pub.publish(SafeStop(active=False, kind="reset", reason="test: reset"))
            time.sleep(0.2)
            bus.listener.destroy_subscription(bsub)
            bus.caller.destroy_publisher(stop_pub)


class TestSimulatorReportsStaleCommands:
    def test_stale_command_steps_are_reported_and_the_drives_brake(self, bus, tmp_path):
        """Issue 17.3: the simulator never steps on a stale command silently. With no
        controller at all, each tick waits ``lockstep_timeout`` and steps on the held command:
        every such step is counted on /diagnostics (WARN, ``stale_effort``, the longest run)
        and logged, and after ``drive_watchdog_steps`` of them in a row the simulated drives
        engage every holding brake (``drive_watchdog``), as a drive's communication watchdog
        does. Before, the count appeared only in the log at shutdown."""
        sim = processes.start("sim_node", {"seed": 1, "lockstep_timeout": 0.02, "drive_watchdog_steps": 3,
                                        "publish_clock": False}, tmp_path)
        try:
            name = "reachset_ros: simulator"
            assert bus.wait(lambda: name in bus.diags and int(bus.diags[name][2].get("stale_effort", 0)) >= 5, 30), \
                sim.log.read_text()[-2000:]
            level, message, values, _ = bus.diags[name]
            assert level == DiagnosticStatus.WARN and "stale command" in message, (level, message)
            assert int(values["drive_watchdog"]) == 1 and int(values["stale_run_max"]) >= 3, values
            log = sim.log.read_text()
            assert "stepped on a stale command" in log and "drive watchdog: 3 consecutive steps" in log
        finally:
            processes.stop([sim])


class TestAbsurdCommand:
    def test_a_non_finite_command_is_never_sent_it_stops_with_brakes(self, bus, tmp_path):
        """Issue 19.2: an overflowing law (a finite but absurd reference, 1e308 rad) gives a
        non-finite u_p: the controller sends the holding torque of the last usable position
        instead, engages every brake, logs and reports it (``bad_command``) until the reset.
        Before: the non-finite torque went to the drives."""
        from reachset_msgs.msg import BrakeCommand
        ctl = start_controller(tmp_path)
        brakes = []
        bsub = bus.listener.create_subscription(BrakeCommand, "brake_command", brakes.append,
                                                QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
        try:
            assert bus.wait(lambda: bus.est.get_subscription_count() == 1 and bus.ref_subscribers() == 1,
                            30), ctl.log.read_text()
            time.sleep(0.5)
            bus.clear()
            assert_law(bus, tracking_law(10.0, 1.0))
            t = stamps(1)[0]
            r = JointReference(name=JOINTS, position=[1e308, 0.0], velocity=[0.0, 0.0], acceleration=[0.0, 0.0])
            to_stamp(r.header.stamp, t)
            bus.ref.publish(r)
            time.sleep(0.05)
            got = drive(bus, [t], reference=False)
            assert t in got and np.array_equal(got[t], [0.0, 0.0]), got
            assert bus.wait(lambda: any(stamp_ns(b.header.stamp) == t and all(b.engage) for b in list(brakes)))
            assert "non-finite command" in ctl.log.read_text()
            c = bus.counters("reachset_ros: controller")
            assert c["bad_command"] == 1, c
        finally:
            bus.listener.destroy_subscription(bsub)
            processes.stop([ctl])


class TestObserverNode:
    def test_non_finite_input_or_sample_does_not_poison_the_estimate(self, bus, tmp_path):
        """A NaN /plant_input or /joint_states is skipped (before: a NaN input made every later
        estimate NaN); the estimates stay finite and follow the measurement."""
        est = []
        sub = bus.listener.create_subscription(JointEstimate, "observer/estimate", est.append,
                                               QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
        obs = processes.start("observer_node", {"joints": JOINTS, "allow_uncertified": True}, tmp_path)
        try:
            # /plant_input: the observer and this test's own listener
            assert bus.wait(lambda: bus.js.get_subscription_count() == 1 and bus.pi.get_subscription_count() == 2,
                            30), obs.log.read_text()
            time.sleep(0.5)
            ts = stamps(60)
            for k, t in enumerate(ts):
                y = [0.1 + 1e-4 * k, -0.2]
                if k == 30:
                    y = [math.nan, -0.2]
                bus.send_y(t, JOINTS, y)
                time.sleep(0.005)
                bus.send_u(t, JOINTS, [math.nan, 0.0] if k in (20, 21) else [0.0, 0.0])
                time.sleep(0.005)
            assert bus.wait(lambda: any(stamp_ns(m.header.stamp) == ts[-1] for m in list(est)))
            mine = [m for m in list(est) if ts[0] <= stamp_ns(m.header.stamp) <= ts[-1]]
            assert len(mine) >= 50 and ts[30] not in [stamp_ns(m.header.stamp) for m in mine]
            assert all(np.all(np.isfinite(m.position)) and np.all(np.isfinite(m.velocity)) for m in mine)
            assert abs(mine[-1].position[0] - (0.1 + 1e-4 * 59)) < 5e-3 and abs(mine[-1].position[1] + 0.2) < 5e-3
            # visible on /diagnostics (issue 19.2): the skipped samples are counted there
            c = bus.counters("reachset_ros: observer")
            assert c["bad_sample"] >= 3, c
            assert obs.alive()
        finally:
            processes.stop([obs])
            bus.listener.destroy_subscription(sub)


class TestWaitForMonitor:
    def test_controller_holds_until_it_knows_the_stop_state(self, bus, tmp_path):
        """With ``wait_for_monitor`` a (re)started controller brakes and holds until the first
        /safe_stop message tells it whether a stop is latched; an inactive one releases it."""
        assert bus.wait(lambda: bus.est.get_subscription_count() == 0 and bus.ref_subscribers() == 0)
        bus.clear()
        qd = np.array([0.5, -0.5])
        ctl = start_controller(tmp_path, wait_for_monitor=True)
        pub = None
        try:
            assert bus.wait(lambda: bus.est.get_subscription_count() == 1 and bus.ref_subscribers() == 1,
                            30), ctl.log.read_text()
            time.sleep(1.0)
            got = drive(bus, stamps(10), qd=qd)
            assert got and all(np.allclose(u, braking_law(Q_TEST, qd, [26.0, 26.0]), rtol=0, atol=1e-9)
                               for u in got.values()), got
            # the monitor's initial state (what monitor_node publishes, latched, when it starts)
            pub = bus.caller.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
            pub.publish(SafeStop(active=False, kind="reset", reason="monitor started: no safe stop active"))
            track = tracking_law(10.0, 1.0, qd=qd)
            assert bus.wait(lambda: outputs_match(drive(bus, stamps(1), qd=qd), track), 15)
            assert ctl.alive()
            assert "safe stop inactive: tracking (reset: monitor started" in ctl.log.read_text()
        finally:
            processes.stop([ctl])
            if pub is not None:
                bus.caller.destroy_publisher(pub)    # its latched message must not reach later tests


class TestSafeStopLatch:
    def test_latched_stop_reaches_a_restarted_controller_and_only_reset_clears_it(self, bus, monitor, tmp_path):
        mproc, _, _ = monitor
        assert bus.call_trigger("/monitor_node/reset").success
        assert bus.wait(lambda: bus.stops and not bus.stops[-1].active)
        bus.clear()
        u_max = np.array([26.0, 26.0])
        qd = np.array([0.5, -0.5])
        track = tracking_law(10.0, 1.0, qd=qd)
        brake = braking_law(Q_TEST, qd, u_max)
        hold_only = -2 * 10.0 * qd       # tracking without a reference
        assert len({tuple(np.round(v, 6)) for v in (track, brake, hold_only)}) == 3

        def settle(expected, timeout=20.0, before=()):
            """Outputs (reference sent) until three are not the no-reference one; all must be
            ``expected``, except outputs equal to one of ``before`` until the first expected one."""
            end = time.monotonic() + timeout
            seen = 0
            while time.monotonic() < end and seen < 3:
                for u in drive(bus, stamps(3), qd=qd).values():
                    if np.allclose(u, hold_only, rtol=0, atol=1e-12):
                        continue
                    if not seen and any(np.allclose(u, b, rtol=0, atol=1e-9) for b in before):
                        continue
                    np.testing.assert_allclose(u, expected, rtol=0, atol=1e-9)
                    seen += 1
            assert seen

        # the controller of the previous class is gone from the graph
        assert bus.wait(lambda: bus.est.get_subscription_count() == 0 and bus.ref_subscribers() == 0)
        a = start_controller(tmp_path / "a", wait_for_monitor=True)
        b = None
        try:
            assert bus.wait(lambda: bus.est.get_subscription_count() == 1 and bus.ref_subscribers() == 1,
                            30), a.log.read_text()
            # wait_for_monitor: it brakes until the monitor's latched state reaches it
            settle(track, before=(brake,))
            # the monitor stops (a /joint_states lacking a joint)
            bus.send_y(stamps(1)[0], [JOINTS[0]], [0.0])
            assert bus.wait(lambda: bus.active_stops())
            assert bus.active_stops()[0].kind == "name_mismatch"
            assert bus.wait(lambda: outputs_match(drive(bus, stamps(1), qd=qd), brake), 15)
            settle(brake)
            # a late subscriber sees it
            late = []
            sub = bus.caller.create_subscription(SafeStop, "safe_stop", late.append, SAFE_STOP_QOS)
            end = time.monotonic() + 15
            while not late and time.monotonic() < end:
                rclpy.spin_once(bus.caller, timeout_sec=0.05)
            bus.caller.destroy_subscription(sub)
            assert late and late[-1].active and late[-1].kind == "name_mismatch"
            # the controller restarts: the new one (waiting for the monitor's state, as it
            # should on a robot) brakes from its first output on
            processes.stop([a])
            assert bus.wait(lambda: bus.est.get_subscription_count() == 0 and bus.ref_subscribers() == 0)
            b = start_controller(tmp_path / "b", wait_for_monitor=True)
            assert bus.wait(lambda: bus.est.get_subscription_count() == 1 and bus.ref_subscribers() == 1,
                            30), b.log.read_text()
            assert bus.wait(lambda: len(bus.caller.get_subscriptions_info_by_topic("/safe_stop")) >= 2, 15)
            time.sleep(1.0)
            ts = stamps(10)
            got = drive(bus, ts, qd=qd, reference=False)
            assert got and all(np.allclose(u, brake, rtol=0, atol=1e-9) for u in got.values()), got
            # more faults do not re-publish; conformant data does not clear it
            bus.send_y(stamps(1)[0], ["x"], [0.0])
            Y, U = stream(30, seed=12)
            bus.send_ticks(stamps(30), Y, U)
            time.sleep(0.5)
            assert len(bus.distinct_active_stops()) == 1 and bus.stops[-1].active
            settle(brake)
            # only the reset service clears it: the controller tracks again
            assert bus.call_trigger("/monitor_node/reset").success
            assert bus.wait(lambda: not bus.stops[-1].active and bus.stops[-1].kind == "reset")
            assert bus.wait(lambda: outputs_match(drive(bus, stamps(1), qd=qd), track), 15)
            assert a.proc.returncode is not None and b.alive() and mproc.alive()
        finally:
            processes.stop([a, b])


def outputs_match(got, expected):
    return bool(got) and all(np.allclose(u, expected, rtol=0, atol=1e-9) for u in got.values())


class TestMonitorLost:
    def test_a_frozen_monitor_is_a_stop_that_only_a_reset_clears(self, bus, tmp_path):
        """Issue 17.2: the controller requests the /safe_stop publishers' liveliness (lease
        MONITOR_LEASE_S); when the monitor freezes (SIGSTOP: no liveliness, as when it is
        killed) it brakes, a stop of its own. The monitor alive again does not release it, nor
        does a monitor's start state; the monitor's reset does. Before: the controller went on
        tracking with no monitor at all. (SIGSTOP rather than SIGKILL here: a killed process
        stays in the DDS graph until its participant lease ends and would confuse later tests.)"""
        qd = np.array([0.5, -0.5])
        track, brake = tracking_law(10.0, 1.0, qd=qd), braking_law(Q_TEST, qd, np.array([26.0, 26.0]))
        assert bus.wait(lambda: bus.est.get_subscription_count() == 0 and bus.ref_subscribers() == 0)
        path = write_model(tmp_path / "m.yaml")
        mon = processes.start("monitor_node", {"model_file": str(path), "max_missing_ticks": 10000,
                                            "reset_clean_ticks": 0, "window_dir": str(tmp_path / "w")}, tmp_path)
        ctl = start_controller(tmp_path / "c", wait_for_monitor=True)
        pub = None
        try:
            assert bus.wait(lambda: bus.est.get_subscription_count() == 1 and bus.ref_subscribers() == 1,
                            30), ctl.log.read_text()
            assert bus.wait(lambda: outputs_match(drive(bus, stamps(1), qd=qd), track), 30), ctl.log.read_text()
            os.kill(mon.proc.pid, signal.SIGSTOP)
            try:
                assert bus.wait(lambda: outputs_match(drive(bus, stamps(1), qd=qd), brake), 10), ctl.log.read_text()
                assert "stop: monitor lost" in ctl.log.read_text()
            finally:
                os.kill(mon.proc.pid, signal.SIGCONT)
            assert bus.wait(lambda: "alive again; the stop stays until ~/reset" in ctl.log.read_text(), 15), \
                ctl.log.read_text()[-1500:]
            pub = bus.caller.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
            pub.publish(SafeStop(active=False, kind="reset", reason=MONITOR_STARTED))
            assert bus.wait(lambda: "stays until the monitor's ~/reset" in ctl.log.read_text(), 15), \
                ctl.log.read_text()[-1500:]
            assert all(np.allclose(u, brake, rtol=0, atol=1e-9) for u in drive(bus, stamps(5), qd=qd).values())
            assert bus.call_trigger("/monitor_node/reset").success
            assert bus.wait(lambda: outputs_match(drive(bus, stamps(1), qd=qd), track), 15), ctl.log.read_text()
            assert ctl.alive() and mon.alive()
        finally:
            processes.stop([ctl, mon])
            if pub is not None:
                bus.caller.destroy_publisher(pub)    # its latched message must not reach later tests


def start_stop_monitor(tmp_path):
    """The monitor node on a two-joint model, with a missing-data limit the tests never reach."""
    path = write_model(tmp_path / "m.yaml")
    return path, processes.start("monitor_node", {"model_file": str(path), "max_missing_ticks": 10000,
                                               "window_dir": str(tmp_path / "windows")}, tmp_path)


def stop_on_a_nan(bus, proc, seed):
    """Once the monitor is connected: 60 ticks with a NaN at tick 50, and its active stop."""
    assert bus.wait(lambda: bus.js.get_subscription_count() and bus.pi.get_subscription_count()
                    and bus.listener.count_publishers("/conformance/status"), 30), proc.log.read_text()
    bus.clear()
    Y, U = stream(60, seed=seed)
    Y[50, 1] = math.nan
    bus.send_ticks(stamps(60), Y, U)
    assert bus.wait(lambda: bus.active_stops(), 15)


def send_clean_ticks(bus, n, seed):
    """``n`` clean ticks, waited for until the monitor has a status for each."""
    Y, U = stream(n, seed=seed)
    ts = stamps(n)
    bus.send_ticks(ts, Y, U)
    assert bus.wait(lambda: len(bus.statuses(ts)) == n, 20)


class TestResetNeedsClearedCondition:
    def test_reset_is_refused_until_clean_data_were_checked_to_the_horizon(self, bus, tmp_path):
        """Issue 19.2: ``~/reset`` clears a stop only once its condition has cleared: the
        monitor keeps checking while stopped and needs ``reset_clean_ticks`` (default k* + 1)
        consecutive ticks checked to k*, conformant, with no fault, and fresh data. Before:
        any reset succeeded at once, whatever the data (a reset straight after a NaN sample
        resumed the arm on a stream that had just failed)."""
        _, proc = start_stop_monitor(tmp_path)
        try:
            stop_on_a_nan(bus, proc, seed=21)
            assert bus.active_stops()[0].kind == "invalid_sample"
            r = bus.call_trigger("/monitor_node/reset")
            assert not r.success and "has not cleared" in r.message, r.message
            # clean data checked to the horizon, but fewer than k* + 1 ticks of it: still refused
            send_clean_ticks(bus, HISTORY + HORIZON + HORIZON // 2, seed=22)
            r = bus.call_trigger("/monitor_node/reset")
            assert not r.success and f"of {HORIZON + 1} consecutive" in r.message, r.message
            # enough clean, fully checked ticks: the reset clears the stop
            send_clean_ticks(bus, HISTORY + 2 * (HORIZON + 1) + 5, seed=23)
            r = bus.call_trigger("/monitor_node/reset")
            assert r.success, r.message
            assert bus.wait(lambda: not bus.stops[-1].active and bus.stops[-1].kind == "reset")
            assert "reset refused" in proc.log.read_text() and proc.alive()
        finally:
            processes.stop([proc])


class TestPrivilegedOperations:
    def test_resets_and_gain_changes_are_logged_with_caller_and_reason(self, bus, tmp_path):
        """Issue 17.4: a reset of the safe stop and a gain change are the two ways to move an
        arm the monitor stopped. ``~/reset_stop`` (reachset_msgs/ResetStop) names the caller
        and the reason; every request, refused or granted, is one PRIVILEGED log line with
        them, the outcome and the nodes with a client of the service in the graph (here this
        test's ``faults_caller``). ``~/reset`` (Trigger) is logged as naming no caller. A
        gain change logs its ``change_reason``, granted or refused. Before: a reset was
        logged only when refused, without caller or reason; gain changes not at all."""
        from reachset_msgs.srv import ResetStop
        path, mon = start_stop_monitor(tmp_path)
        ctl = start_controller(tmp_path, path)
        cli = bus.caller.create_client(ResetStop, "/monitor_node/reset_stop")

        def reset_stop(caller, reason):
            fut = cli.call_async(ResetStop.Request(caller=caller, reason=reason))
            rclpy.spin_until_future_complete(bus.caller, fut, timeout_sec=15.0)
            assert fut.done()
            return fut.result()
        try:
            assert cli.wait_for_service(timeout_sec=30.0), mon.log.read_text()
            stop_on_a_nan(bus, mon, seed=31)
            r = reset_stop("operator_console", "fault cleared by the operator")
            assert not r.success and "has not cleared" in r.message
            send_clean_ticks(bus, HISTORY + 2 * (HORIZON + 1) + 5, seed=32)
            r = reset_stop("operator_console", "fault cleared by the operator")
            assert r.success, r.message
            assert bus.wait(lambda: not bus.stops[-1].active and "operator_console" in bus.stops[-1].reason)
            assert bus.call_trigger("/monitor_node/reset").success
            lines = [l for l in mon.log.read_text().splitlines() if "PRIVILEGED" in l]
            assert len(lines) == 3, lines
            assert all("caller operator_console" in l and "'fault cleared by the operator'" in l for l in lines[:2])
            assert "refused" in lines[0] and "granted" in lines[1] and "/faults_caller" in lines[1]
            assert "through ~/reset:" in lines[2] and "caller not named" in lines[2] and "no reason given" in lines[2]
            # gain changes: granted and refused, each with its reason
            assert bus.wait(lambda: bus.listener.count_publishers("/plant_input") >= 1, 30)
            ok, why = bus.set_params("controller_node", {"omega": [12.0], "change_reason": "test: faster"})
            assert ok, why
            ok, why = bus.set_params("controller_node", {"omega": [-1.0], "change_reason": "test: bad"})
            assert not ok
            ok, _ = bus.set_params("controller_node", {"stop_max_time": 0.25})    # not a gain: no line
            assert ok
            glines = [l for l in ctl.log.read_text().splitlines() if "PRIVILEGED gain change" in l]
            assert len(glines) == 2, glines
            assert "omega=[12.0]" in glines[0] and "'test: faster'" in glines[0] and "granted" in glines[0]
            assert "omega=[-1.0]" in glines[1] and "refused: gain omega must be" in glines[1]
            assert "clients of /controller_node/set_parameters" in glines[0]   # names as discovery has them
        finally:
            bus.caller.destroy_client(cli)
            processes.stop([ctl, mon])


    def test_the_sros2_policy_grants_the_privileged_services_to_one_enclave_each(self):
        """config/sros2/reachset_policy.xml (not enforceable here: no DDS-Security in the
        PyPI Fast DDS): only the operator enclave may request the monitor's resets, only the
        synthesis enclave the controller's and observer's set_parameters."""
        import xml.etree.ElementTree as ET
        from pathlib import Path
        root = ET.parse(Path(__file__).resolve().parents[1] / "config" / "sros2" / "reachset_policy.xml").getroot()
        requesters = {}
        for enclave in root.iter("enclave"):
            for services in enclave.iter("services"):
                if services.get("request") == "ALLOW":
                    for sv in services.iter("service"):
                        requesters.setdefault(sv.text, set()).add(enclave.get("path"))
        assert requesters["/monitor_node/reset_stop"] == {"/reachset/operator"}
        assert requesters["/monitor_node/reset"] == {"/reachset/operator"}
        for node in ("controller_node", "observer_node"):
            for srv in ("set_parameters", "set_parameters_atomically"):
                assert requesters[f"/{node}/{srv}"] == {"/reachset/synthesis"}

    def test_enforced_security_without_credentials_does_not_start(self, tmp_path):
        """What of SROS2 runs here (docs/reliability.md, "Privileged operations"): with
        ``ROS_SECURITY_ENABLE=true`` and ``ROS_SECURITY_STRATEGY=Enforce`` the node does not
        start (exit status not 0): enforcement fails closed. Here it is refused because the
        PyPI Fast DDS is built without the DDS-Security libraries (the log says so), so
        enclaves with credentials and permissions cannot be tested on this machine."""
        keystore = tmp_path / "keystore"
        (keystore / "enclaves").mkdir(parents=True)
        env = dict(os.environ, ROS_SECURITY_ENABLE="true", ROS_SECURITY_STRATEGY="Enforce",
                   ROS_SECURITY_KEYSTORE=str(keystore))
        proc = processes.start("monitor_node", {}, tmp_path, env=env)
        try:
            assert wait_exit(proc, 60), "the monitor started without credentials"
            assert proc.exit_status() not in (0, None)
            assert "doesn't have the security libraries" in proc.log.read_text(), proc.log.read_text()
        finally:
            processes.stop([proc])


class TestOneGateForThePair:
    """Issue 19.4: both nodes certify the pair (systems.gains.certify_pair) whichever receives
    a change. Before: observer_node accepted eps 0.0005 and h2 100 while the controller checked
    its own copy (0.01 / 30), and without a model the controller accepted omega 40 (stability only)."""

    def test_observer_refuses_gains_whose_pair_is_not_certified(self, bus, tmp_path):
        model = write_model(tmp_path / "m.yaml", alpha_w=(0.05, 4.0), alpha_v=(1e-4,))
        obs = processes.start("observer_node", {"joints": JOINTS, "model_file": str(model), "u_max": [26.0, 26.0],
                                             "omega": [10.0], "zeta": [1.0]}, tmp_path)
        try:
            assert bus.wait(lambda: bus.js.get_subscription_count() >= 1, 30), obs.log.read_text()
            # eps 0.0005: the observer alone would run (stable), but the pair's R*_u leaves U_p
            for change, words in (({"eps": [0.0005]}, "R*_u"), ({"omega": [40.0]}, "R*_u")):
                ok, why = bus.set_params("observer_node", change)
                assert not ok and words in why and "arm_1_joint" in why, (change, why)
            assert bus.get_param("observer_node", "eps") == [0.01] and bus.get_param("observer_node", "h2") == [30.0]
            ok, why = bus.set_params("observer_node", {"omega": [12.0]})   # a certified change passes
            assert ok, why
            assert obs.alive()
        finally:
            processes.stop([obs])

    @pytest.mark.parametrize("node", ["observer_node", "controller_node"])
    def test_without_a_model_gains_need_allow_uncertified(self, tmp_path, node):
        p = processes.start(node, {"joints": JOINTS, "omega": [40.0]}, tmp_path)
        try:
            assert p.proc.wait(timeout=60) == 2
        finally:
            processes.stop([p])
        log = p.log.read_text()
        assert "no model covers these gains" in log and "allow_uncertified" in log, log[-1500:]
