"""controller_node: the reference events that leave the certified class (issue 34.3).

The controller tracks the tick's own reference, or a late one carried forward
(:mod:`~reachset_ros.systems.late_reference`), or, with none at all since the start or the
last stop, holds the measured position. Three of these are outside the class ``R*_u ⊆ U_p``
and ``R*_e`` are certified for, and are reported, never as "tracking":

* late ticks (``late_reference``): the carried reference is in the class, but off the
  published one by up to ``u_ff h^2``: ``/diagnostics`` WARN while they come;
* a re-entry (:class:`~reachset_ros.systems.reentry.ReentryWatch`: the tracked reference
  steps out of the class when late references end or change): counted ``reference_reentry``
  (stamp and largest jump ``reference_reentry_dq_max``, ``reference_reentry_dqd_max``), WARN,
  and a transient ("reference re-entry") during which the tracking error is not claimed in
  ``R*_e``; a tick of that transient whose ``u_p`` would leave ``U_p`` is a stop of the
  controller's own ("reference re-entry": brakes, latched until the monitor's reset), never
  sent;
* the hold without a reference (``q_d = q̂``, ``qd_d = 0``): WARN "holding"; a hold tick whose
  ``u_p`` would leave ``U_p`` (the arm moving) is a stop of the controller's own ("no
  reference").

Functions on the :class:`~reachset_ros.nodes.controller_node.ControllerNode`; no ROS import.
"""
import numpy as np

from ..systems.reentry import ReentryWatch

#: the cause of the transient after a re-entry (``transient_cause`` on /diagnostics)
REENTRY = "reference re-entry"
#: the counters these events add to the controller's
COUNTERS = {"reference_reentry": 0, "reference_reentry_last_ns": 0, "reference_reentry_dq_max": 0.0,
            "reference_reentry_dqd_max": 0.0, "reference_hold_ticks": 0}


def init(node):
    """The node's state for these events."""
    node.reentry, node.reentry_last, node.reentry_reported, node.holding = ReentryWatch(), None, True, False
    node.late_reported = 0           # late_reference at the last /diagnostics


def on_reference_tick(node, stamp, ref, late):
    """A tracking tick's reference (None: the hold): watch for a re-entry, start its transient."""
    node.holding = ref is None
    if ref is None:
        node.reentry.reset()
        node.counters["reference_hold_ticks"] += 1
        return
    ev = node.reentry.step(stamp, ref, late, node.u_ff)
    if ev is None:
        return
    c = node.counters
    c["reference_reentry"] += 1
    c["reference_reentry_last_ns"] = ev["stamp"]
    c["reference_reentry_dq_max"] = max(c["reference_reentry_dq_max"], float(np.max(np.abs(ev["dq"]))))
    c["reference_reentry_dqd_max"] = max(c["reference_reentry_dqd_max"], float(np.max(np.abs(ev["dqd"]))))
    joints = ", ".join(node.joints[i] for i in ev["joints"])
    node.reentry_last = (f"reference re-entry at stamp {stamp} ({joints}: the tracked reference jumps by up to "
                         f"{np.max(np.abs(ev['dq'])):.3g} rad, {np.max(np.abs(ev['dqd'])):.3g} rad/s, out of the "
                         "certified class)")
    node.reentry_reported = False
    node.get_logger().warning(f"{node.reentry_last}; a transient starts, a tick of it beyond U_p is a stop")
    node.begin_transient(REENTRY)


def beyond_u_p(node, stamp, u):
    """True (and a stop of the controller's own latched) when ``u`` of a hold tick or of a tick
    in the transient after a re-entry leaves ``U_p``: not certified, so never sent."""
    over = np.abs(u) > node.u_max
    if not np.any(over):
        return False
    tr = getattr(node, "transient", None)
    in_reentry = tr is not None and tr["active"] and tr["cause"] == REENTRY
    if not (node.holding or in_reentry):
        return False
    i = int(np.argmax(np.abs(u) - node.u_max))
    why = "no reference" if node.holding else REENTRY
    node.latch_own_stop(stamp, why, f"{node.joints[i]} u_p {u[i]:.4g} beyond U_p "
                                    f"{float(np.broadcast_to(node.u_max, u.shape)[i]):g} rad/s^2 "
                                    + ("holding without a reference" if node.holding else
                                       f"in the transient after the re-entry at stamp "
                                       f"{node.counters['reference_reentry_last_ns']}"))
    return True


def status(node, late_new):
    """The WARN message of /diagnostics for these events, or None (``late_new``: late ticks
    since the last report)."""
    tr = getattr(node, "transient", None)
    if node.reentry_last is not None and (not node.reentry_reported or tr is not None and tr["active"]
                                          and tr["cause"] == REENTRY):
        node.reentry_reported = True
        end = f" until stamp {tr['end_ns']}" if tr is not None and tr["cause"] == REENTRY else ""
        return f"{node.reentry_last}: the tracking error is not claimed inside R*_e in its transient{end}"
    if node.holding:
        return "holding: no reference (q_d = the estimate, qd_d = 0), not tracking"
    if late_new:
        return (f"late references at {late_new} tick(s) (carried forward up to "
                f"{node.counters['reference_age_max_ns'] * 1e-6:.0f} ms): the tracking error to /reference is "
                "not claimed inside R*_e")
    return None
