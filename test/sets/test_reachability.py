"""Reachability (paper eqs. 3-4, 8-10) and sound invariant sets (reachset_ros.sets.reachability)."""
import time

import numpy as np
import pytest

from reachset_ros.sets.reachability import (NotStableError, disturbance_output_sets, invariant_outer,
                                       markov_parameters, nominal_outputs, radius_coefficients,
                                       rakovic_alpha, reachable_outputs, reachable_subspace,
                                       truncated_sum)
from reachset_ros.sets.zonotope import Zonotope

A_RAKOVIC = np.array([[-0.17, -0.03], [-1.17, -0.03]])
W_BOX = Zonotope.box([-1, -1], [1, 1])


def test_rakovic_2005_example_alpha_10():
    """Rakovic et al. 2005: alpha^o(10) ~ 1.919e-5 for W = [-1, 1]^2."""
    a = rakovic_alpha(A_RAKOVIC, W_BOX, 10)
    assert a == pytest.approx(1.919e-5, rel=1e-3)
    A10 = np.linalg.matrix_power(A_RAKOVIC, 10)
    N, d = W_BOX.halfspaces()
    assert (A10 @ W_BOX).contained_in_polytope(N, a * d + 1e-15)      # A^10 W in a W
    assert not (A10 @ W_BOX).contained_in_polytope(N, 0.999 * a * d)  # and a is the smallest


@pytest.mark.parametrize("method", ["rakovic", "norm"])
def test_invariant_outer_contains_long_truncations(method):
    res = invariant_outer(A_RAKOVIC, np.eye(2), eps=1e-6, method=method)
    assert res.method == method and res.a < 1
    long_sum = truncated_sum(A_RAKOVIC, W_BOX, 400)
    assert np.all(long_sum.radius() <= res.outer.radius() + 1e-12)
    assert np.all(res.inner.radius() <= long_sum.radius() + 1e-12)
    assert np.all(res.outer.radius() <= res.inner.radius() * (1 + 1e-5))
    if method == "rakovic":
        # (1-a)^-1 F_s is robust positively invariant: A O (+) W is inside O
        step = A_RAKOVIC @ res.outer + W_BOX
        N, d = res.outer.halfspaces()
        assert step.contained_in_polytope(N, d + 1e-12)


def test_unreachable_eigenvalue_one_mode_is_ignored():
    # an integrator (eigenvalue 1) that the disturbance cannot reach, coupled into the rest
    A = np.zeros((3, 3))
    A[:2, :2] = A_RAKOVIC
    A[2, 2] = 1.0
    A[0, 2] = 0.5
    G = np.vstack([np.eye(2), np.zeros((1, 2))])
    V = reachable_subspace(A, G)
    assert V.shape == (3, 2)
    res = invariant_outer(A, G)
    ref = invariant_outer(A_RAKOVIC, np.eye(2), method="norm")
    np.testing.assert_allclose(res.outer.radius()[:2], ref.outer.radius(), rtol=1e-6)
    assert res.outer.radius()[2] == pytest.approx(0.0, abs=1e-12)
    Kw, Kv = radius_coefficients(A, G[:, :1], G[:, 1:], np.eye(3))
    np.testing.assert_allclose((Kw + Kv)[:, 0], res.outer.radius(), rtol=1e-5)
    # once the disturbance reaches the integrator, it must be reported
    with pytest.raises(NotStableError, match="spectral radius"):
        invariant_outer(A, np.eye(3))
    with pytest.raises(NotStableError):
        radius_coefficients(A, np.eye(3)[:, :1], np.eye(3)[:, 2:], np.eye(3))


def test_radius_coefficients_linear_and_sound():
    rng = np.random.default_rng(0)
    n = 6
    A = rng.normal(size=(n, n))
    A *= 0.9 / np.max(np.abs(np.linalg.eigvals(A)))
    Ew, Ev = rng.normal(size=(n, 2)), rng.normal(size=(n, 1))
    C = rng.normal(size=(3, n))
    Dv = rng.normal(size=(3, 1))
    H = np.array([[1.0, 0, 0], [0, 1, 1]])
    Kw, Kv, info = radius_coefficients(A, Ew, Ev, C, Dv=Dv, H=H, return_info=True)
    assert Kw.shape == (2, 2) and Kv.shape == (2, 1)
    aw, av = np.array([0.3, 2.0]), np.array([0.7])
    # exact infinite sum approximated by a very long truncation: below the bound, close to it
    E = markov_parameters(A, H @ C, np.hstack([Ew * aw, Ev * av]), 3000)
    exact = np.abs(E).sum(axis=(0, 2)) + np.abs(H @ Dv * av).sum(axis=1)
    bound = Kw @ aw + Kv @ av
    assert np.all(exact <= bound + 1e-12)
    np.testing.assert_allclose(bound, exact, rtol=1e-5)
    assert np.all(info.Kw_inner <= Kw) and np.all(info.Kv_inner <= Kv)
    # linear in alpha: scaling one generator scales its contribution
    np.testing.assert_allclose(Kw @ (2 * aw) + Kv @ av, bound + Kw @ aw)


def test_superposition_reachable_sets_contain_simulations():
    """R[k] = y*[k] (+) R_a[k] (paper eqs. 4 and 8-10) encloses simulated outputs."""
    rng = np.random.default_rng(1)
    A = np.array([[0.9, 0.2, 0.0], [-0.1, 0.8, 0.1], [0.0, 0.0, 0.5]])
    B = np.array([[0.0], [1.0], [0.5]])
    C = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    D = np.array([[0.1], [0.0]])
    W = Zonotope([0.01, 0, 0], np.array([[0.05, 0], [0, 0.02], [0.01, 0.01]]))
    V = Zonotope([0.0, 0.001], np.diag([0.01, 0.02]))
    X0 = Zonotope([1.0, -1.0, 0.5], 0.1 * np.eye(3))
    K = 12
    u = rng.normal(size=(K + 1, 1))
    R = reachable_outputs(A, B, C, D, X0, u, W, V)
    Ra = disturbance_output_sets(A, C, W, V, K)
    ys = nominal_outputs(A, B, C, D, X0.center, u)
    assert len(R) == K + 1 and Ra[0].n_generators == 2
    # eq. 10: generators [E_0 G_W, ..., E_{k-1} G_W, G_V]
    np.testing.assert_allclose(Ra[3].generators[:, :2], C @ W.generators)
    np.testing.assert_allclose(Ra[3].generators[:, 4:6], C @ A @ A @ W.generators)
    np.testing.assert_allclose(Ra[3].center, C @ (np.eye(3) + A + A @ A) @ W.center + V.center)
    for k in range(K + 1):
        np.testing.assert_allclose(R[k].center, ys[k] + Ra[k].center)
    for trial in range(20):
        x = X0.sample(1, rng, method="vertices")[0]
        for k in range(K + 1):
            v = V.sample(1, rng, method="vertices")[0]
            y = C @ x + D @ u[k] + v
            lo, hi = R[k].interval_hull()
            assert np.all((y >= lo - 1e-12) & (y <= hi + 1e-12))
            if trial < 2:
                assert R[k].contains(y, tol=1e-9)
            x = A @ x + B @ u[k] + W.sample(1, rng, method="vertices")[0]


def test_radius_coefficients_fast_for_the_lwa4p_loops():
    from reachset_ros.systems.closedloop import close_loop
    from reachset_ros.systems.closedloop import radius_coefficients as cl_radius
    from reachset_ros.systems.controllers import compensated_feedback, static_feedback
    from reachset_ros.systems.observers import extended_state_observer, high_gain_observer
    from reachset_ros.systems.plant import lwa4p_joint_plant

    plant = lwa4p_joint_plant()
    for obs, ctrl in [(high_gain_observer(15, 30), static_feedback(24.4, 0.96)),
                      (extended_state_observer(57.1, 103.3, 18.1), compensated_feedback(20, 1))]:
        cl_radius(close_loop(plant, obs, ctrl))
        t = time.perf_counter()
        for _ in range(50):
            cl_radius(close_loop(plant, obs, ctrl))
        per_call = (time.perf_counter() - t) / 50
        assert per_call < 0.02, f"{obs.name}: {per_call * 1e3:.2f} ms per closed loop + radius"
