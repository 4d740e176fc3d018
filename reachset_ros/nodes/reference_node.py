"""reference_node: streams ``/reference`` from the reference generator.

For every ``/joint_states`` sample it publishes the reference at that stamp (time since
the first sample), stamped with the measurement's stamp, so the controller pairs the two
by stamp. Random trapezoidal / quintic point-to-point moves inside the position box with
|qd_d| <= qd_max and |qdd_d| <= qdd_max (the paper's U_ref), reproducible from ``seed``.
"""
from rclpy.node import Node
from reachset_msgs.msg import JointReference
from sensor_msgs.msg import JointState

from ..reference import ReferenceConfig, ReferenceGenerator
from .common import TICK_QOS, desc, spin_node, stamp_ns


class ReferenceNode(Node):
    def __init__(self):
        super().__init__("reference_node")
        self.declare_parameter("seed", 0, desc("seed of the random moves", 0, 2 ** 31 - 1, integer=True))
        self.declare_parameter("qd_max", 0.7, desc("velocity limit, rad/s", 0.01, 2.0))
        self.declare_parameter("qdd_max", 2.0, desc("acceleration limit (U_ref), rad/s^2", 0.01, 20.0))
        self.declare_parameter("hold", False, desc("hold the current reference (no new moves)"))
        cfg = ReferenceConfig(qd_max=float(self.get_parameter("qd_max").value),
                              qdd_max=float(self.get_parameter("qdd_max").value))
        self.gen = ReferenceGenerator(cfg, seed=int(self.get_parameter("seed").value))
        self.t0 = None
        self.pub = self.create_publisher(JointReference, "reference", TICK_QOS)
        self.create_subscription(JointState, "joint_states", self.on_joint_states, TICK_QOS)

    def on_joint_states(self, msg):
        t = stamp_ns(msg.header.stamp)
        if self.t0 is None:
            self.t0 = t
        q, qd, qdd = self.gen.sample((t - self.t0) * 1e-9)
        out = JointReference()
        out.header.stamp = msg.header.stamp
        out.name = list(msg.name)[:len(q)]
        out.position = [float(x) for x in q]
        out.velocity = [float(x) for x in qd]
        out.acceleration = [float(x) for x in qdd]
        self.pub.publish(out)


def main(args=None):
    spin_node(ReferenceNode, args)


if __name__ == "__main__":
    main()
