"""The motion a joint's identification data contain, reduced to extremes that merge exactly.

What ``identify`` compares with the reference class (docs/theory.md, row G20;
:mod:`reachset_ros.workflows.coverage`): per joint the largest measured ``|q̇|`` (a central
difference of the positions over +-:data:`VELOCITY_HALF_WINDOW` ticks), the largest measured
``|q̈|`` (a second difference over +-:data:`ACCEL_HALF_WINDOW` ticks), the largest ``|qdd_d|`` of
the recorded ``/reference`` when there is one, and the position range, all inside the segments
(a difference never spans a gap or two recordings, row G2). Maxima and minima merge exactly, so
one bag at a time (a fleet, :mod:`reachset_ros.fleet`) gives the single process' values to the bit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ACCEL_HALF_WINDOW", "VELOCITY_HALF_WINDOW", "MotionExtremes", "merge_motion", "motion_extremes"]

#: central difference of the velocity: +-2 ticks (16 ms at 4 ms)
VELOCITY_HALF_WINDOW = 2
#: second difference of the acceleration: +-10 ticks (80 ms at 4 ms)
ACCEL_HALF_WINDOW = 10


@dataclass(frozen=True, kw_only=True)
class MotionExtremes:
    """One joint's motion extremes (module docstring); ``reference_acceleration`` None without a
    ``/reference``, ``q_min``/``q_max`` None without a finite position."""

    velocity: float
    acceleration: float
    reference_acceleration: float | None = None
    q_min: float | None = None
    q_max: float | None = None


def _diff_max(y, segments, w, dt, order):
    """The largest |central difference| (order 1: velocity, 2: acceleration) inside the segments."""
    best = 0.0
    for a, b in segments:
        s = np.asarray(y[a:b], dtype=np.float64)
        if len(s) <= 2 * w:
            continue
        d = (s[2 * w:] - s[:-2 * w]) / (2 * w * dt) if order == 1 else \
            (s[2 * w:] - 2 * s[w:-w] + s[:-2 * w]) / (w * dt) ** 2
        d = d[np.isfinite(d)]
        if d.size:
            best = max(best, float(np.max(np.abs(d))))
    return best


def motion_extremes(y, segments, dt, *, reference_qdd=None) -> MotionExtremes:
    """The extremes of positions ``y`` inside ``segments`` sampled every ``dt`` s; ``reference_qdd``:
    the joint's recorded ``qdd_d`` samples (arrays), or None."""
    ys = [np.asarray(y[a:b], dtype=np.float64) for a, b in segments]
    ys = np.concatenate(ys) if ys else np.zeros(0)
    ys = ys[np.isfinite(ys)]
    ref = None
    if reference_qdd is not None:
        vals = [np.abs(np.asarray(r, dtype=np.float64)) for r in reference_qdd]
        vals = [v[np.isfinite(v)] for v in vals]
        vals = [float(v.max()) for v in vals if v.size]
        ref = max(vals) if vals else None
    return MotionExtremes(velocity=_diff_max(y, segments, VELOCITY_HALF_WINDOW, dt, 1),
                          acceleration=_diff_max(y, segments, ACCEL_HALF_WINDOW, dt, 2), reference_acceleration=ref,
                          q_min=float(ys.min()) if ys.size else None, q_max=float(ys.max()) if ys.size else None)


def merge_motion(parts) -> MotionExtremes:
    """The extremes of several parts (bags) of one joint's data: exact maxima and minima."""
    def pick(values, fn):
        v = [x for x in values if x is not None]
        return fn(v) if v else None
    return MotionExtremes(velocity=max(p.velocity for p in parts), acceleration=max(p.acceleration for p in parts),
                          reference_acceleration=pick([p.reference_acceleration for p in parts], max),
                          q_min=pick([p.q_min for p in parts], min), q_max=pick([p.q_max for p in parts], max))
