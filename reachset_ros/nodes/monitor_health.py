"""The controller's watch on the monitor: a deadline on its verdicts, and which release clears a stop of its own.

**A stalled monitor is alive** (issue 34.2). The controller's liveliness check
(``ControllerNode.on_monitor_liveliness``: the ``/safe_stop`` publishers' automatic DDS
liveliness, lease ``MONITOR_LEASE_S``) catches a monitor that died or whose process froze, but
not one whose executor is blocked: its DDS participant keeps asserting liveliness while no
tick is checked. The guarantee needs the checks, so the controller holds a deadline on the
monitor's *verdicts* (``/conformance/status``, one per checked tick, stamped with the
measurement's stamp, the same stamps as the controller's estimates and commands):

* while it tracks under a monitor (it has heard a ``/safe_stop`` or a status), the newest
  stamp the monitor checked must be no more than ``monitor_verdict_ticks`` ticks (of ``dt``)
  behind the stamp of the tick the controller commands; the deadline runs from the first
  tracked tick after each stop, hold or start (the monitor checks nothing the controller has
  not yet commanded, so that tick is the earliest it could have checked), so a monitor that
  resumes after a stop has ``monitor_verdict_ticks`` ticks to catch up;
* before the first verdict ever received (DDS may match the status topic later than the
  ``/safe_stop`` one on a loaded machine: a wall-time matter), the allowance is
  ``monitor_first_verdict_timeout`` seconds of wall time from the first tracked tick;
* a verdict newer than the tick (a clock that jumped back, e.g. a restarted simulation) is
  forgotten and the allowance starts again.

Stamps, not wall time, wherever there is a verdict: a slow machine whose loop runs slower
than real time slows the stamps too, so it does not stop falsely. Missing the deadline is a
stop of the controller's own, ``monitor stalled``, latched like the others.

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
    "monitor_first_verdict_timeout": (
        5.0, "s of wall time from the first tracked tick under a monitor to its first verdict ever received; "
             "DDS matching of the status topic on a loaded machine is what it allows for (issue 34.2)"),
}, owner=__name__)


def is_audited_reset(msg) -> bool:
    """True for the monitor's audited reset (an inactive ``/safe_stop`` whose reason starts
    with :data:`AUDITED_RESET`): the one release that clears a stop of the controller's own."""
    return not msg.active and str(msg.reason).startswith(AUDITED_RESET)


def declare_parameters(node):
    """Declare ``monitor_verdict_ticks`` and ``monitor_first_verdict_timeout`` (defaults
    ``controller.*``) on the controller ``node``."""
    node.declare_parameter(
        "monitor_verdict_ticks", defaults.get("controller.monitor_verdict_ticks"),
        desc("while tracking under a monitor: a stop of the controller's own (monitor stalled) when the newest "
             "stamp the monitor checked (/conformance/status) is more than this many ticks (dt) behind the tick "
             "commanded (a blocked monitor keeps its DDS liveliness)", 1, 10**9, integer=True))
    node.declare_parameter(
        "monitor_first_verdict_timeout", defaults.get("controller.monitor_first_verdict_timeout"),
        desc("while tracking under a monitor that has not sent a verdict yet: a stop of the controller's own "
             "(monitor stalled) after this long (s, wall) from the first tracked tick", 0.01, 1e6))


@dataclass(kw_only=True)
class VerdictDeadline:
    """The deadline on the monitor's verdicts (module docstring).

    Parameters
    ----------
    max_lag_ns : int
        Largest lag, ns of stamp time, of the newest verdict behind the commanded tick.
    first_timeout_s : float
        Wall-time allowance before the first verdict ever received.
    """

    max_lag_ns: int
    first_timeout_s: float
    newest_ns: int | None = None     # the newest stamp the monitor checked (None: none yet)
    since_ns: int | None = None      # the first tracked tick since the deadline was armed
    since_wall: float | None = None  # its wall time (monotonic)
    lag_max_ns: int = 0              # the largest lag seen while tracking (/diagnostics)

    def verdict(self, stamp_ns: int) -> None:
        """A status of the monitor for ``stamp_ns``."""
        if self.newest_ns is None or stamp_ns > self.newest_ns:
            self.newest_ns = stamp_ns

    def pause(self) -> None:
        """The controller does not track (a stop, a hold): the deadline starts again at the next tracked tick."""
        self.since_ns = self.since_wall = None

    def check(self, stamp_ns: int, wall: float) -> str | None:
        """At a tracked tick ``stamp_ns`` (wall time ``wall``): None, or why the monitor is stalled."""
        if self.since_ns is None or stamp_ns < self.since_ns - NEW_CLOCK_NS:
            self.since_ns, self.since_wall = stamp_ns, wall
        if self.newest_ns is not None and self.newest_ns > stamp_ns:
            self.newest_ns = None             # checked on another clock: none on this one yet
            self.since_ns, self.since_wall = stamp_ns, wall
        if self.newest_ns is None:
            if wall - self.since_wall > self.first_timeout_s:
                return (f"no verdict (/conformance/status) from the monitor {wall - self.since_wall:.2f} s after "
                        f"tracking began (monitor_first_verdict_timeout {self.first_timeout_s:g} s)")
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
        self.monitor_heard = False   # a /safe_stop or a status came: the loop runs under a monitor
        self.verdicts = VerdictDeadline(max_lag_ns=0, first_timeout_s=0.0)

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
        self.monitor_heard = True
        self.verdicts.verdict(stamp_ns(msg.header.stamp))

    def check_monitor_verdicts(self, stamp, braking):
        """The deadline on the monitor's verdicts at a tick about to be tracked under a
        monitor; missed: a stop of the node's own (monitor stalled). Returns whether the
        tick brakes."""
        if braking or not self.monitor_heard:
            self.verdicts.pause()
            return braking
        self.verdicts.max_lag_ns = int(self.get_parameter("monitor_verdict_ticks").value) * int(round(self.dt * 1e9))
        self.verdicts.first_timeout_s = float(self.get_parameter("monitor_first_verdict_timeout").value)
        why = self.verdicts.check(stamp, time.monotonic())
        if why is None:
            return False
        self.latch_own_stop(stamp, "monitor stalled", why)
        return True
