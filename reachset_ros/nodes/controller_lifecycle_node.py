"""controller_lifecycle_node: the controller as a managed (lifecycle) node, as ros2_control users expect.

The same node as :mod:`.controller_node` (name ``controller_node``, the same parameters and
topics, the same certified law: :class:`~reachset_ros.nodes.controller_node.ControllerNode`'s
``on_estimate`` and ``law_input``), driven through the standard lifecycle services
(``~/change_state``, ``~/get_state``; ``ros2 lifecycle set /controller_node configure``):

* **unconfigured** (start): no robot model, no gains; estimates are ignored, nothing is
  commanded;
* **configure**: loads the robot model and the conformance model and certifies the gain
  pair (:meth:`ControllerNode.configure`, the gate the plain node passes at start-up:
  :func:`~reachset_ros.nodes.gain_params.validate_pair`); a refused configuration fails the
  transition with the reason logged and the node stays unconfigured;
* **inactive** (after configure or deactivate): the arm is stopped and held, by the safe-stop
  code path: each estimate runs the stop policy (:func:`reachset_ros.systems.stopping.stop_tick`;
  category 1 by default: a controlled stop within U_p, then the holding brakes on
  ``/brake_command``), exactly as during a safe stop;
* **activate**: tracking starts (or resumes, as a transient, from where the arm is held);
  an active ``/safe_stop`` still brakes: activation never overrides the monitor;
* **cleanup**: back to unconfigured (brakes stay as last commanded); **shutdown**: as the plain node.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from ..errors import ReachsetError
from .common import spin_node
from .controller_node import ControllerNode


class ControllerLifecycleNode(ControllerNode, LifecycleNode):
    """:class:`ControllerNode` with the lifecycle of a managed node (module docstring)."""

    MANAGED = True

    def __init__(self, **node_kwargs):
        super().__init__(**node_kwargs)
        self.hold_reason = "unconfigured"
        self.counters["ignored_unconfigured"] = 0

    def on_estimate(self, msg, late=False):
        if self.robot is None:
            self.counters["ignored_unconfigured"] += 1
            return
        super().on_estimate(msg, late)

    def on_wait_timer(self):
        if self.robot is not None:
            super().on_wait_timer()

    def publish_diagnostics(self):
        if self.robot is not None:
            super().publish_diagnostics()
            return
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus(name="reachset_ros: controller", hardware_id="",
                              level=DiagnosticStatus.WARN, message="unconfigured: nothing is commanded")
        arr.status.append(st)
        self.diag_pub.publish(arr)

    # -- transitions -------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.configure()
        except (ReachsetError, OSError) as e:
            self.get_logger().error(f"configure failed: {e}")
            return TransitionCallbackReturn.FAILURE
        self.hold_reason = "inactive"
        self.get_logger().info("configured: the gain pair is certified; inactive: the arm is held")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.hold_reason is not None and not self.stop_active and self.own_stop is None:
            self.stop = None              # the brakes are released with the next command
            self.begin_transient("activated")
        self.hold_reason = None
        self.get_logger().info("active: tracking" + (" once the safe stop is reset" if self.stop_active else ""))
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.hold_reason = "inactive"
        self.get_logger().warning("inactive: controlled stop, then the holding brakes")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.robot = None
        self.hold_reason = "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.hold_reason = "shut down"
        return TransitionCallbackReturn.SUCCESS


def main(args=None):
    spin_node(ControllerLifecycleNode, args)


if __name__ == "__main__":
    main()
