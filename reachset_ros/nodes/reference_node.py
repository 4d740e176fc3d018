"""reference_node: streams ``/reference`` from the reference generator.

For every ``/joint_states`` sample it publishes the reference at that stamp (time since
the first sample), stamped with the measurement's stamp, so the controller pairs the two
by stamp, and named with the generator's joints (the LWA-4P's, in its order), so the
controller pairs them by name whatever the order of names on ``/joint_states``. Random
trapezoidal / quintic point-to-point moves inside the position box with |qd_d| <= qd_max
and |qdd_d| <= qdd_max (the paper's U_ref), reproducible from ``seed``.

``hold`` (settable at run time): the move under way is finished and the reference then
rests at its end point (velocity and acceleration 0) until ``hold`` is cleared; the moves
then continue where they stopped (:class:`reachset_ros.sim.reference.ReferenceStream`).
"""
from rclpy.node import Node
from reachset_msgs.msg import JointReference
from sensor_msgs.msg import JointState

from ..sim.reference import ReferenceConfig, ReferenceGenerator, ReferenceStream
from ..robot.dynamics import JOINT_NAMES
from .common import TICK_QOS, desc, spin_node, stamp_ns


class ReferenceNode(Node):
    def __init__(self):
        super().__init__("reference_node")
        self.declare_parameter("seed", 0, desc("seed of the random moves", 0, 2 ** 31 - 1, integer=True,
                                               read_only=True))
        self.declare_parameter("qd_max", 0.7, desc("velocity limit, rad/s", 0.01, 2.0, read_only=True))
        self.declare_parameter("qdd_max", 2.0, desc("acceleration limit (U_ref), rad/s^2", 0.01, 20.0,
                                                    read_only=True))
        self.declare_parameter("hold", False, desc("finish the move under way, then rest at its end point "
                                                   "until cleared (no new moves)"))
        cfg = ReferenceConfig(qd_max=float(self.get_parameter("qd_max").value),
                              qdd_max=float(self.get_parameter("qdd_max").value))
        self.stream = ReferenceStream(ReferenceGenerator(cfg, seed=int(self.get_parameter("seed").value)))
        self.names = list(JOINT_NAMES)
        self.pub = self.create_publisher(JointReference, "reference", TICK_QOS)
        self.create_subscription(JointState, "joint_states", self.on_joint_states, TICK_QOS)

    def on_joint_states(self, msg):
        q, qd, qdd = self.stream.at(stamp_ns(msg.header.stamp), bool(self.get_parameter("hold").value))
        out = JointReference()
        out.header.stamp = msg.header.stamp
        out.name = self.names[:len(q)]
        out.position = [float(x) for x in q]
        out.velocity = [float(x) for x in qd]
        out.acceleration = [float(x) for x in qdd]
        self.pub.publish(out)


def main(args=None):
    spin_node(ReferenceNode, args)


if __name__ == "__main__":
    main()
