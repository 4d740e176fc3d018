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

``--node``: instead, the monitor node's whole tick (issue 38.4,
:mod:`reachset_ros.nodes.monitor_status`) in this process: a real ``MonitorNode`` (rclpy, its
publishers over DDS) whose subscription callbacks are called with real messages (those of
``bench_monitor_load.py``), on both input routes; timed from the entry of the callback that
completes a tick to its return, the status published, as the node times itself.
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


def run_node(route, T, period=0.0):
    """The whole tick of a real MonitorNode in this process, on ``route`` (topic | effort), us.
    ``period`` > 0: the ticks come every ``period`` s (the process sleeps between them, as the
    node does between messages), else back to back."""
    import os
    import sys
    import tempfile
    from pathlib import Path
    import rclpy
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import bench_monitor_load as bml
    from reachset_ros.robot.dynamics import DEFAULT_URDF
    wd = Path(tempfile.mkdtemp(prefix="bench_monitor_node_"))
    bml.write_model(wd / "m.yaml", route)
    args = ["--ros-args", "-p", f"model_file:={wd / 'm.yaml'}", "-p", "max_missing_ticks:=10000",
            "-p", f"window_dir:={wd / 'windows'}"]
    if route == "effort":
        args += ["-p", "input_source:=effort", "-p", f"robot_urdf:={DEFAULT_URDF}"]
    msgs = bml.messages(*bml.stream(T), route)
    rclpy.init(args=args)
    from reachset_ros.nodes.monitor_node import MonitorNode
    node = MonitorNode()
    d = np.empty(T)
    try:
        due = time.monotonic()
        for k, (js, pi) in enumerate(msgs):
            if period > 0:
                due += period
                time.sleep(max(0.0, due - time.monotonic()))
            js.header.stamp.sec, js.header.stamp.nanosec = 1_000_000 + k // 250, 4_000_000 * (k % 250)
            if pi is not None:
                pi.header.stamp = js.header.stamp
                node.on_joint_states(js)
            t0 = time.perf_counter_ns()
            node.on_joint_states(js) if pi is None else node.on_plant_input(pi)
            d[k] = time.perf_counter_ns() - t0
        if node.statuses != T or node.stop_active:
            raise SystemExit(f"{route}: {node.statuses} statuses of {T} ticks, stop {node.stop_msg.reason}")
    finally:
        node.destroy_node()
        rclpy.shutdown()
    return d[K_WARM:] * 1e-3


K_WARM = 135


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=30000)
    ap.add_argument("--node", action="store_true", help="the monitor node's whole tick, both routes (issue 38.4)")
    ap.add_argument("--period", type=float, default=0.0,
                    help="with --node: a tick every PERIOD s (0: back to back); 0.004 is the monitor's rate")
    a = ap.parse_args()
    if a.node:
        import os
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        for route in ("topic", "effort"):
            d = run_node(route, a.ticks, a.period)
            print(f"monitor node's whole tick, {route} route, in-process, period {a.period * 1e3:g} ms, {len(d)} ticks: mean {d.mean():.1f} us, "
                  f"p50 {np.percentile(d, 50):.1f} us, p99 {np.percentile(d, 99):.1f} us, max {d.max():.1f} us")
        return
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
