"""Online monitor core: time per tick for 6 joints, k* = 125, in-process (no ROS).

Run: .venv/bin/python benchmarks/bench_monitor.py [--ticks 30000]
Data follow the per-joint plant with bounded disturbances; the model is identified on
them, so every tick checks k*+1 test cases per joint. Two timings: ``Monitor.tick`` alone,
and the whole per-tick check of the monitor node's core (the tick plus the coverage
accounting of :class:`~reachset_ros.conformance.monitor.CoverageWatch`: how far the test
cases reached, issue 14.1), as ``MonitorCore`` runs it.
"""
import argparse
import time

import numpy as np

from reachset_ros import conformance as cf
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.model import ConformanceModel, JointSets
from reachset_ros.conformance.monitor import CoverageWatch, Monitor, MonitorModel
from reachset_ros.systems.plant import lwa4p_joint_plant


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=30000)
    a = ap.parse_args()
    p, J, K, T = lwa4p_joint_plant(), 6, 125, a.ticks
    rng = np.random.default_rng(0)
    Y, U, X = np.zeros((T, J)), np.zeros((T, J)), np.zeros((J, 5))
    for k in range(T):
        Y[k] = X[:, 0] + 2e-5 * rng.uniform(-1, 1, J)
        U[k] = np.sin(0.003 * k + np.arange(J)) - 100 * X[:, 1] - 20 * X[:, 2]
        X = X @ p.A.T + np.outer(U[k], p.B[:, 0]) + (p.Gw @ (np.array([[0.03], [3.0]]) * rng.uniform(-1, 1, (2, J)))).T
    thm = cf.Theorem1.build(p, K)
    joints = {}
    for j in range(J):
        s = cf.identify_sets(p, thm, cf.deviation_extremes(p, Estimator(), Y[:, j], U[:, j], ((0, T),), K, thm))
        joints[f"j{j}"] = JointSets(tuple(s.alpha_w), tuple(s.alpha_v), tuple(s.c_w), tuple(s.c_v))
    model = ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator(), K, joints)

    def run(with_coverage):
        mon = Monitor([MonitorModel.from_model(model, f"j{j}", thm) for j in range(J)])
        cov = CoverageWatch(4_000_000, model.estimator.history, K)
        d = np.empty(T)
        for i in range(T):
            stamp = 10**18 + 4_000_000 * i
            t0 = time.perf_counter()
            mon.tick(stamp, Y[i], U[i])
            if with_coverage:   # what MonitorCore does after each tick
                longest = K if mon.reached_horizon().all() else int(mon.longest_step().min())
                if cov.update(stamp, longest) is not None:
                    raise SystemExit(f"coverage fault at tick {i} on a clean 250 Hz stream")
            d[i] = time.perf_counter() - t0
        return d[K + 10:] * 1e6

    for label, cov in (("monitor tick", False), ("tick + coverage (MonitorCore)", True)):
        d = run(cov)
        print(f"{label}, {J} joints, k*={K}, {len(d)} ticks: mean {d.mean():.1f} us, "
              f"p50 {np.percentile(d, 50):.1f} us, p99 {np.percentile(d, 99):.1f} us, max {d.max():.1f} us")

if __name__ == "__main__":
    main()
