"""controller_node: late and lost references are never reported as tracking (issue 34.3).

A controller node (real rclpy) whose callbacks the test calls in a chosen order, on an arm
that follows a trapezoidal reference exactly (the estimates are the true trajectory), so
``u_p`` is what the references alone do: late references across the phase switch, then the
references again, are a re-entry out of the certified class (systems.reentry): counted,
WARN on /diagnostics with a transient, and a stop of the controller's own when a tick of
that transient would leave U_p. The old code switched back silently ("tracking") and sent
u_p beyond U_p.
"""
import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
import pytest
from rclpy.parameter import Parameter
from reachset_msgs.msg import JointEstimate, JointReference

from helpers import JOINTS
from reachset_ros.nodes.common import stamp_ns, to_stamp
from reachset_ros.nodes.controller_node import ControllerNode
from reachset_ros.nodes.reference_events import REENTRY
from reachset_ros.systems.late_reference import extrapolate

pytestmark = pytest.mark.dds   # real rclpy nodes

S0, DT, SWITCH = 10**18, 0.004, 100


def _truth(i):
    """The trapezoid at tick i: +2 rad/s^2 until tick SWITCH, then -2 (joint 2 mirrored)."""
    t, ts = DT * i, DT * SWITCH
    if i < SWITCH:
        q, qd, a = 0.5 * 2.0 * t * t, 2.0 * t, 2.0
    else:
        q, qd, a = 0.5 * 2.0 * ts * ts + 2.0 * ts * (t - ts) - (t - ts) ** 2, 2.0 * ts - 2.0 * (t - ts), -2.0
    return np.array([q, -q]), np.array([qd, -qd]), np.array([a, -a])


def _ref(i, bad=False):
    q, qd, a = _truth(i)
    m = JointReference(name=JOINTS, position=list(q), velocity=list(qd),
                       acceleration=[float("nan"), 0.0] if bad else list(a))
    to_stamp(m.header.stamp, S0 + 4_000_000 * i)
    return m


def _est(i, late=()):
    """The estimate at tick i of an arm that follows the reference the controller tracks: the
    truth, or during late ticks and the first tick back the last reference before them
    carried forward (the arm went where the carried reference went)."""
    k = i
    if i in late or i - 1 in late:
        k = i - 1
        while k in late:
            k -= 1
    q, qd, _ = _truth(i) if k == i else extrapolate(*_truth(k), (i - k) * DT)
    e = JointEstimate(name=JOINTS, position=list(q), velocity=list(qd), disturbance=[0.0, 0.0])
    to_stamp(e.header.stamp, S0 + 4_000_000 * i)
    return e


def _node():
    over = {"joints": JOINTS, "u_max": [8.0, 8.0], "omega": [10.0], "zeta": [1.0], "allow_uncertified": True,
            "reference_timeout": 0.0}
    node = ControllerNode(parameter_overrides=[Parameter(k, value=v) for k, v in over.items()])
    sent, brakes, diags = [], [], []
    pub_u, pub_b, pub_d = node.input_pub.publish, node.brake_pub.publish, node.diag_pub.publish
    node.input_pub.publish = lambda m: (sent.append((stamp_ns(m.header.stamp), list(m.acceleration))), pub_u(m))
    node.brake_pub.publish = lambda m: (brakes.append(list(m.engage)), pub_b(m))
    node.diag_pub.publish = lambda m: (diags.append(m.status[0]), pub_d(m))
    return node, sent, brakes, diags


def _run(node, late, end):
    """Ticks 0 .. end-1; the references of the ticks in ``late`` never come."""
    for i in range(end):
        if i not in late:
            node.on_reference(_ref(i))
        node.on_estimate(_est(i, late))


def _law(node, i, ref, late=()):
    e = _est(i, late)
    return [node.law_input(j, e.position[k], e.velocity[k], 0.0, ref[0][k], ref[1][k], ref[2][k])
            for k, j in enumerate(JOINTS)]


def test_references_back_after_late_ones_across_a_switch_are_a_reentry_with_a_transient(ros):
    """40 ms late from 20 ms before the switch: the jump back is small (u_p within U_p 8), so the
    re-entry is counted, WARN, and a transient, the tick controlled with the published reference."""
    node, sent, brakes, diags = _node()
    try:
        late = set(range(SWITCH - 5, SWITCH + 5))
        _run(node, late, SWITCH + 20)
        back = SWITCH + 5
        c = node.counters
        assert c["late_reference"] == 10 and c["reference_reentry"] == 1, c
        assert c["reference_reentry_last_ns"] == S0 + 4_000_000 * back
        assert c["reference_reentry_dqd_max"] == pytest.approx(4.0 * 5 * DT, rel=1e-6)
        assert node.own_stop is None and not any(any(b) for b in brakes)
        assert node.transient["cause"] == REENTRY and node.transient["start_ns"] == S0 + 4_000_000 * back
        assert node.transient["active"]
        t = {s: u for s, u in sent}
        np.testing.assert_allclose(t[S0 + 4_000_000 * back], _law(node, back, _truth(back), late), rtol=0, atol=1e-9)
        warn = [d for d in diags if "re-entry" in d.message]
        assert warn and warn[0].level == DiagnosticStatus.WARN and "not claimed inside R*_e" in warn[0].message, [d.message for d in diags]
        node.publish_diagnostics()      # still in the transient: not "tracking"
        assert diags[-1].level == DiagnosticStatus.WARN and "re-entry" in diags[-1].message, diags[-1].message
    finally:
        node.destroy_node()


def test_a_reentry_whose_transient_would_leave_u_p_is_a_stop_of_the_controllers_own(ros):
    """0.2 s late from 80 ms before the switch (the issue's case): u_p of the jump back would be
    beyond U_p. The tick is not sent as computed: every brake, latched ("reference re-entry").
    The old code sent it (u_p -14.5, beyond 8) and reported tracking."""
    node, sent, brakes, _ = _node()
    try:
        late = set(range(SWITCH - 20, SWITCH + 30))
        _run(node, late, SWITCH + 31)
        assert node.counters["reference_reentry"] == 1
        assert node.own_stop is not None and REENTRY in node.own_stop and "beyond U_p" in node.own_stop
        assert brakes[-1] == [True, True]
        assert max(abs(x) for _, u in sent for x in u) <= 8.0
    finally:
        node.destroy_node()


def test_an_unusable_reference_at_speed_is_carried_forward_not_held(ros):
    """A reference with a non-finite value while the arm moves at 0.8 rad/s: the tick is
    controlled with the previous one carried forward (in class). The old code held the
    measured position with qd_d = 0: u_p = -2 zeta omega qd (-16, beyond U_p 8)."""
    node, sent, _, _ = _node()
    try:
        _run(node, set(), 50)
        node.on_reference(_ref(50, bad=True))
        node.on_estimate(_est(50))
        assert node.counters["bad_reference"] == 1 and node.counters["late_reference"] == 1
        want = _law(node, 50, extrapolate(*_truth(49), DT))
        np.testing.assert_allclose(sent[-1][1], want, rtol=0, atol=1e-9)
        assert node.own_stop is None and node.counters["reference_reentry"] == 0
    finally:
        node.destroy_node()


def test_holding_without_a_reference_is_not_tracking_and_never_leaves_u_p(ros):
    """No reference since the start: the hold is reported (WARN "holding"); an arm moving so
    fast that the hold's u_p would leave U_p is a stop of the controller's own, not sent."""
    node, sent, brakes, diags = _node()
    try:
        e = _est(1)                        # at rest: the hold's u_p is 0
        e.velocity = [0.0, 0.0]
        node.on_estimate(e)
        node.publish_diagnostics()
        assert diags[-1].level == DiagnosticStatus.WARN and "holding" in diags[-1].message, diags[-1].message
        assert node.own_stop is None
        node.on_estimate(_est(SWITCH))     # 0.8 rad/s: u_p = -16 would leave U_p
        assert node.own_stop is not None and "no reference" in node.own_stop
        assert brakes[-1] == [True, True] and max(abs(x) for _, u in sent for x in u) <= 8.0
    finally:
        node.destroy_node()
