"""Issue 35.3 over real DDS: ``reference_node`` plays the ``/reference`` bag ``reachset excite``
writes (``trajectory_file``), sample for sample at the measurement stamps, and rests at its
end; a file outside the class it is configured for is refused at start (exit 2, one line)."""

import numpy as np
import pytest
from reachset_msgs.msg import JointReference
from sensor_msgs.msg import JointState

from reachset_ros import processes
from reachset_ros.cli import main
from reachset_ros.nodes.common import TICK_QOS, to_stamp
from reachset_ros.sim import excite as ex
from helpers import spin_until

pytestmark = pytest.mark.dds


@pytest.fixture(scope="module")
def excite_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("excite") / "arm2"
    assert main(["excite", "--out", str(out), "--joints", "arm_2_joint", "--fractions", "1", "--rest", "0.1"]) == 0
    return out


def test_reference_node_plays_the_excitation_file(ros, tmp_path, excite_bag):
    tr = ex.load_trajectory(excite_bag)
    node = processes.start("reference_node", {"trajectory_file": str(excite_bag)}, tmp_path)
    got = {}
    sub = ros.create_subscription(JointReference, "reference", lambda m: got.setdefault(
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m), TICK_QOS)
    js_pub = ros.create_publisher(JointState, "joint_states", TICK_QOS)
    names = list(tr.names)
    t0 = 10**18

    def send(k):
        m = JointState(name=names, position=[0.0] * len(names))
        to_stamp(m.header.stamp, t0 + k * 4_000_000)
        js_pub.publish(m)

    try:
        assert spin_until(ros, lambda: (send(0), t0 in got)[1], 30.0), node.log.read_text()[-800:]
        ticks = list(range(1, len(tr), 7)) + [len(tr) - 1, len(tr) + 50]       # through the file and past its end
        for k in ticks:
            send(k)
            assert spin_until(ros, lambda: t0 + k * 4_000_000 in got, 10.0), k
    finally:
        processes.stop([node])
        ros.destroy_subscription(sub)
        ros.destroy_publisher(js_pub)
    j = names.index("arm_2_joint")
    fast = 0
    for k in [0] + ticks:
        m = got[t0 + k * 4_000_000]
        i = min(k, len(tr) - 1)
        assert list(m.name) == names
        assert np.allclose(m.position, tr.q[i], atol=1e-12) and np.allclose(m.velocity, tr.qd[i], atol=1e-12)
        assert np.array_equal(np.asarray(m.acceleration), tr.qdd[i])
        fast = max(fast, abs(m.velocity[j]))
    assert fast >= 0.7 * (1 - 1e-6)                    # the class' velocity on /reference
    end = got[t0 + (len(tr) + 50) * 4_000_000]
    assert not any(end.velocity) and not any(end.acceleration)
    assert "trajectory file played to its end" in node.log.read_text()


def test_a_file_outside_the_nodes_class_is_refused_at_start(tmp_path, excite_bag):
    node = processes.start("reference_node", {"trajectory_file": str(excite_bag), "qd_max": 0.5}, tmp_path)
    try:
        assert node.proc.wait(timeout=60) == 2
    finally:
        processes.stop([node])
    lines = [ln for ln in node.log.read_text().splitlines() if ln.strip()]
    assert len(lines) == 1 and "outside the class (0.5)" in lines[0] and str(excite_bag) in lines[0], lines
