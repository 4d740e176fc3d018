"""Input limits U_p from torque limits (paper eq. ``deriveInputConstraint``, Table I).

Feedback linearization ``tau = M(q) u_p + psi(q, qd)`` must respect the torque limits for
every position in the box ``Q``, velocity in ``dQ`` and plant input in
``U_p = [-a_1, a_1] x ... x [-a_n, a_n]``::

    T  contains  M(Q) U_p (+) psi(Q, dQ).

For axis i and ``q`` in a sub-box ``B`` of ``Q`` this holds if

    sum_j  mbar_ij(B) a_j  +  psibar_i(B)  <=  tau_max,i,                          (*)

with ``mbar_ij(B) >= |M_ij(q)|`` and ``psibar_i(B) >= |psi_i(q, qd)|`` for all ``q`` in ``B``,
``qd`` in ``dQ`` (``|tau_i| <= sum_j |M_ij| |u_j| + |psi_i|``). The bounds come from an
**interval-arithmetic recursive Newton-Euler algorithm**
(:func:`reachset_ros.robot.interval.interval_rnea`) on the Pinocchio model: columns of ``M``
are RNEA with ``qd = 0``, no gravity, ``qdd = e_j`` (armature included); ``psi`` is RNEA
with ``qd`` in ``dQ``, gravity, ``qdd = 0``, plus the joint friction (monotone in ``qd``,
bounded exactly). ``Q`` is split into sub-boxes
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
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ..errors import InfeasibleError, ReachsetError
from .dynamics import TABLE1_QD_MAX, TABLE1_Q_MAX, TABLE1_TAU_MAX, create_data, load_model, mass_matrix, psi
from .interval import interval_rnea, joint_axis, next_up

__all__ = ["mass_psi_bounds", "InputLimits", "input_limits", "check_limits",
           "sampled_worst_torque"]


def _friction_bound(model, qd_lo, qd_hi):
    """Largest |friction torque| per joint for qd in [qd_lo, qd_hi] (terms bounded separately)."""
    fr = model.friction
    qd_lo, qd_hi = np.asarray(qd_lo, float), np.asarray(qd_hi, float)
    v = np.maximum(np.abs(fr.viscous * qd_lo), np.abs(fr.viscous * qd_hi))
    c = np.abs(fr.coulomb) * np.maximum(np.abs(np.tanh(qd_lo / fr.coulomb_velocity)),
                                        np.abs(np.tanh(qd_hi / fr.coulomb_velocity)))
    return next_up(next_up(v + c) + np.abs(fr.offset))


def invariant_joints(model):
    """Joints whose position does not change M and psi (first joint, axis parallel to gravity)."""
    pm = model.pin_model
    out = []
    if pm.njoints > 1 and pm.parents[1] == 0:
        try:
            axis = joint_axis(pm.joints[1])
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
        psibar[s:s + chunk] = next_up(np.maximum(np.abs(plo), np.abs(phi)) + fric)
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
        return next_up(np.einsum("ijk,j,k->i", self.Gbar, qd, qd))

    def box_bounds(self, centers, radii):
        """``mbar (N, n, n)``, ``gbar (N, n)`` and the per-dimension contributions (for splitting)."""
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
    from scipy.optimize import linprog  # lazy: 0.3 s of start-up (issue 38.1)
    res = linprog(c, A_ub=np.vstack(rows), b_ub=np.concatenate(rhs), bounds=bounds, method="highs")
    if res.status != 0:
        return None, None
    return float(res.x[-1]), res.x[:n]


def _lp_max_one(A, b, n, j, lower):
    c = np.zeros(n)
    c[j] = -1.0
    from scipy.optimize import linprog  # lazy (issue 38.1)
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
    model = model or load_model()
    n = model.nv
    tau_max = np.broadcast_to(np.asarray(TABLE1_TAU_MAX if tau_max is None else tau_max, float), (n,)).copy()
    q_max = np.broadcast_to(np.asarray(TABLE1_Q_MAX if q_max is None else q_max, float), (n,)).copy()
    qd_max = np.broadcast_to(np.asarray(TABLE1_QD_MAX if qd_max is None else qd_max, float), (n,)).copy()
    if np.any(tau_max <= 0) or not np.all(np.isfinite(tau_max)):
        raise ReachsetError("tau_max must be positive")
    if np.any(q_max < 0) or np.any(qd_max < 0) or not np.all(np.isfinite(np.r_[q_max, qd_max])):
        raise ReachsetError("q_max and qd_max must be finite and non-negative")
    spl = np.broadcast_to(np.asarray(splits, int), (n,))
    if np.any(spl < 1):
        raise ReachsetError("splits must be >= 1")
    if method == "interval":
        fit = _interval_fit(model, tau_max=tau_max, q_max=q_max, qd_max=qd_max, spl=spl, weights=weights)
    elif method == "taylor":
        fit = _taylor_fit(model, tau_max=tau_max, q_max=q_max, qd_max=qd_max, spl=spl, weights=weights,
                          refine=refine, max_boxes=max_boxes)
    else:
        raise ReachsetError(f"unknown input-limits method {method!r} (taylor or interval)")
    a, mbar, psibar = fit.a, fit.mbar, fit.psibar
    N = fit.boxes
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
    return InputLimits(a=a, tau_max=tau_max, q_max=q_max, qd_max=qd_max, method=method, boxes=N, rounds=fit.rounds,
                       binding=tuple(binding), worst_torque=worst, sampled_torque=sampled,
                       invariant_joints=tuple(fit.fixed), joint_names=tuple(model.joint_names), source=model.source,
                       history=tuple(fit.history), weights=tuple(fit.w))


@dataclass(frozen=True, kw_only=True)
class _Fit:
    """The lexicographic max-min ``a`` of :func:`input_limits` and the sub-box bounds it was
    computed from (``mbar`` (boxes, n, n), ``psibar`` (boxes, n))."""

    a: np.ndarray
    mbar: np.ndarray
    psibar: np.ndarray
    boxes: int
    w: np.ndarray
    fixed: object
    rounds: int = 0
    history: list = field(default_factory=list)


def _interval_fit(model, *, tau_max, q_max, qd_max, spl, weights):
    """``method="interval"`` of :func:`input_limits`: interval RNEA on the uniform split."""
    n = model.nv
    mbar, psibar, blo, bhi, fixed = mass_psi_bounds(model, q_max, qd_max, spl)
    A, b = mbar.reshape(-1, n), (tau_max[None, :] - psibar).reshape(-1)
    _feasible_or_raise(model, b, psibar, tau_max)
    w = _weights(weights, mbar, tau_max, n)
    a = _max_min_fair(A, b, n, w)
    return _Fit(a=a, mbar=mbar, psibar=psibar, boxes=len(blo), w=w, fixed=fixed, history=[(len(blo), a)])


def _taylor_fit(model, *, tau_max, q_max, qd_max, spl, weights, refine, max_boxes):
    """``method="taylor"`` of :func:`input_limits`: :class:`TrigBounds` on the sub-boxes, then up
    to ``refine`` rounds bisecting the boxes whose torque rows bind (along the coordinate that
    contributes most), at most ``max_boxes`` boxes."""
    n = model.nv
    fixed = invariant_joints(model)
    history = []
    rounds = 0
    dims = [j for j in range(n) if j not in fixed]
    tb = TrigBounds(model, dims)
    base = next_up(tb.coriolis_bound(qd_max) + _friction_bound(model, -qd_max, qd_max))
    blo, bhi = _boxes(-q_max, q_max, spl, fixed)

    def bounds_of(lo, hi):
        c = 0.5 * (lo + hi)
        r = np.maximum(next_up(hi - c), next_up(c - lo))
        mb, gb, cm, cg = tb.box_bounds(c, r)
        return mb, next_up(gb + base), cm, cg

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
    return _Fit(a=a, mbar=mbar, psibar=psibar, boxes=len(blo), w=w, fixed=fixed, rounds=rounds, history=history)


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
    tau_max = np.broadcast_to(np.asarray(TABLE1_TAU_MAX if tau_max is None else tau_max, float), (n,))
    q_max = np.broadcast_to(np.asarray(TABLE1_Q_MAX if q_max is None else q_max, float), (n,))
    qd_max = np.broadcast_to(np.asarray(TABLE1_QD_MAX if qd_max is None else qd_max, float), (n,))
    fixed = invariant_joints(model)
    dims = [j for j in range(n) if j not in fixed]
    tb = TrigBounds(model, dims)
    base = next_up(tb.coriolis_bound(qd_max) + _friction_bound(model, -qd_max, qd_max))
    blo, bhi = _boxes(-q_max, q_max, np.broadcast_to(np.asarray(splits, int), (n,)), fixed)
    c = 0.5 * (blo + bhi)
    r = np.maximum(next_up(bhi - c), next_up(c - blo))
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
    data = create_data(model)
    q_max = np.broadcast_to(np.asarray(q_max, float), (n,))
    qd_max = np.broadcast_to(np.asarray(qd_max, float), (n,))
    a = np.asarray(a, float)
    worst = np.zeros(n)
    for _ in range(int(samples)):
        q = rng.uniform(-q_max, q_max)
        qd = qd_max * rng.choice([-1.0, 1.0], n)
        M = mass_matrix(model, data, q)
        ps = psi(model, data, q, qd)
        worst = np.maximum(worst, np.abs(M) @ a + np.abs(ps))
    return worst
