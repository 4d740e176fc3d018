"""Corollary 1: the conservative, state-based identification (paper Corollary 1, Remarks 2-3).

For sequential test cases with estimated initial states x^(m)[0] (the model's Estimator),
the one-step state deviations and the output residuals

    x_a^(m)[1] = x^(m+1)[0] - (A x^(m)[0] + B u[m])      must lie in  W,
    v^(m)      = y[m] - C x^(m)[0] - D u[m]              must lie in  V.

Then y_a^(m)[k] = v^(m+k) + C sum_{i<k} A^{k-1-i} x_a^(m+i)[1] (a telescoping identity,
exact for *any* estimator) lies in R_a[k] for every k, so no horizon k* is needed
(Remark 3). The containments are linear in the same xi: with the facet normals N of the
zonotope of the unscaled generators (Prop. 1), ``x in (c, G diag(alpha))`` iff
``|N (x - c)| <= |N G| alpha`` for the normals inside span(G), and ``N_perp (x - c) = 0``
for an orthonormal basis N_perp of span(G)'s orthogonal complement (G not of full row
rank, e.g. the LWA-4P plant's G'_W spans 2 of 5 state directions).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InfeasibleError, ReachsetError
from ..sets.zonotope import halfspace_normals
from .identify import IdentifiedSets, make_sound, set_norm_cost, z_bounds, z_to_xi
from .kernels import advance, as_2d, predict_output, test_case_starts
from .theorem1 import Theorem1, deviation_extremes


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
    ny = plant.C.shape[0]
    pw, pv = plant.Gw.shape[1], plant.Gv.shape[1]
    if centers not in ("zero", "free"):
        raise ReachsetError(f"centers must be 'zero' or 'free', not {centers!r}")
    T = z_to_xi(plant)   # xi = T z
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
    return A_ub, b_ub, z_bounds(plant, centers), T


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

    Minimises ||W|| + ||V|| (as :func:`~.identify_sets`) subject to x_a^(m)[1] in W and
    y[m] - C x^(m)[0] - D u[m] in V for all sequential test cases of the recording, with
    x^(m)[0] from ``estimator``. The result is reachset conformant for every k (no k*,
    Remark 3) and more conservative than Theorem 1 (Remark 2): its feasible set is contained
    in Theorem 1's for every horizon, so its cost is >= :func:`~.identify_sets`'s.

    Feasibility needs every x_a in c_W + span(G'_W): directions orthogonal to it must vanish
    up to ``atol + rtol * scale`` (see :func:`corollary1_constraints`), i.e. the estimator
    must be consistent with the model there. Otherwise :class:`InfeasibleError` names the
    test case, the state direction and the residual. (The per-joint LWA-4P plant with the
    ``fd`` estimator on noisy data is such a case: measurement noise puts x_a outside the
    velocity/acceleration directions of G'_W.)

    Floating point: the LP solution is inflated until every Corollary-1 row holds exactly;
    with ``horizon`` (or ``thm``) given, :func:`~.make_sound` then also closes any rounding gap
    of the Theorem-1 check for k = 0..horizon, so :func:`~.theorem1.check` reports zero violations.

    Parameters
    ----------
    plant : LinearPlant
    estimator : Estimator
    y, u : ndarray, shape (T, ny), (T, nu)
    segments : sequence of (start, stop)
    centers : "zero" | "free"
    weights, alpha_lower : as :func:`~.identify_sets`
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
    from scipy.optimize import linprog  # lazy: 0.3 s of start-up (issue 38.1)
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

