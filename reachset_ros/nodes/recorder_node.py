"""recorder_node: records topics to an MCAP rosbag2 directory with rosbags.

rosbag2 is not on PyPI, so this stands in for ``ros2 bag record``: it subscribes to each
topic as serialized CDR (rclpy ``raw=True``), and writes the bytes unchanged with the
message definitions embedded, so any rosbags or mcap reader decodes the bag without this
package. The bag's log time is the receive time on the node's clock: the wall clock, or
with ``use_sim_time: true`` the latest ``/clock`` (as ``ros2 bag record --use-sim-time``;
messages that arrive before the first ``/clock`` are written with its time). The bag
appears at ``output`` only when the recorder shuts down cleanly (SIGINT/SIGTERM); until
then it is ``<output>.partial``.
"""
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from reachset_msgs.msg import BrakeCommand, ConformanceStatus, JointEstimate, JointReference, PlantInput, SafeStop
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header

from ..bags import BagWriter
from .common import SAFE_STOP_QOS, STATUS_QOS, desc, spin_node

TOPICS = {
    "/joint_states": (JointState, "sensor_msgs/msg/JointState"),
    "/plant_input": (PlantInput, "reachset_msgs/msg/PlantInput"),
    "/reference": (JointReference, "reachset_msgs/msg/JointReference"),
    "/observer/estimate": (JointEstimate, "reachset_msgs/msg/JointEstimate"),
    "/effort_commands": (Float64MultiArray, "std_msgs/msg/Float64MultiArray"),
    "/conformance/status": (ConformanceStatus, "reachset_msgs/msg/ConformanceStatus"),
    "/safe_stop": (SafeStop, "reachset_msgs/msg/SafeStop"),
    "/diagnostics": (DiagnosticArray, "diagnostic_msgs/msg/DiagnosticArray"),
    "/sim/fault_onset": (Header, "std_msgs/msg/Header"),
    "/brake_command": (BrakeCommand, "reachset_msgs/msg/BrakeCommand"),
}


class RecorderNode(Node):
    def __init__(self):
        super().__init__("recorder_node")
        self.declare_parameter("output", "bags/recording", desc("rosbag2 directory to create", read_only=True))
        self.declare_parameter("topics", list(TOPICS), desc("topics to record", read_only=True))
        self.writer = BagWriter(self.get_parameter("output").value)
        self.writer.__enter__()
        self.counts = {}
        self.waiting_for_clock = []   # (topic, data, typename) received before the first /clock
        for topic in self.get_parameter("topics").value:
            if topic not in TOPICS:
                self.get_logger().warning(f"unknown topic {topic}: not recorded")
                continue
            cls, typename = TOPICS[topic]
            qos = SAFE_STOP_QOS if topic in ("/safe_stop", "/sim/fault_onset") else STATUS_QOS
            self.create_subscription(cls, topic, self._cb(topic, typename), qos, raw=True)

    def _cb(self, topic, typename):
        def cb(data):
            self.counts[topic] = self.counts.get(topic, 0) + 1
            t = self.get_clock().now().nanoseconds
            if t == 0:          # use_sim_time and no /clock yet
                self.waiting_for_clock.append((topic, bytes(data), typename))
                return
            self._write_waiting(t)
            self.writer.write_raw(topic, bytes(data), t, typename)
        return cb

    def _write_waiting(self, t):
        for topic, data, typename in self.waiting_for_clock:
            self.writer.write_raw(topic, data, t, typename)
        self.waiting_for_clock.clear()

    def close(self):
        if self.waiting_for_clock:
            self.get_logger().warning(f"no /clock received: {len(self.waiting_for_clock)} messages written "
                                      "with log time 0")
            self._write_waiting(0)
        self.writer.__exit__(None, None, None)


def main(args=None):
    spin_node(RecorderNode, args)


if __name__ == "__main__":
    main()
