"""Zonotopes: the set representation of the paper (Sec. II-A).

A zonotope ``Z = (c, G)`` is the set ``{c + G beta | beta in [-1, 1]^m}`` (paper Def. 1).
:class:`Zonotope` is an immutable value: every operation returns a new zonotope, and the
centre and generator matrix are read-only copies. The operations follow CORA's naming
and are exact unless their docstring says "outer approximation".

Pure numpy/scipy; no ROS import.

References
----------
[TRO] Liu, Schuermann, Althoff, "Guarantees for Real Robotic Systems: Unifying Formal
      Controller Synthesis and Reachset-Conformant Identification", IEEE T-RO.
[Girard05] A. Girard, "Reachability of uncertain linear systems using zonotopes", HSCC 2005.
[Althoff10] M. Althoff, "Reachability analysis and its application to the safety
      assessment of autonomous cars", PhD thesis, TU Munich, 2010 (H-representation).
"""
from __future__ import annotations

import math
from itertools import combinations

import numpy as np

__all__ = ["Zonotope", "halfspace_normals", "box", "MAX_FACETS"]

#: Default limit on the number of facet pairs ``halfspaces`` will enumerate.
MAX_FACETS = 100_000



def _readonly(a):
    a = np.array(a, dtype=float, copy=True)
    a.setflags(write=False)
    return a


class Zonotope:
    """Immutable zonotope ``(c, G) = {c + G beta | ||beta||_inf <= 1}`` (paper Def. 1).

    Parameters
    ----------
    center : array_like, shape (n,)
        Centre ``c``.
    generators : array_like, shape (n, m), optional
        Generator matrix ``G``, one generator per column; ``m`` may be 0 (a point).

    Notes
    -----
    ``center`` and ``generators`` are read-only copies; all operations return new
    zonotopes. ``M @ Z`` (a linear map), ``Z + v`` / ``Z + Z2`` (Minkowski sum) and
    ``a * Z`` (scaling) are supported.
    """

    __slots__ = ("_c", "_G")
    __array_ufunc__ = None  # make ``ndarray @ Zonotope`` call Zonotope.__rmatmul__

    def __init__(self, center, generators=None):
        c = np.asarray(center, dtype=float)
        if c.ndim == 0:
            c = c.reshape(1)
        if c.ndim != 1:
            raise ValueError(f"zonotope centre must be a vector, got shape {c.shape}")
        if generators is None:
            G = np.zeros((c.shape[0], 0))
        else:
            G = np.asarray(generators, dtype=float)
            if G.ndim == 1 and c.shape[0] == 1:
                G = G.reshape(1, -1)
            elif G.ndim == 1:
                G = G.reshape(-1, 1)
        if G.ndim != 2 or G.shape[0] != c.shape[0]:
            raise ValueError(f"generator matrix of shape {G.shape} does not fit a centre of "
                             f"dimension {c.shape[0]}")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(G))):
            raise ValueError("zonotope centre and generators must be finite")
        self._c = _readonly(c)
        self._G = _readonly(G)

    # ------------------------------------------------------------------ basic access
    @property
    def center(self):
        """Centre ``c``, read-only array of shape (n,)."""
        return self._c

    @property
    def generators(self):
        """Generator matrix ``G``, read-only array of shape (n, m)."""
        return self._G

    @property
    def dim(self):
        """Dimension ``n`` of the ambient space."""
        return self._c.shape[0]

    @property
    def n_generators(self):
        """Number of generators ``m``."""
        return self._G.shape[1]

    def __repr__(self):
        if self._G.size <= 24:
            return f"Zonotope({self._c.tolist()!r}, {self._G.tolist()!r})"
        return f"Zonotope(dim={self.dim}, generators={self.n_generators})"

    # ------------------------------------------------------------------ constructors
    @classmethod
    def box(cls, lo, hi):
        """Axis-aligned box ``[lo, hi]`` as a zonotope.

        Syntax: ``Z = Zonotope.box(lo, hi)``

        Parameters
        ----------
        lo, hi : array_like, shape (n,)
            Lower and upper bounds, ``lo <= hi``.

        Returns
        -------
        Zonotope
            ``((lo + hi)/2, diag((hi - lo)/2))`` with zero-width axes dropped.
        """
        lo = np.atleast_1d(np.asarray(lo, dtype=float))
        hi = np.atleast_1d(np.asarray(hi, dtype=float))
        if lo.shape != hi.shape or lo.ndim != 1:
            raise ValueError(f"box bounds must be vectors of equal length, got {lo.shape}, {hi.shape}")
        if np.any(hi < lo):
            raise ValueError("box lower bound exceeds upper bound")
        r = (hi - lo) / 2.0
        G = np.diag(r)[:, r > 0]
        return cls((lo + hi) / 2.0, G)

    # ------------------------------------------------------------------ set operations
    def minkowski_sum(self, other):
        """Minkowski sum with a zonotope or a vector (paper Prop. 2).

        Syntax: ``Z = Z1.minkowski_sum(Z2)``, ``Z = Z1 + Z2``, ``Z = Z1 + v``

        Parameters
        ----------
        other : Zonotope or array_like, shape (n,)
            Second summand; a vector translates the zonotope.

        Returns
        -------
        Zonotope
            ``(c1 + c2, [G1, G2])``, exact.
        """
        if isinstance(other, Zonotope):
            if other.dim != self.dim:
                raise ValueError(f"Minkowski sum of zonotopes of dimension {self.dim} and {other.dim}")
            return Zonotope(self._c + other._c, np.hstack([self._G, other._G]))
        v = np.asarray(other, dtype=float)
        if v.ndim == 0:
            v = np.full(self.dim, float(v))
        if v.shape != (self.dim,):
            raise ValueError(f"cannot add a vector of shape {v.shape} to a {self.dim}-dim zonotope")
        return Zonotope(self._c + v, self._G)

    __add__ = minkowski_sum
    __radd__ = minkowski_sum

    def linear_map(self, M):
        """Linear transformation (paper Prop. 3).

        Syntax: ``Z = Z1.linear_map(M)``, ``Z = M @ Z1``

        Parameters
        ----------
        M : array_like, shape (p, n)
            Matrix.

        Returns
        -------
        Zonotope
            ``(M c, M G)``, exact.
        """
        M = np.asarray(M, dtype=float)
        if M.ndim == 0:
            return self.scale(float(M))
        if M.ndim == 1:
            M = M.reshape(1, -1)
        if M.ndim != 2 or M.shape[1] != self.dim:
            raise ValueError(f"matrix of shape {M.shape} cannot map a {self.dim}-dim zonotope")
        return Zonotope(M @ self._c, M @ self._G)

    def __rmatmul__(self, M):
        return self.linear_map(M)

    def scale(self, factor):
        """Scale about the origin: ``factor * Z = (factor c, factor G)``, exact."""
        f = float(factor)
        return Zonotope(f * self._c, f * self._G)

    def __mul__(self, factor):
        return self.scale(factor)

    __rmul__ = __mul__

    def project(self, dims):
        """Projection onto coordinates ``dims`` (exact).

        Syntax: ``Z = Z1.project([0, 1])``

        Parameters
        ----------
        dims : sequence of int
            Coordinates to keep, in order.

        Returns
        -------
        Zonotope
        """
        idx = np.atleast_1d(np.asarray(dims, dtype=int))
        return Zonotope(self._c[idx], self._G[idx, :])

    # ------------------------------------------------------------------ size
    def radius(self):
        """Interval-hull half-widths ``delta = sum_h |g^(h)|`` (paper Prop. 4).

        Returns
        -------
        ndarray, shape (n,)
        """
        return np.abs(self._G).sum(axis=1)

    def interval_hull(self):
        """Smallest enclosing box ``[c - delta, c + delta]`` (paper Prop. 4).

        Syntax: ``lo, hi = Z.interval_hull()``

        Returns
        -------
        lo, hi : ndarray, shape (n,)
        """
        d = self.radius()
        return self._c - d, self._c + d

    def norm(self):
        """Size of the zonotope: the sum of the interval hull's edge lengths, ``2 sum(delta)``.

        This is the quantity the paper's tables report as ``||R_e||`` (e.g. Table II). Note
        that the paper's Definition 2 writes ``||Z|| = sum_i |delta_i|``, i.e. half of
        this value; the factor 2 is what reproduces the tabulated numbers. Use
        ``Z.radius().sum()`` for the Definition-2 value.

        Returns
        -------
        float
        """
        return float(2.0 * self.radius().sum())

    # ------------------------------------------------------------------ support function
    def support(self, directions):
        """Support function ``h_Z(l) = l^T c + sum_h |l^T g^(h)|`` for each row ``l``.

        Parameters
        ----------
        directions : array_like, shape (k, n) or (n,)

        Returns
        -------
        ndarray, shape (k,) (or float for a single direction)
        """
        L = np.asarray(directions, dtype=float)
        single = L.ndim == 1
        L = np.atleast_2d(L)
        h = L @ self._c + np.abs(L @ self._G).sum(axis=1)
        return float(h[0]) if single else h

    # ------------------------------------------------------------------ simplification
    def compact(self, tol=1e-12):
        """Remove zero generators and merge parallel ones (exact).

        Parameters
        ----------
        tol : float
            Generators shorter than ``tol * max generator length`` are dropped; two
            generators are parallel when their unit vectors agree up to sign within ``tol``.

        Returns
        -------
        Zonotope
        """
        return Zonotope(self._c, _compact_generators(self._G, tol))

    def reduce(self, order):
        """Order reduction by Girard's method (outer approximation) [Girard05].

        Syntax: ``Z = Z1.reduce(order)``

        The ``n * (order - 1)`` generators with the largest ``||g||_1 - ||g||_inf`` are
        kept, the others are enclosed by their interval hull (``n`` axis-aligned
        generators). The result has at most ``n * order`` generators and contains ``Z1``.

        Parameters
        ----------
        order : float, >= 1
            Target order ``m / n``.

        Returns
        -------
        Zonotope
            An outer approximation with at most ``floor(n * order)`` generators.
        """
        if order < 1:
            raise ValueError(f"reduction order must be at least 1, got {order}")
        n, m = self._G.shape
        G = self._G[:, np.any(self._G != 0, axis=0)]
        m = G.shape[1]
        if m <= n * order:
            return Zonotope(self._c, G)
        n_keep = int(math.floor(n * (order - 1)))
        metric = np.abs(G).sum(axis=0) - np.abs(G).max(axis=0)
        idx = np.argsort(-metric, kind="stable")
        keep, red = G[:, idx[:n_keep]], G[:, idx[n_keep:]]
        box_r = np.abs(red).sum(axis=1)
        Gb = np.diag(box_r)[:, box_r > 0]
        return Zonotope(self._c, np.hstack([keep, Gb]))

    # ------------------------------------------------------------------ H-representation
    def halfspaces(self, max_facets=MAX_FACETS, tol=1e-10):
        """Half-space representation ``{x | N x <= d}`` (paper Prop. 1).

        Syntax: ``N, d = Z.halfspaces()``

        Normals are generalized cross products ``nX`` of all ``(r-1)``-subsets of the
        (compacted) generators, where ``r`` is the dimension of the zonotope's affine hull;
        rows come in pairs ``N = [N+; -N+]``, ``d = [d+; d-]`` with
        ``d+ = N+ c + Delta d`` and ``d- = -N+ c + Delta d``,
        ``Delta d_j = sum_h |n_j^T g^(h)|``.

        Degenerate generator sets are handled: zero generators are dropped and parallel
        ones merged first; if ``G`` does not have full row rank, the facets are computed
        inside the affine hull ``c + span(G)`` and each direction ``u`` orthogonal to it
        adds the pair ``u x <= u c``, ``-u x <= -u c`` (an equality as two inequalities).
        A point (no generators) is described by equalities only.

        Sign convention: each ``n+`` is a unit vector whose first non-zero entry (beyond
        ``tol``) is positive; ``-n+`` is the opposite half-space.

        Parameters
        ----------
        max_facets : int
            Raise before enumerating more than this many facet pairs.
        tol : float
            Relative tolerance for rank decisions and for dropping duplicate normals.

        Returns
        -------
        N : ndarray, shape (2 k, n)
            Unit normals.
        d : ndarray, shape (2 k,)
            Offsets.

        Raises
        ------
        ValueError
            If the number of facet pairs ``C(m, r-1)`` exceeds ``max_facets``.
        """
        Np = halfspace_normals(self._G, max_facets=max_facets, tol=tol)
        delta = np.abs(Np @ self._G).sum(axis=1)
        proj = Np @ self._c
        N = np.vstack([Np, -Np])
        d = np.concatenate([proj + delta, -proj + delta])
        return N, d

    # ------------------------------------------------------------------ containment
    def contains(self, points, tol=1e-9):
        """Point containment, exact up to ``tol``.

        Syntax: ``inside = Z.contains(p)``; ``mask = Z.contains(P)`` for rows of ``P``

        A point ``p`` is inside iff ``min ||beta||_inf`` subject to
        ``||G beta - (p - c)||_inf <= tol * size`` is at most ``1 + tol`` (a linear programme
        solved with scipy's HiGHS); ``size = max(max(delta), max|c|)``. One-dimensional
        zonotopes and axis-aligned boxes use an interval check instead.

        Parameters
        ----------
        points : array_like, shape (n,) or (k, n)
        tol : float
            Relative tolerance.

        Returns
        -------
        bool or ndarray of bool, shape (k,)
        """
        P = np.asarray(points, dtype=float)
        single = P.ndim == 1
        P = np.atleast_2d(P)
        if P.shape[1] != self.dim:
            raise ValueError(f"points of dimension {P.shape[1]} tested against a {self.dim}-dim zonotope")
        G = _compact_generators(self._G, 1e-14)
        scale = max(float(np.abs(G).sum(axis=1).max(initial=0.0)), float(np.abs(self._c).max()), 1e-300)
        D = P - self._c
        if G.shape[1] == 0:
            res = np.all(np.abs(D) <= tol * scale, axis=1)
        elif np.all(np.count_nonzero(G, axis=0) == 1):
            # interval: each generator moves one coordinate only
            r = np.abs(G).sum(axis=1)
            res = np.all(np.abs(D) <= r * (1 + tol) + tol * scale, axis=1)
        else:
            r = np.abs(G).sum(axis=1)
            res = np.all(np.abs(D) <= r * (1 + tol) + tol * scale, axis=1)  # interval hull first
            res[res] = [_lp_contains(G, dv, tol, scale) for dv in D[res]]
        return bool(res[0]) if single else res

    def contained_in_interval(self, lo, hi, tol=0.0):
        """Whether the zonotope lies in the box ``[lo, hi]`` (exact, via the interval hull).

        Parameters
        ----------
        lo, hi : array_like, shape (n,)
        tol : float
            Absolute slack.

        Returns
        -------
        bool
        """
        zlo, zhi = self.interval_hull()
        return bool(np.all(zlo >= np.asarray(lo, float) - tol) and np.all(zhi <= np.asarray(hi, float) + tol))

    def contained_in_polytope(self, H, h, tol=0.0):
        """Whether the zonotope lies in ``{x | H x <= h}`` (exact, via support functions).

        ``Z`` is inside iff ``h_Z(H_i) <= h_i`` for every row ``i`` (cf. Schuermann et al.
        2021, Lemma 2, cited in the paper's Sec. III-D).

        Parameters
        ----------
        H : array_like, shape (k, n)
        h : array_like, shape (k,)
        tol : float
            Absolute slack.

        Returns
        -------
        bool
        """
        H = np.atleast_2d(np.asarray(H, dtype=float))
        return bool(np.all(self.support(H) <= np.asarray(h, dtype=float) + tol))

    # ------------------------------------------------------------------ sampling
    def sample(self, n, rng=None, method="uniform"):
        """Random points of the zonotope.

        Parameters
        ----------
        n : int
            Number of points.
        rng : numpy.random.Generator or int, optional
        method : {"uniform", "vertices"}
            ``"uniform"``: ``beta`` uniform in the cube ``[-1, 1]^m`` (points are in ``Z``
            but not uniform in ``Z``); ``"vertices"``: ``beta`` uniform among the cube's
            vertices ``{-1, 1}^m`` (extreme combinations, may include vertices of ``Z``).

        Returns
        -------
        ndarray, shape (n, dim)
        """
        rng = np.random.default_rng(rng)
        m = self.n_generators
        if method == "uniform":
            B = rng.uniform(-1.0, 1.0, size=(n, m))
        elif method == "vertices":
            B = rng.choice([-1.0, 1.0], size=(n, m))
        else:
            raise ValueError(f"unknown sampling method {method!r} (use 'uniform' or 'vertices')")
        return self._c + B @ self._G.T


def box(lo, hi):
    """Axis-aligned box ``[lo, hi]`` as a zonotope; see :meth:`Zonotope.box`."""
    return Zonotope.box(lo, hi)


# ---------------------------------------------------------------------- helpers
def _compact_generators(G, tol=1e-12):
    """Drop (near-)zero generators and merge parallel ones (sum of lengths, same direction)."""
    G = np.asarray(G, dtype=float)
    if G.shape[1] == 0:
        return G
    lengths = np.abs(G).max(axis=0)  # infinity norm: no underflow for tiny generators
    gmax = lengths.max()
    if gmax == 0:
        return G[:, :0]
    keep = lengths > tol * gmax
    G, lengths = G[:, keep], lengths[keep]
    U = G / lengths
    # canonical sign: the largest-magnitude entry (first on ties) is positive
    piv = np.argmax(np.abs(U) > 1 - 1e-9, axis=0)
    U = U * np.sign(U[piv, np.arange(U.shape[1])])
    keys = np.round(U / max(tol, 1e-12) / 10).astype(np.int64)
    _, first, inv = np.unique(keys.T, axis=0, return_index=True, return_inverse=True)
    total = np.zeros(first.size)
    np.add.at(total, inv.ravel(), lengths)
    order = np.argsort(first)
    return U[:, first[order]] * total[order]


def _orth_split(G, tol):
    """Orthonormal bases of span(G) and of its orthogonal complement."""
    n = G.shape[0]
    if G.shape[1] == 0:
        return np.zeros((n, 0)), np.eye(n)
    U, s, _ = np.linalg.svd(G, full_matrices=True)
    r = int(np.sum(s > tol * s[0])) if s.size and s[0] > 0 else 0
    return U[:, :r], U[:, r:]


def _canonical_sign(N, tol=1e-9):
    first = np.argmax(np.abs(N) > tol, axis=1)
    sgn = np.sign(N[np.arange(N.shape[0]), first])
    sgn[sgn == 0] = 1.0
    return N * sgn[:, None]


def _unique_rows(N, tol):
    """Rows of ``N`` without near-duplicates (rounded to ``tol``), in first-occurrence order."""
    if N.shape[0] <= 1:
        return N
    _, first = np.unique(np.round(N / tol).astype(np.int64), axis=0, return_index=True)
    return N[np.sort(first)]


def _cross_normals(G):
    """Generalized cross products nX (paper Prop. 1) of all (n-1)-column subsets of G (n x m).

    Returns an array of shape (C(m, n-1), n), not normalised.
    """
    n, m = G.shape
    combos = np.array(list(combinations(range(m), n - 1)), dtype=int)
    if n == 1:
        return np.ones((1, 1))
    H = G[:, combos].transpose(1, 0, 2)  # (k, n, n-1)
    out = np.empty((combos.shape[0], n))
    for i in range(n):
        minor = np.delete(H, i, axis=1)  # (k, n-1, n-1)
        out[:, i] = (-1) ** i * np.linalg.det(minor)  # (-1)^(i+1) with 1-based i
    return out


def halfspace_normals(G, max_facets=MAX_FACETS, tol=1e-10):
    """Unique unit normals ``N+`` of the zonotope with generator matrix ``G`` (paper Prop. 1).

    Syntax: ``Nplus = halfspace_normals(G)``

    The normal directions do not depend on positive generator scalings (paper Theorem 1,
    proof), so conformance code calls this with the *unscaled* generators ``G'``. Each row
    is one facet pair: the zonotope ``(c, G diag(alpha))`` is
    ``{x | N+ x <= N+ c + Delta d, -N+ x <= -N+ c + Delta d}`` with
    ``Delta d = |N+ G| alpha`` for every ``alpha > 0``.

    Zero generators are dropped and parallel ones merged; for a rank-deficient ``G`` the
    normals are computed in ``span(G)`` and an orthonormal basis of the orthogonal
    complement is appended (those rows give equality constraints, ``Delta d = 0``).

    Parameters
    ----------
    G : array_like, shape (n, m)
        Generator matrix.
    max_facets : int
        Raise ``ValueError`` before enumerating more facet pairs than this.
    tol : float
        Relative tolerance for the rank and for identifying duplicate normals.

    Returns
    -------
    ndarray, shape (k, n)
        Unit normals, sign-normalised (first non-zero entry positive), one per facet pair.
    """
    G = np.atleast_2d(np.asarray(G, dtype=float))
    n = G.shape[0]
    Gc = _compact_generators(G, tol)
    U, Uperp = _orth_split(Gc, tol)
    r = U.shape[1]
    if r == 0:
        return _canonical_sign(Uperp.T.copy())
    Gr = U.T @ Gc  # (r, m) full row rank
    m = Gr.shape[1]
    count = math.comb(m, r - 1)
    if count > max_facets:
        raise ValueError(f"zonotope H-representation would have {2 * count} facets "
                         f"({count} pairs from C({m}, {r - 1})), more than the limit of "
                         f"{2 * max_facets}; reduce the zonotope's order first")
    Nr = _cross_normals(Gr)
    lens = np.linalg.norm(Nr, axis=1)
    ok = lens > tol * max(lens.max(initial=0.0), 1e-300)
    Nr = Nr[ok] / lens[ok, None]
    N = Nr @ U.T
    N = _canonical_sign(N)
    N = _unique_rows(N, 1e-9)
    if Uperp.shape[1]:
        N = np.vstack([N, _canonical_sign(Uperp.T.copy())])
    return N


def _lp_contains(G, dv, tol, scale):
    """LP point containment: ``min t`` s.t. ``|G beta - dv| <= tol*scale``, ``|beta_j| <= t``."""
    n, m = G.shape
    gs = np.abs(G).max()
    Gn, b, tau = G / gs, dv / gs, tol * scale / gs  # HiGHS ignores entries below 1e-9: normalise
    c = np.zeros(m + 1)
    c[-1] = 1.0
    I, one = np.eye(m), np.ones((m, 1))
    zero = np.zeros((n, 1))
    A_ub = np.block([[I, -one], [-I, -one], [Gn, zero], [-Gn, zero]])
    b_ub = np.concatenate([np.zeros(2 * m), b + tau, -b + tau])
    from scipy.optimize import linprog  # lazy: 0.3 s of start-up (issue 38.1)
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=[(None, None)] * m + [(0, None)], method="highs")
    if res.status == 2:  # infeasible: p - c is not in span(G) within the tolerance
        return False
    if res.status != 0:
        raise RuntimeError(f"containment LP failed: {res.message}")
    return bool(res.fun <= 1.0 + tol)
