"""A minimal real node: publishes ``reachset_msgs/msg/PlantInput`` at 250 Hz.

Used by the DDS self-test (``reachset selftest``) and the foundation tests: it proves that
custom interfaces, Fast DDS and parameter services work between processes. Its one
parameter ``acceleration`` (rad/s^2) is the value it publishes for every joint.
"""
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node
from reachset_msgs.msg import PlantInput

from .common import spin_node


class PlantInputTalker(Node):
    """Publish a constant plant input on ``/plant_input`` every 4 ms."""

    def __init__(self):
        super().__init__("plant_input_talker")
        self.declare_parameter(
            "acceleration", 0.0,
            ParameterDescriptor(description="u_p published for every joint, rad/s^2",
                                floating_point_range=[FloatingPointRange(from_value=-100.0, to_value=100.0)]))
        self.declare_parameter("joints", ["joint_1", "joint_2"],
                               ParameterDescriptor(description="joint names"))
        self.pub = self.create_publisher(PlantInput, "plant_input", 10)
        self.timer = self.create_timer(0.004, self.tick)

    def tick(self):
        msg = PlantInput()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(self.get_parameter("joints").value)
        msg.acceleration = [float(self.get_parameter("acceleration").value)] * len(msg.name)
        self.pub.publish(msg)


def main(args=None):
    spin_node(PlantInputTalker, args)


if __name__ == "__main__":
    main()
