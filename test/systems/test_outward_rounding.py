"""Outward rounding of the invariant-set radius coefficients (issue 14.7).

``radius_coefficients`` must return upper bounds, in floating point, of the exact sums
``sum_{i>=0} |C A^i E_j| + |D_j|`` of the closed-loop matrices as given. The reference is a
brute-force sum in x87 extended precision (64-bit mantissa; checked against a 34-digit
mpmath sum of the same matrices to 6e-18 relative for the ESO and LQG loops), long enough
that the remaining terms are below 1e-40.
"""
import numpy as np
import pytest

from reachset_ros.sets.reachability import EPS, radius_coefficients
from reachset_ros.systems.closedloop import close_loop
from reachset_ros.systems.closedloop import radius_coefficients as cl_radius
from test_closedloop import LOOPS

LD = np.finfo(np.longdouble)
pytestmark = pytest.mark.skipif(LD.eps > 1e-18, reason="needs an extended-precision long double")
#: Relative accuracy claimed for the extended-precision reference (measured: 6e-18).
REF_TOL = 1e-15


def _reference(cl, steps=20000):
    A = cl.A.astype(np.longdouble)
    C = cl.C.astype(np.longdouble)
    X = np.hstack([cl.Ew, cl.Ev]).astype(np.longdouble)
    S = np.abs(np.hstack([np.zeros((cl.C.shape[0], cl.Ew.shape[1])), cl.DEv])).astype(np.longdouble)
    for _ in range(steps):
        S += np.abs(C @ X)
        X = A @ X
    assert float(np.abs(X).max()) < 1e-40
    return S


@pytest.mark.parametrize("name", list(LOOPS))
def test_coefficients_are_outer_bounds_in_floating_point(name):
    """HEAD (no outward rounding) is 6.5e-13 below for eso+compensated, 8.8e-11 for lqg."""
    plant, obs, ctrl, _, _ = LOOPS[name]
    cl = close_loop(plant, obs, ctrl)
    Kw, Kv, info = cl_radius(cl, return_info=True)
    assert info.exact_restriction
    K = np.hstack([Kw, Kv]).astype(np.longdouble)
    ref = _reference(cl)
    below = ref * (1 + REF_TOL) - K
    assert np.all(below <= 0), f"{name}: {float((below / ref).max()):.3g} relative below the exact sum"
    # not looser than the documented tail bound (eps relative) plus rounding
    assert np.all(K <= ref * (1 + 2 * EPS) + 1e-300)


def test_outward_rounding_with_an_output_map_and_feedthrough():
    rng = np.random.default_rng(3)
    for _ in range(5):
        A = rng.normal(size=(5, 5))
        A *= 0.9 / np.max(np.abs(np.linalg.eigvals(A)))
        Ew, Ev, C = rng.normal(size=(5, 2)), rng.normal(size=(5, 1)), rng.normal(size=(3, 5))
        Dv, H = rng.normal(size=(3, 1)), rng.normal(size=(2, 3))
        Kw, Kv = radius_coefficients(A, Ew, Ev, C, Dv=Dv, H=H)
        Al, Cl, Hl = (m.astype(np.longdouble) for m in (A, C, H))
        X = np.hstack([Ew, Ev]).astype(np.longdouble)
        D = np.hstack([np.zeros((3, 2)), Dv]).astype(np.longdouble)
        S = np.abs(Hl @ D)
        HC = Hl @ Cl
        for _ in range(3000):
            S += np.abs(HC @ X)
            X = Al @ X
        K = np.hstack([Kw, Kv]).astype(np.longdouble)
        assert np.all(K >= S * (1 + REF_TOL))
        assert np.all(K <= S * (1 + 2 * EPS) + 1e-300)
