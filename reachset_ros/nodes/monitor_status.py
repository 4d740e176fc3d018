"""The monitor node's whole tick, timed (issue 38.4).

**The whole tick** is what the monitor node does for one tick: from the entry of the
subscription callback that receives the message completing the tick (``/plant_input`` or
``/joint_states``, whichever of the pair comes second; ``/joint_states`` alone with
``input_source: effort``) to the callback's return, after ``/conformance/status`` is
published: the name mapping and pairing, u_p from the effort (``input_source: effort``),
the compiled tick, the coverage, stuck-sensor and envelope rules, the verdict's handling and
the status message, in Python and C. What it does not contain: the executor taking the
message from DDS and deserializing it, and the time the message waited before that.

:class:`TickTimes` keeps the last :attr:`TickTimes.KEPT` whole-tick wall times; the node
reports their p50, p99 and maximum on ``/diagnostics`` (``tick_wall_us_p50``,
``tick_wall_us_p99``, ``tick_wall_us_max``, ``tick_wall_ticks``), which
``benchmarks/bench_monitor_load.py`` reads, and the same of its part in ``publish`` of the
status (``publish_wall_us_*``: serializing and handing the message to DDS, which on a
matched subscriber's host includes waking it). :class:`StatusMessage` is the status message the
node fills at each tick.
"""
from __future__ import annotations

import array
import math

import numpy as np


class TickTimes:
    """A ring of the last :attr:`KEPT` wall times, ns (:meth:`add`), and their summary under ``key``."""

    #: ticks kept: 65 s at 250 Hz
    KEPT = 16384

    def __init__(self, key="tick_wall"):
        self.ns = np.zeros(self.KEPT, dtype=np.int64)
        self.count = 0
        self.key = key

    def add(self, ns):
        """Record one whole tick's wall time, ns."""
        self.ns[self.count % self.KEPT] = ns
        self.count += 1

    def summary(self) -> dict:
        """``{"<key>_us_p50", "<key>_us_p99", "<key>_us_max", "<key>_ticks"}`` over the ticks kept
        (the last :attr:`KEPT`); only ``<key>_ticks`` (0) before the first tick."""
        n, key = min(self.count, self.KEPT), self.key
        if not n:
            return {f"{key}_ticks": 0}
        us = self.ns[:n] * 1e-3
        p50, p99 = np.percentile(us, (50, 99))
        return {f"{key}_us_p50": f"{p50:.1f}", f"{key}_us_p99": f"{p99:.1f}", f"{key}_us_max": f"{us.max():.1f}",
                f"{key}_ticks": self.count}


class StatusMessage:
    """One ``ConformanceStatus`` message, built once and filled anew at each tick (issue 38.4).

    Building a message per tick and filling its arrays from Python lists is costly (the
    generated setters check every element); the arrays are given here as ``array.array``,
    which the setters take as they are, and the joint names only when they change. The
    values are those of a message built from the tick's result: a margin that is not finite
    is +-1e300 (+1e300 where nothing was checked, -1e300 for -inf and NaN), and so on
    (``test/nodes/test_monitor_status.py`` compares the two). Publishing serializes the
    message at once, so one object serves every tick.
    """

    def __init__(self):
        from reachset_msgs.msg import ConformanceStatus
        from std_msgs.msg import Header
        # the values set below have the fields' types by construction: the setters' per-element
        # checks are skipped (test_monitor_status.py compares the message with the per-tick one)
        self.msg = ConformanceStatus(check_fields=False, header=Header(check_fields=False))
        self._names = None

    def fill(self, *, stamp, result, conformant, stop_active, tick, horizon, joints, duration, model_id):
        """The message of one tick: ``result`` is :meth:`Monitor.tick`'s dict, ``joints`` the names."""
        m = self.msg
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp), 1_000_000_000)
        m.conformant = bool(conformant)
        m.safe_stop_active = bool(stop_active)
        m.tick = int(tick)
        m.horizon = int(horizon)
        checked = result["checked"]
        m.active_test_cases = int(checked.max()) if len(checked) else 0
        if self._names is not joints:
            m.name = list(joints)
            self._names = joints
        margin = result["margin"].tolist()
        if not math.isfinite(sum(margin)):     # +-1e300 for what is not finite (NaN: -1e300)
            margin = [x if math.isfinite(x) else (1e300 if x > 0 else -1e300) for x in margin]
        m.margin = array.array("d", margin)
        m.deviation = array.array("d", result["deviation"].tolist())
        m.tightest_step = array.array("i", result["step"].tolist())
        m.set_use = array.array("d", result["use"].tolist())
        m.check_duration = float(duration)
        m.model_id = model_id
        return m
