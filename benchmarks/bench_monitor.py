"""Online monitor core: time per tick for 6 joints, k* = 125, in-process (no ROS).

Run: .venv/bin/python benchmarks/bench_monitor.py [--ticks 30000]
Data follow the per-joint plant with bounded disturbances; the model is identified on
them, so every tick checks k*+1 test cases per joint. Two timings: ``Monitor.tick`` alone,
and the whole per-tick check of the monitor node's core (the tick plus the coverage
accounting of :class:`~reachset_ros.conformance.watches.CoverageWatch`: how far the test
cases reached, issue 14.1), and the monitor node's whole per-tick work without ROS
(``MonitorCore.add_y`` + ``add_u``: name mapping, pairing, gap counting, the tick, coverage),
and the same with ``input_source: effort`` (``MonitorCore.add_joint_state``: u_p from the
message's effort with Pinocchio, issue 15.3).
"""
import argparse
import time

import numpy as np

from reachset_ros import conformance as cf
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.model import ConformanceModel, JointSets
from reachset_ros.conformance.monitor import Monitor, MonitorModel
from reachset_ros.conformance.monitor_core import MonitorCore
from reachset_ros.conformance.watches import CoverageWatch, TickEvent
from reachset_ros.systems.plant import lwa4p_joint_plant


def make_data(T, J=6, K=125):
    """Closed-loop data of J joints for T ticks and the model identified on them."""
    p = lwa4p_joint_plant()
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
    return model, thm, Y, U


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=30000)
    a = ap.parse_args()
    J, K, T = 6, 125, a.ticks
    model, thm, Y, U = make_data(T, J, K)

    def run(with_coverage):
        mon = Monitor([MonitorModel.from_model(model, f"j{j}", thm) for j in range(J)])
        cov = CoverageWatch(4_000_000, model.estimator.history, K)
        d = np.empty(T)
        for i in range(T):
            stamp = 10**18 + 4_000_000 * i
            t0 = time.perf_counter()
            res = mon.tick(stamp, Y[i], U[i])
            if with_coverage:   # what MonitorCore does after each tick
                if cov.update(stamp, min(res["longest"].tolist())) is not None:
                    raise SystemExit(f"coverage fault at tick {i} on a clean 250 Hz stream")
            d[i] = time.perf_counter() - t0
        return d[K + 10:] * 1e6

    def run_core():
        """The monitor node's whole per-tick work without ROS: pairing, the tick, coverage,
        the stuck-sensor rule with the tick's /reference (moving: the rule looks at every tick)."""
        core = MonitorCore(model)
        names = [f"j{j}" for j in range(J)]
        qd = [0.3] * J
        d = np.empty(T)
        for i in range(T):
            stamp = 10**18 + 4_000_000 * i
            y, u = Y[i].tolist(), U[i].tolist()     # as the node gets them from the messages
            t0 = time.perf_counter()
            core.add_y(stamp, names, y)
            core.add_reference(stamp, names, qd)
            events = core.add_u(stamp, names, u)
            d[i] = time.perf_counter() - t0
            if len(events) != 1 or not isinstance(events[0], TickEvent):
                raise SystemExit(f"unexpected events at tick {i}: {events}")
        return d[K + 10:] * 1e6

    def run_effort():
        """``input_source: effort``: MonitorCore.add_joint_state, u_p of each message from its
        position, velocity and effort with the LWA-4P's nominal model (Pinocchio ABA), then
        the same pairing, tick and coverage. The data are the same; u_p is what the effort
        gives, so this times the work, not a verdict."""
        from reachset_ros.robot.dynamics import DEFAULT_URDF, JOINT_NAMES
        from reachset_ros.robot.effort import load_effort_input
        src = load_effort_input(DEFAULT_URDF)
        names = list(JOINT_NAMES)
        m2 = ConformanceModel(model.plant, model.plant_spec, model.estimator, K,
                              {n: model.joints[f"j{j}"] for j, n in enumerate(names)})
        core = MonitorCore(m2, None, 10**9, src)
        qd, tau = [0.0] * J, [1.0] * J
        d = np.empty(T)
        for i in range(T):
            stamp = 10**18 + 4_000_000 * i
            y = (0.3 + Y[i]).tolist()
            t0 = time.perf_counter()
            core.add_joint_state(stamp, names, y, qd, tau)
            d[i] = time.perf_counter() - t0
        return d[K + 10:] * 1e6

    for label, d in (("monitor tick", lambda: run(False)), ("tick + coverage", lambda: run(True)),
                     ("MonitorCore.add_y + add_reference + add_u (the node's whole check)", run_core),
                     ("MonitorCore.add_joint_state, input_source effort (u_p by Pinocchio ABA)", run_effort)):
        d = d()
        print(f"{label}, {J} joints, k*={K}, {len(d)} ticks: mean {d.mean():.1f} us, "
              f"p50 {np.percentile(d, 50):.1f} us, p99 {np.percentile(d, 99):.1f} us, max {d.max():.1f} us")

if __name__ == "__main__":
    main()
