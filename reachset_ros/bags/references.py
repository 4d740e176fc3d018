"""References and observer estimates recorded in bags (``/reference``, ``/observer/estimate``).

The paper's Appendix-B reference error needs the references the closed loop was driven with;
:func:`read_references` cuts them into consecutive stretches (:class:`Reference`) per joint.
Both topics are read through the bag reader (:func:`.series.read_topic_rows`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .messages import ESTIMATE_TOPIC, REFERENCE_TOPIC
from .decoded import read_topic_rows
from .series import segments_of


@dataclass(frozen=True)
class Reference:
    """One consecutive stretch of a joint's reference (``/reference``): q_d, qd_d, qdd_d."""

    stamps: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    warmup: int = 0     # leading ticks simulated but not counted (search windows)

    def __len__(self):
        return len(self.stamps)

    def slice(self, lo, hi, warmup=0):
        return Reference(self.stamps[lo:hi], self.q[lo:hi], self.qd[lo:hi], self.qdd[lo:hi], int(warmup))


def _split(stamps, valid, dt):
    return segments_of(stamps, valid, dt)


def read_references(paths, joints=None, dt=0.004):
    """References of the bags per joint: ``{joint: [Reference, ...]}`` (one per consecutive stretch).

    Each bag is read on its own (a stretch never spans two bags). Returns ``{}`` when no bag
    has a ``/reference`` topic.
    """
    out = {}
    for p in paths:
        rows = read_topic_rows([p], REFERENCE_TOPIC, ("position", "velocity", "acceleration"), joints)
        if rows is None:
            continue
        for nm, (st, v) in rows.items():
            valid = np.all(np.isfinite(v), axis=1)
            for a, b in _split(st, valid, dt):
                out.setdefault(nm, []).append(Reference(st[a:b], v[a:b, 0].copy(), v[a:b, 1].copy(),
                                                        v[a:b, 2].copy()))
    return out


def read_estimates(paths, joints=None):
    """``{joint: (stamps, [q_hat, qd_hat, d_hat])}`` of ``/observer/estimate``, or ``None``."""
    rows = {}
    any_found = False
    for p in paths:
        r = read_topic_rows([p], ESTIMATE_TOPIC, ("position", "velocity", "disturbance"), joints)
        if r is None:
            continue
        any_found = True
        for nm, (st, v) in r.items():
            s0, v0 = rows.get(nm, (np.zeros(0, np.int64), np.zeros((0, 3))))
            rows[nm] = (np.concatenate([s0, st]), np.vstack([v0, v]))
    return rows if any_found else None
