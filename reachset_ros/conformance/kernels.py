"""Deterministic element-wise kernels of the nominal predictions, and the batch sweep.

Paper Sec. II-B (Defs. 2-3) and III-B. For sequential test cases (Def. 3) starting at
every valid tick m of a recording, the deviation of the measurement from the nominal
prediction (eq. 12)

    y_a^(m)[k] = y[m+k] - y_*^(m)[k],   y_*^(m)[k] = C x_*^(m)[k] + D u[m+k],
    x_*^(m)[0] = x0(m) (an :class:`~reachset_ros.conformance.estimators.Estimator`),
    x_*^(m)[k+1] = A x_*^(m)[k] + B u[m+k],

is computed here: :func:`sweep` runs all test cases of a recording for k = 0..k* and
hands each block of deviations to a visitor (Theorem 1's reductions in
:mod:`~reachset_ros.conformance.theorem1`, the checks of
:mod:`~reachset_ros.conformance.validation`).

All arithmetic on the nominal trajectories uses the element-wise :func:`matvec`, so the
batch sweep here and the online monitor (:mod:`reachset_ros.conformance.monitor`), which
advances one tick at a time, produce bitwise identical deviations and hence identical
verdicts.

The compiled kernels (``reachset_ros/conformance/_tick.c``) are loaded here with ctypes:
the one place that loads them. Each is an exact copy of a numpy code path of this package
(same floating-point operations in the same order, compiled with ``-ffp-contract=off``), so
results are bitwise equal whether or not the kernel is used:

* ``reachset_sweep_block``: one block of :func:`sweep` (numpy: :func:`_sweep_block`);
* ``reachset_sweep_extremes``: :func:`sweep` fused with Theorem 1's reduction to the largest
  ``N_k y_a`` and ``-N_k y_a`` (:func:`sweep_extremes`; numpy: the visitor of
  :func:`reachset_ros.conformance.theorem1.deviation_extremes`; maxima are exact, so their
  order does not matter, but for the sign of a zero maximum where +0.0 and -0.0 are both the
  largest deviation of a step, which numpy's SIMD reductions leave unspecified too);
* ``reachset_monitor_tick``: one tick of :class:`reachset_ros.conformance.monitor.Monitor`
  (numpy: ``Monitor._tick_numpy``); ``reachset_monitor_ticks`` calls it for many ticks in a row
  (``Monitor.tick_many``, ``reachset replay``).

``LIB`` is None when the shared library was not built (e.g. no C compiler at install time)
or the environment variable ``REACHSET_NO_KERNEL`` is set; callers then use numpy.
"""
from __future__ import annotations

import ctypes
import importlib.machinery
import os
from pathlib import Path

import numpy as np

from .. import guarantees
from ..errors import ReachsetError

# ------------------------------------------------------------------ the compiled kernels
_P = ctypes.c_void_p
_I = ctypes.c_int64


#: the layout of ``tick_state`` in ``_tick.c`` this module's mirror expects and the exported
#: functions' signatures (``reachset_tick_abi``; 3: ``reachset_sweep_extremes`` and
#: ``reachset_monitor_ticks`` added; 4: the ``lsq`` estimator)
TICK_ABI = 4


def _load():
    if os.environ.get("REACHSET_NO_KERNEL"):
        return None, None
    here = Path(__file__).resolve().parent
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = here / f"_tick{suffix}"
        if path.exists():
            lib = ctypes.CDLL(str(path))
            abi = getattr(lib, "reachset_tick_abi", None)
            if abi is None or _abi(abi) != TICK_ABI:
                import warnings
                warnings.warn(f"{path} is a stale build of _tick.c (rebuild: pip install -e . or make venv); "
                              "the numpy tick is used", RuntimeWarning, stacklevel=2)
                return None, None
            lib.reachset_monitor_tick.argtypes = [_P, _I, _P, _P]
            lib.reachset_monitor_tick.restype = _I
            lib.reachset_sweep_block.argtypes = [_P, _P, _P, _P, _I, _I, _I, _I, _P, _P, _P, _P, _I, _I, _P, _P]
            lib.reachset_sweep_block.restype = _I
            lib.reachset_sweep_extremes.argtypes = [_P, _P, _P, _P, _I, _I, _I, _I, _P, _P, _P, _P, _I, _I, _P,
                                                    _P, _P, _P, _P]
            lib.reachset_sweep_extremes.restype = _I
            lib.reachset_monitor_ticks.argtypes = [_P, _I, _P, _P, _P, _P, _P, _P, _P, _P, _P]
            lib.reachset_monitor_ticks.restype = _I
            return lib, str(path)
    return None, None


def _abi(fn):
    fn.argtypes, fn.restype = [], _I
    return int(fn())


#: The loaded shared library (None: not built, or ``REACHSET_NO_KERNEL`` set) and its path.
LIB, LIB_PATH = _load()


def ptr(a):
    """ctypes pointer to the data of a C-contiguous numpy array."""
    return a.ctypes.data_as(_P)


# ------------------------------------------------------------------ deterministic kernels
_PLANS = {}


def matvec_plan(M):
    """The plan of ``M`` for :func:`matvec_into`: per row, the (column, factor) pairs of its
    nonzero entries in order (cached by the value of ``M``)."""
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
    return matvec_into(matvec_plan(M), X, np.empty((M.shape[0], X.shape[1])))


def matvec_into(plan, X, out):
    """:func:`matvec` with a precomputed ``matvec_plan(M)`` into a preallocated ``out`` (same arithmetic)."""
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
    require_runs({name: max((b - a for a, b in s.segments), default=0) for name, s in series.items()},
                 history, horizon, bags)


def require_runs(longest, history, horizon, bags):
    """:func:`require_horizon` from each joint's longest run of consecutive valid ticks
    (``{name: ticks}``, e.g. the largest over a fleet's bags)."""
    need = history + horizon + 1
    for name, n in longest.items():
        if n < need:
            raise ReachsetError(f"{', '.join(map(str, bags))}: joint {name}: too few samples for horizon {horizon}: "
                                f"the longest run of consecutive valid ticks has {n}, a test case needs {need}")


def minimum_horizon(plant):
    """The smallest k* at which Theorem 1's rows constrain every scaling factor alpha.

    Theorem 1 (paper Sec. III-B) bounds y_a^(m)[k] by R_a[k] = (+)_{i<k} C A^i W (+) V
    (eq. 13): the row D_k of step k has the coefficient sum_{i<k} |N_k C A^i g_j| for
    alpha_W,j (column g_j of G'_W) and |N_k G'_V,j| for alpha_V,j. With k* below the first
    k at which a column's coefficient is non-zero, no inequality mentions that alpha, so the
    identification leaves it at its lower bound (zero): a vacuous W (``--horizon 0`` or 1
    on the per-joint LWA-4P plant, whose input and output each carry one sample of delay,
    gives alpha_W = 0 and a reachable error set R_e that ignores the process disturbance).

    Returns max_j k_j over the columns, with k_j = 0 for a V column with a non-zero
    generator and k_j = 1 + (first i with C A^i g_j != 0) for a W column. Columns that never
    reach the output (C A^i g_j = 0 for all i < n, hence for all i) cannot be bounded from
    output data by any horizon and are left out. 2 for :func:`~reachset_ros.systems.plant.lwa4p_joint_plant`.
    """
    A, C = np.asarray(plant.A, float), np.asarray(plant.C, float)
    need = [0 for j in range(plant.Gv.shape[1]) if np.any(np.asarray(plant.Gv)[:, j] != 0.0)]
    n = A.shape[0]
    for j in range(plant.Gw.shape[1]):
        v = np.asarray(plant.Gw, float)[:, j]
        for i in range(n):
            if np.any(C @ v != 0.0):
                need.append(i + 1)
                break
            v = A @ v
    return max(need, default=0)


def require_minimum_horizon(plant, horizon, allow_weak=False):
    """The horizon rule of ``identify``, ``synthesize`` and the synthesis node (one place).

    Refuses (:class:`ReachsetError`, exit 2) a k* below :func:`minimum_horizon` unless
    ``allow_weak`` (the ``--allow-weak-horizon`` option), in which case the model file
    records ``horizon_below_minimum: true``. Returns ``(minimum, below)``.
    """
    horizon = int(horizon)
    if horizon < 0:
        raise ReachsetError(f"horizon must be >= 0, got {horizon}")
    k_min = minimum_horizon(plant)
    below = horizon < k_min
    if below and not allow_weak:
        raise guarantees.refused("G1", f"horizon {horizon} is below the minimum horizon {k_min} of this plant (the "
                                 f"first k* at which Theorem 1 constrains every alpha_W and alpha_V); use --horizon "
                                 f"{k_min} or more, or --allow-weak-horizon to accept a weaker guarantee")
    return k_min, below


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
    if LIB is not None and plant.A.shape[0] <= 64 and plant.B.shape[1] <= 64:
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
    p = ptr
    # The C function's 16 arguments in the order of its signature in _tick.c (and of its
    # ``argtypes`` above): a foreign function takes positional arguments only, so they are
    # named here, one per line, and passed as one tuple.
    args = (p(A), p(B), p(C), p(D),             # const double *A, *B, *C, *D: the plant
            int(bool(np.any(plant.D))),         # int64_t has_d: D is not zero
            A.shape[0], B.shape[1], ny,         # int64_t n, nu, ny: states, inputs, outputs
            p(y), p(u),                         # const double *y, *u: the recording
            p(starts), p(rem),                  # const int64_t *starts, *rem: the test cases
            M, K,                               # int64_t M, horizon: test cases, largest step
            p(X), p(ya))                        # double *X (initial states, advanced), *ya (out)
    rc = LIB.reachset_sweep_block(*args)
    if rc != 0:
        raise RuntimeError("reachset_sweep_block failed")
    for k in range(K + 1):
        Mk = int(np.searchsorted(-rem, -k, side="left"))  # rem > k, rem sorted descending
        if Mk == 0:
            break
        m = starts[:Mk]
        visit(k, m, m + k, ya[k, :, :Mk])



def sweep_extremes(plant, estimator, y, u, segments, horizon, normals):
    """All sequential test cases reduced to Theorem 1's left-hand sides in the compiled kernel.

    The deviations :func:`sweep` computes, multiplied by the normals ``N_k`` of each step
    (``normals[k]``, shape (q_k, ny)) and reduced to their largest value and the largest of
    their negation over the test cases, without storing them: ``reachset_sweep_extremes`` in
    ``_tick.c``, the same operations in the same order as the numpy path
    (:func:`~reachset_ros.conformance.theorem1.deviation_extremes`' visitor: ``matvec``, ``max``,
    ``np.maximum`` folded in the test cases' order), so the result is the same to the bit.
    The GIL is released while it runs (ctypes), so joints run in parallel threads.

    Returns
    -------
    (maxp, maxm, test_cases, checks) or None
        ``maxp``/``maxm``: per k an array (q_k,), ``-inf`` where no test case reaches k;
        None when the kernel is not loaded or does not cover the plant (callers use numpy).
    """
    n, nu, ny = plant.A.shape[0], plant.B.shape[1], plant.C.shape[0]
    if LIB is None or max(n, nu, ny) > 64:
        return None
    y, u = as_2d(y), as_2d(u)
    starts, ends = test_case_starts(segments, estimator.history)
    q = np.array([0] + [len(N) for N in normals[:horizon + 1]], dtype=np.int64)
    qoff = np.cumsum(q)
    maxp, maxm = np.full(int(qoff[-1]), -np.inf), np.full(int(qoff[-1]), -np.inf)
    M = len(starts)
    checks = 0
    if M:
        order = np.argsort(-(ends - starts), kind="stable")
        starts, rem = np.ascontiguousarray(starts[order], np.int64), np.ascontiguousarray((ends - starts)[order],
                                                                                            np.int64)
        f8 = lambda a: np.ascontiguousarray(a, dtype=np.float64)   # noqa: E731
        A, B, C, D = f8(plant.A), f8(plant.B), f8(plant.C), f8(plant.D)
        y, u = f8(y), f8(u)
        X = f8(estimator.estimate(plant, y, u, starts))
        N = f8(np.vstack([np.reshape(Nk, (-1, ny)) for Nk in normals[:horizon + 1]]))
        p = ptr
        args = (p(A), p(B), p(C), p(D),         # const double *A, *B, *C, *D: the plant
                int(bool(np.any(plant.D))),     # int64_t has_d: D is not zero
                n, nu, ny,                      # int64_t n, nu, ny: states, inputs, outputs
                p(y), p(u),                     # const double *y, *u: the recording
                p(starts), p(rem),              # const int64_t *starts, *rem: the test cases
                M, int(horizon),                # int64_t M, horizon: test cases, largest step
                p(X),                           # double *X: initial states (overwritten)
                p(N), p(qoff),                  # const double *normals, const int64_t *qoff: N_k's rows
                p(maxp), p(maxm))               # double *maxp, *maxm: folded into (in: -inf)
        if LIB.reachset_sweep_extremes(*args) != 0:
            raise RuntimeError("reachset_sweep_extremes failed")
        checks = int(np.minimum(rem, int(horizon) + 1).sum())
    split = [(int(a), int(b)) for a, b in zip(qoff[:-1], qoff[1:])]
    return tuple(maxp[a:b] for a, b in split), tuple(maxm[a:b] for a, b in split), M, checks
