"""Reachable sets of discrete linear systems and sound invariant-set bounds.

System (paper eq. ``discreteSystem``; equations are cited by their LaTeX label in
the paper's LaTeX source (docs/theory.md) because the numbering differs between versions of the paper)::

    x[k+1] = A x[k] + B u[k] + w[k],   w[k] in W = (c_W, G'_W diag(alpha_W))
    y[k]   = C x[k] + D u[k] + v[k],   v[k] in V = (c_V, G'_V diag(alpha_V))

* :func:`reachable_outputs` - the reachable output sets ``R[k]`` of paper eq. ``reachableSet`` over a
  horizon, split by superposition (paper Sec. III-A/III-B) into the nominal output
  ``y*[k]`` (:func:`nominal_outputs`; initial state and inputs, a vector) and the
  disturbance part ``R_a[k] = (+)_{i<k} C A^i W (+) V`` (:func:`disturbance_output_sets`,
  paper eqs. ``Ra``, ``reachA``, ``Gk``; a zonotope).
* :func:`invariant_outer` - a SOUND outer bound of the minimal robust positively invariant
  (mRPI) set ``F_inf = (+)_{i>=0} A^i W`` of a stable system, together with the truncated
  sum ``F_s = (+)_{i<s} A^i W`` (an inner approximation, ``F_s`` is a subset of ``F_inf``).
* :func:`radius_coefficients` - the interval-hull radius of ``H`` times the outer invariant
  output set as a linear function ``Kw alpha_w + Kv alpha_v`` of the generator scalings
  (sound: the tail of the infinite sum is bounded), the fast path used by the synthesis.

Modes the disturbances cannot reach (e.g. the plant's constant-disturbance state ``d``
with eigenvalue 1) are removed first: everything is computed on the reachable
(controllable) subspace of ``(A, [G_W, G_V])`` (:func:`reachable_subspace`), and
stability means a spectral radius below one there.

Soundness of the tail bound ("norm" method, the default)
--------------------------------------------------------
Let ``A_r`` be ``A`` on the reachable subspace (orthonormal coordinates) and
``a = ||A_r^s||_inf < 1``. For each generator ``g_j`` let
``rho_j = max_x { ||x||_inf : x in (+)_{i<s} A_r^i [-g_j, g_j] }``. Then
``(+)_{i>=s} A_r^i [-g_j, g_j] = (+)_{m>=1} A_r^{ms} (+)_{l<s} A_r^l [-g_j, g_j]`` is contained
in the box ``a/(1-a) rho_j [-1, 1]^r`` and its support in direction ``h`` is at most
``a/(1-a) rho_j ||h||_1``. ``s`` is increased (in doubling blocks) until that tail is at
most ``eps`` times the truncated sum (``eps`` is relative, default ``1e-6``); the returned
outer bound is the truncated sum plus the tail bound. It contains the mRPI set, hence
every state reachable from the disturbance-free equilibrium and the limit of every
trajectory; unlike Rakovic's set it need not itself be positively invariant. All of this
is exact arithmetic on zonotopes up to floating-point rounding, which
:func:`radius_coefficients` bounds and adds (outward rounding, see its docstring).

The "rakovic" method (Rakovic, Kerrigan, Kouramas, Mayne 2005, IEEE TAC 50(3)) needs a
disturbance set with the origin in its interior (full-dimensional on the reachable
subspace): it finds the smallest ``s`` with ``A^s W`` contained in ``a W``,
``a/(1-a) <= eps``, and returns ``(1-a)^-1 F_s``, which contains ``F_inf``.

Pure numpy/scipy; no ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .zonotope import Zonotope

__all__ = ["reachable_subspace", "nominal_outputs", "disturbance_output_sets", "reachable_outputs",
           "markov_parameters", "rakovic_alpha", "truncated_sum", "invariant_outer",
           "InvariantSet", "radius_coefficients", "RadiusInfo", "NotStableError",
           "spectral_radius_reachable"]

#: Default relative size of the tail bound.
EPS = 1e-6
#: Largest truncation length tried before giving up (spectral radius too close to one).
MAX_STEPS = 1 << 17


class NotStableError(ValueError):
    """The system is not asymptotically stable on the disturbances' reachable subspace."""


# ---------------------------------------------------------------------- subspaces
def _orth_cols(Z, tol):
    """Orthonormal basis of range(Z), dropping directions with singular value <= tol."""
    if Z.shape[1] == 0:
        return Z[:, :0]
    U, s, _ = np.linalg.svd(Z, full_matrices=False)
    return U[:, s > tol]


def reachable_subspace(A, B, tol=1e-10):
    """Orthonormal basis of the reachable subspace ``range [B, AB, ..., A^{n-1}B]``.

    Computed by an orthogonal staircase iteration: each input column is normalised first
    (so tiny generators such as ``dt^2/2`` count), then new directions ``A V`` are
    orthogonalised against the basis and kept when their singular value exceeds
    ``tol * max(1, ||A||_2)``.

    Parameters
    ----------
    A : array_like, (n, n)
    B : array_like, (n, m)
    tol : float

    Returns
    -------
    V : ndarray, (n, r)
        Orthonormal columns; ``A V = V (V^T A V)`` up to rounding (the subspace is invariant).
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    n = A.shape[0]
    norms = np.linalg.norm(B, axis=0)
    B = B[:, norms > 0] / norms[norms > 0]
    basis = _orth_cols(B, tol)
    new = basis
    thr = tol * max(1.0, np.linalg.norm(A, 2))
    while new.shape[1] and basis.shape[1] < n:
        Z = A @ new
        Z -= basis @ (basis.T @ Z)
        Z -= basis @ (basis.T @ Z)
        new = _orth_cols(Z, thr)
        if new.shape[1]:
            new -= basis @ (basis.T @ new)
            new = _orth_cols(new, 0.5)
            basis = np.hstack([basis, new])
    return basis


def spectral_radius_reachable(A, B, tol=1e-10):
    """Spectral radius of ``A`` restricted to the reachable subspace of ``(A, B)``.

    Returns
    -------
    rho : float
        0 if nothing is reachable.
    V : ndarray
        The basis from :func:`reachable_subspace`.
    """
    V = reachable_subspace(A, B, tol)
    if V.shape[1] == 0:
        return 0.0, V
    Ar = V.T @ np.asarray(A, float) @ V
    return float(np.max(np.abs(np.linalg.eigvals(Ar)))), V


# ---------------------------------------------------------------------- finite horizon
def markov_parameters(A, C, G, horizon):
    """``E_i G = C A^i G`` for ``i = 0..horizon-1`` (paper eq. ``reachA``), shape ``(horizon, p, g)``."""
    A, C, G = (np.atleast_2d(np.asarray(a, float)) for a in (A, C, G))
    out = np.empty((horizon, C.shape[0], G.shape[1]))
    X = G
    for i in range(horizon):
        out[i] = C @ X
        X = A @ X
    return out


def nominal_outputs(A, B, C, D, x0, u):
    """Nominal output ``y*[k] = C x*[k] + D u[k]`` without disturbances (superposition part).

    Parameters
    ----------
    A, B, C, D : array_like
    x0 : array_like, (n,)
    u : array_like, (K+1, m) or (K+1,)
        Inputs ``u[0..K]``.

    Returns
    -------
    ndarray, (K+1, p)
    """
    A, B, C, D = (np.atleast_2d(np.asarray(a, float)) for a in (A, B, C, D))
    u = np.asarray(u, float).reshape(len(u), -1)
    x = np.asarray(x0, float).copy()
    ys = np.empty((u.shape[0], C.shape[0]))
    for k in range(u.shape[0]):
        ys[k] = C @ x + D @ u[k]
        x = A @ x + B @ u[k]
    return ys


def disturbance_output_sets(A, C, W, V, horizon):
    """Disturbance part ``R_a[k] = (+)_{i<k} C A^i W (+) V`` for ``k = 0..horizon`` (paper eqs. ``Ra``-``Gk``).

    Parameters
    ----------
    A, C : array_like
    W : Zonotope
        Process disturbance set (state space).
    V : Zonotope
        Measurement noise set (output space).
    horizon : int
        ``k*``.

    Returns
    -------
    list of Zonotope
        ``horizon + 1`` zonotopes with centres ``sum_{i<k} C A^i c_W + c_V`` and generators
        ``[E_0 G_W, ..., E_{k-1} G_W, G_V]`` (paper eq. ``Gk``).
    """
    A, C = np.atleast_2d(np.asarray(A, float)), np.atleast_2d(np.asarray(C, float))
    E = markov_parameters(A, C, np.column_stack([W.center, W.generators]), horizon)
    sets, cen, gens = [], V.center.copy(), [V.generators]
    for k in range(horizon + 1):
        sets.append(Zonotope(cen, np.hstack(gens[1:] + gens[:1])))
        if k < horizon:
            cen = cen + E[k][:, 0]
            gens.append(E[k][:, 1:])
    return sets


def reachable_outputs(A, B, C, D, X0, u, W, V):
    """Reachable output sets ``R[k]`` of paper eq. ``reachableSet``, ``k = 0..K``.

    Computed by superposition: ``R[k] = y*[k] (+) C A^k (X0 - x0) (+) R_a[k]`` with the
    nominal output ``y*`` from the centre of ``X0`` (exact for zonotopes).

    Parameters
    ----------
    A, B, C, D : array_like
    X0 : Zonotope or array_like
        Initial set or state.
    u : array_like, (K+1, m)
    W, V : Zonotope

    Returns
    -------
    list of Zonotope
    """
    X0 = X0 if isinstance(X0, Zonotope) else Zonotope(np.asarray(X0, float))
    u = np.asarray(u, float).reshape(len(u), -1)
    K = u.shape[0] - 1
    ys = nominal_outputs(A, B, C, D, X0.center, u)
    Ra = disturbance_output_sets(A, C, W, V, K)
    A, C = np.atleast_2d(np.asarray(A, float)), np.atleast_2d(np.asarray(C, float))
    out, G0 = [], X0.generators
    for k in range(K + 1):
        out.append(Zonotope(ys[k] + Ra[k].center, np.hstack([C @ G0, Ra[k].generators])))
        G0 = A @ G0
    return out


# ---------------------------------------------------------------------- invariant sets
def rakovic_alpha(A, W, s):
    """Smallest ``a`` with ``A^s W`` contained in ``a W`` (Rakovic et al. 2005).

    ``a = max_i h_W((A^s)^T f_i) / g_i`` for the H-representation ``W = {x | f_i x <= g_i}``;
    needs the origin in the interior of ``W`` (all ``g_i > 0``).

    Parameters
    ----------
    A : array_like, (n, n)
    W : Zonotope
        Full-dimensional, containing the origin in its interior.
    s : int

    Returns
    -------
    float
    """
    F, g = W.halfspaces()
    if np.any(g <= 0):
        raise ValueError("Rakovic's bound needs the origin in the interior of W")
    return _rakovic_alpha(np.linalg.matrix_power(np.asarray(A, float), int(s)), W, F, g)


def _rakovic_alpha(As, W, F, g):
    return float(np.max(W.support(F @ As) / g))


def truncated_sum(A, W, N):
    """``F_N = (+)_{i<N} A^i W`` (exact; an inner approximation of the mRPI set).

    Parameters
    ----------
    A : array_like
    W : Zonotope
    N : int

    Returns
    -------
    Zonotope
    """
    A = np.asarray(A, float)
    c, G = np.zeros(W.dim), []
    X, x = W.generators, W.center
    for _ in range(int(N)):
        G.append(X)
        c = c + x
        X, x = A @ X, A @ x
    return Zonotope(c, np.hstack(G) if G else np.zeros((W.dim, 0)))


@dataclass(frozen=True, eq=False, kw_only=True)
class InvariantSet:
    """Result of :func:`invariant_outer`.

    Attributes
    ----------
    outer : Zonotope
        Sound outer bound of the (projected) mRPI set (robust positively invariant itself
        for the "rakovic" method).
    inner : Zonotope
        Truncated sum ``(+)_{i<s} A^i W`` (projected); a subset of the mRPI set.
    s : int
        Truncation length.
    a : float
        Contraction factor (``||A_r^s||_inf`` for "norm", ``alpha^o(s)`` for "rakovic").
    eps : float
    method : str
    reachable_dim : int
    spectral_radius : float
    """

    outer: Zonotope
    inner: Zonotope
    s: int
    a: float
    eps: float
    method: str
    reachable_dim: int
    spectral_radius: float


def _restrict(A, G, tol=1e-10):
    rho, V = spectral_radius_reachable(A, G, tol)
    if rho >= 1.0 - 1e-12:
        raise NotStableError(f"not asymptotically stable: spectral radius {rho:.9g} >= 1 on the "
                             f"{V.shape[1]}-dimensional reachable subspace")
    return V, V.T @ A @ V, rho


def invariant_outer(A, G, C=None, eps=EPS, method="auto", center=None):
    """Sound outer bound and truncated inner set of the mRPI set ``(+)_{i>=0} A^i W``.

    ``W = (center, G)`` (centre zero by default); with ``C`` given, both sets are
    projected by ``C`` (an output map).

    Parameters
    ----------
    A : array_like, (n, n)
        Must be stable on the reachable subspace of ``(A, G)``; unreachable modes (any
        eigenvalue) are ignored.
    G : array_like, (n, g)
        Generators of the disturbance set.
    C : array_like, (p, n), optional
    eps : float
        Relative tolerance of the outer bound: the added tail is at most ``eps`` times the
        truncated sum ("norm": per generator and output direction; "rakovic":
        ``a/(1-a) <= eps``, so ``outer = (1 + a/(1-a)) inner``).
    method : {"auto", "norm", "rakovic"}
        "rakovic" needs ``G`` of full row rank (checked), "auto" uses it then and "norm"
        otherwise.
    center : array_like, (n,), optional
        Centre ``c_W``; the mRPI set is then centred at ``(I - A)^-1 c_W`` (which must lie
        in the reachable subspace of ``(A, [G, c_W])``).

    Returns
    -------
    InvariantSet

    Raises
    ------
    NotStableError
        If the spectral radius on the reachable subspace is not below one.
    """
    A = np.atleast_2d(np.asarray(A, float))
    G = np.asarray(G, float).reshape(A.shape[0], -1)
    n = A.shape[0]
    Cm = np.eye(n) if C is None else np.atleast_2d(np.asarray(C, float))
    cvec = np.zeros(n) if center is None else np.asarray(center, float)
    full = np.linalg.matrix_rank(G) == n if G.size else False
    if method == "auto":
        method = "rakovic" if full and n <= 6 else "norm"
    V, Ar, rho = _restrict(A, np.column_stack([G, cvec]))
    zc = V @ np.linalg.solve(np.eye(Ar.shape[0]) - Ar, V.T @ cvec) if V.shape[1] else np.zeros(n)
    if method == "rakovic":
        if not full:
            raise ValueError("method 'rakovic' needs a full-dimensional disturbance set W")
        W0 = Zonotope(np.zeros(n), G)
        F, g = W0.halfspaces()
        if np.any(g <= 0):
            raise ValueError("Rakovic's bound needs the origin in the interior of W")
        s, As = 1, A.copy()
        a = _rakovic_alpha(As, W0, F, g)
        while a >= 1 or a / (1 - a) > eps:
            s += 1
            if s > MAX_STEPS:
                raise NotStableError("Rakovic bound did not converge")
            As = A @ As
            a = _rakovic_alpha(As, W0, F, g)
        inner0 = truncated_sum(A, W0, s)
        inner = Zonotope(Cm @ zc, Cm @ inner0.generators)
        outer = Zonotope(Cm @ zc, Cm @ inner0.generators / (1.0 - a))
        return InvariantSet(outer=outer, inner=inner, s=s, a=a, eps=eps, method="rakovic", reachable_dim=n,
                            spectral_radius=rho)
    if method != "norm":
        raise ValueError(f"unknown method {method!r}")
    r = V.shape[1]
    Gr = V.T @ G
    Mr = Cm @ V
    S, R, s, a, blocks = _abs_sums(Ar, Gr, Mr, eps, keep=True)
    Xs = np.hstack(blocks)[:, : s * G.shape[1]] if blocks else np.zeros((r, 0))
    inner_G = Mr @ Xs
    rho_all = R.sum(axis=1).max(initial=0.0)
    tail = (a / (1.0 - a)) * rho_all * Mr if r else np.zeros((Cm.shape[0], 0))
    inner = Zonotope(Cm @ zc, inner_G)
    outer = Zonotope(Cm @ zc, np.hstack([inner_G, tail]))
    return InvariantSet(outer=outer, inner=inner, s=s, a=a, eps=eps, method="norm", reachable_dim=r,
                        spectral_radius=rho)


#: Unit roundoff of IEEE double precision.
UNIT_ROUNDOFF = np.finfo(float).eps / 2


def _gamma(n):
    """``gamma_n = n u / (1 - n u)``: relative error bound of an ``n``-term sum or dot product."""
    return n * UNIT_ROUNDOFF / (1.0 - n * UNIT_ROUNDOFF)


def _norm_inf(M):
    """An upper bound of ``||M||_inf`` in floating point (the row sums' rounding included)."""
    return float(np.abs(M).sum(axis=1).max(initial=0.0)) * (1.0 + _gamma(M.shape[1] + 1))


def _abs_sums(Ar, Gr, Mr, eps, keep=False, block=16, max_block=512):
    """Truncated absolute impulse-response sums with an adaptive, sound tail bound.

    Returns ``S[r, j] = sum_{i<s} |Mr_r A^i g_j|``, ``R[k, j] = sum_{i<s} |(A^i g_j)_k|``,
    ``s`` and ``a = ||A^s||_inf`` such that the tail ``a/(1-a) max_k R[k, j] ||Mr_r||_1``
    is at most ``eps (S[r, j] + 1e-6 max_j S[r, j])``.
    """
    r, g = Gr.shape
    p = Mr.shape[0]
    if r == 0 or g == 0:
        return np.zeros((p, g)), np.zeros((r, g)), 0, 0.0, []
    X, P = Gr, Ar
    while X.shape[1] < block * g:
        X = np.hstack([X, P @ X])
        P = P @ P
    b = block
    S = np.zeros((p, g))
    R = np.zeros((r, g))
    As = np.eye(r)
    s = 0
    hnorm = np.abs(Mr).sum(axis=1)[:, None]
    blocks = []
    while True:
        if keep:
            blocks.append(X)
        S += np.abs(Mr @ X).reshape(p, b, g).sum(axis=1)
        R += np.abs(X).reshape(r, b, g).sum(axis=1)
        s += b
        As = P @ As
        a = float(np.abs(As).sum(axis=1).max())
        if a < 0.5:
            tail = (a / (1.0 - a)) * R.max(axis=0)[None, :] * hnorm
            if np.all(tail <= eps * (S + 1e-6 * S.max(axis=1, keepdims=True))):
                return S, R, s, a, blocks
        if s >= MAX_STEPS:
            raise NotStableError(f"tail bound did not converge within {MAX_STEPS} steps "
                                 f"(spectral radius too close to 1)")
        X = P @ X
        if b < max_block:  # double the block: cover steps [s, s + 2b)
            X = np.hstack([X, P @ X])
            P = P @ P
            b *= 2


def _abs_sums_rounded(Ar, Gr, Mr, eps, chunk=256):
    """Sound upper bounds of ``sum_{i>=0} |Mr Ar^i g_j|``, rounding included (outward rounding).

    Computed step by step, ``x^_{i+1} = fl(Ar x^_i)`` (one product per step: the local error
    is ``|delta_i| <= gamma_r |Ar| |x^_i|``, Higham, *Accuracy and Stability of Numerical
    Algorithms*, 2nd ed., eq. (3.13)), with the identity carried along as extra generators,
    which gives ``fl(Ar^i)`` and the gain ``Z = sum_{m>=0} |[Mr; I] Ar^m|`` from a local error
    to the sums (``x^_i - x_i = sum_{k<i} Ar^{i-1-k} delta_k``). With ``R = sum_{i<s} |x^_i|``
    (computed sums of ``s`` non-negative terms divided by ``1 - gamma_s``, Higham eq. (4.3)):

    * truncated part: ``sum_{i<s} |Mr x_i| <= S + gamma_r |Mr| R + gamma_r Z_M |Ar| R``;
    * tail: ``sum_{i>=s} |Mr x_i| <= Z_M |x_s|`` with ``|x_s| <= |x^_s| + gamma_r Z_I |Ar| R``
      (replaces the norm-based tail of :func:`_abs_sums`, which rounding would floor);
    * ``Z`` itself: ``Z <= B + Z T`` with ``B`` the computed truncated sums (plus their
      product rounding) and ``T = |fl(Ar^s)| + gamma_r |Ar| R_I + gamma_r Z_I |Ar| R_I``; with
      ``v = 1^T R_I > 0`` and ``v T <= v / 2`` (checked) the Neumann series gives
      ``Z <= B + B T + 2 c v T^2`` (``c`` the row-wise ``max B / v``). ``Z_I`` inside ``T``
      (an O(u) term) is taken as ``2 R_I``: the one first-order step, its neglected part
      O(u^2).

    Returns ``(K, R_all, s, a, S_inner)``: the bounds ``K[r, j]``, ``R_all[k, j] >= sum_{i>=0}
    |(Ar^i g_j)_k|``, the truncation length, ``a = ||fl(Ar^s)||_inf`` and the plain truncated
    sums (inner). Raises :class:`NotStableError` when the sums do not converge or the
    rounding bound does not close (a loop too ill-conditioned for double precision).
    """
    r, g = Gr.shape
    p = Mr.shape[0]
    if r == 0 or g == 0:
        return np.zeros((p, g)), np.zeros((r, g)), 0, 0.0, np.zeros((p, g))
    gr = _gamma(r)
    absA, absM = np.abs(Ar), np.abs(Mr)
    X = np.hstack([Gr, np.eye(r)])
    nc = g + r
    S = np.zeros((p, nc))
    R = np.zeros((r, nc))
    buf = np.empty((chunk, r, nc))
    s = 0
    while True:
        for i in range(chunk):
            buf[i] = X
            X = Ar @ X
        S += np.abs(np.matmul(Mr, buf)).sum(axis=0)
        R += np.abs(buf).sum(axis=0)
        s += chunk
        a = _norm_inf(X[:, g:])
        if a < 0.25:
            gs = _gamma(s)
            R_c, S_c = R / (1.0 - gs), S / (1.0 - gs)
            RI, Rg = R_c[:, g:], R_c[:, :g]
            xs = np.abs(X[:, :g]) + gr * (2.0 * RI) @ absA @ Rg
            tail = (2.0 * S_c[:, g:]) @ xs
            Sg = S_c[:, :g]
            if np.all(tail <= eps * (Sg + 1e-6 * Sg.max(axis=1, keepdims=True))):
                break
        if s >= MAX_STEPS:
            raise NotStableError(f"tail bound did not converge within {MAX_STEPS} steps "
                                 f"(spectral radius too close to 1)")
    B = np.vstack([S_c[:, g:] + gr * (absM @ RI), RI])
    T = np.abs(X[:, g:]) + gr * (absA @ RI) + gr * ((2.0 * RI) @ absA @ RI)
    v = RI.sum(axis=0)
    if not np.all(v @ T <= 0.5 * v):
        raise NotStableError("rounding bound of the impulse-response sums did not close "
                             "(the closed loop is too ill-conditioned for double precision)")
    c = (B / v[None, :]).max(axis=1)
    Z = (B + B @ T + 2.0 * c[:, None] * (v @ T @ T)[None, :]) * (1.0 + _gamma(3 * r + 8))
    ZM, ZI = Z[:p], Z[p:]
    dx = gr * (ZI @ absA @ Rg)                            # propagated local errors, per state
    xs = np.abs(X[:, :g]) + dx
    K = S_c[:, :g] + gr * (absM @ Rg) + gr * (ZM @ absA @ Rg) + ZM @ xs
    R_all = Rg + dx + ZI @ xs
    return K, R_all, s, a, S[:, :g]


def _coordinate_restriction(A, E):
    """Indices ``J`` of the states reachable from ``E`` through the *nonzero pattern* of ``A``.

    The smallest index set containing the nonzero rows of ``E`` and closed under ``A`` (every
    ``i`` with ``A[i, j] != 0`` for some ``j`` in ``J``). Exact: outside ``J`` every ``A^k E``
    is exactly zero, in floating point as well, so ``C A^k E = C[:, J] A[J, J]^k E[J]``
    with no rounding from a change of coordinates (e.g. the plant's constant disturbance
    ``d``, whose row of ``A`` is the unit vector, is dropped exactly).
    """
    nz = A != 0
    J = np.any(E != 0, axis=1)
    while True:
        new = J | np.any(nz[:, J], axis=1)
        if np.array_equal(new, J):
            return np.nonzero(J)[0]
        J = new


@dataclass(frozen=True, eq=False, kw_only=True)
class RadiusInfo:
    """Details of :func:`radius_coefficients`.

    ``Kw_inner``, ``Kv_inner``: the truncated (inner) coefficients; ``s``, ``a``: truncation
    length and tail contraction; ``exact_restriction``: the unreachable states were dropped by
    selecting coordinates (exact, :func:`_coordinate_restriction`) rather than by an orthogonal
    projection, so the floating-point bound covers every rounding.
    """

    Kw_inner: np.ndarray
    Kv_inner: np.ndarray
    s: int
    a: float
    reachable_dim: int
    spectral_radius: float
    exact_restriction: bool = False


def _feedthrough(Hm, Dw, Dv, *, p, gw, gv):
    """``(|H D|, its upper bound with the rounding of fl(H D))`` of :func:`radius_coefficients`
    (``D = [Dw, Dv]``, zero where not given; ``H`` the identity when ``Hm`` is None)."""
    D = np.hstack([np.zeros((p, gw)) if Dw is None else np.asarray(Dw, float).reshape(p, gw),
                   np.zeros((p, gv)) if Dv is None else np.asarray(Dv, float).reshape(p, -1)])
    if Hm is None:
        HD = np.abs(D)
        return HD, HD
    HD = np.abs(Hm @ D)
    return HD, HD + _gamma(p) * (np.abs(Hm) @ np.abs(D))


def radius_coefficients(A, Ew, Ev, C, Dw=None, Dv=None, H=None, eps=EPS, return_info=False):
    """Interval-hull radius of ``H`` times the outer invariant output set, linear in ``alpha``.

    For ``z[k+1] = A z + Ew diag(alpha_w) bw + Ev diag(alpha_v) bv``,
    ``out = C z + Dw diag(alpha_w) bw + Dv diag(alpha_v) bv`` with ``bw, bv`` in unit boxes,
    the set of steady-state outputs is ``(+)_{i>=0} C A^i W (+) D (...)`` (the mRPI set of paper
    Sec. III-A, projected); its box radius after the map ``H`` is ``Kw alpha_w + Kv alpha_v`` with

    ``K[:, j] = |H D_j| + sum_{i>=0} |H C A^i E_j|``  (exact, an infinite sum).

    The returned ``Kw``, ``Kv`` are *upper bounds* of these sums, in floating point: the
    truncated sum, plus the tail bound of the module docstring, plus a bound on every
    rounding error (outward rounding), so ``Kw alpha_w + Kv alpha_v`` is a sound radius for
    every ``alpha >= 0``, and linear in ``alpha`` (the synthesis' inner LP relies on it).

    Rounding (``u`` the unit roundoff, ``gamma_n = n u / (1 - n u)``; Higham, *Accuracy and
    Stability of Numerical Algorithms*, 2nd ed., Lemma 3.1, eqs. (3.5), (4.3)). The matrices
    ``A, E, C, D, H`` as given are the system (its composition from plant/observer/controller
    is a separate computation). With ``J`` the exact coordinate restriction, ``Ar = A[J, J]``,
    ``x_i = Ar^i g_j`` and ``x^_i`` its computed value:

    * powers: ``||x^_i - Ar^b x^_{i-b}||_inf <= loc ||x^_{i-b}||_inf`` (see :func:`_abs_sums`);
      the local errors ``delta_i`` propagate as ``x^_i - x_i = sum Ar^{i-k} delta_k``, so
      ``sum_i |M (x^_i - x_i)| <= Z_M 1 * sum_k ||delta_k||_inf`` with
      ``Z_M = sum_{m>=0} |M Ar^m|`` (computed by the same routine with generators ``I``;
      doubled, which covers its own relative error, itself of the order of this bound);
    * sums of ``s`` non-negative terms: ``sum <= fl(sum) / (1 - gamma_{s})``; products
      ``|fl(M x) - M x| <= gamma_r |M| |x|``; ``fl(H C)``, ``fl(H D)``: ``gamma |H| |C|``;
    * the tail uses ``a >= ||Ar^s||_inf`` including the rounding of ``fl(Ar^s)``, and the
      rounding-corrected ``R``;
    * the final few operations that form the bound: a factor ``1 + gamma_{p+r+32}``.

    When the coordinate restriction still contains a mode that is not stable (an
    unreachable mode the nonzero pattern cannot separate), the orthonormal reachable-subspace
    projection is used instead; its rounding (``V^T A V``) is then not covered
    (``info.exact_restriction`` is False). The closed loops of this package never take that path.

    Parameters
    ----------
    A : array_like, (n, n)
    Ew : array_like, (n, gw)
    Ev : array_like, (n, gv)
    C : array_like, (p, n)
    Dw, Dv : array_like, (p, gw), (p, gv), optional
        Direct feedthrough of the disturbance generators (zero by default).
    H : array_like, (q, p), optional
        Output map (identity by default).
    eps : float
        Relative size of the tail bound.
    return_info : bool
        Also return a :class:`RadiusInfo`.

    Returns
    -------
    Kw : ndarray, (q, gw)
    Kv : ndarray, (q, gv)
    info : RadiusInfo, only with ``return_info``

    Raises
    ------
    NotStableError
        If ``A`` is not stable on the reachable subspace of ``(A, [Ew, Ev])``.
    """
    A = np.asarray(A, float)
    n = A.shape[0]
    Ew = np.asarray(Ew, float).reshape(n, -1)
    Ev = np.asarray(Ev, float).reshape(n, -1)
    C = np.atleast_2d(np.asarray(C, float))
    Hm = None if H is None else np.atleast_2d(np.asarray(H, float))
    HC = C if Hm is None else Hm @ C
    E = np.hstack([Ew, Ev])
    gw = Ew.shape[1]
    p = C.shape[0]
    V, Ar_o, rho = _restrict(A, E)
    J = _coordinate_restriction(A, E)
    AJ = A[np.ix_(J, J)]
    exact = J.size == 0 or float(np.max(np.abs(np.linalg.eigvals(AJ)))) < 1.0 - 1e-12
    if exact:
        Ar, Gr, Mr = AJ, E[J], HC[:, J]
    else:
        Ar, Gr, Mr = Ar_o, V.T @ E, HC @ V
    K, R_all, s, a, K_inner = _abs_sums_rounded(Ar, Gr, Mr, eps)
    q, r = Mr.shape
    if s and Hm is not None and exact:                     # fl(H C) instead of H C
        K = K + _gamma(p) * ((np.abs(Hm) @ np.abs(C))[:, J] @ R_all)
    HD, HDb = _feedthrough(Hm, Dw, Dv, p=p, gw=gw, gv=Ev.shape[1])
    K = (K + HDb) * (1.0 + _gamma(q + r + 32))
    K_inner = K_inner + HD
    Kw, Kv = K[:, :gw], K[:, gw:]
    if return_info:
        return Kw, Kv, RadiusInfo(Kw_inner=K_inner[:, :gw], Kv_inner=K_inner[:, gw:], s=s, a=a,
                                  reachable_dim=V.shape[1], spectral_radius=rho,
                                  exact_restriction=bool(exact))
    return Kw, Kv
