"""Reachset conformance: test cases, deviations y_a, Theorem 1, identification, checking.

Paper Sec. II-B (Defs. 2-4) and III-B. For sequential test cases (Def. 3) starting at
every valid tick m of a recording, the deviation of the measurement from the nominal
prediction (eq. 12)

    y_a^(m)[k] = y[m+k] - y_*^(m)[k],   y_*^(m)[k] = C x_*^(m)[k] + D u[m+k],
    x_*^(m)[0] = x0(m) (an :class:`~reachset_ros.conformance.estimators.Estimator`),
    x_*^(m)[k+1] = A x_*^(m)[k] + B u[m+k],

must lie in R_a[k] = (+)_{i<k} C A^i W (+) V (eq. 13). Theorem 1 writes this as
``max_m N_k y_a^(m)[k] <= D_k xi`` with xi = [c_W, c_V, alpha_W, alpha_V], linear in xi,
where the normals N_k come from the H-representation of R_a[k] built from the *unscaled*
generators (they do not depend on alpha > 0).

All arithmetic on the nominal trajectories uses the element-wise :func:`matvec`, so the
batch sweep here and the online monitor (:mod:`reachset_ros.conformance.monitor`), which advances one
tick at a time, produce bitwise identical deviations and hence identical verdicts.
"""
from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from . import compiled
from ..errors import InfeasibleError, ReachsetError


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
    return matvec_into(_plan(M), X, np.empty((M.shape[0], X.shape[1])))


def matvec_into(plan, X, out):
    """:func:`matvec` with a precomputed ``_plan(M)`` into a preallocated ``out`` (same arithmetic)."""
    for i, row in enumerate(plan):
        if not row:
            out[i] = 0.0
            continue
        j, a = row[0]
        if a == 1.0:
            out[i] = X[j]
        else:
            np.multiply(a, X[j], out=out[i])
        for j, a in row[1:]:
            if a == 1.0:
                out[i] += X[j]
            else:
                out[i] += a * X[j]
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


def require_horizon(series, history, horizon, bags):
    """Exit cleanly unless some test case of every joint reaches step k* = ``horizon``.

    A test case starting at tick m needs ``history`` ticks before it and ``horizon`` after
    it, all in one segment (consecutive valid ticks).
    """
    need = history + horizon + 1
    for name, s in series.items():
        longest = max((b - a for a, b in s.segments), default=0)
        if longest < need:
            raise ReachsetError(f"{', '.join(map(str, bags))}: joint {name}: too few samples for horizon {horizon}: "
                                f"the longest run of consecutive valid ticks has {longest}, a test case needs {need}")


def sweep(plant, estimator, y, u, segments, horizon, visit, block=16384):
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
        Called once per k and block of test cases; visitors accumulate.
    block : int
        Test cases processed together (memory locality only; results are identical).

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
    # Blocks of test cases keep the working set in cache; every column's arithmetic is the
    # same whatever the block, so results do not depend on the block size.
    for b in range(0, len(starts), block):
        _sweep_block(plant, estimator, y, u, starts[b:b + block], rem[b:b + block], horizon, visit)
    return len(starts)


def _sweep_block(plant, estimator, y, u, starts, rem, horizon, visit):
    X = estimator.estimate(plant, y, u, starts)
    if compiled.LIB is not None and plant.A.shape[0] <= 64 and plant.B.shape[1] <= 64:
        return _sweep_block_compiled(plant, y, u, starts, rem, horizon, visit, X)
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


def _sweep_block_compiled(plant, y, u, starts, rem, horizon, visit, X):
    """:func:`_sweep_block` with the deviations computed by the compiled kernel (bitwise equal)."""
    M, ny = len(starts), plant.C.shape[0]
    K = int(min(horizon, rem.max() - 1))
    f8 = lambda a: np.ascontiguousarray(a, dtype=np.float64)   # noqa: E731
    A, B, C, D = f8(plant.A), f8(plant.B), f8(plant.C), f8(plant.D)
    y, u, X = f8(y), f8(u), f8(X)
    starts, rem = np.ascontiguousarray(starts, np.int64), np.ascontiguousarray(rem, np.int64)
    ya = np.empty((K + 1, ny, M))
    p = compiled.ptr
    rc = compiled.LIB.reachset_sweep_block(p(A), p(B), p(C), p(D), int(bool(np.any(plant.D))), A.shape[0], B.shape[1],
                                         ny, p(y), p(u), p(starts), p(rem), M, K, p(X), p(ya))
    if rc != 0:
        raise RuntimeError("reachset_sweep_block failed")
    for k in range(K + 1):
        Mk = int(np.searchsorted(-rem, -k, side="left"))  # rem > k, rem sorted descending
        if Mk == 0:
            break
        m = starts[:Mk]
        visit(k, m, m + k, ya[k, :, :Mk])


# ------------------------------------------------------------------ Theorem 1
def output_normals(plant, horizon):
    """Unit normals N_k^+ of R_a[k] for k = 0..horizon (Theorem 1), shape (q_k, ny) each.

    For a one-dimensional output N_k^+ = [[1]]. Otherwise the facet normals of the zonotope
    with the unscaled generators [C A^0 G'_W, ..., C A^{k-1} G'_W, G'_V] (Prop. 1).
    """
    ny = plant.C.shape[0]
    if ny == 1:
        return [np.ones((1, 1))] * (horizon + 1)
    from ..sets.zonotope import halfspace_normals
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
        hi, lo = Ny.max(axis=1), (-Ny).max(axis=1)
        maxp[k] = hi if maxp[k] is None else np.maximum(maxp[k], hi)
        maxm[k] = lo if maxm[k] is None else np.maximum(maxm[k], lo)
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


def deviation_extremes_many(plant, estimator, series, horizon, thm=None, workers=None):
    """:func:`deviation_extremes` of several joints, in threads (one per core by default).

    ``series``: {name: object with ``y``, ``u``, ``segments``}. The compiled sweep kernel
    releases the GIL, so joints run in parallel; each joint's result is the one
    :func:`deviation_extremes` gives on its own. A ReachsetError names the first failing
    joint in ``series`` order.
    """
    from concurrent.futures import ThreadPoolExecutor
    thm = thm or Theorem1.build(plant, horizon)
    names = list(series)
    workers = workers or min(len(names), os.cpu_count() or 1)

    def one(name):
        s = series[name]
        try:
            return deviation_extremes(plant, estimator, s.y, s.u, s.segments, horizon, thm)
        except ReachsetError as e:
            return ReachsetError(f"joint {name}: {e}")

    if workers <= 1 or len(names) <= 1:
        res = [one(n) for n in names]
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            res = list(pool.map(one, names))
    for r in res:
        if isinstance(r, ReachsetError):
            raise r
    return dict(zip(names, res))


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


# ================================================================== Corollary 1
# The conservative, state-based variant (paper Corollary 1, Remarks 2-3). For sequential
# test cases with estimated initial states x^(m)[0] (the model's Estimator), the one-step
# state deviations and the output residuals
#
#     x_a^(m)[1] = x^(m+1)[0] - (A x^(m)[0] + B u[m])      must lie in  W,
#     v^(m)      = y[m] - C x^(m)[0] - D u[m]              must lie in  V.
#
# Then y_a^(m)[k] = v^(m+k) + C sum_{i<k} A^{k-1-i} x_a^(m+i)[1] (a telescoping identity,
# exact for *any* estimator) lies in R_a[k] for every k, so no horizon k* is needed
# (Remark 3). The containments are linear in the same xi: with the facet normals N of the
# zonotope of the unscaled generators (Prop. 1), ``x in (c, G diag(alpha))`` iff
# ``|N (x - c)| <= |N G| alpha`` for the normals inside span(G), and ``N_perp (x - c) = 0``
# for an orthonormal basis N_perp of span(G)'s orthogonal complement (G not of full row
# rank, e.g. the LWA-4P plant's G'_W spans 2 of 5 state directions).
@dataclass(frozen=True)
class StateDeviations:
    """The data of Corollary 1 for one recording.

    Attributes
    ----------
    xa : ndarray, shape (n, P)
        x_a^(m)[1] for the P start ticks ``xa_ticks`` whose successor m+1 starts a test case
        in the same segment.
    xa_scale : ndarray, shape (P,)
        max(||x^(m+1)[0]||_inf, ||A x^(m)[0] + B u[m]||_inf, 1): the size of the two terms
        whose difference is x_a, for the relative tolerance of the equality constraints.
    v : ndarray, shape (ny, M)
        y[m] - C x^(m)[0] - D u[m] for all M start ticks ``v_ticks``.
    v_scale : ndarray, shape (M,)
    """

    xa: np.ndarray
    xa_ticks: np.ndarray
    xa_scale: np.ndarray
    v: np.ndarray
    v_ticks: np.ndarray
    v_scale: np.ndarray

    @property
    def test_cases(self):
        return int(self.v.shape[1])


def state_deviations(plant, estimator, y, u, segments):
    """Corollary 1's x_a^(m)[1] and v^(m) for all sequential test cases of a recording."""
    y, u = as_2d(y), as_2d(u)
    starts, ends = test_case_starts(segments, estimator.history)
    if len(starts) == 0:
        raise ReachsetError("too few samples for a test case (need at least "
                            f"{estimator.history + 1} consecutive valid ticks)")
    X = estimator.estimate(plant, y, u, starts)
    Y0 = predict_output(plant, X, u[starts].T)
    v = y[starts].T - Y0
    v_scale = np.maximum(np.maximum(np.abs(y[starts]).max(axis=1), np.abs(Y0).max(axis=0)), 1.0)
    i = np.flatnonzero((starts[1:] == starts[:-1] + 1) & (ends[1:] == ends[:-1]))
    nxt = advance(plant, X[:, i], u[starts[i]].T)
    xa = X[:, i + 1] - nxt
    xa_scale = np.maximum(np.maximum(np.abs(X[:, i + 1]).max(axis=0, initial=0.0),
                                     np.abs(nxt).max(axis=0, initial=0.0)), 1.0)
    return StateDeviations(xa, starts[i], xa_scale, v, starts, v_scale)


def _split_normals(G, tol=1e-10):
    """Facet normals of (0, G) inside span(G) and the orthonormal complement rows."""
    from ..sets.zonotope import halfspace_normals
    N = halfspace_normals(G)
    reach = np.abs(N @ G).sum(axis=1)
    inside = reach > tol * max(float(reach.max(initial=0.0)), 1e-300)
    return N[inside], N[~inside]


def _direction_text(n, names):
    parts = [f"{c:+.3g}*{names[i]}" for i, c in enumerate(n) if abs(c) > 1e-6]
    return " ".join(parts) if parts else "0"


def corollary1_constraints(plant, sdev, centers="zero", rtol=1e-9, atol=1e-12, estimator_name="?"):
    """Corollary 1 as ``A_ub z <= b_ub`` over z = [gamma, c_V, alpha_W, alpha_V].

    Same variables as :func:`identification_constraints` (c_W = G'_W gamma). The directions
    orthogonal to span(G'_W) carry equality constraints ``N_perp x_a = 0`` (c_W lies in
    span(G'_W)); they are data checks, not LP rows, and hold when every
    ``|N_perp x_a| <= atol + rtol * xa_scale`` (a residual that small is floating-point
    rounding of the nominal step). Otherwise :class:`InfeasibleError` names the test case,
    the state direction and the size of the residual. The same for span(G'_V) and v, where
    with ``centers="free"`` the complement part of c_V absorbs a common offset.
    """
    n, ny = plant.A.shape[0], plant.C.shape[0]
    pw, pv = plant.Gw.shape[1], plant.Gv.shape[1]
    if centers not in ("zero", "free"):
        raise ReachsetError(f"centers must be 'zero' or 'free', not {centers!r}")
    T = np.zeros((n + ny + pw + pv, pw + ny + pw + pv))
    T[:n, :pw] = plant.Gw
    T[n:n + ny, pw:pw + ny] = np.eye(ny)
    T[n + ny:, pw + ny:] = np.eye(pw + pv)
    nz = pw + ny + pw + pv
    rows, rhs = [], []

    # ---- W: x_a^(m)[1] in (G'_W gamma, G'_W diag alpha_W)
    NW, PW = _split_normals(plant.Gw)
    if sdev.xa.shape[1]:
        if PW.shape[0]:
            R = PW @ sdev.xa
            tol = atol + rtol * sdev.xa_scale
            ratio = np.abs(R) / tol
            j, c = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
            if ratio[j, c] > 1.0:
                bad = int(np.count_nonzero((ratio > 1.0).any(axis=0)))
                raise InfeasibleError(
                    f"Corollary 1 infeasible: x_a[1] of the test case starting at tick "
                    f"{int(sdev.xa_ticks[c])} has a component {R[j, c]:.3g} along the state direction "
                    f"[{_direction_text(PW[j], plant.state_names)}] that no generator of G'_W reaches "
                    f"(tolerance {tol[c]:.3g}; {bad} of {sdev.xa.shape[1]} test cases exceed it): "
                    f"the initial-state estimator '{estimator_name}' is not consistent with the model "
                    f"in that direction; use Theorem 1")
        if NW.shape[0]:
            NX = NW @ sdev.xa
            D = np.abs(NW @ plant.Gw)
            NG = NW @ plant.Gw
            blk = np.zeros((NW.shape[0], nz))
            # N x_a <= N G gamma + |N G| alpha_W  and  -N x_a <= -N G gamma + |N G| alpha_W
            for sgn, lhs in ((1.0, NX.max(axis=1)), (-1.0, (-NX).max(axis=1))):
                r = blk.copy()
                r[:, :pw] = -sgn * NG
                r[:, pw + ny:pw + ny + pw] = -D
                rows.append(r)
                rhs.append(-lhs)

    # ---- V: v^(m) in (c_V, G'_V diag alpha_V)
    NV, PV = _split_normals(plant.Gv)
    if PV.shape[0]:
        R = PV @ sdev.v
        tol = atol + rtol * sdev.v_scale
        if centers == "free":   # a common offset along PV is absorbed by c_V
            mid = 0.5 * (R.max(axis=1) + R.min(axis=1))
            R = R - mid[:, None]
        ratio = np.abs(R) / tol
        j, c = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        if ratio[j, c] > 1.0:
            raise InfeasibleError(
                f"Corollary 1 infeasible: the output residual y - C x0 - D u of the test case starting "
                f"at tick {int(sdev.v_ticks[c])} has a component {R[j, c]:.3g} along the output direction "
                f"[{_direction_text(PV[j], plant.output_names)}] that no generator of G'_V reaches "
                f"(tolerance {tol[c]:.3g})")
        if centers == "free":
            r = np.zeros((PV.shape[0], nz))
            r[:, pw:pw + ny] = PV
            PVv = PV @ sdev.v
            tmax = float(tol.max())
            rows += [r, -r]
            rhs += [PVv.min(axis=1) + tmax, -(PVv.max(axis=1) - tmax)]
    if NV.shape[0]:
        NVv = NV @ sdev.v
        D = np.abs(NV @ plant.Gv)
        for sgn, lhs in ((1.0, NVv.max(axis=1)), (-1.0, (-NVv).max(axis=1))):
            r = np.zeros((NV.shape[0], nz))
            r[:, pw:pw + ny] = -sgn * NV
            r[:, pw + ny + pw:] = -D
            rows.append(r)
            rhs.append(-lhs)
    A_ub = np.vstack(rows) if rows else np.zeros((0, nz))
    b_ub = np.concatenate(rhs) if rhs else np.zeros(0)
    bounds = [(None, None)] * (pw + ny) + [(0, None)] * (pw + pv)
    if centers == "zero":
        bounds[:pw + ny] = [(0, 0)] * (pw + ny)
    return A_ub, b_ub, bounds, T


def _inflate_rows(A_ub, b_ub, z, first_alpha):
    """Raise the alphas (columns >= first_alpha) until ``A_ub z <= b_ub`` holds in floating point.

    Alpha coefficients of the rows are <= 0, so raising an alpha never breaks another row.
    Returns the new z and the total added.
    """
    z = np.array(z, float)
    bumped = 0.0
    for _ in range(60):
        viol = A_ub @ z - b_ub
        j = int(np.argmax(viol)) if viol.size else 0
        if not viol.size or viol[j] <= 0.0:
            return z, bumped
        coef = -A_ub[j, first_alpha:]
        if coef.max() <= 0.0:
            raise InfeasibleError("Corollary 1: a constraint without disturbance generators is violated "
                                  f"by {viol[j]:.3g}")
        k = int(np.argmax(coef))
        step = viol[j] / coef[k] * (1 + 1e-6) + 1e-15
        z[first_alpha + k] += step
        bumped += step
    raise InfeasibleError("Corollary 1: constraints could not be restored after 60 inflation steps")


def identify_corollary1(plant, estimator, y, u, segments, *, centers="zero", weights=None,
                        alpha_lower=None, rtol=1e-9, atol=1e-12, horizon=None, thm=None):
    """Conservative state-based identification (paper Corollary 1) as a linear programme.

    Minimises ||W|| + ||V|| (as :func:`identify`) subject to x_a^(m)[1] in W and
    y[m] - C x^(m)[0] - D u[m] in V for all sequential test cases of the recording, with
    x^(m)[0] from ``estimator``. The result is reachset conformant for every k (no k*,
    Remark 3) and more conservative than Theorem 1 (Remark 2): its feasible set is contained
    in Theorem 1's for every horizon, so its cost is >= :func:`identify`'s.

    Feasibility needs every x_a in c_W + span(G'_W): directions orthogonal to it must vanish
    up to ``atol + rtol * scale`` (see :func:`corollary1_constraints`), i.e. the estimator
    must be consistent with the model there. Otherwise :class:`InfeasibleError` names the
    test case, the state direction and the residual. (The per-joint LWA-4P plant with the
    ``fd`` estimator on noisy data is such a case: measurement noise puts x_a outside the
    velocity/acceleration directions of G'_W.)

    Floating point: the LP solution is inflated until every Corollary-1 row holds exactly;
    with ``horizon`` (or ``thm``) given, :func:`make_sound` then also closes any rounding gap
    of the Theorem-1 check for k = 0..horizon, so :func:`check` reports zero violations.

    Parameters
    ----------
    plant : LinearPlant
    estimator : Estimator
    y, u : ndarray, shape (T, ny), (T, nu)
    segments : sequence of (start, stop)
    centers : "zero" | "free"
    weights, alpha_lower : as :func:`identify`
    rtol, atol : float
        Tolerance of the equality constraints outside span(G'_W) / span(G'_V).
    horizon : int, optional
    thm : Theorem1, optional

    Returns
    -------
    IdentifiedSets
        ``soundness_bump``: total alpha added after the LP (Corollary rows, then Theorem 1).
    """
    sdev = state_deviations(plant, estimator, y, u, segments)
    A_ub, b_ub, bounds, T = corollary1_constraints(plant, sdev, centers, rtol, atol,
                                                   getattr(estimator, "name", "?"))
    pw, pv, ny = plant.Gw.shape[1], plant.Gv.shape[1], plant.C.shape[0]
    cost = set_norm_cost(plant, weights)
    c = np.concatenate([np.zeros(pw + ny), cost])
    if alpha_lower is not None:
        lo = np.broadcast_to(np.asarray(alpha_lower, float), (pw + pv,))
        for i in range(pw + pv):
            bounds[pw + ny + i] = (float(lo[i]), None)
    res = linprog(c, A_ub=A_ub if A_ub.size else None, b_ub=b_ub if b_ub.size else None,
                  bounds=bounds, method="highs")
    if res.status != 0:
        raise InfeasibleError(f"Corollary 1 LP failed: {res.message}")
    z = res.x.copy()
    z[pw + ny:] = np.maximum(z[pw + ny:], [b[0] for b in bounds[pw + ny:]])
    for i, (lo_, hi_) in enumerate(bounds[:pw + ny]):
        if lo_ == hi_ == 0:
            z[i] = 0.0
    z, bump = _inflate_rows(A_ub, b_ub, z, pw + ny) if A_ub.size else (z, 0.0)
    xi = T @ z
    n = plant.A.shape[0]
    c_w, c_v = xi[:n], xi[n:n + ny]
    aw, av = z[pw + ny:pw + ny + pw], z[pw + ny + pw:]
    if thm is not None or horizon is not None:
        K = horizon if horizon is not None else len(thm.Dp) - 1
        thm = thm or Theorem1.build(plant, K)
        devs = deviation_extremes(plant, estimator, y, u, segments, K, thm)
        aw, av, b2 = make_sound(plant, thm, devs, c_w, c_v, aw, av)
        bump += b2
    return IdentifiedSets(c_w, c_v, np.array(aw, float), np.array(av, float),
                          float(cost @ np.concatenate([aw, av])), float(bump))


# ================================================================== quadratic cost
def frobenius_weights(plant):
    """Per-alpha weights of ||G'_W diag alpha_W||_F^2 + ||G'_V diag alpha_V||_F^2 (column norms^2)."""
    return np.concatenate([(plant.Gw ** 2).sum(axis=0), (plant.Gv ** 2).sum(axis=0)])


def identify_quadratic(plant, thm, devs, *, centers="zero", alpha_lower=None, horizon=None,
                       eps=1e-8, max_iter=100_000):
    """Identification with the quadratic cost ||G'_W diag a_W||_F^2 + ||G'_V diag a_V||_F^2.

    Same Theorem-1 constraints as :func:`identify` (:func:`identification_constraints`),
    solved as a QP with OSQP through cvxpy. The problem is scaled before solving (variables
    by their constraint-column norms, data by the largest right-hand side; OSQP's absolute
    tolerance is otherwise far above alpha_V of a real robot) and OSQP's result, accurate
    only to its tolerance (``eps`` on the scaled problem, relaxed by factors of 100 up to 1e-5
    if OSQP does not converge; solution polishing on), is passed through :func:`make_sound`,
    so that the returned sets have zero violations on the data in floating point.

    Returns
    -------
    IdentifiedSets
        ``cost``: the Frobenius objective of the returned (sound) alphas.
    """
    import cvxpy as cp
    A_ub, b_ub, bounds, T = identification_constraints(plant, thm, devs, horizon, centers)
    pw, pv, ny = plant.Gw.shape[1], plant.Gv.shape[1], plant.C.shape[0]
    na = pw + pv
    lo = np.zeros(na)
    if alpha_lower is not None:
        lo = np.array(np.broadcast_to(np.asarray(alpha_lower, float), (na,)))
    free = [i for i, b in enumerate(bounds) if b != (0, 0)]      # variables that are not fixed at 0
    A = A_ub[:, free]
    col = np.abs(A).max(axis=0)
    col[col == 0] = 1.0
    beta = max(float(np.abs(b_ub).max(initial=0.0)), float(np.abs(lo).max(initial=0.0) * col.max()), 1e-300)
    An = A / col                       # z_free = zhat * beta / col
    bn = b_ub / beta
    nf = len(free)
    wq = np.zeros(nf)
    alpha_pos = {i: free.index(i) for i in range(pw + ny, pw + ny + na) if i in free}
    fw = frobenius_weights(plant)
    for i, f in alpha_pos.items():
        wq[f] = fw[i - pw - ny] / col[f] ** 2
    wq = wq / max(wq.max(), 1e-300)
    zh = cp.Variable(nf)
    cons = [An @ zh <= bn]
    for i, f in alpha_pos.items():
        cons.append(zh[f] >= lo[i - pw - ny] * col[f] / beta)
    prob = cp.Problem(cp.Minimize(cp.sum(cp.multiply(wq, cp.square(zh)))), cons)
    status, tol = None, float(eps)
    while True:   # ADMM may not reach a tight tolerance: relax it (make_sound closes the gap)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                prob.solve(solver=cp.OSQP, eps_abs=tol, eps_rel=tol, max_iter=max_iter, polishing=True,
                           verbose=False)
            status = prob.status
        except cp.error.SolverError as e:
            status = f"solver error ({e})"
        if status in ("infeasible", "infeasible_inaccurate"):
            raise InfeasibleError("quadratic identification: the Theorem-1 constraints are infeasible")
        if status == "optimal" and zh.value is not None:
            break
        if tol >= 1e-5:
            if status == "optimal_inaccurate" and zh.value is not None:
                break
            raise InfeasibleError(f"quadratic identification: OSQP status {status}")
        tol *= 100.0
    z = np.zeros(A_ub.shape[1])
    z[free] = np.asarray(zh.value) * beta / col
    xi = T @ z
    n = plant.A.shape[0]
    c_w, c_v = xi[:n], xi[n:n + ny]
    aw = np.maximum(z[pw + ny:pw + ny + pw], lo[:pw])
    av = np.maximum(z[pw + ny + pw:], lo[pw:])
    aw, av, bump = make_sound(plant, thm, devs, c_w, c_v, aw, av)
    cost = float(frobenius_weights(plant) @ np.concatenate([aw, av]) ** 2)
    return IdentifiedSets(c_w, c_v, aw, av, cost, float(bump))


# ================================================================== held-out validation
@dataclass(frozen=True)
class CaseCheck:
    """A batch check (as :class:`CheckResult`) that also counts violated test cases."""

    violations: int               # measurement ticks at which some test case is outside
    first_violation_tick: int
    violated_test_cases: int      # test cases (start ticks) with a violation at some k
    test_cases: int               # = checked measurement ticks (each valid tick starts one)
    checks: int
    worst_margin: float
    bad: np.ndarray               # bool (T,): violating measurement ticks


def check_many(plant, thm, estimator, xis, y, u, segments, horizon):
    """:func:`check` for several parameter vectors in one sweep (same arithmetic, same verdicts).

    Every measurement tick after a segment's estimator history starts a test case and is
    checked at k = 0, so ``test_cases`` is also the number of checked ticks.
    """
    offs = [thm.offsets(np.asarray(x, float)) for x in xis]
    T = len(as_2d(y))
    bad = [np.zeros(T, dtype=bool) for _ in xis]
    badm = [np.zeros(T, dtype=bool) for _ in xis]
    margin = [np.inf] * len(xis)
    checks = [0]

    def visit(k, m, t, ya):
        Ny = matvec(thm.normals[k], ya)
        checks[0] += ya.shape[1]
        for i, o in enumerate(offs):
            dp, dm = o[k]
            mp = dp[:, None] - Ny
            mm = dm[:, None] + Ny
            viol = (mp < 0).any(axis=0) | (mm < 0).any(axis=0)
            bad[i][t[viol]] = True
            badm[i][m[viol]] = True
            margin[i] = min(margin[i], float(mp.min()), float(mm.min()))

    M = sweep(plant, estimator, y, u, segments, horizon, visit)
    out = []
    for i in range(len(xis)):
        idx = np.flatnonzero(bad[i])
        out.append(CaseCheck(int(bad[i].sum()), int(idx[0]) if len(idx) else -1,
                             int(badm[i].sum()), M, checks[0], margin[i], bad[i]))
    return out


def inject_acceleration_fault(y, segments, onset, accel, dt):
    """Test fault: a constant acceleration ``accel`` (rad/s^2) from tick ``onset`` on.

    The measured position gets the double integrator of the disturbance,
    ``y[t] += accel/2 * ((t - onset) dt)^2`` for ``onset <= t < end`` of the segment that
    contains ``onset`` (the recorded inputs are unchanged). Returns a new array.
    """
    y = np.array(as_2d(y), float, copy=True)
    for s, e in segments:
        if s <= onset < e:
            tt = (np.arange(onset, e) - onset) * dt
            y[onset:e] += 0.5 * accel * tt[:, None] ** 2
            return y
    raise ReachsetError(f"fault onset tick {onset} is not in a valid segment")


def fault_onset_tick(segments, history):
    """Default onset: the middle of the longest segment's checked ticks."""
    s, e = max(segments, key=lambda se: se[1] - se[0])
    if e - s - history < 2:
        raise ReachsetError("validation data too short to inject a test fault")
    return s + history + (e - s - history) // 2


def detection_delay(plant, thm, estimator, xi, y, u, segments, horizon, accel, dt, onset=None):
    """Ticks from a test fault's onset to the first violation (see :func:`inject_acceleration_fault`).

    Returns a dict: ``onset_tick``, ``accel``, ``detected``, ``delay_ticks`` and ``delay_s``
    (None if not detected before the segment ends), ``alarms_before_onset`` (violating
    ticks before the onset; the fault changes nothing there).
    """
    y = as_2d(y)
    onset = fault_onset_tick(segments, estimator.history) if onset is None else int(onset)
    yf = inject_acceleration_fault(y, segments, onset, accel, dt)
    r = check_many(plant, thm, estimator, [xi], yf, u, segments, horizon)[0]
    after = np.flatnonzero(r.bad[onset:])
    d = int(after[0]) if len(after) else None
    return {"onset_tick": int(onset), "accel": float(accel), "detected": d is not None,
            "delay_ticks": d, "delay_s": None if d is None else d * float(dt),
            "alarms_before_onset": int(r.bad[:onset].sum())}


def validation_grid(plant, thm, estimator, joint_sets, y, u, segments, horizon, grid):
    """Held-out violation rates of one joint for inflations 0 and ``grid`` (one sweep).

    ``joint_sets`` is a :class:`~reachset_ros.conformance.model.JointSets`; inflation s checks with
    ``joint_sets.xi(s)`` exactly as ``reachset check`` would with the model's inflation s.
    Returns (rows, chosen, flagged): a row per inflation, the smallest grid inflation with no
    held-out violation (or the largest grid value, ``flagged=True``).
    """
    infl = sorted({0.0, *map(float, grid)})
    res = check_many(plant, thm, estimator, [joint_sets.xi(s) for s in infl], y, u, segments, horizon)
    rows = []
    for s, r in zip(infl, res):
        rows.append({"inflation": s, "violating_ticks": r.violations, "checked_ticks": r.test_cases,
                     "violation_rate": r.violations / r.test_cases if r.test_cases else 0.0,
                     "violated_test_cases": r.violated_test_cases, "test_cases": r.test_cases,
                     "first_violation_tick": r.first_violation_tick,
                     "worst_margin": r.worst_margin if r.checks else None})
    ok = [row["inflation"] for row in rows if row["violating_ticks"] == 0]
    if ok:
        return rows, ok[0], False
    return rows, infl[-1], True
