"""The compiled Theorem-1 reduction (``reachset_sweep_extremes`` in _tick.c, issue 38.2) equals the
numpy sweep and its reduction bit for bit, and Remark 3's walk down the grid finds the horizon the
full grid finds."""
import hashlib

import numpy as np
import pytest

from reachset_ros import conformance as cf
from reachset_ros.conformance import kernels
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.identify import identify_sets, stable_horizon
from reachset_ros.conformance.theorem1 import _extremes_numpy
from reachset_ros.errors import ReachsetError
from reachset_ros.systems.plant import LinearPlant, lwa4p_joint_plant

needs_kernel = pytest.mark.skipif(kernels.LIB_PATH is None, reason="compiled kernel not built")


def recording(p, T, seed, w=(0.03, 3.0), v=3.5e-5, gains=(100.0, 20.0)):
    """A closed loop of ``p`` with bounded disturbances and noise, computed with the element-wise
    kernels.matvec only (no BLAS, no transcendental function): the same bits on every machine."""
    rng = np.random.default_rng(seed)
    n, ny = p.A.shape[0], p.C.shape[0]
    x = np.zeros((n, 1))
    Y, U = np.zeros((T, ny)), np.zeros((T, 1))
    ref = np.repeat(rng.uniform(-2.0, 2.0, T // 50 + 1), 50)[:T]       # steps of the reference
    for k in range(T):
        Y[k] = kernels.matvec(p.C, x)[:, 0] + v * rng.uniform(-1, 1, ny)
        U[k] = ref[k] - gains[0] * x[min(1, n - 1), 0] - gains[1] * x[min(2, n - 1), 0]
        wk = np.asarray(w)[:p.Gw.shape[1], None] * rng.uniform(-1, 1, (p.Gw.shape[1], 1))
        x = kernels.matvec(p.A, x) + kernels.matvec(p.B, U[k][:, None]) + kernels.matvec(p.Gw, wk)
    return Y, U


def bits(devs):
    return [a.tobytes() for a in devs.maxp] + [a.tobytes() for a in devs.maxm]


def both_paths(p, est, Y, U, segments, K, thm=None):
    thm = thm or cf.Theorem1.build(p, K)
    compiled = cf.deviation_extremes(p, est, Y, U, segments, K, thm)
    reference = _extremes_numpy(p, est, Y, U, segments, K, thm)
    return compiled, reference


def two_output_plant():
    p = lwa4p_joint_plant()
    C = np.vstack([p.C, [[0.0, 0.0, 1.0, 0.0, 0.0]]])
    return LinearPlant(p.A, p.B, C, np.array([[0.0], [0.5 * p.dt]]), p.Gw, np.diag([1e-4, 2e-3]), p.dt)


@needs_kernel
@pytest.mark.parametrize("case", ["lwa4p_one_segment", "lwa4p_segments", "lwa4p_other_dt", "two_outputs_with_d",
                                  "other_sparsity"])
def test_compiled_extremes_equal_numpy_extremes_bit_for_bit(case):
    """Every path of the kernel against the numpy visitor: the LWA-4P loop (test cases that reach
    k*, LANES at a time, contiguous and not), the general loop (the rest: short segments, test
    cases near a segment's end; a feedthrough D and the facet normals of a two-output plant; a
    plant of another sparsity), with the numpy sweep's blocks (16384) shorter than the data."""
    p, K = lwa4p_joint_plant(), 125
    est = Estimator("fd")
    Y, U = recording(p, 20_000, seed=3)
    segments = ((0, 20_000),)
    if case == "lwa4p_segments":      # a segment shorter than k*, one of 11 ticks, odd lengths: every remainder
        segments = ((0, 40), (41, 7_003), (7_010, 7_021), (7_030, 19_997))
    elif case == "lwa4p_other_dt":
        p = lwa4p_joint_plant(dt=0.001)
        Y, U = recording(p, 5_000, seed=4)
        segments = ((0, 5_000),)
    elif case == "two_outputs_with_d":
        p, K, est = two_output_plant(), 12, Estimator("output")
        Y, U = recording(p, 3_000, seed=5)
        segments = ((0, 1_500), (1_501, 3_000))
    elif case == "other_sparsity":
        A = np.array([[0.99, 0.01, 0.0], [0.0, 0.97, 0.01], [0.02, 0.0, 0.9]])
        p = LinearPlant(A, np.array([[0.0], [0.01], [0.3]]), np.array([[1.0, 0.0, 0.5]]), np.zeros((1, 1)),
                        np.eye(3)[:, :2], np.eye(1), 0.01)
        est, K = Estimator("output"), 30
        Y, U = recording(p, 4_000, seed=6, w=(1e-3, 1e-3), gains=(0.0, 0.0))
        segments = ((0, 4_000),)
    compiled, reference = both_paths(p, est, Y, U, segments, K)
    assert compiled.test_cases == reference.test_cases > 0
    assert compiled.checks == reference.checks
    assert bits(compiled) == bits(reference)
    assert np.all(np.isfinite(compiled.maxp[K]))


@needs_kernel
def test_compiled_extremes_keep_numpy_nan_and_inf():
    """A NaN or an infinite sample inside a segment (the caller's segments need not exclude them)
    gives what numpy's max gives: NaN at the steps whose deviations it enters (a NaN's sign bit is
    not compared: x86 and numpy make NaNs of either sign), inf/-inf likewise."""
    p, K = lwa4p_joint_plant(), 20
    Y, U = recording(p, 3_000, seed=7)
    for t, what in ((1_000, np.nan), (2_000, np.inf)):
        Yb = Y.copy()
        Yb[t, 0] = what
        compiled, reference = both_paths(p, Estimator("fd"), Yb, U, ((0, 3_000),), K)
        for a, b in zip(compiled.maxp + compiled.maxm, reference.maxp + reference.maxm):
            assert np.array_equal(a, b, equal_nan=True)
        assert any(np.isnan(a).any() for a in compiled.maxp) or any(np.isinf(a).any() for a in compiled.maxp)


@needs_kernel
def test_no_test_case_and_empty_steps():
    """Steps no test case reaches are -inf on both paths; no test case at all is refused on both."""
    p, K = lwa4p_joint_plant(), 50
    Y, U = recording(p, 200, seed=8)
    compiled, reference = both_paths(p, Estimator("fd"), Y, U, ((0, 30), (40, 70)), K)
    assert bits(compiled) == bits(reference) and np.isneginf(compiled.maxp[K]).all()
    empty = cf.deviation_extremes(p, Estimator("fd"), Y, U, ((0, 3),), K, allow_empty=True)
    assert empty.test_cases == 0 and bits(empty) == bits(_extremes_numpy(p, Estimator("fd"), Y, U, ((0, 3),), K,
                                                                         cf.Theorem1.build(p, K)))
    with pytest.raises(ReachsetError, match="too few samples"):
        cf.deviation_extremes(p, Estimator("fd"), Y, U, ((0, 3),), K)


def test_extremes_of_a_pinned_recording_do_not_change():
    """The deviation extremes of a recording computed without BLAS or libm (:func:`recording`) are
    pinned: a change of the sweep's arithmetic (an operation reordered, a fused multiply-add, a
    skipped term) changes this hash, on the compiled path and on numpy's alike (the test runs the
    path this build uses; ``REACHSET_NO_KERNEL=1`` runs numpy's)."""
    p, K = lwa4p_joint_plant(), 125
    Y, U = recording(p, 6_000, seed=11)
    devs = cf.deviation_extremes(p, Estimator("fd"), Y, U, ((0, 2_500), (2_501, 6_000)), K)
    digest = hashlib.sha256(b"".join(bits(devs))).hexdigest()
    assert (devs.test_cases, devs.checks) == (5_993, 739_368)
    assert digest == PINNED_DIGEST


PINNED_DIGEST = "29a5e4a5cfa72a8bc037060e496c029ad9181d464923af115706f665e74cd654"


def full_grid_settled(plant, thm, devs, rtol=0.01):
    """Remark 3 as it was computed before issue 38.2: every grid horizon identified, then scanned
    down from the full horizon."""
    K = len(thm.Dp) - 1
    grid = sorted({k for k in (0, 1, 2, 5, 10, 25, 50, 75, 100, 125, 150, 200, 250) if k <= K} | {K})
    table = [(k, *(lambda s: (s.alpha_w, s.alpha_v))(identify_sets(plant, thm, devs, horizon=k))) for k in grid]
    final = np.concatenate(table[-1][1:])
    scale = np.maximum(np.abs(final), 1e-12)
    settled = K
    for k, aw, av in reversed(table):
        if not np.all(np.abs(np.concatenate([aw, av]) - final) <= rtol * scale):
            break
        settled = k
    return settled


@pytest.mark.parametrize("K", [30, 125])
def test_stable_horizon_walk_down_equals_the_full_grid(K):
    """The walk down the grid stops at the first horizon whose sets differ; the answer is the full
    grid's, on data whose sets settle early (K = 30: the walk goes far down) and late."""
    p = lwa4p_joint_plant()
    Y, U = recording(p, 6_000, seed=12)
    thm = cf.Theorem1.build(p, K)
    devs = cf.deviation_extremes(p, Estimator("fd"), Y, U, ((0, 6_000),), K, thm)
    settled, table = stable_horizon(p, thm, devs)
    assert settled == full_grid_settled(p, thm, devs)
    assert [k for k, _, _ in table] == sorted(k for k, _, _ in table) and table[-1][0] == K


def old_rows(plant, horizon, normals):
    """Theorem 1's radii of W as Theorem1.build summed them before issue 38.2: for every k anew,
    sum_{i<k} |N_k C A^i G'_W| from i = 0."""
    out = []
    for k in range(horizon + 1):
        N = normals[k]
        radW = np.zeros((N.shape[0], plant.Gw.shape[1]))
        Ei = plant.C.copy()
        for _ in range(k):
            radW += np.abs(N @ Ei @ plant.Gw)
            Ei = Ei @ plant.A
        out.append(radW)
    return out


@pytest.mark.parametrize("case", ["lwa4p", "initial_state_set", "two_outputs"])
def test_theorem1_rows_equal_the_sum_from_zero_bit_for_bit(case):
    """Theorem1.build continues the previous step's sum of |N C A^i G'_W| while the normals stay
    the same (one output: always); the rows are those of the sum recomputed from i = 0 per k."""
    p, K, initial = lwa4p_joint_plant(), 125, None
    if case == "initial_state_set":
        initial = Estimator("fd")
    elif case == "two_outputs":
        p, K = two_output_plant(), 15
    thm = cf.Theorem1.build(p, K, initial)
    n, ny, pw = p.A.shape[0], p.C.shape[0], p.Gw.shape[1]
    if initial is not None:
        SwG = [S @ p.Gw for S in cf.theorem1.initial_error_maps(p, initial)[0]]
    E = p.C.copy()
    for k, radW in enumerate(old_rows(p, K, thm.normals)):
        expect = radW
        if initial is not None:              # build's initial-state terms, added as build adds them
            for G in SwG:
                expect = expect + np.abs(thm.normals[k] @ E @ G)
        assert thm.Dp[k][:, n + ny:n + ny + pw].tobytes() == expect.tobytes(), k
        assert thm.Dm[k][:, n + ny:n + ny + pw].tobytes() == expect.tobytes(), k
        E = E @ p.A
    if case == "lwa4p":
        assert all(np.array_equal(N, [[1.0]]) for N in thm.normals)
