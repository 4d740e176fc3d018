"""The online monitor's events and fault watches (beyond the paper: the input the monitor gets).

What :class:`~reachset_ros.conformance.monitor_core.MonitorCore` (the monitor node without
ROS) makes of the ticks it feeds to :class:`~reachset_ros.conformance.monitor.Monitor` are
events: :class:`TickEvent` (a tick was processed) and :class:`FaultEvent` (a fault latches
the safe stop). :class:`CoverageWatch` turns a stream on which the test cases Theorem 1
needs cannot be formed (period not the model's dt, or losses that keep every test case short
of k*) into a ``coverage`` fault: a tick at which nothing was checked is never conformant,
and not checking is not allowed to go on. :class:`StuckSensorWatch` turns a position
reading that repeats while the joint's reference moves into an ``invalid_sample`` fault.
"""
from __future__ import annotations

import bisect
import collections
from dataclasses import dataclass

import numpy as np



@dataclass(frozen=True)
class TickEvent:
    """A processed tick, as the monitor node's core reports it (no safe stop by itself).

    ``result`` is :meth:`Monitor.tick`'s dict of per-joint verdicts (``status``, ``margin``,
    ``checked``, ``step``, ``start_tick``, ``deviation``, ``bound``); a ``violation``
    status in it is what latches the safe stop. ``longest`` is the largest step k checked
    at this tick by every joint (the smallest over joints of each joint's largest k; -1:
    some joint checked nothing).
    """

    stamp: int                  # the tick's header stamp, ns
    result: dict
    duration: float             # wall time of Monitor.tick, s
    longest: int = -1
    outside_envelope: tuple = None   # per joint: classified outside the validated envelope; None: no envelope

    @property
    def conformant(self):
        """True only if every joint checked at least one test case and none left its set.

        A tick at which nothing was checked (the first ``history`` ticks after a start, a
        reset or a gap) is not conformant: it is not a violation either (``margin`` is
        +inf there, a violation is a margin < 0).
        """
        res = self.result
        return bool(len(res["checked"]) and min(res["checked"]) > 0
                    and all(s in ("ok", "gap_reset") for s in res["status"]))


@dataclass(frozen=True)
class FaultEvent:
    """A fault of the input that latches the safe stop (``SafeStop.kind``, ``reason``, ``joint``)."""

    stamp: int                  # ns
    kind: str                   # invalid_sample (also a stuck sensor) | name_mismatch | stamp_backwards | coverage
    reason: str                 # one line, for the log and SafeStop.reason
    joint: str = ""             # the joint concerned ("" if none or not known)


class CoverageWatch:
    """Whether the monitor forms the test cases its model needs (Theorem 1 checks steps 0..k*).

    Fed once per processed tick with its stamp and ``longest``, the largest step k checked
    at it by every joint (-1: nothing; k*: the horizon), :meth:`update` returns a
    ``coverage`` :class:`FaultEvent` when, in stamp time,

    * nothing was checked for longer than the warm-up (``history`` ticks) plus the
      missing-data limit ``max_missing_ticks``·dt since the later of the start and the last
      checked tick (e.g. a 125 Hz stream for a 4 ms model: every step is a gap);
    * no test case reached k* for longer than the warm-up ``history + k*`` ticks plus the
      same limit since the later of the start and the last tick that checked step k*
      (losses that keep every test case short of the horizon);
    * the mean of the last ``max(max_missing_ticks, PERIOD_MIN_STEPS)`` consecutive stamp
      steps (none a gap) is off dt by more than ``PERIOD_TOLERANCE`` (e.g. 300 Hz for a
      4 ms model: no gap, but every test case on the wrong time grid).

    * a gap (a stamp step outside [0.5, 1.5] dt: samples lost) follows the previous gap
      within ``gap_window`` ticks of stamp time (a link that loses samples again and
      again; 0: off). A single lost sample ends the test cases and costs their warm-up;
      losses that recur faster than that keep the monitor from checking what Theorem 1
      needs, and waiting for the horizon rule above takes H + k* + the missing-data limit
      (1.01 s in the fault campaign) where this rule takes the second loss (issue 17).

    A stamp step longer than the missing-data limit starts the stamp-time rules afresh
    (silence is the watchdog's business, on wall time), so a single gap never causes a
    coverage fault. It does not restart the count of ticks received since a test case last
    reached k*: a source clock that jumps forward again and again while samples keep coming
    (the watchdog quiet) restarts every test case before k*, and

    * more than ``history + k* + max_missing_ticks`` ticks received without a test case at
      k*, across such jumps, is a ``coverage`` fault too (a stamp jump is lost coverage,
      issue 34.8).

    After a fault the watch starts afresh. ``ticks`` and ``full_ticks`` count since the last
    :meth:`reset`.
    """

    PERIOD_TOLERANCE = 0.05
    PERIOD_MIN_STEPS = 10
    RECENT = 64                 # stamp steps kept for the reason (measured period, gaps)

    def __init__(self, dt_ns, history, horizon, max_missing_ticks=25, gap_window=0):
        self.dt_ns, self.history, self.horizon = int(dt_ns), int(history), int(horizon)
        self.max_missing_ticks = int(max_missing_ticks)
        self.gap_window = int(gap_window)
        self.reset()

    def reset(self):
        """Start afresh and count anew (a start, the reset service, a new model)."""
        self.ticks = self.full_ticks = 0
        self._restart()

    def _restart(self):
        self.last = None
        self.ref_check = self.ref_full = None
        self.run = collections.deque(maxlen=max(self.max_missing_ticks, self.PERIOD_MIN_STEPS) + 1)
        self.recent = collections.deque(maxlen=self.RECENT)
        self.longest_seen = -1      # largest step checked since the last check of step k*
        self.last_longest = -1
        self.last_gap = None        # (stamp of the tick after the previous gap, its step)
        self.since_full = 0         # ticks received since a test case last reached k* (across jumps)
        self.jumps = 0              # stamp steps longer than the limit among them

    def set_max_missing_ticks(self, n):
        self.max_missing_ticks = int(n)
        self._restart()

    def set_gap_window(self, n):
        self.gap_window = int(n)
        self._restart()

    @property
    def share(self):
        """Share of the ticks seen at which every joint checked step k*."""
        return self.full_ticks / self.ticks if self.ticks else 0.0

    def update(self, stamp, longest):
        """Account for the tick at ``stamp`` (ns); returns a FaultEvent or None."""
        dt, mm = self.dt_ns, self.max_missing_ticks
        repeated = None
        if self.last is None or stamp - self.last > mm * dt:
            if self.last is not None:
                self.jumps += 1
            self.ref_check = self.ref_full = stamp
            self.run.clear()
            self.recent.clear()
            self.longest_seen = -1
            self.last_gap = None
        else:
            step = stamp - self.last
            self.recent.append(step)
            if not (dt <= 2 * step <= 3 * dt):        # a gap (the monitor's rule): a new run
                self.run.clear()
                if (self.gap_window > 0 and self.last_gap is not None
                        and stamp - self.last_gap[0] <= self.gap_window * dt):
                    repeated = self.last_gap
                self.last_gap = (stamp, step)
        self.run.append(stamp)
        self.last = stamp
        self.ticks += 1
        self.last_longest = longest = int(longest)
        if longest >= 0:
            self.ref_check = stamp
        if longest >= self.horizon:
            self.ref_full = stamp
            self.full_ticks += 1
            self.longest_seen = -1
            self.since_full = self.jumps = 0
        else:
            self.longest_seen = max(self.longest_seen, longest)
            self.since_full += 1
        H, K = self.history, self.horizon
        why = None
        if repeated is not None:
            why = (f"samples lost again {_ms(stamp - repeated[0])} after the previous loss (stamp steps of "
                   f"{_ms(repeated[1])} and {_ms(self.last_gap[1])}; allowed: one loss per "
                   f"{self.gap_window}-tick window, {_ms(self.gap_window * dt)}): the stream loses samples "
                   f"repeatedly and the test cases cannot reach k*={K}; {self._stream()}")
        elif stamp - self.ref_check > (H + mm) * dt:
            why = (f"nothing checked for {_ms(stamp - self.ref_check)} (allowed: {H}-tick warm-up + "
                   f"{_ms(mm * dt)} missing-data limit): {self._stream()}")
        elif stamp - self.ref_full > (H + K + mm) * dt:
            why = (f"no test case reached the horizon k*={K} for {_ms(stamp - self.ref_full)} (allowed: "
                   f"{H + K}-tick warm-up + {_ms(mm * dt)} missing-data limit), longest step checked "
                   f"{self.longest_seen} of {K}: {self._stream()}")
        elif self.since_full > H + K + mm:
            why = (f"no test case reached the horizon k*={K} in the last {self.since_full} ticks received "
                   f"(allowed: {H + K}-tick warm-up + {mm} ticks), {self.jumps} stamp steps longer than the "
                   f"{_ms(mm * dt)} missing-data limit among them restarted every test case: "
                   f"the stamps jump while samples keep coming; {self._stream()}")
        elif len(self.run) == self.run.maxlen:
            w = len(self.run) - 1
            mean = (self.run[-1] - self.run[0]) / w
            if abs(mean - dt) > self.PERIOD_TOLERANCE * dt:
                why = (f"measured stream period {_ms(mean)} (mean of the last {w} consecutive stamp steps) "
                       f"does not match the model's dt {_ms(dt)} (tolerance {self.PERIOD_TOLERANCE:.0%}): "
                       "the test cases would be formed on the wrong time grid")
        if why is None:
            return None
        self._restart()
        return FaultEvent(stamp, "coverage", why)   # kind and reason are separate fields

    def _stream(self):
        """The measured stream: median stamp step and how many of the recent steps were gaps."""
        steps = np.array(self.recent, dtype=np.float64)
        if not len(steps):
            return f"no stamp step measured yet, model dt {_ms(self.dt_ns)}"
        gaps = int(np.sum((2 * steps < self.dt_ns) | (2 * steps > 3 * self.dt_ns)))
        return (f"measured stream period {_ms(float(np.median(steps)))} (median of the last {len(steps)} "
                f"stamp steps) for a model dt of {_ms(self.dt_ns)}; {gaps} of those steps are gaps "
                "(outside [0.5, 1.5] dt), which end every test case")


class StuckSensorWatch:
    """A position reading that repeats itself while the joint's reference moves: a stuck sensor.

    A frozen encoder (or a drive that resends its last frame) changes nothing the monitor's
    sets see until the joint has moved farther than the sets allow, which on a slowly
    starting move took 1.3-2.7 s in the fault campaign (issue 17). The reading itself says
    it sooner: fed each processed tick (:meth:`update`: stamp, the monitored joints'
    positions) and each reference sample (:meth:`add_reference`: stamp, the joints' reference
    velocities), the watch returns an ``invalid_sample`` :class:`FaultEvent` for joint j when

    * its position reading was bit-identical over the last ``ticks`` + 1 consecutive ticks
      (``ticks`` repeats, no gap between them), and
    * at every one of those ticks the joint's reference velocity |qd_d| was at least
      ``speed``; the reference of a tick is the last one stamped within (t - dt, t]. A tick
      whose reference has not arrived is not established yet (the next tick looks again);
      without references the rule checks nothing (``unreferenced`` counts such ticks).

    It is evidence, not a model bound: a tracking loop that follows a reference moving at
    ``speed`` moves its joint, and a real encoder that moves changes its reading. The LWA-4P
    recordings (``benchmarks/stuck_readings.py``) repeat a reading at most 4 times in a row
    while the measured speed stays >= 0.01 rad/s, never at >= 0.05 rad/s; at rest, for up
    to 391 ticks (so the rule needs the reference: the reading alone cannot tell a stuck
    sensor from a joint at rest). The defaults of the monitor node (5 repeats at >= 0.05
    rad/s) stop 20 ms after a frozen joint's reference starts to move. The rule only adds
    stops: the sets' check is unchanged.
    """

    REFERENCES_KEPT = 256

    def __init__(self, joints, dt_ns, ticks=5, speed=0.05):
        if int(ticks) < 1 or not speed > 0:
            raise ValueError(f"stuck-sensor rule: ticks must be >= 1 and speed > 0, got {ticks}, {speed}")
        self.joints = list(joints)
        self.dt_ns, self.ticks, self.speed = int(dt_ns), int(ticks), float(speed)
        self.unreferenced = 0
        self.reset()

    def reset(self):
        """Forget readings and references (a start, the reset service, a new model)."""
        J = len(self.joints)
        self.last_y = None
        self.last_stamp = None
        self.repeats = np.zeros(J, dtype=np.int64)
        self.stamps = collections.deque(maxlen=self.ticks + 1)       # the last consecutive ticks
        self.ref_stamps = collections.deque(maxlen=self.REFERENCES_KEPT)
        self.ref_speeds = collections.deque(maxlen=self.REFERENCES_KEPT)

    def add_reference(self, stamp, velocity):
        """A reference sample: its stamp (ns) and the monitored joints' qd_d (rad/s, in
        ``joints`` order; a non-finite value counts as not moving). Out-of-order stamps are
        ignored."""
        if self.ref_stamps and stamp <= self.ref_stamps[-1]:
            return
        self.ref_stamps.append(int(stamp))
        v = np.abs(np.asarray(velocity, dtype=np.float64))
        self.ref_speeds.append(np.where(np.isfinite(v), v, 0.0))

    def _speed_at(self, stamp):
        """The reference speeds of the tick at ``stamp``: the last reference stamped in
        (stamp - dt, stamp], or None."""
        i = bisect.bisect_right(self.ref_stamps, stamp) - 1
        if i < 0 or self.ref_stamps[i] <= stamp - self.dt_ns:
            return None
        return self.ref_speeds[i]

    def update(self, stamp, y):
        """Account for the tick at ``stamp`` with positions ``y`` (J,); a FaultEvent or None."""
        y = np.asarray(y, dtype=np.float64)
        step = None if self.last_stamp is None else stamp - self.last_stamp
        repeated = False
        if step is None or not (self.dt_ns <= 2 * step <= 3 * self.dt_ns):   # a gap: runs start anew
            self.repeats[:] = 0
            self.stamps.clear()
        else:
            same = y == self.last_y
            repeated = bool(same.any())
            if repeated:
                self.repeats = np.where(same, self.repeats + 1, 0)
            else:                       # the usual tick (every joint's reading changed): no candidate
                self.repeats[:] = 0
        self.last_y, self.last_stamp = y.copy(), stamp
        self.stamps.append(stamp)
        if self._speed_at(stamp) is None:
            self.unreferenced += 1
        if not repeated:                # ticks >= 1: no run of repeats
            return None
        cand = np.flatnonzero(self.repeats >= self.ticks)
        if not len(cand):
            return None
        speeds = [self._speed_at(s) for s in self.stamps]
        if any(v is None for v in speeds):
            return None
        low = np.min(np.stack(speeds), axis=0)
        for j in cand:
            if low[j] >= self.speed:
                name = self.joints[j]
                return FaultEvent(stamp, "invalid_sample",
                                  f"joint {name}: position reading {y[j]:.9g} rad repeated {int(self.repeats[j])} "
                                  f"times in a row, the last {self.ticks} ({_ms(stamp - self.stamps[0])}) while its "
                                  f"reference moved at >= {low[j]:.3g} rad/s (rule: {self.ticks} repeats at "
                                  f">= {self.speed:g} rad/s): stuck sensor", name)
        return None


def _ms(ns):
    return f"{ns / 1e6:.4g} ms"
