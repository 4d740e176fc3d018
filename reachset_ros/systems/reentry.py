"""Re-entry after late references: a step of the tracked reference out of the certified class.

The reachable input ``R*_u ⊆ U_p`` and the reference error ``Y_e,ref`` (paper Sec. III-A,
Appendix B) are certified for the references of the class the controller accepts
(``ReferenceClass`` with ``qdd_max = u_ff``, ``step_max = 2 u_ff``): samples of a trajectory
with ``|qdd_d| <= u_ff``, in particular without jumps of ``q_d`` or ``qd_d``. A late reference
carried forward at constant acceleration (:mod:`~reachset_ros.systems.late_reference`) is in
that class, but when the references return the published one is where the true trajectory
went meanwhile: across a phase switch of a trapezoid, ``h`` s late is a jump of up to
``u_ff h^2`` in ``q_d`` and ``2 u_ff h`` in ``qd_d``. In the noise-free nominal loop (HG
observer h1 15, h2 30, omega 20, zeta 1; U_p 26, ``Y_e,ref`` 0.009 rad over the class) 0.2 s
late from 80 ms before a switch gave ``max |u_p| = 35.7`` rad/s^2 and a tracking error of
0.038 rad, reported as "tracking" (issue 34.3; ``test/systems/test_reentry.py``,
``python benchmarks/late_reference.py --reentry``).

Keeping the tracked reference in the class instead (a bounded-acceleration blend from the
carried reference onto the returned one) was measured and rejected: with ``u_ff`` equal to
the references' own ``qdd_max`` (2 rad/s^2, the demo's and the campaigns') the blend cannot
catch a reference that decelerates at the limit: 2 ticks late across a switch left the
tracked reference up to 0.016 rad off the published one for 485 ticks (1.9 s), the issue's
0.2 s 0.51 rad, not back on it within 3 s (``benchmarks/late_reference.py --reentry``).

So a re-entry is out of class, and the controller says so (:class:`ReentryWatch`): each tick,
per joint, the step from the previous tracked sample to this one is tested with
:func:`class_step` (the test of ``ReferenceClass.violation``); a step that fails on a tick
whose reference, or the previous one, was late (carried forward) is a *re-entry*: counted
``reference_reentry`` on ``/diagnostics`` (WARN, with the jump), and a transient starts
(the tracking error is not claimed inside ``R*_e`` until the loop settled, as after a gain
change). ``u_p`` of the transient is not certified either: a tick whose ``u_p`` would leave
``U_p`` during it is a stop of the controller's own ("reference re-entry"), so a commanded
``u_p`` never leaves ``U_p`` because of a re-entry. A step that fails on ticks with on-time
references is the reference's own (``reference_out_of_class`` flags its acceleration).

Pure numpy; no ROS import.
"""
from __future__ import annotations

import numpy as np

from .late_reference import extrapolate

__all__ = ["ReentryWatch", "class_step", "switching_reference"]


def class_step(prev, sample, h, u_ff):
    """Per joint: is going from the sample ``prev`` to ``sample``, ``h`` s later, a step of the
    class ``|qdd_d| <= a`` varying by ``<= 2 a`` within a tick?

    The tick means ``(qd[k+1] - qd[k]) / h`` and ``2 (q[k+1] - q[k] - h qd[k]) / h^2`` must lie
    within ``a`` and within ``2 a`` of ``qdd[k]``, and ``qdd[k+1]`` within ``2 a`` of it:
    ``ReferenceClass.violation``'s test with its tolerance (``1e-6`` of ``2 a``). ``a`` is
    ``u_ff``, or the larger ``|qdd_d|`` of the two samples when one is beyond it (an
    acceleration out of class is flagged on its own, ``reference_out_of_class``).

    Parameters
    ----------
    prev, sample : tuple of array_like
        ``(q_d, qd_d, qdd_d)``.
    h : float
        Seconds between them (> 0).
    u_ff : float

    Returns
    -------
    ndarray of bool
    """
    q0, v0, a0 = (np.asarray(x, dtype=np.float64) for x in prev)
    q1, v1, a1 = (np.asarray(x, dtype=np.float64) for x in sample)
    a = np.maximum(abs(float(u_ff)), np.maximum(np.abs(a0), np.abs(a1)))
    tol = 1e-6 * np.maximum(2.0 * a, 1e-3)
    av = (v1 - v0) / h
    ap = 2.0 * (q1 - q0 - h * v0) / (h * h)
    ok = (np.abs(av) <= a + tol) & (np.abs(ap) <= a + tol)
    for x in (av, ap, a1):
        ok &= np.abs(x - a0) <= 2.0 * a + tol
    return ok


class ReentryWatch:
    """Finds the re-entries of the tracked reference (module docstring).

    Feed every tracking tick's reference with :meth:`step`; :meth:`reset` when tracking stops
    (a stop, a hold without reference): the first reference after it is a start, whose
    transient the controller begins on its own.
    """

    def __init__(self):
        self.reset()

    def reset(self):
        """Forget the previous tracked sample."""
        self.prev = None         # (stamp ns, (q_d, qd_d, qdd_d), late) of the last tracked tick

    def step(self, stamp, ref, late, u_ff):
        """The re-entry at this tick, or None.

        Parameters
        ----------
        stamp : int
            The tick's stamp, ns.
        ref : tuple of ndarray
            ``(q_d, qd_d, qdd_d)`` the tick is controlled with.
        late : bool
            ``ref`` is a late reference carried forward.
        u_ff : float
            The class bound.

        Returns
        -------
        dict or None
            ``joints`` (indices whose step left the class), ``dq``, ``dqd`` (the jump of each
            joint against the previous sample carried forward to this tick), ``stamp``.
        """
        prev, self.prev = self.prev, (int(stamp), tuple(np.array(x, dtype=np.float64) for x in ref), bool(late))
        if prev is None or not 0 < stamp - prev[0] <= 1_000_000_000 or not (late or prev[2]):
            return None
        h = (stamp - prev[0]) * 1e-9
        ok = class_step(prev[1], ref, h, u_ff)
        if ok.all():
            return None
        q, qd, _ = extrapolate(*prev[1], h)
        return {"stamp": int(stamp), "joints": np.flatnonzero(~ok), "dq": np.asarray(ref[0]) - q,
                "dqd": np.asarray(ref[1]) - qd}


def switching_reference(*, dt, u_ff, switch=250, ticks=1000):
    """The reference of the issue-34.3 measurement: ``+u_ff`` until tick ``switch``, then
    ``-u_ff`` until ``2 switch``, then at rest; sampled exactly (zero-order-hold integrals of
    ``qdd_d``, so in the class ``qdd_max = u_ff``). Used by ``test/systems/test_reentry.py`` and
    ``benchmarks/late_reference.py --reentry``.

    Returns
    -------
    tuple of ndarray
        ``(q_d, qd_d, qdd_d)``, each of length ``ticks``.
    """
    a = np.full(ticks, float(u_ff))
    a[switch:] = -float(u_ff)
    a[2 * switch:] = 0.0
    qd = np.concatenate([[0.0], np.cumsum(a[:-1]) * dt])
    q = np.concatenate([[0.0], np.cumsum(qd[:-1] * dt + 0.5 * a[:-1] * dt * dt)])
    return q, qd, a
