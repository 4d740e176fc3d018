"""Reachset-conformant identification of the disturbance sets W and V (Theorem 1).

Paper Sec. III-B and IV-B (the separate approach): find xi = [c_W, c_V, alpha_W, alpha_V]
minimising ||W|| + ||V|| (the zonotope norm: interval-hull edge lengths) subject to Theorem 1's
inequalities ``max_m N_k y_a^(m)[k] <= D_k xi`` for k = 0..k*
(:func:`identification_constraints`), as a linear programme (:func:`identify_sets`, HiGHS)
or with the quadratic cost ||G'_W diag a_W||_F^2 + ||G'_V diag a_V||_F^2
(:func:`identify_quadratic`, OSQP). :func:`make_sound` closes the solvers' feasibility
tolerance so that the identified sets have zero violations on their data in floating point;
:func:`stable_horizon` is Remark 3. The state-based variant (Corollary 1) is in
:mod:`~reachset_ros.conformance.corollary1`.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import InfeasibleError, ReachsetError
from .theorem1 import xi_of


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


def z_to_xi(plant):
    """The matrix T with xi = T z for the LP variables z = [gamma, c_V, alpha_W, alpha_V]
    (c_W = G'_W gamma lies in the disturbance directions)."""
    n, ny = plant.A.shape[0], plant.C.shape[0]
    pw, pv = plant.Gw.shape[1], plant.Gv.shape[1]
    T = np.zeros((n + ny + pw + pv, pw + ny + pw + pv))
    T[:n, :pw] = plant.Gw
    T[n:n + ny, pw:pw + ny] = np.eye(ny)
    T[n + ny:, pw + ny:] = np.eye(pw + pv)
    return T


def z_bounds(plant, centers):
    """Bounds of z = [gamma, c_V, alpha_W, alpha_V] for ``linprog``: alpha >= 0; gamma and c_V
    fixed to 0 (``centers="zero"``) or free (``"free"``)."""
    ny = plant.C.shape[0]
    pw, pv = plant.Gw.shape[1], plant.Gv.shape[1]
    bounds = [(None, None)] * (pw + ny) + [(0, None)] * (pw + pv)
    if centers == "zero":
        bounds[:pw + ny] = [(0, 0)] * (pw + ny)
    elif centers != "free":
        raise ReachsetError(f"centers must be 'zero' or 'free', not {centers!r}")
    return bounds


def identification_constraints(plant, thm, devs, horizon=None, centers="zero"):
    """Theorem 1 as ``A_ub z <= b_ub`` over z = [gamma, c_V, alpha_W, alpha_V].

    With ``centers="zero"`` (the paper's Appendix A) gamma and c_V are fixed to 0;
    ``"free"``: c_W = G'_W gamma lies in the disturbance directions and c_V is free.
    """
    T = z_to_xi(plant)   # xi = T z
    K = len(thm.Dp) - 1 if horizon is None else horizon
    rows, rhs = [], []
    for k in range(K + 1):
        for D, lhs in ((thm.Dp[k], devs.maxp[k]), (thm.Dm[k], devs.maxm[k])):
            ok = np.isfinite(lhs)
            rows.append(-(D @ T)[ok])
            rhs.append(-lhs[ok])
    A_ub, b_ub = np.vstack(rows), np.concatenate(rhs)
    return A_ub, b_ub, z_bounds(plant, centers), T


def set_norm_cost(plant, weights=None):
    """Cost vector of the separate approach ||W|| + ||V|| (interval-hull edge lengths), over alpha."""
    cw = 2.0 * np.abs(plant.Gw).sum(axis=0)
    cv = 2.0 * np.abs(plant.Gv).sum(axis=0)
    c = np.concatenate([cw, cv])
    if weights is not None:
        c = c * np.asarray(weights, dtype=np.float64)
    return c


def detection_cost(plant, thm, window=None):
    """Cost vector over alpha = [alpha_W, alpha_V] aimed at detection power (issue 35.2): the
    radii of the reachable output sets R_a[k] of Theorem 1 (eq. 13) summed over k = 0..window
    (default: the horizon of ``thm``), i.e. the alpha columns of ``D_k`` summed over the
    half-spaces' rows and steps. A fault is detected once the deviation it causes leaves
    R_a[k]; min ||W|| + ||V|| weighs every generator by its own size only and may leave large
    output sets (e.g. all of W on the generator whose set grows fastest); this weighs each
    generator by how much it widens the sets the monitor checks."""
    K = len(thm.Dp) - 1 if window is None else min(int(window), len(thm.Dp) - 1)
    n, ny = plant.A.shape[0], plant.C.shape[0]
    c = np.zeros(plant.Gw.shape[1] + plant.Gv.shape[1])
    for k in range(K + 1):
        c += thm.Dp[k][:, n + ny:].sum(axis=0) + thm.Dm[k][:, n + ny:].sum(axis=0)
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


def prefetch_solver():
    """Import the LP solver (``scipy.optimize``, 0.3 s) in a background thread and return it.

    ``reachset identify`` starts it before the Theorem-1 sweep, whose compiled kernel runs
    without the GIL, so the import overlaps the sweep instead of following it (issue 38.2).
    :func:`identify_sets` imports the module as before; Python's import lock makes it wait for
    a prefetch still running. The thread is a daemon: an error ends the command before it."""
    import importlib
    import threading
    t = threading.Thread(target=importlib.import_module, args=("scipy.optimize",), name="prefetch-scipy.optimize",
                         daemon=True)
    t.start()
    return t


def identify_sets(plant, thm, devs, *, centers="zero", weights=None, alpha_lower=None, horizon=None,
                  cost_vector=None):
    """Reachset-conformant identification as a linear programme (HiGHS).

    Minimises ||W|| + ||V|| (the paper's separate approach, Sec. IV-B; optional per-alpha
    ``weights``), or ``cost_vector @ alpha`` when given (e.g. :func:`detection_cost`),
    subject to Theorem 1 for k = 0..horizon, alpha >= ``alpha_lower``.

    Returns
    -------
    IdentifiedSets
    """
    A_ub, b_ub, bounds, T = identification_constraints(plant, thm, devs, horizon, centers)
    pw, pv, ny = plant.Gw.shape[1], plant.Gv.shape[1], plant.C.shape[0]
    cvec = set_norm_cost(plant, weights) if cost_vector is None else np.asarray(cost_vector, dtype=np.float64)
    c = np.concatenate([np.zeros(pw + ny), cvec])
    if alpha_lower is not None:
        lo = np.broadcast_to(np.asarray(alpha_lower, float), (pw + pv,))
        for i in range(pw + pv):
            bounds[pw + ny + i] = (float(lo[i]), None)
    from scipy.optimize import linprog  # lazy: 0.3 s of start-up (issue 38.1)
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
    if res.status != 0:
        raise InfeasibleError(f"identification LP failed: {res.message}")
    z = res.x
    xi = T @ z
    n = plant.A.shape[0]
    c_w, c_v = xi[:n], xi[n:n + ny]
    aw, av = np.maximum(z[pw + ny:pw + ny + pw], 0.0), np.maximum(z[pw + ny + pw:], 0.0)
    aw, av, bump = make_sound(plant, thm, devs, c_w, c_v, aw, av)
    cost = float(cvec @ np.concatenate([aw, av]))
    return IdentifiedSets(c_w, c_v, aw, av, cost, bump)


def stable_horizon(plant, thm, devs, rtol=0.01, **kw):
    """Remark 3: the smallest horizon beyond which the identified alphas change < rtol.

    On a grid of horizons up to the full one K: the smallest grid k* such that the alphas
    identified with k* and with every larger grid horizon are within ``rtol`` of those at K.
    The grid is walked down from K and stops at the first horizon whose alphas differ (the
    smaller ones cannot change the answer), so data whose sets still change near K cost two
    LPs, not one per grid point. Returns (k, table) where table lists (k*, alpha_W, alpha_V)
    of the horizons identified, in increasing k*.
    """
    K = len(thm.Dp) - 1
    grid = sorted({k for k in (0, 1, 2, 5, 10, 25, 50, 75, 100, 125, 150, 200, 250) if k <= K} | {K})
    table, final, scale, settled = [], None, None, K
    for k in reversed(grid):
        s = identify_sets(plant, thm, devs, horizon=k, **kw)
        table.insert(0, (k, s.alpha_w.tolist(), s.alpha_v.tolist()))
        alphas = np.concatenate([s.alpha_w, s.alpha_v])
        if final is None:
            final = alphas
            scale = np.maximum(np.abs(final), 1e-12)
        if not np.all(np.abs(alphas - final) <= rtol * scale):
            break
        settled = k
    return settled, table


# ================================================================== quadratic cost
def frobenius_weights(plant):
    """Per-alpha weights of ||G'_W diag alpha_W||_F^2 + ||G'_V diag alpha_V||_F^2 (column norms^2)."""
    return np.concatenate([(plant.Gw ** 2).sum(axis=0), (plant.Gv ** 2).sum(axis=0)])


def identify_quadratic(plant, thm, devs, *, centers="zero", alpha_lower=None, horizon=None,
                       eps=1e-8, max_iter=100_000):
    """Identification with the quadratic cost ||G'_W diag a_W||_F^2 + ||G'_V diag a_V||_F^2.

    Same Theorem-1 constraints as :func:`identify_sets` (:func:`identification_constraints`),
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
    import cvxpy as cp  # heavy optional dependency: only the quadratic cost needs it
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

