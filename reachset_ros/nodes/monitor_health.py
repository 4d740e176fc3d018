"""The controller's watch on the monitor: a deadline on its verdicts, and which release clears a stop of its own.

**A stalled monitor is alive** (issue 34.2). The controller's liveliness check
(``ControllerNode.on_monitor_liveliness``: the ``/safe_stop`` publishers' automatic DDS
liveliness, lease ``MONITOR_LEASE_S``) catches a monitor that died or whose process froze, but
not one whose executor is blocked: its DDS participant keeps asserting liveliness while no
tick is checked. The guarantee needs the checks, so the controller holds a deadline on the
monitor's *verdicts* (``/conformance/status``, one per checked tick, stamped with the
measurement's stamp, the same stamps as the controller's estimates and commands):

* once the monitor has sent a verdict, at every tick the controller tracks, the newest stamp
  the monitor checked must be no more than ``monitor_verdict_ticks`` ticks (of ``dt``) behind
  the stamp of the tick commanded; the deadline runs from the first tracked tick after each
  stop or hold (the monitor checks nothing the controller has not commanded yet, so that tick
  is the earliest it could have checked): a monitor that resumes after a stop has
  ``monitor_verdict_ticks`` ticks to catch up;
* a verdict newer than the tick (a clock that jumped back, e.g. a restarted simulation) is
  forgotten: the deadline waits for a verdict on the new clock;
* a stamp jump forward by more than the limit while tracking is a stop too: no verdict can
  cover it.

Stamps, not wall time: a slow machine whose loop runs slower than real time slows the stamps
too, so it does not stop falsely. Missing the deadline is a stop of the controller's own,
``monitor stalled``, latched like the others.

Before its first verdict a monitor is not relied on by this deadline (no wall-time allowance):
a monitor without a model (``reachset demo`` trains with one: the training runs unmonitored)
sends none, and one that has a model holds the arm with its own start-up stop until it has
checked k* + 1 ticks (issue 34.1), so a monitor stalled before its first check never releases it.

**Only the audited reset clears a stop of the controller's own** (issue 34.9). The monitor
publishes ``active: false`` for several reasons: its start state (``MONITOR_STARTED``), the
managed monitor's activation (its lifecycle stop released), and the reset through
``~/reset`` / ``~/reset_stop`` (:meth:`MonitorNode.reset_stop`: the clean-tick rule, a
``PRIVILEGED`` audit line, :mod:`reachset_ros.nodes.audit`). Only the last, recognised by its
reason (:func:`is_audited_reset`), clears a stop of the controller's own (monitor lost or
stalled, no usable estimate, reference lost, a non-finite command); a lifecycle transition
of either node never does.

:class:`VerdictDeadline` is pure Python; :class:`MonitorWatch` is the controller's part
(a mixin of ``ControllerNode``): the ``/safe_stop`` subscription with its liveliness, the
status subscription and the deadline's check at each tick.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from rclpy.event_handler import SubscriptionEventCallbacks
from reachset_msgs.msg import ConformanceStatus, SafeStop

from .. import defaults
from .common import MONITOR_LEASE_S, SAFE_STOP_QOS, desc, stamp_ns

__all__ = ["AUDITED_RESET", "is_audited_reset", "VerdictDeadline", "declare_parameters", "MonitorWatch"]

#: the reason prefix of the monitor's audited reset (``MonitorNode.reset_stop``:
#: "reset through ~/reset ...", "reset through ~/reset_stop by CALLER: REASON")
AUDITED_RESET = "reset through "
#: a stamp this far behind the newest is a new clock (as for the controller's commands)
NEW_CLOCK_NS = 1_000_000_000

defaults.register("controller", {
    "monitor_verdict_ticks": (
        250, "the controller stops on its own (monitor stalled) when the newest tick the monitor checked "
             "(/conformance/status) is more than this many ticks behind the tick it commands: 1 s at 4 ms, the "
             "/safe_stop liveliness lease (a dead or frozen process is caught as fast); measured in the node "
             "tests, a healthy monitor trails by a few ticks (issue 34.2)"),
}, owner=__name__)


def is_audited_reset(msg) -> bool:
    """True for the monitor's audited reset (an inactive ``/safe_stop`` whose reason starts
    with :data:`AUDITED_RESET`): the one release that clears a stop of the controller's own."""
    return not msg.active and str(msg.reason).startswith(AUDITED_RESET)


def declare_parameters(node):
    """Declare ``monitor_verdict_ticks`` (default ``controller.monitor_verdict_ticks``) on the controller ``node``."""
    node.declare_parameter(
        "monitor_verdict_ticks", defaults.get("controller.monitor_verdict_ticks"),
        desc("once the monitor has sent a verdict: a stop of the controller's own (monitor stalled) when the "
             "newest stamp it checked (/conformance/status) is more than this many ticks (dt) behind the tick "
             "commanded, counted from the first tick tracked after a stop or hold (a monitor whose executor is "
             "blocked keeps its DDS liveliness)", 1, 10**9, integer=True))


@dataclass(kw_only=True)
class VerdictDeadline:
    """The deadline on the monitor's verdicts (module docstring).

    Parameters
    ----------
    max_lag_ns : int
        Largest lag, ns of stamp time, of the newest verdict behind the commanded tick.
    """

    max_lag_ns: int
    newest_ns: int | None = None     # the newest stamp the monitor checked (None: none yet)
    since_ns: int | None = None      # the first tracked tick since the last stop or hold
    lag_max_ns: int = 0              # the largest lag seen while tracking (/diagnostics)

    def verdict(self, stamp_ns: int) -> None:
        """A status of the monitor for ``stamp_ns``."""
        if self.newest_ns is None or stamp_ns > self.newest_ns:
            self.newest_ns = stamp_ns

    def pause(self) -> None:
        """The controller does not track (a stop, a hold): the deadline starts again at the next tracked tick."""
        self.since_ns = None

    def check(self, stamp_ns: int) -> str | None:
        """At a tracked tick ``stamp_ns``: None, or why the monitor is stalled."""
        if self.since_ns is None or stamp_ns < self.since_ns - NEW_CLOCK_NS:
            self.since_ns = stamp_ns
        if self.newest_ns is not None and self.newest_ns > stamp_ns:
            self.newest_ns = None             # checked on another clock: none on this one yet
            self.since_ns = stamp_ns
        if self.newest_ns is None:
            return None
        lag = stamp_ns - max(self.newest_ns, self.since_ns)
        self.lag_max_ns = max(self.lag_max_ns, stamp_ns - self.newest_ns if self.newest_ns >= self.since_ns else 0)
        if lag > self.max_lag_ns:
            return (f"no tick checked by the monitor in the {lag * 1e-6:.0f} ms of stamps up to the tick commanded "
                    f"(newest checked stamp {self.newest_ns}; limit {self.max_lag_ns * 1e-6:g} ms, "
                    "monitor_verdict_ticks): its checks stalled, its DDS liveliness notwithstanding")
        return None


class MonitorWatch:
    """The controller's watch on the monitor (a mixin of ``ControllerNode``, which provides
    ``on_safe_stop``, ``latch_own_stop``, ``stop_known``, ``last_command_stamp`` and ``dt``)."""

    def watch_monitor(self):
        """Subscribe ``/safe_stop`` (with the liveliness of its publishers: a monitor that died
        or whose process froze) and ``/conformance/status`` (the deadline on the verdicts: a
        monitor whose executor is blocked stays alive)."""
        self.create_subscription(SafeStop, "safe_stop", self.on_safe_stop, SAFE_STOP_QOS,
                                 event_callbacks=SubscriptionEventCallbacks(liveliness=self.on_monitor_liveliness))
        self.monitor_lost = None     # wall time at which the last live /safe_stop publisher was lost
        self.create_subscription(ConformanceStatus, "conformance/status", self.on_monitor_status, 10)
        self.verdicts = VerdictDeadline(max_lag_ns=0)

    def on_monitor_liveliness(self, info):
        """The /safe_stop publishers' liveliness changed (issue 17.2). When the last live one
        is lost (the monitor was killed, froze, or its host went away) after the stop state was
        known, every brake engages: a stop of this node's own, cleared only by the monitor's
        audited reset, not by a new monitor's start state."""
        if info.alive_count > 0 or info.alive_count_change >= 0:
            if self.monitor_lost is not None and info.alive_count > 0:
                self.get_logger().info("a /safe_stop publisher is alive again; the stop stays until ~/reset")
                self.monitor_lost = None
            return
        self.monitor_lost = time.monotonic()
        if not self.stop_known:          # never heard from a monitor: wait_for_monitor decides
            return
        stamp = self.last_command_stamp if self.last_command_stamp is not None else self.get_clock().now().nanoseconds
        self.latch_own_stop(stamp, "monitor lost",
                            f"no live /safe_stop publisher (liveliness lease {MONITOR_LEASE_S:g} s): the monitor "
                            "died or froze")

    def on_monitor_status(self, msg):
        """A verdict of the monitor (/conformance/status): the newest stamp it checked."""
        self.verdicts.verdict(stamp_ns(msg.header.stamp))

    def check_monitor_verdicts(self, stamp, braking):
        """The deadline on the monitor's verdicts at a tick about to be tracked; missed: a stop
        of the node's own (monitor stalled). Returns whether the tick brakes."""
        if braking:
            self.verdicts.pause()
            return braking
        self.verdicts.max_lag_ns = int(self.get_parameter("monitor_verdict_ticks").value) * int(round(self.dt * 1e9))
        why = self.verdicts.check(stamp)
        if why is None:
            return False
        self.latch_own_stop(stamp, "monitor stalled", why)
        return True
