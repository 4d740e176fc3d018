"""A lossy, delaying link: the fault model of the campaign's relay (issue 17, message loss and delay).

:class:`LinkFault` is the value (what the link does: drop a share of the samples, drop every
n-th, add a constant delay); :class:`Link` is the state (the random generator, the counters,
the samples waiting for their release time) -- the model/data split of the core. The link
never reorders: a sample is released at ``max(arrival + delay, release of the sample before
it)``, so a reader that pairs samples by stamp sees the stamps in the order they were sent,
as over one reliable DDS connection; only losses and late arrivals are injected.
"""
from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np

from ..errors import ReachsetError


@dataclass(frozen=True)
class LinkFault:
    """What the link does to the samples (all zero: a faithful link).

    Attributes
    ----------
    drop_share : float
        Each sample is dropped with this probability (0..1), independently.
    drop_every : int
        Also drop every ``drop_every``-th sample (0: none); a deterministic loss pattern.
    delay_s : float
        Constant delay added to every sample, s (>= 0).
    """

    drop_share: float = 0.0
    drop_every: int = 0
    delay_s: float = 0.0

    def __post_init__(self):
        if not (0.0 <= self.drop_share <= 1.0):
            raise ReachsetError(f"drop_share must be in [0, 1], got {self.drop_share}")
        if self.drop_every < 0:
            raise ReachsetError(f"drop_every must be >= 0, got {self.drop_every}")
        if not (np.isfinite(self.delay_s) and self.delay_s >= 0):
            raise ReachsetError(f"delay_s must be finite and >= 0, got {self.delay_s}")

    @property
    def faithful(self):
        return self.drop_share == 0 and self.drop_every == 0 and self.delay_s == 0


class Link:
    """The state of a link under a :class:`LinkFault`: ``offer`` samples, ``due`` releases them.

    Times are in seconds on any monotonic clock (the relay node uses wall time).
    """

    def __init__(self, fault: LinkFault = LinkFault(), seed=0):
        self.fault = fault
        self.rng = np.random.default_rng(seed)
        self.queue = collections.deque()       # (release time, sample), release times non-decreasing
        self.offered = self.dropped = self.released = 0
        self._count = 0                         # samples offered under the current fault (drop_every)

    def set_fault(self, fault: LinkFault):
        """Change what the link does; samples already waiting keep their release times."""
        self.fault = fault
        self._count = 0

    def offer(self, sample, now):
        """A sample arrives at ``now``; returns False if the link drops it."""
        f = self.fault
        self.offered += 1
        self._count += 1
        if (f.drop_every and self._count % f.drop_every == 0) or (f.drop_share and self.rng.random() < f.drop_share):
            self.dropped += 1
            return False
        release = now + f.delay_s
        if self.queue and self.queue[-1][0] > release:
            release = self.queue[-1][0]         # never overtake the sample before
        self.queue.append((release, sample))
        return True

    def due(self, now):
        """The samples whose release time has come, in the order they were offered."""
        out = []
        while self.queue and self.queue[0][0] <= now:
            out.append(self.queue.popleft()[1])
        self.released += len(out)
        return out

    def next_release(self):
        """When the next waiting sample is due (None: nothing waits)."""
        return self.queue[0][0] if self.queue else None
