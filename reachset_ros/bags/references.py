"""References and observer estimates recorded in bags (``/reference``, ``/observer/estimate``).

The paper's Appendix-B reference error needs the references the closed loop was driven with;
:func:`read_references` cuts them into consecutive stretches (:class:`Reference`) per joint.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from ..errors import ReachsetError
from . import segments_of, typestore

REFERENCE_TOPIC = "/reference"
ESTIMATE_TOPIC = "/observer/estimate"

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


def read_topic_rows(paths, topic, fields, joints=None):
    """Per-joint ``(stamps, values (T, len(fields)))`` of a topic with ``name[]`` and float arrays.

    Decoded with rosbags (the bag's own message definitions); sorted by header stamp,
    duplicate stamps dropped. Returns ``None`` when no bag has the topic.
    """
    ts = typestore()
    cols, found = {}, False
    for p in paths:
        path = Path(p)
        try:
            with Reader(path) as reader:
                conns = [c for c in reader.connections if c.topic == topic]
                if not conns:
                    continue
                found = True
                for conn, _, raw in reader.messages(connections=conns):
                    msg = ts.deserialize_cdr(raw, conn.msgtype)
                    st = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                    arrs = [np.asarray(getattr(msg, f), float) for f in fields]
                    for i, nm in enumerate(msg.name):
                        if joints is not None and nm not in joints:
                            continue
                        row = [a[i] if i < len(a) else np.nan for a in arrs]
                        cols.setdefault(nm, ([], []))
                        cols[nm][0].append(st)
                        cols[nm][1].append(row)
        except ReachsetError:
            raise
        except Exception as e:  # rosbags raises many types for damaged files
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ReachsetError(f"{path}: cannot read {topic} ({type(e).__name__}: {first})") from None
    if not found:
        return None
    out = {}
    for nm, (st, rows) in cols.items():
        st = np.asarray(st, np.int64)
        vals = np.asarray(rows, float).reshape(len(st), len(fields))
        order = np.argsort(st, kind="stable")
        st, vals = st[order], vals[order]
        keep = np.ones(len(st), bool)
        keep[1:] = st[1:] != st[:-1]
        out[nm] = (st[keep], vals[keep])
    return out


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
