"""How much of the reference class the identification data covered (``reachset identify``'s ``coverage``).

A model is conformant on what its data contain (Definition 4, Theorem 1), and cross-validation
(``--calibrate``) can only see what some fold contains: data that never moved a joint near the
class' limits say nothing about a run that does (the fault campaign's false stops came from
training that moved arm_2 at 0.18 rad/s of the class' 0.7, docs/reliability.md). So
``identify`` reports per joint, against the class ``|qd_d| <= qd_max``, ``|qdd_d| <= u_ff``
(docs/theory.md rows G5 and G20):

* ``max_abs_velocity``: the largest ``|q̇|`` measured, a central difference of the positions
  inside the segments (:mod:`reachset_ros.conformance.coverage`);
* ``max_abs_acceleration``: the largest ``|qdd_d|`` of the bags' ``/reference`` (the class'
  own variable; ``acceleration_source: reference``) or, without one, of the measured
  acceleration, a second difference of the positions (``position``: the closed loop's
  overshoot makes it larger than the reference's);
* their fractions of ``qd_max`` and ``u_ff``, the position range, and ``thin``: a fraction
  below ``threshold`` (default 0.8). ``identify`` warns on stderr for each thin joint and
  suggests ``reachset excite``. A fleet (``--workers``/``--scheduler``) reduces each bag to
  the same extremes (:class:`~reachset_ros.conformance.coverage.MotionExtremes`) and merges
  them: the same values to the bit.
"""
from __future__ import annotations

from .. import defaults
from ..bags import read_references
from ..conformance.coverage import motion_extremes

__all__ = ["class_coverage", "series_motion", "warning_lines"]

defaults.register("identify.coverage", {
    "qd_max": (0.7, "the reference class' velocity limit the data's coverage is measured against, rad/s "
                    "(reference_node qd_max; identify --class-qd-max)"),
    "qdd_max": (2.0, "the reference class' acceleration limit u_ff the coverage is measured against, rad/s^2 "
                     "(U_ref, gains.u_ff; identify --class-qdd-max)"),
    "threshold": (0.8, "a joint's data are thin when the largest velocity or acceleration seen is below this share "
                       "of the class' limit: identify warns (identify --coverage-threshold)"),
}, owner=__name__)


def series_motion(series, bags):
    """``{name: MotionExtremes}`` of the joints' series, with the bags' ``/reference`` (read here)."""
    if not series:
        return {}
    dt = next(iter(series.values())).dt
    refs = read_references(list(bags), list(series), dt)
    return {n: motion_extremes(s.y, s.segments, s.dt, reference_qdd=[r.qdd for r in refs[n]] if n in refs else None)
            for n, s in series.items()}


def class_coverage(motion, *, qd_max, qdd_max, threshold):
    """Per joint of ``motion`` ({name: MotionExtremes}) the class' coverage (module docstring):
    ``{name: {max_abs_velocity, velocity_limit, velocity_fraction, max_abs_acceleration,
    acceleration_source, acceleration_limit, acceleration_fraction, position_range, threshold,
    thin}}``."""
    out = {}
    for n, m in motion.items():
        ref = m.reference_acceleration is not None
        a = m.reference_acceleration if ref else m.acceleration
        fv, fa = m.velocity / qd_max, a / qdd_max
        out[n] = {"max_abs_velocity": m.velocity, "velocity_limit": float(qd_max), "velocity_fraction": fv,
                  "max_abs_acceleration": a, "acceleration_source": "reference" if ref else "position",
                  "acceleration_limit": float(qdd_max), "acceleration_fraction": fa,
                  "position_range": None if m.q_min is None else [m.q_min, m.q_max], "threshold": float(threshold),
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
