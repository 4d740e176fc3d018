"""relay_node: forwards one per-tick topic, dropping or delaying samples on demand (fault injection).

The fault campaign's message loss and delay (issue 17): a node whose input is remapped to the
relay's output (``--ros-args -r joint_states:=relay/joint_states``) receives what the relay
lets through. The relay never reorders (:class:`reachset_ros.sim.link.Link`): a reader that
pairs by stamp sees the stamps in the order they were sent, so only losses and late arrivals
are injected. ``drop_share``, ``drop_every`` and ``delay_s`` are set at run time; all zero,
the relay forwards every sample at once (one DDS hop more). Delayed samples are released by a
``release_period`` timer on wall time. Counters (offered, dropped, released) are logged
every 10 s and on exit.
"""
import time

from rclpy.node import Node
from rcl_interfaces.msg import SetParametersResult
from reachset_msgs.msg import PlantInput
from sensor_msgs.msg import JointState

from ..errors import ReachsetError
from ..sim.link import Link, LinkFault
from .common import TICK_QOS, declare_realtime_priority, desc, spin_node

TYPES = {"sensor_msgs/msg/JointState": JointState, "reachset_msgs/msg/PlantInput": PlantInput}


class RelayNode(Node):
    def __init__(self):
        super().__init__("relay_node")
        declare_realtime_priority(self)
        self.declare_parameter("input_topic", "joint_states", desc("the topic relayed", read_only=True))
        self.declare_parameter("output_topic", "relay/joint_states",
                               desc("where the samples that pass go (remap the reader's input here)", read_only=True))
        self.declare_parameter("message_type", "sensor_msgs/msg/JointState",
                               desc("the topic's type: " + " or ".join(TYPES), read_only=True))
        self.declare_parameter("seed", 0, desc("seed of the random losses", 0, 2 ** 31 - 1, integer=True,
                                               read_only=True))
        self.declare_parameter("drop_share", 0.0, desc("probability of dropping each sample", 0.0, 1.0))
        self.declare_parameter("drop_every", 0, desc("also drop every n-th sample (0: none)", 0, 1_000_000,
                                                     integer=True))
        self.declare_parameter("delay_s", 0.0, desc("constant delay added to every sample, s (order kept)",
                                                    0.0, 10.0))
        self.declare_parameter("release_period", 0.001, desc("period of the timer that releases delayed "
                                                             "samples, s", 0.0002, 0.1, read_only=True))
        kind = str(self.get_parameter("message_type").value)
        if kind not in TYPES:
            raise ReachsetError(f"message_type must be one of {', '.join(TYPES)}, got {kind!r}")
        self.link = Link(self._fault({}), seed=int(self.get_parameter("seed").value))
        self.pub = self.create_publisher(TYPES[kind], str(self.get_parameter("output_topic").value), TICK_QOS)
        self.create_subscription(TYPES[kind], str(self.get_parameter("input_topic").value), self.on_sample,
                                 TICK_QOS)
        self.create_timer(float(self.get_parameter("release_period").value), self.release)
        self.create_timer(10.0, self.report)
        self.add_on_set_parameters_callback(self.on_params)

    def _fault(self, new):
        def value(name):
            return new[name] if name in new else self.get_parameter(name).value
        return LinkFault(float(value("drop_share")), int(value("drop_every")), float(value("delay_s")))

    def on_params(self, params):
        new = {p.name: p.value for p in params if p.name in ("drop_share", "drop_every", "delay_s")}
        if not new:
            return SetParametersResult(successful=True)
        try:
            fault = self._fault(new)
        except ReachsetError as e:
            return SetParametersResult(successful=False, reason=str(e))
        self.link.set_fault(fault)
        self.get_logger().info(f"link fault now {fault}")
        return SetParametersResult(successful=True)

    def on_sample(self, msg):
        if self.link.offer(msg, time.monotonic()):
            self.release()

    def release(self):
        for msg in self.link.due(time.monotonic()):
            self.pub.publish(msg)

    def report(self):
        lk = self.link
        self.get_logger().info(f"offered {lk.offered}, dropped {lk.dropped}, released {lk.released}, "
                               f"waiting {len(lk.queue)}")

    def destroy_node(self):
        self.report()
        super().destroy_node()


def main(args=None):
    spin_node(RelayNode, args)


if __name__ == "__main__":
    main()
