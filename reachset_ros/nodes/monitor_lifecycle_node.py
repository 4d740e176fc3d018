"""monitor_lifecycle_node: the monitor as a managed (lifecycle) node, as ros2_control users expect.

The same node as :mod:`.monitor_node` (name ``monitor_node``, the same parameters, topics,
``~/reset``, the same :class:`~reachset_ros.nodes.monitor_node.MonitorCore` check each tick),
driven through the standard lifecycle services (``~/change_state``, ``~/get_state``;
``ros2 lifecycle set /monitor_node configure`` on a ROS install):

* **unconfigured** (start): nothing is checked; the latched ``/safe_stop`` says so
  (``active: true, kind: manual``), so a controller waiting for the monitor holds the arm;
* **configure**: loads ``model_file`` (and the effort source, if ``input_source: effort``);
  a model or source that does not load fails the transition (the reason logged), the node
  stays unconfigured;
* **activate**: checking starts (``/conformance/status`` every tick, the watchdog); the
  lifecycle's own stop becomes the start-up stop of the plain node (``kind: not_ready``,
  issue 34.1), which the node releases itself after k* + 1 consecutive ticks checked to the
  horizon, all conformant, on every input (before: released at once, with nothing checked).
  A stop latched by a check (a violation, a fault) stays latched: only ``~/reset`` clears it;
* **deactivate**: checking stops; as nothing is checked any more, ``/safe_stop`` is latched
  active (``kind: manual``): the controller brakes and holds the arm;
* **cleanup**: the model is dropped (back to unconfigured); **shutdown**: as for the plain node.
"""
from __future__ import annotations

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from .common import spin_node
from .monitor_node import MonitorNode

#: reason prefix of the stops this variant latches for its lifecycle (released on activate)
LIFECYCLE_STOP = "monitor_node lifecycle:"


class MonitorLifecycleNode(MonitorNode, LifecycleNode):
    """:class:`MonitorNode` with the lifecycle of a managed node (module docstring)."""

    MANAGED = True

    def __init__(self):
        self.active = False
        super().__init__()
        self.lifecycle_stop("unconfigured: nothing is checked")

    # -- gating: nothing is checked unless active -----------------------------------------
    def on_joint_states(self, msg):
        if self.active:
            super().on_joint_states(msg)

    def on_plant_input(self, msg):
        if self.active:
            super().on_plant_input(msg)

    def on_reference(self, msg):
        if self.active:
            super().on_reference(msg)

    def watchdog(self):
        if self.active:
            super().watchdog()

    def lifecycle_stop(self, why):
        """Latch the lifecycle's own safe stop (the controller brakes and holds); a stop
        already latched by a check stays as it is (the start-up stop is replaced)."""
        if not self.stop_active or self.not_ready:
            self.publish_stop_state(True, "manual", f"{LIFECYCLE_STOP} {why}")
            self.get_logger().warning(f"safe stop latched: {self.stop_msg.reason}")

    # -- transitions -------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        path = self.get_parameter("model_file").value
        if not path:
            self.get_logger().error("configure failed: model_file is empty")
            return TransitionCallbackReturn.FAILURE
        ok, why = MonitorNode.load(self, path)
        if not ok:
            self.get_logger().error(f"configure failed: {why}")
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.core.reset()
        self.restart_watchdog()
        self.active = True
        if self.stop_active and self.stop_msg is not None and self.stop_msg.reason.startswith(LIFECYCLE_STOP):
            # not released here: released once checked ticks show the arm conformant
            self.enter_not_ready(f"{LIFECYCLE_STOP} active, no tick checked yet")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.lifecycle_stop("inactive: nothing is checked")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.core = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.lifecycle_stop("shut down: nothing is checked")
        return TransitionCallbackReturn.SUCCESS


def main(args=None):
    spin_node(MonitorLifecycleNode, args)


if __name__ == "__main__":
    main()
