"""Reachset conformance: test cases, deviations y_a, Theorem 1, identification, checking.

Paper Sec. II-B (Defs. 2-4) and III-B. For sequential test cases (Def. 3) starting at
every valid tick m of a recording, the deviation of the measurement from the nominal
prediction (eq. 12)

    y_a^(m)[k] = y[m+k] - y_*^(m)[k],   y_*^(m)[k] = C x_*^(m)[k] + D u[m+k],
    x_*^(m)[0] = x0(m) (an :class:`~reachset_ros.estimators.Estimator`),
    x_*^(m)[k+1] = A x_*^(m)[k] + B u[m+k],

must lie in R_a[k] = (+)_{i<k} C A^i W (+) V (eq. 13). Theorem 1 writes this as
``max_m N_k y_a^(m)[k] <= D_k xi`` with xi = [c_W, c_V, alpha_W, alpha_V], linear in xi,
where the normals N_k come from the H-representation of R_a[k] built from the *unscaled*
generators (they do not depend on alpha > 0).

All arithmetic on the nominal trajectories uses the element-wise :func:`matvec`, so the
batch sweep here and the online monitor (:mod:`reachset_ros.monitor`), which advances one
tick at a time, produce bitwise identical deviations and hence identical verdicts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from .errors import InfeasibleError, ReachsetError


# ------------------------------------------------------------------ deterministic kernels
_PLANS = {}


def _plan(M):
    key = (M.shape, M.tobytes())
    plan = _PLANS.get(key)
    if plan is None:
        plan = tuple(tuple((j, float(M[i, j])) for j in range(M.shape[1]) if M[i, j] != 0.0)
                     for i in range(M.shape[0]))
        if len(_PLANS) > 256:
            _PLANS.clear()
        _PLANS[key] = plan
    return plan


def matvec(M, X):
    """``M @ X`` for ``X`` of shape (n, N) with a fixed, length-independent summation order.

    Element-wise multiply-adds over the nonzero entries of ``M`` in row-major order
    (a factor of exactly 1.0 is skipped, which does not change any result); the result for
    one column does not depend on how many columns are processed together, unlike BLAS.
    Used by every code path that computes nominal predictions, so batch and online
    computations agree to the bit.
    """
    M = np.asarray(M, dtype=np.float64)
    out = np.zeros((M.shape[0], X.shape[1]))
    for i, row in enumerate(_plan(M)):
        acc = None
        for j, a in row:
            term = X[j] if a == 1.0 else a * X[j]
            if acc is None:
                acc = term
            else:
                acc = acc + term
        if acc is not None:
            out[i] = acc
    return out


def predict_output(plant, X, U):
    """Nominal output ``C X + D U`` (eq. 3), columns = test cases."""
    Y = matvec(plant.C, X)
    if np.any(plant.D):
        Y = Y + matvec(plant.D, U)
    return Y


def advance(plant, X, U):
    """Nominal state step ``A X + B U`` (eq. 3), columns = test cases."""
    return matvec(plant.A, X) + matvec(plant.B, U)


def as_2d(a):
    a = np.asarray(a, dtype=np.float64)
    return a[:, None] if a.ndim == 1 else a


# ------------------------------------------------------------------ test cases
def test_case_starts(segments, history):
    """Start ticks m of sequential test cases and the end of each one's segment."""
    starts, ends = [], []
    for s, e in segments:
        if e - (s + history) > 0:
            starts.append(np.arange(s + history, e))
            ends.append(np.full(e - s - history, e))
    if not starts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(starts), np.concatenate(ends)


def sweep(plant, estimator, y, u, segments, horizon, visit):
    """Run all sequential test cases for k = 0..horizon and call ``visit`` per step.

    Parameters
    ----------
    plant : LinearPlant
    estimator : Estimator
    y, u : ndarray, shape (T, ny) and (T, nu)
    segments : sequence of (start, stop)
        Test cases never span two segments; (m, k) is visited only if m + k < stop.
    horizon : int
        k*, the last step checked.
    visit : callable ``visit(k, m, t, ya)``
        ``m``: start ticks, ``t = m + k``: measurement ticks, ``ya``: (ny, M_k) deviations.

    Returns
    -------
    int : number of test cases (start ticks).
    """
    y, u = as_2d(y), as_2d(u)
    starts, ends = test_case_starts(segments, estimator.history)
    if len(starts) == 0:
        return 0
    order = np.argsort(-(ends - starts), kind="stable")
    starts, rem = starts[order], (ends - starts)[order]
    X = estimator.estimate(plant, y, u, starts)
    for k in range(horizon + 1):
        Mk = int(np.searchsorted(-rem, -k, side="left"))  # rem > k, rem sorted descending
        if Mk == 0:
            break
        X = X[:, :Mk]
        m = starts[:Mk]
        t = m + k
        U = u[t].T
        ya = y[t].T - predict_output(plant, X, U)
        visit(k, m, t, ya)
        X = advance(plant, X, U)
    return len(starts)


# ------------------------------------------------------------------ Theorem 1
def output_normals(plant, horizon):
    """Unit normals N_k^+ of R_a[k] for k = 0..horizon (Theorem 1), shape (q_k, ny) each.

    For a one-dimensional output N_k^+ = [[1]]. Otherwise the facet normals of the zonotope
    with the unscaled generators [C A^0 G'_W, ..., C A^{k-1} G'_W, G'_V] (Prop. 1).
    """
    ny = plant.C.shape[0]
    if ny == 1:
        return [np.ones((1, 1))] * (horizon + 1)
    from .zonotope import halfspace_normals
    out, E, blocks = [], np.eye(plant.A.shape[0]), []
    for k in range(horizon + 1):
        G = np.hstack(blocks + [plant.Gv]) if blocks else plant.Gv
        out.append(halfspace_normals(G))
        blocks.append(plant.C @ E @ plant.Gw)
        E = plant.A @ E
    return out


@dataclass(frozen=True)
class Theorem1:
    """The linear conformance constraints of Theorem 1 for a plant and horizon.

    ``Dp[k] @ xi`` and ``Dm[k] @ xi`` are the offsets of the half-spaces ``N_k y <= d+`` and
    ``-N_k y <= d-`` of R_a[k]; xi = [c_W (n), c_V (ny), alpha_W (pw), alpha_V (pv)].
    """

    normals: tuple
    Dp: tuple
    Dm: tuple

    @classmethod
    def build(cls, plant, horizon):
        n, ny = plant.A.shape[0], plant.C.shape[0]
        normals = output_normals(plant, horizon)
        Dp, Dm = [], []
        sumE = np.zeros((ny, n))       # sum_{i<k} C A^i
        sumR = None                    # per normal: sum_{i<k} |n C A^i G'_W|
        E = plant.C.copy()
        for k in range(horizon + 1):
            N = normals[k]
            radW = np.zeros((N.shape[0], plant.Gw.shape[1]))
            # recompute per k (normals change with k when ny > 1)
            Ei = plant.C.copy()
            for _ in range(k):
                radW += np.abs(N @ Ei @ plant.Gw)
                Ei = Ei @ plant.A
            radV = np.abs(N @ plant.Gv)
            cW = N @ sumE
            cV = N
            Dp.append(np.hstack([cW, cV, radW, radV]))
            Dm.append(np.hstack([-cW, -cV, radW, radV]))
            sumE = sumE + E
            E = E @ plant.A
        return cls(tuple(normals), tuple(Dp), tuple(Dm))

    def offsets(self, xi):
        """Per k: (d+, d-) arrays for the parameter vector xi."""
        return [(Dp @ xi, Dm @ xi) for Dp, Dm in zip(self.Dp, self.Dm)]


def xi_of(c_w, c_v, alpha_w, alpha_v):
    return np.concatenate([np.ravel(c_w), np.ravel(c_v), np.ravel(alpha_w), np.ravel(alpha_v)]).astype(np.float64)


@dataclass(frozen=True)
class Deviations:
    """Per k: the largest ``N_k y_a`` and ``-N_k y_a`` over all test cases (Theorem 1's LHS)."""

    maxp: tuple
    maxm: tuple
    test_cases: int
    checks: int


def deviation_extremes(plant, estimator, y, u, segments, horizon, thm=None):
    """Reduce all test cases to the left-hand sides of Theorem 1, per k and normal."""
    thm = thm or Theorem1.build(plant, horizon)
    maxp = [None] * (horizon + 1)
    maxm = [None] * (horizon + 1)
    count = [0]

    def visit(k, m, t, ya):
        Ny = matvec(thm.normals[k], ya)
        maxp[k] = Ny.max(axis=1)
        maxm[k] = (-Ny).max(axis=1)
        count[0] += ya.shape[1]

    M = sweep(plant, estimator, y, u, segments, horizon, visit)
    if M == 0:
        raise ReachsetError("too few samples for a test case (need at least "
                            f"{estimator.history + 1} consecutive valid ticks)")
    for k in range(horizon + 1):
        if maxp[k] is None:
            q = thm.normals[k].shape[0]
            maxp[k] = np.full(q, -np.inf)
            maxm[k] = np.full(q, -np.inf)
    return Deviations(tuple(maxp), tuple(maxm), M, count[0])


def combine(devs):
    """Deviations of several recordings (joints' data from several bags) together."""
    maxp = tuple(np.maximum.reduce([d.maxp[k] for d in devs]) for k in range(len(devs[0].maxp)))
    maxm = tuple(np.maximum.reduce([d.maxm[k] for d in devs]) for k in range(len(devs[0].maxm)))
    return Deviations(maxp, maxm, sum(d.test_cases for d in devs), sum(d.checks for d in devs))


# ------------------------------------------------------------------ identification
@dataclass(frozen=True)
class IdentifiedSets:
    """Identified disturbance sets W = (c_W, G'_W diag alpha_W), V = (c_V, G'_V diag alpha_V)."""

    c_w: np.ndarray
    c_v: np.ndarray
    alpha_w: np.ndarray
    alpha_v: np.ndarray
    cost: float
    soundness_bump: float

    @property
    def xi(self):
        return xi_of(self.c_w, self.c_v, self.alpha_w, self.alpha_v)


def identification_constraints(plant, thm, devs, horizon=None, centers="zero"):
    """Theorem 1 as ``A_ub z <= b_ub`` over z = [gamma, c_V, alpha_W, alpha_V].

    With ``centers="zero"`` (the paper's Appendix A) gamma and c_V are fixed to 0;
    ``"free"``: c_W = G'_W gamma lies in the disturbance directions and c_V is free.
    """
    n, ny = plant.A.shape[0], plant.C.shape[0]
    pw, pv = plant.Gw.shape[1], plant.Gv.shape[1]
    # xi = T z
    T = np.zeros((n + ny + pw + pv, pw + ny + pw + pv))
    T[:n, :pw] = plant.Gw
    T[n:n + ny, pw:pw + ny] = np.eye(ny)
    T[n + ny:, pw + ny:] = np.eye(pw + pv)
    K = len(thm.Dp) - 1 if horizon is None else horizon
    rows, rhs = [], []
    for k in range(K + 1):
        for D, lhs in ((thm.Dp[k], devs.maxp[k]), (thm.Dm[k], devs.maxm[k])):
            ok = np.isfinite(lhs)
            rows.append(-(D @ T)[ok])
            rhs.append(-lhs[ok])
    A_ub, b_ub = np.vstack(rows), np.concatenate(rhs)
    bounds = [(None, None)] * (pw + ny) + [(0, None)] * (pw + pv)
    if centers == "zero":
        bounds[:pw + ny] = [(0, 0)] * (pw + ny)
    elif centers != "free":
        raise ReachsetError(f"centers must be 'zero' or 'free', not {centers!r}")
    return A_ub, b_ub, bounds, T


def set_norm_cost(plant, weights=None):
    """Cost vector of the separate approach ||W|| + ||V|| (interval-hull edge lengths), over alpha."""
    cw = 2.0 * np.abs(plant.Gw).sum(axis=0)
    cv = 2.0 * np.abs(plant.Gv).sum(axis=0)
    c = np.concatenate([cw, cv])
    if weights is not None:
        c = c * np.asarray(weights, dtype=np.float64)
    return c


def make_sound(plant, thm, devs, c_w, c_v, alpha_w, alpha_v):
    """Inflate alpha_V (else alpha_W) until every Theorem-1 inequality holds in floating point.

    LP solvers satisfy constraints only to a tolerance (HiGHS: 1e-7 primal feasibility);
    this closes that gap so that the identified model has zero violations on its own data
    when evaluated with :meth:`Theorem1.offsets`, exactly as ``check`` and the monitor do.
    Returns the new alpha_W, alpha_V and the total added.
    """
    aw, av = np.array(alpha_w, float), np.array(alpha_v, float)
    bumped = 0.0
    for _ in range(60):
        xi = xi_of(c_w, c_v, aw, av)
        worst, coef = 0.0, None
        for k, (dp, dm) in enumerate(thm.offsets(xi)):
            for D, d, lhs in ((thm.Dp[k], dp, devs.maxp[k]), (thm.Dm[k], dm, devs.maxm[k])):
                viol = lhs - d
                j = int(np.argmax(viol))
                if np.isfinite(viol[j]) and viol[j] > worst - 0.0 and viol[j] > 0:
                    if viol[j] > worst:
                        worst = viol[j]
                        coef = D[j]
        if worst <= 0.0:
            return aw, av, bumped
        npw = plant.Gw.shape[1]
        cv = coef[-av.size:] if av.size else np.zeros(0)
        if av.size and cv.sum() > 0:
            step = worst / cv.sum() * (1 + 1e-6) + 1e-15
            av = av + step
        else:
            cw = coef[-(av.size + npw):len(coef) - av.size]
            if cw.sum() <= 0:
                raise InfeasibleError("conformance cannot be restored: a deviation is in a direction "
                                      "no disturbance generator reaches")
            step = worst / cw.sum() * (1 + 1e-6) + 1e-15
            aw = aw + step
        bumped += step
    raise InfeasibleError("conformance could not be restored after 60 inflation steps")


def identify(plant, thm, devs, *, centers="zero", weights=None, alpha_lower=None, horizon=None):
    """Reachset-conformant identification as a linear programme (HiGHS).

    Minimises ||W|| + ||V|| (the paper's separate approach, Sec. IV-B; optional per-alpha
    ``weights``) subject to Theorem 1 for k = 0..horizon, alpha >= ``alpha_lower``.

    Returns
    -------
    IdentifiedSets
    """
    A_ub, b_ub, bounds, T = identification_constraints(plant, thm, devs, horizon, centers)
    pw, pv, ny = plant.Gw.shape[1], plant.Gv.shape[1], plant.C.shape[0]
    c = np.concatenate([np.zeros(pw + ny), set_norm_cost(plant, weights)])
    if alpha_lower is not None:
        lo = np.broadcast_to(np.asarray(alpha_lower, float), (pw + pv,))
        for i in range(pw + pv):
            bounds[pw + ny + i] = (float(lo[i]), None)
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
    if res.status != 0:
        raise InfeasibleError(f"identification LP failed: {res.message}")
    z = res.x
    xi = T @ z
    n = plant.A.shape[0]
    c_w, c_v = xi[:n], xi[n:n + ny]
    aw, av = np.maximum(z[pw + ny:pw + ny + pw], 0.0), np.maximum(z[pw + ny + pw:], 0.0)
    aw, av, bump = make_sound(plant, thm, devs, c_w, c_v, aw, av)
    cost = float(set_norm_cost(plant, weights) @ np.concatenate([aw, av]))
    return IdentifiedSets(c_w, c_v, aw, av, cost, bump)


def stable_horizon(plant, thm, devs, rtol=0.01, **kw):
    """Remark 3: the smallest horizon beyond which the identified alphas change < rtol.

    Identifies for k* on a grid up to the full horizon; returns (k, table) where table
    lists (k*, alpha_W, alpha_V).
    """
    K = len(thm.Dp) - 1
    grid = sorted({k for k in (0, 1, 2, 5, 10, 25, 50, 75, 100, 125, 150, 200, 250) if k <= K} | {K})
    table = []
    for k in grid:
        s = identify(plant, thm, devs, horizon=k, **kw)
        table.append((k, s.alpha_w.tolist(), s.alpha_v.tolist()))
    final = np.concatenate([table[-1][1], table[-1][2]])
    scale = np.maximum(np.abs(final), 1e-12)
    settled = K
    for k, aw, av in reversed(table):
        if np.all(np.abs(np.concatenate([aw, av]) - final) <= rtol * scale):
            settled = k
        else:
            break
    return settled, table


# ------------------------------------------------------------------ batch check
@dataclass(frozen=True)
class CheckResult:
    """Verdict of a batch conformance check of one joint."""

    violations: int               # measurement ticks at which some test case is outside
    first_violation_tick: int     # index into the series (-1 if none)
    test_cases: int
    checks: int
    worst_margin: float           # min over all checks of (offset - N y_a); < 0 = violated


def check(plant, thm, estimator, xi, y, u, segments, horizon):
    """Theorem-1 check of every (test case, k) pair; counts violating measurement ticks."""
    offs = thm.offsets(xi)
    T = len(as_2d(y))
    bad = np.zeros(T, dtype=bool)
    stats = {"checks": 0, "margin": np.inf}

    def visit(k, m, t, ya):
        N = thm.normals[k]
        Ny = matvec(N, ya)
        dp, dm = offs[k]
        mp = dp[:, None] - Ny
        mm = dm[:, None] + Ny
        viol = (mp < 0).any(axis=0) | (mm < 0).any(axis=0)
        bad[t[viol]] = True
        stats["checks"] += ya.shape[1]
        stats["margin"] = min(stats["margin"], float(mp.min()), float(mm.min()))

    M = sweep(plant, estimator, y, u, segments, horizon, visit)
    idx = np.flatnonzero(bad)
    return CheckResult(int(bad.sum()), int(idx[0]) if len(idx) else -1, M, stats["checks"],
                       stats["margin"])
