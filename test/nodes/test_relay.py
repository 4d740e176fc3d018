"""The campaign's lossy link (reachset_ros/sim/link.py) and relay_node over real DDS (issue 17).

The link drops and delays samples but never reorders them; the node does the same to a
topic, with the fault changed at run time through its parameters.
"""
import time

import pytest
from sensor_msgs.msg import JointState

from reachset_ros import processes
from reachset_ros.errors import ReachsetError
from reachset_ros.nodes.common import set_remote_parameters, stamp_ns, to_stamp
from reachset_ros.sim.link import Link, LinkFault

from helpers import PUB_QOS, Recorder, wait_until


pytestmark = pytest.mark.dds   # real DDS participants / node processes


# ------------------------------------------------------------------ the pure link
def test_link_keeps_the_order_when_the_delay_changes():
    """A sample never overtakes the one before it, even when the delay drops from 80 ms to 0."""
    link = Link(LinkFault(delay_s=0.08))
    out = []
    for i in range(200):
        now = i * 0.004
        if i == 50:
            link.set_fault(LinkFault(delay_s=0.0))
        link.offer(i, now)
        out += [(now, s) for s in link.due(now)]
    out += [(9.0, s) for s in link.due(9.0)]
    assert [s for _, s in out] == list(range(200))                 # nothing lost, nothing reordered
    first = dict((s, t) for t, s in reversed(out))
    assert first[0] == pytest.approx(0.08) and first[10] == pytest.approx(0.12)   # delayed by 80 ms
    assert first[51] == pytest.approx(50 * 0.004 + 0.08 - 0.004) or first[51] >= first[49]
    assert first[199] == pytest.approx(199 * 0.004)                # the queue drained: no delay left


def test_link_drops_every_nth_and_a_seeded_share():
    link = Link(LinkFault(drop_every=10))
    kept = [i for i in range(100) if link.offer(i, 0.0)]
    assert len(kept) == 90 and all((i + 1) % 10 for i in kept)
    assert link.due(0.0) == kept and (link.offered, link.dropped, link.released) == (100, 10, 90)
    a, b = Link(LinkFault(drop_share=0.3), seed=5), Link(LinkFault(drop_share=0.3), seed=5)
    ka = [i for i in range(5000) if a.offer(i, 0.0)]
    assert ka == [i for i in range(5000) if b.offer(i, 0.0)]        # seeded
    assert 0.27 < 1 - len(ka) / 5000 < 0.33
    for bad in (dict(drop_share=1.5), dict(drop_every=-1), dict(delay_s=float("nan")), dict(delay_s=-0.1)):
        with pytest.raises(ReachsetError):
            LinkFault(**bad)


# ------------------------------------------------------------------ the node, over DDS
def test_relay_node_drops_and_delays_on_demand_and_keeps_the_order(ros, tmp_path):
    proc = processes.start("relay_node", {"input_topic": "/relay_test/in", "output_topic": "/relay_test/out",
                                       "seed": 1}, tmp_path)
    rec = Recorder("relay_test_rec", {"/relay_test/out": JointState})
    pub = ros.create_publisher(JointState, "/relay_test/in", PUB_QOS)
    try:
        assert wait_until(lambda: pub.get_subscription_count() > 0 and
                          rec.matched("/relay_test/out"), 30.0)
        got = rec.msgs["/relay_test/out"]

        def send(first, n):
            sent = {}
            for i in range(first, first + n):
                m = JointState()
                to_stamp(m.header.stamp, 1_000_000 + i * 4_000_000)
                m.name, m.position = ["a"], [float(i)]
                pub.publish(m)
                sent[i] = time.monotonic()
                time.sleep(0.004)
            return sent

        def index(m):
            return int(m.position[0])

        send(0, 50)                                   # faithful: all 50, in order
        assert rec.wait(lambda: len(got) >= 50, 10.0)
        assert [index(m) for _, m in got] == list(range(50))
        ok, why = set_remote_parameters(ros, "relay_node", {"drop_every": 10})
        assert ok, why
        send(50, 100)                                 # one in ten dropped
        assert rec.wait(lambda: len(got) >= 140, 10.0)
        time.sleep(0.3)
        idx = [index(m) for _, m in got[50:]]
        assert len(idx) == 90 and idx == sorted(idx)
        ok, why = set_remote_parameters(ros, "relay_node", {"drop_every": 0, "delay_s": 0.1})
        assert ok, why
        n0 = len(got)
        sent = send(150, 30)                          # 100 ms later, still in order
        assert rec.wait(lambda: len(got) >= n0 + 30, 10.0)
        late = [t - sent[index(m)] for t, m in got[n0:]]
        assert min(late) >= 0.1 and [index(m) for _, m in got[n0:]] == list(range(150, 180))
        stamps = [stamp_ns(m.header.stamp) for _, m in got]
        assert stamps == sorted(stamps)
        ok, why = set_remote_parameters(ros, "relay_node", {"drop_share": 2.0})
        assert not ok                                 # out of range: refused with the reason
    finally:
        rec.close()
        ros.destroy_publisher(pub)
        processes.stop([proc])
    assert "dropped 10" in proc.log.read_text()
