"""Bad input, faults and parameter updates at the nodes (docs/reliability.md, "Nodes").

Two levels: :class:`MonitorCore` without ROS, for the exact accounting of each case, and
real ``monitor_node`` / ``controller_node`` processes over DDS fed by a test node, for the
behaviour a user sees (a latched ``/safe_stop`` with its reason, or a skip counted on
``/diagnostics``), each case ending with a check that the node still works.

Stamps increase across the whole module (:func:`stamps`): a monitor hearing an older
test's late message must never see a stamp going backwards by accident.
"""
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import GetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from reachset_msgs.msg import ConformanceStatus, JointEstimate, JointReference, PlantInput, SafeStop
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from reachset_ros import launch
from reachset_ros import model as mdl
from reachset_ros.errors import ReachsetError
from reachset_ros.estimators import Estimator
from reachset_ros.nodes.common import SAFE_STOP_QOS, set_remote_parameters, stamp_ns, to_stamp
from reachset_ros.nodes.monitor_node import MonitorCore
from reachset_ros.plant import lwa4p_joint_plant

JOINTS = ["arm_1_joint", "arm_2_joint"]
DT_NS = 4_000_000
HORIZON = 25
#: sets about 4x those identified on :func:`stream` (0.035 / 1.4e-4): no false alarm on it
#: (15,000 ticks, 5 seeds, smallest margin 2.5e-4 rad), a 0.01 rad jump is caught at once
ALPHA_W, ALPHA_V = (0.15, 0.0), (4e-4,)
#: deep publishers, so that the test itself never drops what it sends
PUB_QOS = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
_next = [10**18]


def stamps(n):
    """Stamps for ``n`` ticks, later than any used before in this module."""
    t0 = _next[0]
    _next[0] += (n + 10_000) * DT_NS
    return [t0 + k * DT_NS for k in range(n)]


def write_model(path, alpha_w=ALPHA_W, alpha_v=ALPHA_V, joints=JOINTS, horizon=HORIZON):
    p = lwa4p_joint_plant()
    js = {j: mdl.JointSets(tuple(alpha_w), tuple(alpha_v), (0.0,) * 5, (0.0,), 0, horizon) for j in joints}
    mdl.save(mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), horizon, js), path)
    return Path(path)


def stream(n, seed=0):
    """(Y, U) of shape (n, 2): two joints following the per-joint plant in closed loop,
    bounded disturbances (0.01, 1.0) and 2e-5 rad noise."""
    p = lwa4p_joint_plant()
    rng = np.random.default_rng(seed)
    X = np.zeros((2, 5))
    Y, U = np.empty((n, 2)), np.empty((n, 2))
    for k in range(n):
        Y[k] = X[:, 0] + 2e-5 * rng.uniform(-1, 1, 2)
        U[k] = np.sin(0.01 * k + np.arange(2)) - 50 * X[:, 1] - 10 * X[:, 2]
        for j in range(2):
            X[j] = p.A @ X[j] + p.B[:, 0] * U[k, j] + p.Gw @ (np.array([0.01, 1.0]) * rng.uniform(-1, 1, 2))
    return Y, U


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
    return [e for e in events if e[0] == "tick"]


def faults_of(events):
    return [e for e in events if e[0] == "fault"]


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
    assert [e[1] for e in ticks_of(ev)] == ts
    assert all(s == "ok" for e in ev for s in e[2]["status"])
    assert core.counters["ticks"] == 400 and core.counters["gaps"] == 0
    # the same data in stamp order but all of /plant_input first (a burst from one side)
    core2 = MonitorCore(mdl.load(model))
    ts2 = stamps(40)
    ev2 = [e for k, t in enumerate(ts2) for e in core2.add_u(t, JOINTS, list(U[k]))]
    assert ev2 == [] and len(core2.pending) == 40
    for k, t in enumerate(ts2):
        ev2 += core2.add_y(t, JOINTS, list(Y[k]))
    assert [e[1] for e in ticks_of(ev2)] == ts2 and not core2.pending


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
    _, stamp, fkind, reason, fjoint = f[0]
    assert (stamp, fkind, fjoint) == (t, kind, joint) and words in reason, f[0]
    # the core goes on: later ticks are processed (after a gap where the tick was rejected)
    ev = feed(core, ts[62:80], Y[62:], U[62:])
    assert not faults_of(ev) and len(ticks_of(ev)) == 18
    assert ticks_of(ev)[-1][1] == ts[79]


def test_core_extra_names_are_ignored_and_counted(model):
    core = MonitorCore(mdl.load(model))
    Y, U = stream(50, seed=2)
    ts = stamps(50)
    ev = []
    for k, t in enumerate(ts):
        ev += core.add_y(t, ["gripper_joint", JOINTS[1], JOINTS[0]], [123.0, Y[k, 1], Y[k, 0]])
        ev += core.add_u(t, JOINTS + ["other"], list(U[k]) + [math.nan])
    assert not faults_of(ev) and len(ticks_of(ev)) == 50
    assert all(s == "ok" for e in ev for s in e[2]["status"])
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
    assert all(s == "ok" for e in ev for s in e[2]["status"])


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
    assert all(s in ("ok", "gap_reset") for e in ticks for s in e[2]["status"])
    assert [e[2]["status"][0] for e in ticks if e[1] in (ts[101], ts[151], ts[203])] == ["gap_reset"] * 3
    c = core.counters
    assert (c["dropped_incomplete"], c["gaps"], c["missing_ticks"]) == (2, 3, 5)
    assert c["ticks"] + c["missing_ticks"] == 300
    # right after a gap nothing spans it: the first test case starts history+1 ticks later
    after = next(e for e in ticks if e[1] == ts[203])
    assert max(after[2]["checked"]) == 0


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
    assert [e[1] for e in ticks] == ts[200 - core.max_pending:]
    c = core.counters
    # the oldest u-only ticks left the queue, then their y halves (older than all waiting
    # ticks) were dropped on arrival: both counted; the newest ticks were all completed
    assert c["dropped_incomplete"] == 2 * (200 - core.max_pending)
    assert c["ticks"] == core.max_pending and not core.pending


def test_core_joint_list_must_be_in_the_model(model):
    with pytest.raises(ReachsetError, match="arm_3_joint is not in the model"):
        MonitorCore(mdl.load(model), ["arm_1_joint", "arm_3_joint"])
    with pytest.raises(ReachsetError, match="twice"):
        MonitorCore(mdl.load(model), ["arm_1_joint", "arm_1_joint"])
