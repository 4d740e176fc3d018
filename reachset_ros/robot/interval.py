"""Interval arithmetic with outward rounding and an interval recursive Newton-Euler algorithm.

The machinery behind the sound torque bounds of :mod:`reachset_ros.robot.input_limits`
(paper eq. ``deriveInputConstraint``: ``T contains M(Q) U_p (+) psi(Q, dQ)``).
:func:`interval_rnea` encloses the rigid-body joint torques ``M(q) qdd + C(q, qd) qd + g(q)``
(Pinocchio's ``rnea``, armature included) for every ``q`` in a box and ``qd`` in an interval
vector, optionally as a mean-value form with first-order derivative enclosures (interval
forward-mode differentiation).

What is rigorous: every interval operation rounds outwards (one ``nextafter`` step after each
addition and multiplication, :func:`next_down` / :func:`next_up`; IEEE round-to-nearest errs
by at most half an ulp), and ``sin``/``cos`` enclosures are widened by 1e-15 (numpy's libm is
accurate to a few ulps). The robot's parameters are taken as exact. Revolute joints about the
x, y or z axis of their frame only (:func:`joint_axis`).
"""
from __future__ import annotations

import numpy as np

from ..errors import ReachsetError

__all__ = ["next_down", "next_up", "joint_axis", "interval_rnea"]

_INF = np.inf


def next_down(x):
    """The next float towards -inf (outward rounding of a lower bound)."""
    return np.nextafter(x, -_INF)


def next_up(x):
    """The next float towards +inf (outward rounding of an upper bound)."""
    return np.nextafter(x, _INF)


class _IA:
    """Interval arrays with first-order information: rows ``0`` value, ``1..d`` d/dq_l.

    ``lo``, ``hi`` have shape ``(1 + d, N)``: the value enclosure over the box and enclosures
    of the partial derivatives with respect to the ``d`` split coordinates (interval
    forward-mode differentiation). Every operation rounds outwards.
    """

    __slots__ = ("lo", "hi")

    def __init__(self, lo, hi):
        self.lo, self.hi = lo, hi

    @classmethod
    def const(cls, x, R, N):
        lo = np.zeros((R, N))
        lo[0] = x
        return cls(lo, lo.copy())

    def __add__(self, o):
        return _IA(next_down(self.lo + o.lo), next_up(self.hi + o.hi))

    def __sub__(self, o):
        return _IA(next_down(self.lo - o.hi), next_up(self.hi - o.lo))

    def neg(self):
        return _IA(-self.hi, -self.lo)

    @staticmethod
    def _m(alo, ahi, blo, bhi):
        p0, p1, p2, p3 = alo * blo, alo * bhi, ahi * blo, ahi * bhi
        return (next_down(np.minimum(np.minimum(p0, p1), np.minimum(p2, p3))),
                next_up(np.maximum(np.maximum(p0, p1), np.maximum(p2, p3))))

    def __mul__(self, o):
        vlo, vhi = self._m(self.lo[:1], self.hi[:1], o.lo[:1], o.hi[:1])
        if self.lo.shape[0] == 1:
            return _IA(vlo, vhi)
        g1lo, g1hi = self._m(self.lo[1:], self.hi[1:], o.lo[:1], o.hi[:1])
        g2lo, g2hi = self._m(self.lo[:1], self.hi[:1], o.lo[1:], o.hi[1:])
        return _IA(np.vstack([vlo, next_down(g1lo + g2lo)]), np.vstack([vhi, next_up(g1hi + g2hi)]))

    def scale(self, c):
        """Point scalar ``c`` times this interval."""
        c = float(c)
        if c >= 0:
            return _IA(next_down(c * self.lo), next_up(c * self.hi))
        return _IA(next_down(c * self.hi), next_up(c * self.lo))


def _sum(terms, R, N):
    if not terms:
        return _IA.const(0.0, R, N)
    acc = terms[0]
    for t in terms[1:]:
        acc = acc + t
    return acc


class _Vec:
    """An interval 3-vector (three :class:`_IA`)."""

    __slots__ = ("c",)

    def __init__(self, comps):
        self.c = list(comps)

    @classmethod
    def point(cls, v, R, N):
        v = np.asarray(v, float)
        return cls([_IA.const(v[i], R, N) for i in range(3)])

    def __add__(self, o):
        return _Vec([a + b for a, b in zip(self.c, o.c)])

    def cross(self, o):
        a, b = self.c, o.c
        return _Vec([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])

    def pmat(self, M):
        """Point 3x3 matrix times this interval vector."""
        M = np.asarray(M, float)
        R, N = self.c[0].lo.shape
        return _Vec([_sum([self.c[k].scale(M[r, k]) for k in range(3) if M[r, k] != 0.0], R, N)
                     for r in range(3)])

    def pcross(self, p):
        """Point vector ``p`` cross this interval vector (exact zeros skipped)."""
        p = np.asarray(p, float)
        a = self.c
        R, N = a[0].lo.shape

        def term(coef, x):
            return [x.scale(coef)] if coef != 0.0 else []
        return _Vec([_sum(term(p[1], a[2]) + term(-p[2], a[1]), R, N),
                     _sum(term(p[2], a[0]) + term(-p[0], a[2]), R, N),
                     _sum(term(p[0], a[1]) + term(-p[1], a[0]), R, N)])


class _Rot:
    """Rotation of a revolute joint ``R(q) = R0 Raxis(q)`` with interval cos/sin."""

    def __init__(self, R0, axis, cq, sq):
        self.R0 = np.asarray(R0, float)
        self.axis = axis
        self.cq, self.sq = cq, sq

    def _axis_rot(self, v, transpose):
        c, s = self.cq, self.sq
        if transpose:                       # R_axis(q)^T v
            s = s.neg()
        i, j, k = {"z": (0, 1, 2), "x": (1, 2, 0), "y": (2, 0, 1)}[self.axis]
        comps = [None] * 3
        vi, vj = v.c[i], v.c[j]
        comps[i] = c * vi - s * vj
        comps[j] = s * vi + c * vj
        comps[k] = v.c[k]
        return _Vec(comps)

    def apply(self, v):
        """``R v`` (child frame -> parent frame)."""
        return self._axis_rot(v, False).pmat(self.R0)

    def apply_t(self, v):
        """``R^T v`` (parent frame -> child frame)."""
        return self._axis_rot(v.pmat(self.R0.T), True)


def _cos_sin(lo, hi):
    """Interval enclosures of cos and sin over [lo, hi] (arrays), widened by 1e-15."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)

    def enc(f, ph):   # maxima of f at ph + 2 pi k, minima at ph + pi + 2 pi k
        a, b = f(lo), f(hi)
        mn, mx = np.minimum(a, b), np.maximum(a, b)
        kmax = np.ceil((lo - ph) / (2 * np.pi) - 1e-12)
        has_max = ph + 2 * np.pi * kmax <= hi + 1e-12
        kmin = np.ceil((lo - ph - np.pi) / (2 * np.pi) - 1e-12)
        has_min = ph + np.pi + 2 * np.pi * kmin <= hi + 1e-12
        mx = np.where(has_max, 1.0, mx)
        mn = np.where(has_min, -1.0, mn)
        return np.maximum(mn - 1e-15, -1.0), np.minimum(mx + 1e-15, 1.0)

    return enc(np.cos, 0.0), enc(np.sin, np.pi / 2)


def joint_axis(jmodel):
    """Axis ``"x"``, ``"y"`` or ``"z"`` of a revolute Pinocchio joint model (else ReachsetError)."""
    name = jmodel.shortname()
    axes = {"JointModelRZ": "z", "JointModelRX": "x", "JointModelRY": "y"}
    if name not in axes:
        raise ReachsetError(f"input limits: joint type {name} is not supported (revolute X/Y/Z only)")
    return axes[name]


def _rnea_ia(model, q_lo, q_hi, qd_lo, qd_hi, qdd, gravity, dims):
    """Interval RNEA; returns per joint an :class:`_IA` with gradient rows for ``dims``."""
    pm = model.pin_model
    n = pm.nv
    N = q_lo.shape[0]
    R = 1 + len(dims)
    (clo, chi), (slo, shi) = _cos_sin(q_lo, q_hi)
    g = np.asarray(pm.gravity.linear, float) if gravity else np.zeros(3)

    def trig(k):
        c = _IA.const(0.0, R, N)
        s = _IA.const(0.0, R, N)
        c.lo[0], c.hi[0] = clo[:, k], chi[:, k]
        s.lo[0], s.hi[0] = slo[:, k], shi[:, k]
        if k in dims:
            r = 1 + dims.index(k)
            c.lo[r], c.hi[r] = -shi[:, k], -slo[:, k]      # d cos = -sin
            s.lo[r], s.hi[r] = clo[:, k], chi[:, k]        # d sin = cos
        return c, s

    def ivec(lo, hi):
        x = _IA.const(0.0, R, N)
        x.lo[0], x.hi[0] = lo, hi
        return x

    w, dw, a, Rot, F, Nm = {}, {}, {}, {}, {}, {}
    w[0], dw[0] = _Vec.point(np.zeros(3), R, N), _Vec.point(np.zeros(3), R, N)
    a[0] = _Vec.point(-g, R, N)
    for i in range(1, pm.njoints):
        lam = pm.parents[i]
        axis = joint_axis(pm.joints[i])
        k = pm.joints[i].idx_v
        pl = pm.jointPlacements[i]
        Ri = _Rot(pl.rotation, axis, *trig(k))
        Rot[i] = Ri
        p = np.asarray(pl.translation, float)
        ai = {"x": 0, "y": 1, "z": 2}[axis]
        qdi = ivec(np.broadcast_to(qd_lo[k], (N,)), np.broadcast_to(qd_hi[k], (N,)))
        wl = Ri.apply_t(w[lam])
        wi = _Vec(list(wl.c))
        wi.c[ai] = wi.c[ai] + qdi
        jw = _Vec.point(np.zeros(3), R, N)
        jw.c[ai] = qdi
        dwi = Ri.apply_t(dw[lam]) + wl.cross(jw)
        dwi.c[ai] = dwi.c[ai] + _IA.const(qdd[k], R, N)
        acc = a[lam] + dw[lam].cross(_Vec.point(p, R, N)) + w[lam].cross(w[lam].cross(_Vec.point(p, R, N)))
        ai_vec = Ri.apply_t(acc)
        inert = pm.inertias[i]
        m, c, Ic = float(inert.mass), np.asarray(inert.lever, float), np.asarray(inert.inertia, float)
        Cv = _Vec.point(c, R, N)
        ac = ai_vec + dwi.cross(Cv) + wi.cross(wi.cross(Cv))
        F[i] = _Vec([x.scale(m) for x in ac.c])
        Nm[i] = dwi.pmat(Ic) + wi.cross(wi.pmat(Ic))
        w[i], dw[i], a[i] = wi, dwi, ai_vec
    f = {i: F[i] for i in range(1, pm.njoints)}
    nn = {i: Nm[i] + F[i].pcross(np.asarray(pm.inertias[i].lever, float)) for i in range(1, pm.njoints)}
    tau = [None] * n
    for i in range(pm.njoints - 1, 0, -1):
        ai = {"x": 0, "y": 1, "z": 2}[joint_axis(pm.joints[i])]
        k = pm.joints[i].idx_v
        tau[k] = nn[i].c[ai] + _IA.const(float(pm.armature[k]) * qdd[k], R, N)
        lam = pm.parents[i]
        if lam > 0:
            fR = Rot[i].apply(f[i])
            f[lam] = f[lam] + fR
            p = np.asarray(pm.jointPlacements[i].translation, float)
            nn[lam] = nn[lam] + Rot[i].apply(nn[i]) + fR.pcross(p)
    return tau


def interval_rnea(model, q_lo, q_hi, qd_lo, qd_hi, qdd, gravity=True, mean_value=True):
    """Interval enclosure of the joint torques of the rigid-body dynamics (no friction).

    ``tau = M(q) qdd + C(q, qd) qd + g(q)`` (Pinocchio's ``rnea``, armature included) for every
    ``q`` in ``[q_lo, q_hi]`` and ``qd`` in ``[qd_lo, qd_hi]``; ``qdd`` is a point.

    With ``mean_value`` the enclosure is the intersection of the natural interval extension
    and the mean-value form ``tau(c) + sum_l dtau/dq_l(B) [-r_l, r_l]`` (centre ``c``, radii
    ``r``; the derivative enclosures from interval forward-mode differentiation), whose
    over-approximation shrinks quadratically with the box size.

    Parameters
    ----------
    model : reachset_ros.robot.RobotModel
    q_lo, q_hi : array_like, (N, n)
        A batch of N position boxes.
    qd_lo, qd_hi : array_like, (n,)
    qdd : array_like, (n,)
    gravity : bool

    Returns
    -------
    lo, hi : ndarray, (N, n)
    """
    n = model.nv
    q_lo = np.atleast_2d(np.asarray(q_lo, float))
    q_hi = np.atleast_2d(np.asarray(q_hi, float))
    N = q_lo.shape[0]
    qd_lo = np.broadcast_to(np.asarray(qd_lo, float), (n,))
    qd_hi = np.broadcast_to(np.asarray(qd_hi, float), (n,))
    qdd = np.asarray(qdd, float)
    wide = [j for j in range(n) if np.any(q_hi[:, j] > q_lo[:, j])]
    if not mean_value or not wide:
        tau = _rnea_ia(model, q_lo, q_hi, qd_lo, qd_hi, qdd, gravity, [])
        return np.column_stack([t.lo[0] for t in tau]), np.column_stack([t.hi[0] for t in tau])
    tau = _rnea_ia(model, q_lo, q_hi, qd_lo, qd_hi, qdd, gravity, wide)
    c = 0.5 * (q_lo + q_hi)
    # radius covering [lo, hi] from c in floating point
    r = np.maximum(next_up(q_hi - c), next_up(c - q_lo))
    t0 = _rnea_ia(model, c, c, qd_lo, qd_hi, qdd, gravity, [])
    lo, hi = np.empty((N, n)), np.empty((N, n))
    for k in range(n):
        mlo, mhi = t0[k].lo[0], t0[k].hi[0]
        for ri, j in enumerate(wide):
            glo, ghi = tau[k].lo[1 + ri], tau[k].hi[1 + ri]
            bound = next_up(np.maximum(np.abs(glo), np.abs(ghi)) * r[:, j])
            mlo, mhi = next_down(mlo - bound), next_up(mhi + bound)
        lo[:, k] = np.maximum(mlo, tau[k].lo[0])
        hi[:, k] = np.minimum(mhi, tau[k].hi[0])
    return lo, hi
