"""What-if: how much faster could the Theorem-1 sweep of ``reachset identify`` be?

Not run by ``make benchmark`` (it times code that is not in the package). Compares, on one
joint of the cached 33-minute bag (``bench_conformance.py`` generates it):

* ``conformance.deviation_extremes`` as it is (all test cases advanced together, k by k);
* the same arithmetic on blocks of test cases that fit in the CPU caches (the per-k
  maxima combined over blocks) -- element-wise kernels, so the result is bitwise identical;
* the blocked sweep of all 6 joints serially and in 2 worker processes (one per core).

Syntax::

    .venv/bin/python benchmarks/whatif_sweep.py [--block N]
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import simbag  # noqa: E402

from reachset_ros import conformance as cf  # noqa: E402
from reachset_ros.conformance.estimators import Estimator  # noqa: E402
from reachset_ros.systems.plant import lwa4p_joint_plant  # noqa: E402

TICKS, K = 497_883, 125
PLANT, EST = lwa4p_joint_plant(), Estimator("fd")
THM = cf.Theorem1.build(PLANT, K)


def blocked_extremes(y, u, segments, block):
    """``deviation_extremes``'s maxima, computed block by block over the test cases."""
    y2, u2 = cf.as_2d(y), cf.as_2d(u)
    starts, ends = cf.test_case_starts(segments, EST.history)
    order = np.argsort(-(ends - starts), kind="stable")
    starts, rem = starts[order], (ends - starts)[order]
    maxp = [np.full(THM.normals[k].shape[0], -np.inf) for k in range(K + 1)]
    maxm = [np.full(THM.normals[k].shape[0], -np.inf) for k in range(K + 1)]
    for a in range(0, len(starts), block):
        st, rm = starts[a:a + block], rem[a:a + block]
        X = EST.estimate(PLANT, y2, u2, st)
        for k in range(K + 1):
            Mk = int(np.searchsorted(-rm, -k, side="left"))
            if Mk == 0:
                break
            X = X[:, :Mk]
            t = st[:Mk] + k
            U = u2[t].T
            ya = y2[t].T - cf.predict_output(PLANT, X, U)
            Ny = cf.matvec(THM.normals[k], ya)
            maxp[k] = np.maximum(maxp[k], Ny.max(axis=1))
            maxm[k] = np.maximum(maxm[k], (-Ny).max(axis=1))
            X = cf.advance(PLANT, X, U)
    return maxp, maxm


def _load():
    simbag.ensure_bag("sim6_33min", TICKS)
    d = np.load(simbag.CACHE / f"sim6_33min_v{simbag.VERSION}_s0_T{TICKS}" / "sim.npz")
    return d["y"], d["u"]


def _joint(args):
    j, block = args
    y, u = _load()
    return blocked_extremes(y[:, j], u[:, j], ((0, len(y)),), block)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--block", type=int, default=16384, help="test cases per block")
    args = ap.parse_args(argv)
    y, u = _load()
    segs = ((0, len(y)),)
    t = time.perf_counter()
    dev = cf.deviation_extremes(PLANT, EST, y[:, 0], u[:, 0], segs, K, THM)
    t_ref = time.perf_counter() - t
    print(f"deviation_extremes as is (1 joint, {dev.test_cases} test cases): {t_ref:.2f} s", flush=True)
    for block in sorted({4096, args.block, 65536}):
        t = time.perf_counter()
        mp, mm = blocked_extremes(y[:, 0], u[:, 0], segs, block)
        t_b = time.perf_counter() - t
        same = all(np.array_equal(a, b) for a, b in zip(mp, dev.maxp)) and \
            all(np.array_equal(a, b) for a, b in zip(mm, dev.maxm))
        print(f"blocked, {block} test cases per block: {t_b:.2f} s ({t_ref / t_b:.1f}x), bitwise equal: {same}",
              flush=True)
    t = time.perf_counter()
    for j in range(y.shape[1]):
        _joint((j, args.block))
    t_s = time.perf_counter() - t
    t = time.perf_counter()
    with ProcessPoolExecutor(2) as ex:
        list(ex.map(_joint, [(j, args.block) for j in range(y.shape[1])]))
    t_p = time.perf_counter() - t
    print(f"6 joints blocked: serial {t_s:.1f} s, 2 worker processes {t_p:.1f} s", flush=True)


if __name__ == "__main__":
    main()
