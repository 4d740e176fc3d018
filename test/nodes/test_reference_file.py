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


def test_reference_node_keeps_its_moves_inside_the_models_envelope(ros, tmp_path):
    """Issue 37.3: with ``envelope_model`` the random moves stay inside the envelope's position,
    velocity and acceleration axes (each cut logged, naming the part never validated); a model
    without an envelope is refused at start (exit 2, one line). Before: no such parameter."""
    from helpers import write_envelope_model, write_model
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.envelope import axis_range
    model = write_envelope_model(tmp_path / "env.yaml")
    env = mdl.load(model).envelope
    node = processes.start("reference_node", {"envelope_model": str(model), "seed": 5, "lead": 1.0}, tmp_path)
    got = []
    sub = ros.create_subscription(JointReference, "reference", got.append, TICK_QOS)
    js_pub = ros.create_publisher(JointState, "joint_states", TICK_QOS)
    names = ["arm_1_joint", "arm_2_joint", "arm_3_joint", "arm_4_joint", "arm_5_joint", "arm_6_joint"]
    t0 = 10**18
    k = [0]

    def send():
        m = JointState(name=names, position=[0.0] * 6)
        to_stamp(m.header.stamp, t0 + k[0] * 4_000_000)
        js_pub.publish(m)
        k[0] += 1

    try:
        assert spin_until(ros, lambda: (send(), len(got) > 0)[1], 30.0), node.log.read_text()[-800:]
        for _ in range(2500):                                  # 10 s of references
            send()
            spin_until(ros, lambda: False, 0.0005)
        assert spin_until(ros, lambda: len(got) > 2000, 30.0), len(got)
    finally:
        processes.stop([node])
        ros.destroy_subscription(sub)
        ros.destroy_publisher(js_pub)
    log = node.log.read_text()
    assert "reference class cut to the validated envelope: arm_1_joint:" in log, log[-1500:]
    for j, name in enumerate(names[:2]):
        je = env.joints[name]
        qd = np.array([m.velocity[j] for m in got])
        (lo, hi), (vlo, vhi) = axis_range(je, "q"), axis_range(je, "qd")
        assert np.all(np.abs(qd) <= min(-vlo, vhi) + 1e-9), (name, np.abs(qd).max(), (vlo, vhi))
        later = np.array([m.position[j] for m in got[500:]])  # after the first move from 0 (inside q)
        assert lo - 1e-9 <= later.min() and later.max() <= hi + 1e-9, (name, later.min(), later.max(), lo, hi)
    assert max(abs(m.velocity[2]) for m in got) > 0.2          # a joint not in the envelope keeps its class
    bare = write_model(tmp_path / "bare.yaml")
    refused = processes.start("reference_node", {"envelope_model": str(bare)}, tmp_path)
    try:
        assert refused.proc.wait(timeout=60) == 2
    finally:
        processes.stop([refused])
    lines = [ln for ln in refused.log.read_text().splitlines() if ln.strip()]
    assert len(lines) == 1 and "records no validated envelope" in lines[0], lines
