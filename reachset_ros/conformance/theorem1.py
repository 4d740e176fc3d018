"""Theorem 1: reachset conformance as linear inequalities in xi, and the batch check.

Paper Sec. III-B, Theorem 1 (``eq:methods:linearConstraint``). The deviations y_a^(m)[k]
of the sequential test cases (:mod:`~reachset_ros.conformance.kernels`) must lie in
R_a[k] = (+)_{i<k} C A^i W (+) V (eq. 13) for k = 0..k*. Theorem 1 writes this as
``max_m N_k y_a^(m)[k] <= D_k xi`` with xi = [c_W, c_V, alpha_W, alpha_V], linear in xi,
where the normals N_k come from the H-representation (Prop. 1) of R_a[k] built from the
*unscaled* generators (they do not depend on alpha > 0).

:class:`Theorem1` holds N_k and D_k; :func:`deviation_extremes` reduces all test cases of a
recording to the left-hand sides (one sweep); :func:`check` is Def. 4 checked in batch
(``reachset check``): it counts the measurement ticks at which some test case leaves
R_a[k].
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReachsetError
from ..sets.zonotope import halfspace_normals
from .estimators import pinned_states
from .kernels import as_2d, matvec, sweep, sweep_extremes


# ------------------------------------------------------------------ Theorem 1
def output_normals(plant, horizon):
    """Unit normals N_k^+ of R_a[k] for k = 0..horizon (Theorem 1), shape (q_k, ny) each.

    For a one-dimensional output N_k^+ = [[1]]. Otherwise the facet normals of the zonotope
    with the unscaled generators [C A^0 G'_W, ..., C A^{k-1} G'_W, G'_V] (Prop. 1).
    """
    ny = plant.C.shape[0]
    if ny == 1:
        return [np.ones((1, 1))] * (horizon + 1)
    out, E, blocks = [], np.eye(plant.A.shape[0]), []
    for k in range(horizon + 1):
        G = np.hstack(blocks + [plant.Gv]) if blocks else plant.Gv
        out.append(halfspace_normals(G))
        blocks.append(plant.C @ E @ plant.Gw)
        E = plant.A @ E
    return out


def initial_error_maps(plant, estimator, tol=1e-9):
    """How the estimator's initial-state error depends on the noise and disturbance samples it read.

    For an estimator that is exact on noise-free model data (``fd`` with ``d = 0``), the
    error of the test case's initial state is linear in the samples the estimator reads:
    with ``h = estimator.history`` and the model ``x[t+1] = A x[t] + B u[t] + w[t]``,
    ``y[t] = C x[t] + v[t]`` over ``t = m-h .. m``,

        x[m] - x_hat[m] = sum_{t<h} Sw[t] w[m-h+t] + sum_{t<=h} Sv[t] v[m-h+t].

    The maps are found by unit impulses through :meth:`Estimator.estimate` (the same code
    the sweep and the monitor run). Returns ``(Sw, Sv)``: lists of ``(n, n)`` and ``(n, ny)``
    arrays. Raises :class:`ReachsetError` if the estimator is not exact on noise-free model
    data (error above ``tol`` times the data's size): then no such linear map exists.
    """
    h = int(estimator.history)
    A, B, C = (np.asarray(getattr(plant, a), float) for a in ("A", "B", "C"))
    n, ny, nu = A.shape[0], C.shape[0], B.shape[1]
    T = h + 1
    try:                                      # the closed-loop sets hold these at zero
        pinned = list(pinned_states(plant))
    except ReachsetError:                     # not single coordinates: the exactness check decides
        pinned = []

    def error(x0, u, w, v, scale=False):
        X, y, x = np.zeros((T, n)), np.zeros((T, ny)), x0.copy()
        for t in range(T):
            X[t], y[t] = x, C @ x + v[t]
            x = A @ x + B @ u[t] + w[t]
        e = X[h] - estimator.estimate(plant, y, u, np.array([h]))[:, 0]
        return (e, max(1.0, np.abs(X).max(), np.abs(u).max())) if scale else e

    rng = np.random.default_rng(0)
    for _ in range(3):
        x0 = rng.standard_normal(n)
        x0[pinned] = 0.0
        e, size = error(x0, rng.standard_normal((T, nu)), np.zeros((T, n)), np.zeros((T, ny)), True)
        if np.abs(e).max() > tol * size:
            raise ReachsetError(f"the initial-state set needs an estimator that is exact on noise-free model data; "
                                f"{estimator.name!r} is not (error {np.abs(e).max():.3g}); use 'fd' or 'lsq'")
    zero_u, zw, zv = np.zeros((T, nu)), np.zeros((T, n)), np.zeros((T, ny))

    def unit(shape, t, i):
        a = np.zeros(shape)
        a[t, i] = 1.0
        return a

    Sw = [np.column_stack([error(np.zeros(n), zero_u, unit(zw.shape, t, i), zv) for i in range(n)])
          for t in range(h)]
    Sv = [np.column_stack([error(np.zeros(n), zero_u, zw, unit(zv.shape, t, i)) for i in range(ny)])
          for t in range(T)]
    return Sw, Sv


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
    def build(cls, plant, horizon, initial=None):
        """The rows for ``plant`` and ``horizon`` (eq. 13).

        ``initial``: an :class:`~reachset_ros.conformance.estimators.Estimator` whose
        initial-state error is part of the reachable set (the *initial-state set*, an
        extension of the paper's eq. 13, which takes the estimated initial state as exact):

            R_a[k] = C A^k E (+) (+)_{i<k} C A^i W (+) V,
            E = (+)_t Sw[t] W (+) (+)_t Sv[t] V    (:func:`initial_error_maps`)

        -- the error of the estimate made from the same kind of noise and disturbance
        samples, which precede the test case and are therefore other samples than those of
        the sum (the bound adds their absolute values, as for any other sample). Without it
        (the paper, the default) the estimate's error must be explained by W and V of the
        test case itself: for ``fd`` a velocity error up to ``2 alpha_V / dt`` that grows over
        the horizon like a persistent velocity disturbance, charged to W1 and V. One-output
        plants only.
        """
        n, ny = plant.A.shape[0], plant.C.shape[0]
        if initial is not None and ny != 1:
            raise ReachsetError("the initial-state set is implemented for one-output plants only")
        if initial is not None:         # the estimate's error maps, through the generators, once
            Sw, Sv = initial_error_maps(plant, initial)
            SwG, SvG = [S @ plant.Gw for S in Sw], [S @ plant.Gv for S in Sv]
            Sw_sum, Sv_sum = sum(Sw, np.zeros((n, n))), sum(Sv, np.zeros((n, ny)))
        normals = output_normals(plant, horizon)
        Dp, Dm = [], []
        sumE = np.zeros((ny, n))       # sum_{i<k} C A^i
        sumR = None                    # per normal: sum_{i<k} |n C A^i G'_W|
        E = plant.C.copy()
        run = None                     # (N, k, radW, Ei): the sum of step k for the normals N
        for k in range(horizon + 1):
            N = normals[k]
            # sum_{i<k} |N C A^i G'_W|, summed in order i = 0..k-1; with the normals of step k-1
            # (always for ny = 1) it continues that step's sum, the same additions in the same order
            if run is not None and run[0].shape == N.shape and np.array_equal(run[0], N):
                radW, Ei = run[2].copy(), run[3]
                for _ in range(run[1], k):
                    radW += np.abs(N @ Ei @ plant.Gw)
                    Ei = Ei @ plant.A
            else:
                radW = np.zeros((N.shape[0], plant.Gw.shape[1]))
                Ei = plant.C.copy()
                for _ in range(k):
                    radW += np.abs(N @ Ei @ plant.Gw)
                    Ei = Ei @ plant.A
            run = (N, k, radW.copy(), Ei)
            radV = np.abs(N @ plant.Gv)
            cW = N @ sumE
            cV = N
            if initial is not None:         # N C A^k (E = C A^k here): the estimate's error k steps on
                P = N @ E
                for G in SwG:
                    radW = radW + np.abs(P @ G)
                for G in SvG:
                    radV = radV + np.abs(P @ G)
                cW = cW + P @ Sw_sum
                cV = cV + P @ Sv_sum
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


def deviation_extremes(plant, estimator, y, u, segments, horizon, thm=None, allow_empty=False):
    """Reduce all test cases to the left-hand sides of Theorem 1, per k and normal.

    Extremes merge exactly (:func:`combine`): the extremes of several recordings are the
    extremes of their concatenation, to the bit. ``allow_empty``: a recording without any
    test case gives ``-inf`` extremes and ``test_cases == 0`` (one bag of a fleet's,
    :mod:`reachset_ros.fleet`) instead of raising.
    """
    thm = thm or Theorem1.build(plant, horizon)
    fused = sweep_extremes(plant, estimator, y, u, segments, horizon, thm.normals)   # compiled, to the bit
    devs = Deviations(*fused) if fused is not None else _extremes_numpy(plant, estimator, y, u, segments, horizon,
                                                                        thm)
    if devs.test_cases == 0 and not allow_empty:
        raise ReachsetError("too few samples for a test case (need at least "
                            f"{estimator.history + 1} consecutive valid ticks)")
    return devs


def _extremes_numpy(plant, estimator, y, u, segments, horizon, thm):
    """:func:`deviation_extremes` with numpy (the visitor of :func:`sweep`; the compiled kernel's
    ``reachset_sweep_extremes`` is its copy)."""
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
    """Deviations of several recordings (joints' data from several bags) together.

    Exact: the elementwise maximum of the recordings' extremes, the test cases and checks
    summed; order does not matter (max and integer sums are associative in floating point).
    """
    maxp = tuple(np.maximum.reduce([d.maxp[k] for d in devs]) for k in range(len(devs[0].maxp)))
    maxm = tuple(np.maximum.reduce([d.maxm[k] for d in devs]) for k in range(len(devs[0].maxm)))
    return Deviations(maxp, maxm, sum(d.test_cases for d in devs), sum(d.checks for d in devs))


# ------------------------------------------------------------------ batch check
@dataclass(frozen=True)
class CheckResult:
    """Verdict of a batch conformance check of one joint."""

    violations: int               # measurement ticks at which some test case is outside
    first_violation_tick: int     # index into the series (-1 if none)
    test_cases: int
    checks: int
    worst_margin: float           # min over all checks of (offset - N y_a); < 0 = violated
    violating: np.ndarray = field(default=None, compare=False, repr=False)   # per tick: some test case outside
    envelope: dict = field(default=None, compare=False)   # a fleet's envelope.tick_counts of the joint (issue 37)


def check_extremes(thm, xi, devs):
    """The verdict of :func:`check` from the deviation extremes alone, where it is exact.

    ``max_m N_k y_a^(m)[k] <= d+_k`` (and the same for ``-N_k``) for all k holds exactly when
    no test case leaves R_a[k], and ``min_k (d_k - max_m N_k y_a)`` is, to the bit, the
    smallest margin :func:`check` finds (``fl(d - x)`` is monotone in x). Only the number
    of violating ticks and the first one need the data.

    Returns
    -------
    (conformant : bool, worst_margin : float)
    """
    worst = np.inf
    for (dp, dm), hp, hm in zip(thm.offsets(xi), devs.maxp, devs.maxm):
        # np.min propagates a NaN: a NaN margin is no margin (fail closed, never conformant)
        worst = float(np.min([worst, (dp - hp).min(), (dm - hm).min()]))
    return bool(worst >= 0.0), worst


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
        viol = ~(mp >= 0).all(axis=0) | ~(mm >= 0).all(axis=0)     # a NaN margin is a violation
        bad[t[viol]] = True
        stats["checks"] += ya.shape[1]
        stats["margin"] = float(np.min([stats["margin"], mp.min(), mm.min()]))   # NaN propagates

    M = sweep(plant, estimator, y, u, segments, horizon, visit)
    idx = np.flatnonzero(bad)
    return CheckResult(int(bad.sum()), int(idx[0]) if len(idx) else -1, M, stats["checks"],
                       stats["margin"], violating=bad)

