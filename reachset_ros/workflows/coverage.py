"""How much of the reference class the identification data covered (``reachset identify``'s ``coverage``).

A model is conformant on what its data contain (Definition 4, Theorem 1), and cross-validation
(``--calibrate``) can only see what some fold contains: data that never moved a joint near the
class' limits say nothing about a run that does (the fault campaign's false stops came from
training that moved arm_2 at 0.18 rad/s of the class' 0.7, docs/reliability.md). So
``identify`` reports per joint, against the class ``|qd_d| <= qd_max``, ``|qdd_d| <= u_ff``
(docs/theory.md rows G5 and G20):

* ``max_abs_velocity``: the largest ``|q̇|`` measured, a central difference of the positions
  over +-:data:`VELOCITY_HALF_WINDOW` ticks inside the segments (16 ms at 4 ms);
* ``max_abs_acceleration``: the largest ``|qdd_d|`` of the bags' ``/reference`` (the class'
  own variable; ``acceleration_source: reference``) or, without one, of the measured
  acceleration, a second difference of the positions over +-:data:`ACCEL_HALF_WINDOW` ticks
  (40 ms; ``position``: the closed loop's overshoot makes it larger than the reference's);
* their fractions of ``qd_max`` and ``u_ff``, the position range, and ``thin``: a fraction
  below ``threshold`` (default 0.8). ``identify`` warns on stderr for each thin joint and
  suggests ``reachset excite``. Not computed on a fleet (``--workers``/``--scheduler``).
"""
from __future__ import annotations

import numpy as np

from .. import defaults
from ..bags import read_references

__all__ = ["ACCEL_HALF_WINDOW", "VELOCITY_HALF_WINDOW", "class_coverage", "warning_lines"]

defaults.register("identify.coverage", {
    "qd_max": (0.7, "the reference class' velocity limit the data's coverage is measured against, rad/s "
                    "(reference_node qd_max; identify --class-qd-max)"),
    "qdd_max": (2.0, "the reference class' acceleration limit u_ff the coverage is measured against, rad/s^2 "
                     "(U_ref, gains.u_ff; identify --class-qdd-max)"),
    "threshold": (0.8, "a joint's data are thin when the largest velocity or acceleration seen is below this share "
                       "of the class' limit: identify warns (identify --coverage-threshold)"),
}, owner=__name__)

#: central difference of the velocity: +-2 ticks
VELOCITY_HALF_WINDOW = 2
#: second difference of the acceleration (no /reference): +-10 ticks
ACCEL_HALF_WINDOW = 10


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


def _reference_accel(bags, joints, dt):
    """``{joint: max |qdd_d|}`` of the bags' ``/reference`` (empty without one)."""
    refs = read_references(list(bags), list(joints), dt)
    out = {}
    for n, stretches in refs.items():
        vals = [np.max(np.abs(r.qdd)) for r in stretches if len(r)]
        if vals:
            out[n] = float(max(vals))
    return out


def class_coverage(series, *, bags, qd_max, qdd_max, threshold):
    """Per joint of ``series`` ({name: JointSeries}) the class' coverage (module docstring):
    ``{name: {max_abs_velocity, velocity_limit, velocity_fraction, max_abs_acceleration,
    acceleration_source, acceleration_limit, acceleration_fraction, position_range, threshold,
    thin}}``; ``bags`` are read for ``/reference``."""
    ref = _reference_accel(bags, series, next(iter(series.values())).dt) if series else {}
    out = {}
    for n, s in series.items():
        segs = s.segments
        v = _diff_max(s.y, segs, VELOCITY_HALF_WINDOW, s.dt, 1)
        src = "reference" if n in ref else "position"
        a = ref[n] if n in ref else _diff_max(s.y, segs, ACCEL_HALF_WINDOW, s.dt, 2)
        ys = np.concatenate([np.asarray(s.y[lo:hi], dtype=np.float64) for lo, hi in segs]) if segs else np.zeros(0)
        ys = ys[np.isfinite(ys)]
        rng = [float(ys.min()), float(ys.max())] if ys.size else None
        fv, fa = v / qd_max, a / qdd_max
        out[n] = {"max_abs_velocity": v, "velocity_limit": float(qd_max), "velocity_fraction": fv,
                  "max_abs_acceleration": a, "acceleration_source": src, "acceleration_limit": float(qdd_max),
                  "acceleration_fraction": fa, "position_range": rng, "threshold": float(threshold),
                  "thin": bool(fv < threshold or fa < threshold)}
    return out


def warning_lines(coverage):
    """One warning line per thin joint of :func:`class_coverage`'s result."""
    lines = []
    for n, c in coverage.items():
        if not c["thin"]:
            continue
        lines.append(f"warning: joint {n}: the data cover {c['velocity_fraction']:.0%} of the class' velocity "
                     f"(max |qd| {c['max_abs_velocity']:.3g} of {c['velocity_limit']:g} rad/s) and "
                     f"{c['acceleration_fraction']:.0%} of its acceleration (max |qdd| {c['max_abs_acceleration']:.3g} "
                     f"of {c['acceleration_limit']:g} rad/s^2, from the {c['acceleration_source']}), below the "
                     f"{c['threshold']:.0%} threshold: the sets and their calibration say nothing about faster "
                     f"motions; record references that reach the class (reachset excite)")
    return lines
