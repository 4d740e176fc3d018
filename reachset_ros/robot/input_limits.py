"""Input limits U_p from torque limits (paper eq. ``deriveInputConstraint``, Table I).

Feedback linearization ``tau = M(q) u_p + psi(q, qd)`` must respect the torque limits for
every position in the box ``Q``, velocity in ``dQ`` and plant input in
``U_p = [-a_1, a_1] x ... x [-a_n, a_n]``::

    T  contains  M(Q) U_p (+) psi(Q, dQ).

For axis i and ``q`` in a sub-box ``B`` of ``Q`` this holds if

    sum_j  mbar_ij(B) a_j  +  psibar_i(B)  <=  tau_max,i,                          (*)

with ``mbar_ij(B) >= |M_ij(q)|`` and ``psibar_i(B) >= |psi_i(q, qd)|`` for all ``q`` in ``B``,
``qd`` in ``dQ`` (``|tau_i| <= sum_j |M_ij| |u_j| + |psi_i|``). The bounds come from an
**interval-arithmetic recursive Newton-Euler algorithm** (:func:`interval_rnea`) on the
Pinocchio model: columns of ``M`` are RNEA with ``qd = 0``, no gravity, ``qdd = e_j``
(armature included); ``psi`` is RNEA with ``qd`` in ``dQ``, gravity, ``qdd = 0``, plus the
joint friction (monotone in ``qd``, bounded exactly). ``Q`` is split into sub-boxes
(domain splitting, the paper splits into four intervals per axis) to limit the
over-approximation of interval arithmetic. (*) over all sub-boxes is a set of linear
constraints in ``a``; the largest symmetric ``U_p`` is found by lexicographic max-min
(linear programmes, HiGHS): first the largest common ``a``, then every axis that can grow
further without shrinking the others.

What is rigorous
----------------
Every interval operation rounds outwards (one ``nextafter`` step after each addition and
multiplication; IEEE round-to-nearest errs by at most half an ulp), and ``sin``/``cos``
enclosures are widened by 1e-15 (numpy's libm is accurate to a few ulps). The robot's
parameters (link inertias, joint placements, armature, friction) are taken as exact.
Sub-boxes share their edges, so they cover ``Q``. A first joint whose axis is parallel to
gravity and that is attached to the fixed base does not change ``M`` or ``psi`` (the
dynamics are invariant under rotating the whole arm about the gravity axis); its position
is then fixed at 0 (reported as ``invariant_joints``). The LP result is verified against
(*) in floating point and shrunk by a relative 1e-9 if needed. What is *not* covered:
model error (the true robot's inertias differ from the model's), which the reachset-
conformant disturbance sets absorb.

Pure numpy/scipy + Pinocchio; no ROS import.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from .. import robot as rb
from ..errors import InfeasibleError, ReachsetError

__all__ = ["interval_rnea", "mass_psi_bounds", "InputLimits", "input_limits", "check_limits",
           "sampled_worst_torque"]

_INF = np.inf


# ---------------------------------------------------------------------- interval arithmetic
def _down(x):
    return np.nextafter(x, -_INF)


def _up(x):
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
        return _IA(_down(self.lo + o.lo), _up(self.hi + o.hi))

    def __sub__(self, o):
        return _IA(_down(self.lo - o.hi), _up(self.hi - o.lo))

    def neg(self):
        return _IA(-self.hi, -self.lo)

    @staticmethod
    def _m(alo, ahi, blo, bhi):
        p0, p1, p2, p3 = alo * blo, alo * bhi, ahi * blo, ahi * bhi
        return (_down(np.minimum(np.minimum(p0, p1), np.minimum(p2, p3))),
                _up(np.maximum(np.maximum(p0, p1), np.maximum(p2, p3))))

    def __mul__(self, o):
        vlo, vhi = self._m(self.lo[:1], self.hi[:1], o.lo[:1], o.hi[:1])
        if self.lo.shape[0] == 1:
            return _IA(vlo, vhi)
        g1lo, g1hi = self._m(self.lo[1:], self.hi[1:], o.lo[:1], o.hi[:1])
        g2lo, g2hi = self._m(self.lo[:1], self.hi[:1], o.lo[1:], o.hi[1:])
        return _IA(np.vstack([vlo, _down(g1lo + g2lo)]), np.vstack([vhi, _up(g1hi + g2hi)]))

    def scale(self, c):
        """Point scalar ``c`` times this interval."""
        c = float(c)
        if c >= 0:
            return _IA(_down(c * self.lo), _up(c * self.hi))
        return _IA(_down(c * self.hi), _up(c * self.lo))


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


def _joint_axis(jmodel):
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
        axis = _joint_axis(pm.joints[i])
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
        ai = {"x": 0, "y": 1, "z": 2}[_joint_axis(pm.joints[i])]
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
    r = np.maximum(_up(q_hi - c), _up(c - q_lo))
    t0 = _rnea_ia(model, c, c, qd_lo, qd_hi, qdd, gravity, [])
    lo, hi = np.empty((N, n)), np.empty((N, n))
    for k in range(n):
        mlo, mhi = t0[k].lo[0], t0[k].hi[0]
        for ri, j in enumerate(wide):
            glo, ghi = tau[k].lo[1 + ri], tau[k].hi[1 + ri]
            bound = _up(np.maximum(np.abs(glo), np.abs(ghi)) * r[:, j])
            mlo, mhi = _down(mlo - bound), _up(mhi + bound)
        lo[:, k] = np.maximum(mlo, tau[k].lo[0])
        hi[:, k] = np.minimum(mhi, tau[k].hi[0])
    return lo, hi


def _friction_bound(model, qd_lo, qd_hi):
    """Largest |friction torque| per joint for qd in [qd_lo, qd_hi] (terms bounded separately)."""
    fr = model.friction
    qd_lo, qd_hi = np.asarray(qd_lo, float), np.asarray(qd_hi, float)
    v = np.maximum(np.abs(fr.viscous * qd_lo), np.abs(fr.viscous * qd_hi))
    c = np.abs(fr.coulomb) * np.maximum(np.abs(np.tanh(qd_lo / fr.coulomb_velocity)),
                                        np.abs(np.tanh(qd_hi / fr.coulomb_velocity)))
    return _up(_up(v + c) + np.abs(fr.offset))


def invariant_joints(model):
    """Joints whose position does not change M and psi (first joint, axis parallel to gravity)."""
    pm = model.pin_model
    out = []
    if pm.njoints > 1 and pm.parents[1] == 0:
        try:
            axis = _joint_axis(pm.joints[1])
        except ReachsetError:
            return out
        ax = pm.jointPlacements[1].rotation[:, {"x": 0, "y": 1, "z": 2}[axis]]
        g = np.asarray(pm.gravity.linear, float)
        if np.linalg.norm(g) > 0 and np.linalg.norm(np.cross(ax, g)) <= 1e-12 * np.linalg.norm(g):
            out.append(0)
    return out


def _boxes(q_lo, q_hi, splits, fixed):
    """Sub-boxes (lo, hi) of [q_lo, q_hi], ``splits[j]`` pieces per joint; ``fixed`` joints at 0."""
    n = len(q_lo)
    edges = []
    for j in range(n):
        if j in fixed:
            edges.append([(0.0, 0.0)])
            continue
        e = np.linspace(q_lo[j], q_hi[j], int(splits[j]) + 1)
        edges.append(list(zip(e[:-1], e[1:])))
    combos = list(itertools.product(*edges))
    lo = np.array([[c[j][0] for j in range(n)] for c in combos])
    hi = np.array([[c[j][1] for j in range(n)] for c in combos])
    return lo, hi


def mass_psi_bounds(model, q_max, qd_max, splits=4, chunk=4096):
    """Per sub-box bounds ``mbar (N, n, n)`` and ``psibar (N, n)`` of (*) by interval RNEA.

    The plain interval method (see :func:`interval_rnea`): sound, but the wrapping effect of
    interval rotations makes it several times too large on boxes of tens of degrees; the
    default of :func:`input_limits` is :class:`TrigBounds`.

    Returns
    -------
    mbar, psibar, boxes_lo, boxes_hi, fixed_joints
    """
    n = model.nv
    q_max = np.broadcast_to(np.asarray(q_max, float), (n,))
    qd_max = np.broadcast_to(np.asarray(qd_max, float), (n,))
    if np.any(q_max < 0) or np.any(qd_max < 0):
        raise ReachsetError("q_max and qd_max must be non-negative")
    splits = np.broadcast_to(np.asarray(splits, int), (n,))
    if np.any(splits < 1):
        raise ReachsetError("splits must be >= 1")
    fixed = invariant_joints(model)
    blo, bhi = _boxes(-q_max, q_max, splits, fixed)
    N = len(blo)
    mbar = np.zeros((N, n, n))
    psibar = np.zeros((N, n))
    fric = _friction_bound(model, -qd_max, qd_max)
    for s in range(0, N, chunk):
        lo, hi = blo[s:s + chunk], bhi[s:s + chunk]
        for j in range(n):
            e = np.zeros(n)
            e[j] = 1.0
            mlo, mhi = interval_rnea(model, lo, hi, np.zeros(n), np.zeros(n), e, gravity=False)
            mbar[s:s + chunk, :, j] = np.maximum(np.abs(mlo), np.abs(mhi))
        plo, phi = interval_rnea(model, lo, hi, -qd_max, qd_max, np.zeros(n), gravity=True)
        psibar[s:s + chunk] = _up(np.maximum(np.abs(plo), np.abs(phi)) + fric)
    return mbar, psibar, blo, bhi, fixed


# ---------------------------------------------------------------------- trigonometric Taylor bounds
class TrigBounds:
    """Second-order bounds of ``|M_ij|`` and ``|g_i|`` over boxes from exact trigonometric polynomials.

    For a chain of revolute joints every entry of ``M(q)`` is a trigonometric polynomial of
    degree at most 2 in each joint angle (products of two Jacobian columns / ``R I R^T``) and
    ``g(q)`` of degree at most 1. Sampling on the grid ``q_l in {2 pi m / 5}`` therefore gives
    their Fourier coefficients ``c_k`` exactly (FFT, up to rounding); the representation is
    verified against Pinocchio at random configurations (it must agree to 1e-9 relative, else
    :class:`ReachsetError`: the model is not such a chain). Then for every ``q`` in a box with
    centre ``c`` and radii ``r``

        |f(q)| <= |f(c)| + sum_l |d_l f(c)| r_l + 1/2 sum_lm Hbar_lm r_l r_m,
        Hbar_lm = sum_k |c_k| |k_l k_m|  >=  max_q |d_l d_m f(q)|,

    with ``f(c)`` and ``d f(c)`` from Pinocchio (``crba``, ``computeRNEADerivatives``,
    generalized gravity and its derivatives). Coriolis/centrifugal torques are bounded
    globally: ``|c_i(q, qd)| <= sum_jk Gbar_ijk qd_max_j qd_max_k`` with ``Gbar`` the
    coefficient sums of the Christoffel symbols ``(d_k M_ij + d_j M_ik - d_i M_jk) / 2``.
    A margin of 1e-9 times the coefficient sum covers floating-point rounding.

    Parameters
    ----------
    model : RobotModel
    dims : sequence of int
        Joints whose angle varies (the others are held at 0: invariant joints).
    """

    def __init__(self, model, dims, check_points=200, seed=0):
        import pinocchio as pin
        self.model = model
        pm = model.pin_model
        n = pm.nv
        self.n, self.dims = n, list(dims)
        d = len(self.dims)
        P = 5
        grid = 2 * np.pi * np.arange(P) / P
        shape = (P,) * d
        Mv = np.zeros(shape + (n, n))
        gv = np.zeros(shape + (n,))
        data = pm.createData()
        for idx in itertools.product(range(P), repeat=d):
            q = np.zeros(n)
            q[self.dims] = grid[list(idx)]
            M = pin.crba(pm, data, q)
            Mv[idx] = np.triu(M) + np.triu(M, 1).T
            gv[idx] = pin.computeGeneralizedGravity(pm, data, q)
        axes = tuple(range(d))
        self.cM = np.fft.fftn(Mv, axes=axes) / P ** d if d else Mv.astype(complex)
        self.cg = np.fft.fftn(gv, axes=axes) / P ** d if d else gv.astype(complex)
        freq = np.fft.fftfreq(P, 1.0 / P).astype(int)           # 0, 1, 2, -2, -1
        self.K = np.stack(np.meshgrid(*([freq] * d), indexing="ij"), axis=-1).reshape(-1, d) if d else np.zeros((1, 0), int)
        cM = self.cM.reshape(-1, n, n)
        cg = self.cg.reshape(-1, n)
        absM, absg = np.abs(cM), np.abs(cg)
        kk = np.abs(self.K[:, :, None] * self.K[:, None, :]).astype(float)     # (terms, d, d)
        self.HM = np.einsum("tij,tlm->ijlm", absM, kk)
        self.Hg = np.einsum("ti,tlm->ilm", absg, kk)
        self.marginM = 1e-9 * absM.sum(axis=0) + 1e-12
        self.marginG = 1e-9 * absg.sum(axis=0) + 1e-12
        # Christoffel symbols: coefficients of d_l M_ij are i k_l c_k
        dM = np.zeros((cM.shape[0], n, n, n), complex)               # [t, i, j, l] = d_l M_ij
        for a, jnt in enumerate(self.dims):
            dM[:, :, :, jnt] = 1j * self.K[:, a][:, None, None] * cM
        # Gamma_ijk = (d_k M_ij + d_j M_ik - d_i M_jk) / 2
        Gam = np.zeros((cM.shape[0], n, n, n), complex)
        for i in range(n):
            for j in range(n):
                for k in range(n):
                    Gam[:, i, j, k] = 0.5 * (dM[:, i, j, k] + dM[:, i, k, j] - dM[:, j, k, i])
        self.Gbar = np.abs(Gam).sum(axis=0) * (1 + 1e-9) + 1e-12
        self._verify(check_points, seed)

    def _eval(self, Q):
        """Trigonometric polynomials at configurations Q (m, n): M (m, n, n), g (m, n)."""
        d = len(self.dims)
        if d == 0:
            return (np.repeat(self.cM.real[None], len(Q), 0), np.repeat(self.cg.real[None], len(Q), 0))
        ph = np.exp(1j * (Q[:, self.dims] @ self.K.T))                # (m, terms)
        M = np.einsum("mt,tij->mij", ph, self.cM.reshape(-1, self.n, self.n)).real
        g = np.einsum("mt,ti->mi", ph, self.cg.reshape(-1, self.n)).real
        return M, g

    def _verify(self, m, seed):
        import pinocchio as pin
        pm = self.model.pin_model
        data = pm.createData()
        rng = np.random.default_rng(seed)
        Q = np.zeros((m, self.n))
        Q[:, self.dims] = rng.uniform(-np.pi, np.pi, (m, len(self.dims)))
        Mt, gt = self._eval(Q)
        errM = errg = 0.0
        for r in range(m):
            M = pin.crba(pm, data, Q[r])
            M = np.triu(M) + np.triu(M, 1).T
            errM = max(errM, float(np.max(np.abs(M - Mt[r]))))
            errg = max(errg, float(np.max(np.abs(pin.computeGeneralizedGravity(pm, data, Q[r]) - gt[r]))))
        scaleM = float(np.abs(self.cM).sum(axis=tuple(range(len(self.dims)))).max()) if self.dims else 1.0
        scaleg = float(np.abs(self.cg).sum(axis=tuple(range(len(self.dims)))).max()) if self.dims else 1.0
        if errM > 1e-9 * max(scaleM, 1e-300) or errg > 1e-9 * max(scaleg, 1e-300):
            raise ReachsetError(f"input limits: M(q) / g(q) are not trigonometric polynomials of degree <= 2 "
                                f"per joint (mismatch {errM:.3g} / {errg:.3g}); use method 'interval'")
        self.verify_error = (errM, errg)

    def coriolis_bound(self, qd_max):
        qd = np.abs(np.asarray(qd_max, float))
        return _up(np.einsum("ijk,j,k->i", self.Gbar, qd, qd))

    def box_bounds(self, centers, radii):
        """``mbar (N, n, n)``, ``gbar (N, n)`` and the per-dimension contributions (for splitting)."""
        import pinocchio as pin
        pm = self.model.pin_model
        data = pm.createData()
        n, dims = self.n, self.dims
        N = len(centers)
        mbar = np.zeros((N, n, n))
        gbar = np.zeros((N, n))
        contM = np.zeros((N, n, n, len(dims)))
        contg = np.zeros((N, n, len(dims)))
        zero = np.zeros(n)
        E = np.eye(n)
        for b in range(N):
            q = centers[b]
            r = radii[b][dims]
            M = pin.crba(pm, data, q)
            M = np.triu(M) + np.triu(M, 1).T
            g = pin.computeGeneralizedGravity(pm, data, q).copy()
            dg = pin.computeGeneralizedGravityDerivatives(pm, data, q).copy()
            dM = np.zeros((n, n, n))                                 # [i, j, l] = d_l M_ij
            for j in range(n):
                dtdq = pin.computeRNEADerivatives(pm, data, q, zero, E[j])[0]
                dM[:, j, :] = dtdq - dg
            first = np.abs(dM[:, :, dims]) * r                       # (n, n, d)
            second = 0.5 * np.einsum("ijlm,l,m->ijl", self.HM, r, r)
            contM[b] = first + second
            mbar[b] = np.abs(M) + contM[b].sum(axis=-1) + self.marginM
            fg = np.abs(dg[:, dims]) * r
            sg = 0.5 * np.einsum("ilm,l,m->il", self.Hg, r, r)
            contg[b] = fg + sg
            gbar[b] = np.abs(g) + contg[b].sum(axis=-1) + self.marginG
        # outward rounding of the sums (a relative 1e-12 is far above their rounding error)
        return mbar * (1 + 1e-12), gbar * (1 + 1e-12), contM, contg


@dataclass(frozen=True)
class InputLimits:
    """Result of :func:`input_limits`."""

    a: np.ndarray              # U_p = [-a_i, a_i], rad/s^2
    tau_max: np.ndarray
    q_max: np.ndarray
    qd_max: np.ndarray
    method: str
    boxes: int
    rounds: int
    binding: tuple             # per axis: the axis whose torque row limits it
    worst_torque: np.ndarray   # max over sub-boxes of the left side of (*) at a, per axis (sound)
    sampled_torque: np.ndarray  # max |tau| over random samples at a (an inner estimate), per axis
    invariant_joints: tuple
    joint_names: tuple
    source: str
    history: tuple = ()        # (boxes, a) after each refinement round
    weights: tuple = ()

    def as_dict(self):
        return {"u_max": [float(x) for x in self.a], "tau_max": self.tau_max.tolist(),
                "q_max_deg": np.rad2deg(self.q_max).round(6).tolist(), "qd_max": self.qd_max.tolist(),
                "method": self.method, "weights": [float(x) for x in self.weights],
                "boxes": int(self.boxes), "rounds": int(self.rounds),
                "binding_axis": [self.joint_names[b] for b in self.binding],
                "bound_torque": self.worst_torque.tolist(), "sampled_torque": self.sampled_torque.tolist(),
                "invariant_joints": [self.joint_names[j] for j in self.invariant_joints],
                "joints": list(self.joint_names), "model": self.source,
                "history": [{"boxes": int(b), "u_max": [float(x) for x in a]} for b, a in self.history]}


def _lp_max_min(A, b, n, fixed_vals=None):
    """max t s.t. A a <= b, a_j >= t (free j), a_j >= v_j (fixed j), a >= 0. Returns (t, a)."""
    fixed_vals = fixed_vals or {}
    free = [j for j in range(n) if j not in fixed_vals]
    c = np.zeros(n + 1)
    c[-1] = -1.0
    rows = [np.hstack([A, np.zeros((A.shape[0], 1))])]
    rhs = [b]
    for j in free:
        r = np.zeros(n + 1)
        r[j], r[-1] = -1.0, 1.0
        rows.append(r[None, :])
        rhs.append(np.zeros(1))
    bounds = [(fixed_vals.get(j, 0.0), None) for j in range(n)] + [(0, None)]
    res = linprog(c, A_ub=np.vstack(rows), b_ub=np.concatenate(rhs), bounds=bounds, method="highs")
    if res.status != 0:
        return None, None
    return float(res.x[-1]), res.x[:n]


def _lp_max_one(A, b, n, j, lower):
    c = np.zeros(n)
    c[j] = -1.0
    res = linprog(c, A_ub=A, b_ub=b, bounds=[(lo, None) for lo in lower], method="highs")
    return float(res.x[j]) if res.status == 0 else None


def _max_min_fair(A, b, n, w=None):
    """Lexicographic max-min of ``a / w`` subject to ``A a <= b``, ``a >= 0`` (verified, shrunk)."""
    w = np.ones(n) if w is None else np.asarray(w, float)
    a = w * _max_min_unit(A * w[None, :], b, n)
    for _ in range(200):
        if np.all(A @ a <= b):
            break
        a = a * (1 - 1e-9) - 1e-12
    return np.maximum(a, 0.0)


def _max_min_unit(A, b, n):
    fixed_vals = {}
    for _ in range(n):
        t, _ = _lp_max_min(A, b, n, fixed_vals)
        if t is None:
            raise InfeasibleError("input limits: the linear programme failed")
        free = [j for j in range(n) if j not in fixed_vals]
        lower = [fixed_vals.get(j, t) for j in range(n)]
        newly = []
        for j in free:
            mx = _lp_max_one(A, b, n, j, lower)
            if mx is None or mx <= t * (1 + 1e-7) + 1e-12:
                newly.append(j)
        for j in (newly or free):
            fixed_vals[j] = t
        if len(fixed_vals) == n:
            break
    return np.array([fixed_vals[j] for j in range(n)])


def input_limits(model=None, tau_max=None, q_max=None, qd_max=None, splits=4, method="taylor",
                 refine=6, max_boxes=16000, weights="inertia", samples=20000, seed=0):
    """Largest symmetric U_p per axis satisfying (*) on every sub-box (lexicographic max-min).

    Parameters
    ----------
    model : RobotModel, optional
        Default :func:`reachset_ros.robot.load_model` (the shipped URDF).
    tau_max, q_max, qd_max : array_like, optional
        Default the paper's Table I (:data:`reachset_ros.robot.TABLE1_TAU_MAX`, ...).
    splits : int or sequence
        Initial pieces per joint of ``Q`` (paper: 4).
    method : {"taylor", "interval"}
        ``"taylor"`` (default): :class:`TrigBounds`, then up to ``refine`` rounds that bisect
        the sub-boxes whose torque rows bind (along the coordinate that contributes most),
        at most ``max_boxes`` boxes. ``"interval"``: interval RNEA on the uniform split only.
    weights : {"inertia", "equal"} or array_like
        The axes share the torque budget (a wrist acceleration needs shoulder torque too), so
        "largest" needs a trade-off: lexicographic max-min of ``a_j / w_j``. ``"inertia"``
        (default): ``w_j = tau_max_j / max_q M_jj(q)``, the acceleration each axis could reach
        alone (the paper's Table I gives the light wrist axes about 4x the shoulder's);
        ``"equal"``: the same limit for all axes first.
    samples : int
        Random (q, qd) samples for the reported inner estimate ``sampled_torque``.

    Returns
    -------
    InputLimits

    Raises
    ------
    InfeasibleError
        If even ``U_p = {0}`` violates the torque limits (gravity and friction alone exceed T).
    """
    model = model or rb.load_model()
    n = model.nv
    tau_max = np.broadcast_to(np.asarray(rb.TABLE1_TAU_MAX if tau_max is None else tau_max, float), (n,)).copy()
    q_max = np.broadcast_to(np.asarray(rb.TABLE1_Q_MAX if q_max is None else q_max, float), (n,)).copy()
    qd_max = np.broadcast_to(np.asarray(rb.TABLE1_QD_MAX if qd_max is None else qd_max, float), (n,)).copy()
    if np.any(tau_max <= 0) or not np.all(np.isfinite(tau_max)):
        raise ReachsetError("tau_max must be positive")
    if np.any(q_max < 0) or np.any(qd_max < 0) or not np.all(np.isfinite(np.r_[q_max, qd_max])):
        raise ReachsetError("q_max and qd_max must be finite and non-negative")
    spl = np.broadcast_to(np.asarray(splits, int), (n,))
    if np.any(spl < 1):
        raise ReachsetError("splits must be >= 1")
    fixed = invariant_joints(model)
    history = []
    rounds = 0
    if method == "interval":
        mbar, psibar, blo, bhi, fixed = mass_psi_bounds(model, q_max, qd_max, spl)
        A, b = mbar.reshape(-1, n), (tau_max[None, :] - psibar).reshape(-1)
        _feasible_or_raise(model, b, psibar, tau_max)
        w = _weights(weights, mbar, tau_max, n)
        a = _max_min_fair(A, b, n, w)
        history.append((len(blo), a))
    elif method == "taylor":
        dims = [j for j in range(n) if j not in fixed]
        tb = TrigBounds(model, dims)
        base = _up(tb.coriolis_bound(qd_max) + _friction_bound(model, -qd_max, qd_max))
        blo, bhi = _boxes(-q_max, q_max, spl, fixed)

        def bounds_of(lo, hi):
            c = 0.5 * (lo + hi)
            r = np.maximum(_up(hi - c), _up(c - lo))
            mb, gb, cm, cg = tb.box_bounds(c, r)
            return mb, _up(gb + base), cm, cg

        mbar, psibar, contM, contg = bounds_of(blo, bhi)
        w = _weights(weights, mbar, tau_max, n)
        while True:
            A, b = mbar.reshape(-1, n), (tau_max[None, :] - psibar).reshape(-1)
            _feasible_or_raise(model, b, psibar, tau_max)
            a = _max_min_fair(A, b, n, w)
            history.append((len(blo), a))
            if rounds >= refine:
                break
            slack = (tau_max[None, :] - psibar - np.einsum("bij,j->bi", mbar, a)) / tau_max[None, :]
            worst_axis = slack.argmin(axis=1)
            tight = np.flatnonzero(slack.min(axis=1) <= 0.01)
            if len(tight) == 0 or len(blo) + len(tight) > max_boxes:
                break
            rounds += 1
            new_lo, new_hi = [], []
            for bx in tight:
                i = worst_axis[bx]
                cont = np.einsum("jl,j->l", contM[bx, i], a) + contg[bx, i]
                l = dims[int(np.argmax(cont))]
                mid = 0.5 * (blo[bx, l] + bhi[bx, l])
                lo1, hi1 = blo[bx].copy(), bhi[bx].copy()
                hi1[l] = mid
                lo2, hi2 = blo[bx].copy(), bhi[bx].copy()
                lo2[l] = mid
                new_lo += [lo1, lo2]
                new_hi += [hi1, hi2]
            keep = np.ones(len(blo), bool)
            keep[tight] = False
            nlo, nhi = np.array(new_lo), np.array(new_hi)
            mb2, pb2, cm2, cg2 = bounds_of(nlo, nhi)
            blo, bhi = np.vstack([blo[keep], nlo]), np.vstack([bhi[keep], nhi])
            mbar, psibar = np.concatenate([mbar[keep], mb2]), np.concatenate([psibar[keep], pb2])
            contM, contg = np.concatenate([contM[keep], cm2]), np.concatenate([contg[keep], cg2])
    else:
        raise ReachsetError(f"unknown input-limits method {method!r} (taylor or interval)")
    N = len(blo)
    A, b = mbar.reshape(-1, n), (tau_max[None, :] - psibar).reshape(-1)
    lhs = (A @ a).reshape(N, n) + psibar
    worst = lhs.max(axis=0)
    slack = (tau_max[None, :] - lhs) / tau_max[None, :]
    tight_rows = [i for i in range(n) if slack[:, i].min() <= 1e-6]
    binding = []
    for j in range(n):
        if not tight_rows:
            binding.append(int(np.argmin(slack.min(axis=0))))
            continue
        use = [mbar[:, i, j].max() * a[j] / tau_max[i] for i in tight_rows]
        binding.append(int(tight_rows[int(np.argmax(use))]))
    sampled = sampled_worst_torque(model, a, q_max, qd_max, samples, seed)
    return InputLimits(a, tau_max, q_max, qd_max, method, N, rounds, tuple(binding), worst, sampled,
                       tuple(fixed), tuple(model.joint_names), model.source, tuple(history), tuple(w))


def _weights(weights, mbar, tau_max, n):
    if isinstance(weights, str):
        if weights == "equal":
            return np.ones(n)
        if weights == "inertia":
            mjj = np.einsum("bjj->bj", mbar).max(axis=0)
            return tau_max / np.maximum(mjj, 1e-12)
        raise ReachsetError(f"unknown weights {weights!r} (inertia, equal or numbers)")
    w = np.broadcast_to(np.asarray(weights, float), (n,))
    if np.any(w <= 0) or not np.all(np.isfinite(w)):
        raise ReachsetError("weights must be positive")
    return np.array(w)


def _feasible_or_raise(model, b, psibar, tau_max):
    n = model.nv
    if np.any(b < 0):
        k = int(np.argmin(b))
        raise InfeasibleError(f"axis {model.joint_names[k % n]}: gravity, Coriolis and friction alone need up to "
                              f"{psibar.reshape(-1)[k]:.4g} N m > tau_max {tau_max[k % n]:g} N m")


def check_limits(model, a, tau_max=None, q_max=None, qd_max=None, splits=4):
    """Verify a given U_p = [-a, a] against (*) with :class:`TrigBounds` (sound).

    Returns ``(ok, bound torque per axis)``; ``ok`` False means the bound exceeds ``tau_max``
    on some sub-box (not necessarily that the limits are violated: refine with more splits).
    """
    n = model.nv
    tau_max = np.broadcast_to(np.asarray(rb.TABLE1_TAU_MAX if tau_max is None else tau_max, float), (n,))
    q_max = np.broadcast_to(np.asarray(rb.TABLE1_Q_MAX if q_max is None else q_max, float), (n,))
    qd_max = np.broadcast_to(np.asarray(rb.TABLE1_QD_MAX if qd_max is None else qd_max, float), (n,))
    fixed = invariant_joints(model)
    dims = [j for j in range(n) if j not in fixed]
    tb = TrigBounds(model, dims)
    base = _up(tb.coriolis_bound(qd_max) + _friction_bound(model, -qd_max, qd_max))
    blo, bhi = _boxes(-q_max, q_max, np.broadcast_to(np.asarray(splits, int), (n,)), fixed)
    c = 0.5 * (blo + bhi)
    r = np.maximum(_up(bhi - c), _up(c - blo))
    mbar, gbar, _, _ = tb.box_bounds(c, r)
    a = np.broadcast_to(np.asarray(a, float), (n,))
    worst = (np.einsum("bij,j->bi", mbar, a) + gbar + base).max(axis=0)
    return bool(np.all(worst <= tau_max)), worst


def sampled_worst_torque(model, a, q_max, qd_max, samples=20000, seed=0):
    """Largest |tau_i| over random (q, qd) samples in the boxes and the worst u in U_p (not rigorous).

    For each sample the worst ``u`` per axis is ``a_j sign(M_ij)``, so the value is
    ``sum_j |M_ij(q)| a_j + |psi_i(q, qd)|`` evaluated with Pinocchio; ``qd`` at random corners
    of ``dQ``. An inner estimate of what (*) bounds from above.
    """
    n = model.nv
    if samples <= 0:
        return np.full(n, np.nan)
    rng = np.random.default_rng(seed)
    data = rb.create_data(model)
    q_max = np.broadcast_to(np.asarray(q_max, float), (n,))
    qd_max = np.broadcast_to(np.asarray(qd_max, float), (n,))
    a = np.asarray(a, float)
    worst = np.zeros(n)
    for _ in range(int(samples)):
        q = rng.uniform(-q_max, q_max)
        qd = qd_max * rng.choice([-1.0, 1.0], n)
        M = rb.mass_matrix(model, data, q)
        ps = rb.psi(model, data, q, qd)
        worst = np.maximum(worst, np.abs(M) @ a + np.abs(ps))
    return worst
