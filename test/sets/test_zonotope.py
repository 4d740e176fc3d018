"""Zonotope value type: paper Props. 1-4, containment, reduction (reachset_ros.sets.zonotope)."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from reachset_ros.sets.zonotope import Zonotope, box, halfspace_normals

Z_PAPER = Zonotope([-4, 1], [[-3, -2, -1], [2, 3, 4]])


def _rows_as_set(N, d, digits=9):
    return sorted((tuple(np.round(n, digits)), round(float(o), digits)) for n, o in zip(N, d))


def test_interval_hull_of_the_issue_example():
    lo, hi = Z_PAPER.interval_hull()
    np.testing.assert_allclose(lo, [-10, -8])
    np.testing.assert_allclose(hi, [2, 10])
    np.testing.assert_allclose(Z_PAPER.radius(), [6, 9])
    # norm = sum of the interval hull's edge lengths (what the paper's tables report)
    assert Z_PAPER.norm() == pytest.approx(2 * (6 + 9))


def test_halfspaces_of_the_issue_example_exact():
    """Normals +-[2,3]/sqrt13, +-[3,2]/sqrt13, +-[4,1]/sqrt17 (= 0.5547..., 0.8321..., 0.9701...).

    Sign convention of ``halfspaces``: rows come as [N+; -N+]; each n+ has its first
    non-zero entry positive. Expected offsets from Prop. 1 by hand:
    d+ = n.c + sum|n.g|, d- = -n.c + sum|n.g|.
    """
    s13, s17 = math.sqrt(13), math.sqrt(17)
    expected = [((2 / s13, 3 / s13), 10 / s13), ((-2 / s13, -3 / s13), 20 / s13),
                ((3 / s13, 2 / s13), 0.0), ((-3 / s13, -2 / s13), 20 / s13),
                ((4 / s17, 1 / s17), 0.0), ((-4 / s17, -1 / s17), 30 / s17)]
    N, d = Z_PAPER.halfspaces()
    assert N.shape == (6, 2)
    got = sorted(zip(map(tuple, N), d))
    exp = sorted(expected)
    for (gn, gd), (en, ed) in zip(got, exp):
        np.testing.assert_allclose(gn, en, atol=1e-9)
        assert gd == pytest.approx(ed, abs=1e-9)
    # the 4-digit values quoted in the issue
    quoted = {(0.5547, 0.8321): (2.7735, 5.5470), (0.8321, 0.5547): (0.0, 5.5470),
              (0.9701, 0.2425): (0.0, 7.2761)}
    Np, k = N[:3], 3
    for n, (dp, dm) in quoted.items():
        i = int(np.argmin(np.abs(Np - n).sum(axis=1)))
        np.testing.assert_allclose(Np[i], n, atol=1e-4)
        assert d[i] == pytest.approx(dp, abs=1e-4) and d[i + k] == pytest.approx(dm, abs=1e-4)
    np.testing.assert_allclose(N[3:], -N[:3])


def test_halfspace_normals_independent_of_positive_scaling():
    """Paper Theorem 1 (proof): normals from G' equal those from G' diag(alpha), alpha > 0."""
    rng = np.random.default_rng(3)
    G = rng.normal(size=(3, 5))
    a = rng.uniform(0.1, 5, size=5)
    N1, N2 = halfspace_normals(G), halfspace_normals(G * a)
    assert N1.shape == N2.shape == (10, 3)
    assert _rows_as_set(N1, np.zeros(10)) == _rows_as_set(N2, np.zeros(10))
    assert halfspace_normals(np.array([[0.3, -2.0]])).tolist() == [[1.0]]


def test_degenerate_generators_zero_and_parallel():
    Z = Zonotope([1.0, 2.0], [[1, 0, 2, 0, -1], [1, 0, 2, 3, -1]])  # zero column, three parallel
    N, d = Z.halfspaces()
    assert N.shape[0] == 4  # a parallelogram: 2 facet pairs
    pts = Z.sample(200, rng=0, method="vertices")
    assert np.all(N @ pts.T <= d[:, None] + 1e-9)


def test_rank_deficient_zonotope_gets_equalities():
    # a parallelogram in the plane z = 5 of R^3
    Z = Zonotope([0.0, 0.0, 5.0], [[1, 1], [0, 2], [0, 0]])
    N, d = Z.halfspaces()
    inside = Z.sample(50, rng=1)
    assert np.all(N @ inside.T <= d[:, None] + 1e-9)
    off_plane = inside + np.array([0, 0, 1e-3])
    assert np.all(np.any(N @ off_plane.T > d[:, None] + 1e-9, axis=0))
    assert not Z.contains(off_plane[0]) and Z.contains(inside[0])
    # a segment in R^3 and a single point
    seg = Zonotope([1, 1, 1], [[1], [1], [0]])
    Ns, ds = seg.halfspaces()
    assert np.all(Ns @ np.array([1.5, 1.5, 1]) <= ds + 1e-12)
    assert np.any(Ns @ np.array([1.5, 1.4, 1]) > ds + 1e-9)
    pt = Zonotope([1.0, -1.0])
    Np, dp = pt.halfspaces()
    assert np.all(Np @ pt.center <= dp + 1e-12) and Np.shape == (4, 2)


def test_facet_explosion_raises_before_enumerating():
    G = np.random.default_rng(0).normal(size=(6, 60))  # C(60, 5) = 5,461,512 facet pairs
    with pytest.raises(ValueError, match="5461512 pairs"):
        Zonotope(np.zeros(6), G).halfspaces()
    with pytest.raises(ValueError, match="facets"):
        halfspace_normals(G, max_facets=1000)


def test_operations_and_immutability():
    Z = Z_PAPER
    M = np.array([[2.0, 0.0], [1.0, 1.0]])
    MZ = M @ Z
    assert isinstance(MZ, Zonotope)
    np.testing.assert_allclose(MZ.center, M @ Z.center)
    np.testing.assert_allclose((Z + Z).generators, np.hstack([Z.generators] * 2))
    np.testing.assert_allclose((Z + np.array([1.0, 1.0])).center, [-3, 2])
    np.testing.assert_allclose((0.5 * Z).generators, Z.generators / 2)
    with pytest.raises(ValueError):
        Z.center[0] = 3.0
    c = np.array([1.0, 2.0])
    Zc = Zonotope(c, np.eye(2))
    c[0] = 99
    assert Zc.center[0] == 1.0
    P = Z.project([1])
    assert P.dim == 1 and P.interval_hull() == (pytest.approx([-8]), pytest.approx([10]))


def test_box_and_interval_and_polytope_containment():
    B = box([-1, 0], [1, 4])
    np.testing.assert_allclose(B.interval_hull()[0], [-1, 0])
    assert B.contains([0.99, 3.99]) and not B.contains([1.01, 2])
    assert Z_PAPER.contained_in_interval([-10, -8], [2, 10])
    assert not Z_PAPER.contained_in_interval([-10, -8], [2, 9.9])
    N, d = Z_PAPER.halfspaces()
    assert Z_PAPER.contained_in_polytope(N, d + 1e-9)
    assert not Z_PAPER.contained_in_polytope(N, d - 1e-3)
    assert Zonotope([0.0], [[1.0, -2.0]]).contains(np.array([[2.9], [3.1]])).tolist() == [True, False]


def test_reduce_is_an_outer_approximation():
    rng = np.random.default_rng(5)
    Z = Zonotope(rng.normal(size=3), rng.normal(size=(3, 20)))
    R = Z.reduce(2)
    assert R.n_generators <= 6
    assert np.all(R.radius() >= Z.radius() - 1e-12)
    pts = Z.sample(30, rng=rng, method="vertices")
    assert np.all(R.contains(pts))
    assert Z.reduce(10).n_generators == 20


def test_sample_points_are_inside_and_vertices_option():
    pts = Z_PAPER.sample(100, rng=0, method="vertices")
    assert Z_PAPER.contains(pts).all()
    betas = np.linalg.lstsq(Z_PAPER.generators, (pts - Z_PAPER.center).T, rcond=None)[0]
    assert np.all(np.abs(np.abs(Z_PAPER.generators @ betas) - np.abs(pts - Z_PAPER.center).T) < 1e-9)
    with pytest.raises(ValueError):
        Z_PAPER.sample(3, method="nope")


# ---------------------------------------------------------------- property tests
# magnitudes near the floating-point underflow are out of scope
_coef = st.floats(-3, 3, allow_nan=False, allow_infinity=False).map(lambda x: 0.0 if abs(x) < 1e-6 else x)


@st.composite
def zonotopes(draw, dims=(2, 3)):
    n = draw(st.sampled_from(dims))
    m = draw(st.integers(n, n + 3))
    G = draw(arrays(float, (n, m), elements=_coef))
    c = draw(arrays(float, (n,), elements=_coef))
    return Zonotope(c, G)


@settings(max_examples=25, deadline=None)
@given(Z=zonotopes(), seed=st.integers(0, 2 ** 31))
def test_hrep_agrees_with_lp_containment(Z, seed):
    """A point satisfies N x <= d iff the LP finds beta in [-1,1]^m with c + G beta = x."""
    rng = np.random.default_rng(seed)
    N, d = Z.halfspaces()
    lo, hi = Z.interval_hull()
    pts = rng.uniform(lo - 0.5, hi + 0.5, size=(8, Z.dim))
    margin = (N @ pts.T - d[:, None]).max(axis=0)
    scale = 1 + np.abs(d).max()
    keep = np.abs(margin) > 1e-6 * scale  # not on the boundary
    lp = Z.contains(pts[keep], tol=1e-9)
    np.testing.assert_array_equal(lp, margin[keep] < 0)


@settings(max_examples=20, deadline=None)
@given(Z1=zonotopes(dims=(2,)), Z2=zonotopes(dims=(2,)), M=arrays(float, (3, 2), elements=_coef),
       seed=st.integers(0, 2 ** 31))
def test_linear_map_and_minkowski_sum_commute_with_sampling(Z1, Z2, M, seed):
    rng = np.random.default_rng(seed)
    b1 = rng.uniform(-1, 1, size=(3, Z1.n_generators))
    b2 = rng.uniform(-1, 1, size=(3, Z2.n_generators))
    p1 = Z1.center + b1 @ Z1.generators.T
    p2 = Z2.center + b2 @ Z2.generators.T
    S = Z1 + Z2
    np.testing.assert_allclose(p1 + p2, S.center + np.hstack([b1, b2]) @ S.generators.T, atol=1e-12)
    assert S.contains(p1 + p2, tol=1e-7).all()
    MZ = M @ Z1
    np.testing.assert_allclose(p1 @ M.T, MZ.center + b1 @ MZ.generators.T, atol=1e-12)
    assert MZ.contains(p1 @ M.T, tol=1e-7).all()
    lo, hi = MZ.interval_hull()
    assert np.all((p1 @ M.T >= lo - 1e-9) & (p1 @ M.T <= hi + 1e-9))
