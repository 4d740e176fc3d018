"""controller_node: a safe stop without estimates (issue 17), timed in the arm's time.

A safe stop acts through the braking law on the observer's estimates. When none has come
for :data:`STOP_ESTIMATE_TIMEOUT` of the arm's time during a stop (the observer died or
froze, or its data stopped), the law has nothing to act on and every holding brake engages
at once, on ``/brake_command``.

The arm's time is the node's clock under ``use_sim_time`` (the simulation's ``/clock``) and
the wall (monotonic) otherwise. A lockstep simulation waits for the loop's command, so a
loop paused by the machine's load (an observer starved of CPU while another process starts)
is no pause in the arm's time and engages no brake. Before, a 100 ms wall pause while the
monitor held the arm in its start-up stop braked the arm, the braked arm left the modelled
plant, and the monitor latched a violation (the demo's start-up, 2026-11-26).

Functions on the :class:`~reachset_ros.nodes.controller_node.ControllerNode`.
"""
import time

from builtin_interfaces.msg import Time

from ..systems.stopping import StopState

#: a safe stop with no estimate for this long (s of :func:`arm_time`) engages every brake at once
STOP_ESTIMATE_TIMEOUT = 0.1


def arm_time(node):
    """The arm's time (s): the node's clock under ``use_sim_time``, else the wall (monotonic);
    ``None`` under ``use_sim_time`` before the first ``/clock`` (no time of the arm's known)."""
    if node.get_parameter("use_sim_time").value:
        ns = node.get_clock().now().nanoseconds
        return ns * 1e-9 if ns > 0 else None
    return time.monotonic()


def brake_without_estimates(node):
    """Engage every holding brake when a safe stop is active and no estimate has come for
    :data:`STOP_ESTIMATE_TIMEOUT` s of the arm's time (issue 17: a killed observer left the
    arm on the drives' last command). Once per stop: nothing happens while every brake is
    already engaged."""
    now = arm_time(node)
    if not node.stop_active or now is None:
        return
    if node.last_estimate_time is None:
        if not node.last_estimate_stamp:
            return                      # no estimate yet: nothing the braking law ever acted on
        # estimates came before the arm's clock was known (/clock not yet received): the gap
        # counts from the first moment it is
        node.last_estimate_time = now
        return
    if now - node.last_estimate_time < STOP_ESTIMATE_TIMEOUT:
        return
    if node.stop is None:
        node.stop = StopState(len(node.joints))
    if bool(node.stop.engaged.all()):
        return
    stamp = node.last_command_stamp if node.last_command_stamp is not None else node.last_estimate_stamp
    before = int(node.stop.engaged.sum())
    node.stop.engage_all(stamp, f"no estimate for {STOP_ESTIMATE_TIMEOUT * 1e3:.0f} ms during the safe stop")
    node.counters["brakes_engaged"] += len(node.joints) - before
    node.get_logger().error(f"safe stop without estimates (none for {STOP_ESTIMATE_TIMEOUT * 1e3:.0f} ms of the "
                            "arm's time): every holding brake engaged")
    t = Time()
    t.sec, t.nanosec = divmod(int(stamp), 1_000_000_000)
    node.publish_brakes(t)
