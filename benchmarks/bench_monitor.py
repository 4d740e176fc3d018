"""Online monitor core: time per tick for 6 joints, k* = 125, in-process (no ROS).

Run: .venv/bin/python benchmarks/bench_monitor.py [--ticks 30000]
Data follow the per-joint plant with bounded disturbances; the model is identified on
them, so every tick checks k*+1 test cases per joint.
"""
import argparse
import time

import numpy as np

from reachset_ros import conformance as cf
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.model import ConformanceModel, JointSets
from reachset_ros.conformance.monitor import Monitor, MonitorModel
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
    mon = Monitor([MonitorModel.from_model(model, f"j{j}", thm) for j in range(J)])
    d = np.empty(T)
    for i in range(T):
        t0 = time.perf_counter()
        mon.tick(10**18 + 4_000_000 * i, Y[i], U[i])
        d[i] = time.perf_counter() - t0
    d = d[K + 10:] * 1e6
    print(f"monitor tick, {J} joints, k*={K}, {len(d)} ticks: mean {d.mean():.1f} us, "
          f"p50 {np.percentile(d, 50):.1f} us, p99 {np.percentile(d, 99):.1f} us, max {d.max():.1f} us")


if __name__ == "__main__":
    main()
