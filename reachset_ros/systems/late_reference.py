"""A late reference: the controller's reference for a tick whose own reference has not come.

The controller pairs each estimate with the reference of the same stamp (paper eqs. 5-7 act
on ``q_d, qd_d, qdd_d`` of that tick). When the reference of a tick is late (not received
within the controller's ``reference_timeout``), the tick is controlled with the newest
*earlier* reference received, carried forward to the tick's stamp at constant acceleration
(:func:`extrapolate`)::

    q_d(t + h) = q_d(t) + h qd_d(t) + h^2/2 qdd_d(t),   qd_d(t + h) = qd_d(t) + h qdd_d(t),
    qdd_d(t + h) = qdd_d(t).

This keeps ``qdd_d`` inside the class the reachable input ``R_u`` is certified for (paper
Sec. III-A: ``|qdd_d| <= u_ff``) and is exact inside a constant-acceleration phase of a
trapezoidal move; across a phase change within ``h`` it is off by at most
``|delta qdd_d| h^2 / 2`` (``<= qdd_max h^2`` for accelerations within ``+-qdd_max``), and within a quintic move by
``j_max h^3 / 6``. It is an approximation, so its age is bounded: a reference older than
``max_age`` (:func:`usable`) is no reference; the controller then stops on its own
("reference lost"). Holding the newest reference instead (``q_d`` standing still while the
arm moves on, the rule before) took the tracking error outside ``R*_e`` and the input
outside ``U_p`` in the fifth long fault campaign (docs/reliability.md).

The carried reference is in the class, but it is not the published one: when the references
return after a phase switch, ``q_d`` and ``qd_d`` jump back (up to ``qdd_max h^2`` and
``2 qdd_max h``), a step out of the class that ``R*_u ⊆ U_p`` and ``R*_e`` are certified for
(0.2 s late: ``|u_p|`` 35.7 > ``U_p`` 26 in the nominal loop). The controller reports late
ticks and such a re-entry, never as tracking, and stops when a tick of the re-entry's
transient would leave ``U_p`` (:mod:`~reachset_ros.systems.reentry`, issue 34.3).

Pure numpy; no ROS import. ``benchmarks/late_reference.py`` measures the extrapolation's
error on the campaign's reference class against its age.
"""
from __future__ import annotations

import numpy as np

__all__ = ["MAX_AGE_S", "extrapolate", "usable"]

#: default largest age (s of stamp time) of a reference carried forward to a tick: 50 ticks.
#: The sixth long fault campaign had, with 0.1 s, the reference node silent for 152 ms of
#: stamps right after a reset (the loop catching up faster than real time): a stop of the
#: controller's own, then the monitor's, where the carried reference (at rest) was exact.
#: At 0.2 s the worst error on the campaign's reference class is 0.058 rad
#: (``benchmarks/late_reference.py``). The jump back onto the reference when references return
#: is a re-entry out of the class (:mod:`~reachset_ros.systems.reentry`): reported, a transient,
#: and a stop of the controller's own when its u_p would leave U_p (issue 34.3).
MAX_AGE_S = 0.2


def extrapolate(q_d, qd_d, qdd_d, h):
    """The reference ``h`` seconds after ``(q_d, qd_d, qdd_d)``, at constant acceleration.

    Parameters
    ----------
    q_d, qd_d, qdd_d : array_like
        Position, velocity and acceleration of the reference at its stamp.
    h : float
        Seconds from the reference's stamp to the tick's (>= 0).

    Returns
    -------
    tuple of ndarray
        ``(q_d + h qd_d + h^2/2 qdd_d, qd_d + h qdd_d, qdd_d)`` (new arrays). ``h = 0``
        returns copies of the inputs, bit for bit.
    """
    h = float(h)
    if not h >= 0.0:
        raise ValueError(f"a reference is carried forward only: h = {h!r} s")
    q_d, qd_d, qdd_d = (np.array(a, dtype=np.float64) for a in (q_d, qd_d, qdd_d))
    if h == 0.0:
        return q_d, qd_d, qdd_d
    return q_d + h * qd_d + (0.5 * h * h) * qdd_d, qd_d + h * qdd_d, qdd_d


def usable(ref_stamp, stamp, max_age_s=MAX_AGE_S):
    """True when a reference stamped ``ref_stamp`` (ns) may be carried forward to ``stamp``:
    not newer and at most ``max_age_s`` older."""
    return ref_stamp is not None and 0 <= stamp - ref_stamp <= int(round(max_age_s * 1e9))
