"""The demo's closed loop in real time: how fast does it run, with which executor?

Run: .venv/bin/python benchmarks/bench_closed_loop.py [--seconds 20] [--executors events,single] [--json]

Starts the nodes of ``reachset demo`` as separate processes over Fast DDS (localhost):
``sim_node`` (realistic simulated LWA-4P, lockstep), ``reference_node``, ``observer_node``
(HG) and ``controller_node`` (static law), without a monitor as in the demo's training phases
(a monitor without a model does not run, issue 34.1), once per executor (``REACHSET_EXECUTOR``). This process listens to ``/joint_states`` (with the
``EventsExecutor``) and, after a 6 s warm-up, measures for ``--seconds``:

* **rate**: received ``/joint_states`` per wall-clock second (the simulator's target is
  250 Hz);
* **real-time factor**: simulated time (stamp span) / wall time: 1.0 when the loop keeps
  up, lower when the simulator has to wait for commands;
* **gaps**: wall-clock time between consecutive ``/joint_states`` (p50 / p99 / max);
* **CPU**: each node's user + system CPU time over the window, in % of one core
  (``/proc/PID/stat``).

Nothing is asserted; the numbers go to docs/performance.md.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np

def cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(executor, seconds, workdir, warmup=6.0):
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from reachset_ros import processes
    from reachset_ros.nodes.common import TICK_QOS
    from reachset_ros.workflows.demo import INITIAL_GAINS
    from reachset_ros.robot import JOINT_NAMES

    joints = list(JOINT_NAMES)
    env = dict(os.environ, REACHSET_EXECUTOR=executor)
    procs = [processes.start("sim_node", {"seed": 1, "realistic": True}, workdir, env=env),
             processes.start("reference_node", {"seed": 1}, workdir, env=env),
             processes.start("observer_node", {"joints": joints, **INITIAL_GAINS, "allow_uncertified": True}, workdir,
                          env=env),
             processes.start("controller_node", {"joints": joints, **INITIAL_GAINS, "allow_uncertified": True}, workdir,
                          env=env)]
    rclpy.init()
    node = Node("bench_closed_loop")
    arrivals = []
    node.create_subscription(JointState, "joint_states",
                             lambda m: arrivals.append((time.monotonic(), m.header.stamp.sec * 10 ** 9
                                                        + m.header.stamp.nanosec)), TICK_QOS)
    ex = EventsExecutor()
    ex.add_node(node)
    try:
        t_start = time.monotonic() + warmup
        while time.monotonic() < t_start:
            ex.spin_once(timeout_sec=0.05)
        cpu0 = {p.name: cpu_seconds(p.proc.pid) for p in procs}
        arrivals.clear()
        t_end = t_start + seconds
        while time.monotonic() < t_end:
            ex.spin_once(timeout_sec=0.05)
        wall = time.monotonic() - t_start
        cpu = {p.name: 100.0 * (cpu_seconds(p.proc.pid) - cpu0[p.name]) / wall for p in procs}
        alive = all(p.alive() for p in procs)
    finally:
        processes.stop(procs)
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    w = np.array([a[0] for a in arrivals])
    s = np.array([a[1] for a in arrivals], dtype=np.int64)
    gaps = np.diff(w) * 1e3
    return {"executor": executor, "seconds": wall, "messages": len(w), "nodes_alive": alive,
            "rate_hz": (len(w) - 1) / (w[-1] - w[0]) if len(w) > 1 else 0.0,
            "real_time_factor": float((s[-1] - s[0]) * 1e-9 / (w[-1] - w[0])) if len(w) > 1 else 0.0,
            "gap_ms_p50": float(np.median(gaps)) if len(gaps) else None,
            "gap_ms_p99": float(np.percentile(gaps, 99)) if len(gaps) else None,
            "gap_ms_max": float(gaps.max()) if len(gaps) else None,
            "cpu_percent": cpu, "load_average": os.getloadavg()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--executors", default="events,single")
    ap.add_argument("--json", action="store_true")
    args, _ = ap.parse_known_args(argv)  # run_all.py passes its arguments to every benchmark
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 100 + 1))
    from pathlib import Path
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_closed_loop_") as tmp:
        for ex in args.executors.split(","):
            r = run(ex, args.seconds, Path(tmp) / ex)
            results.append(r)
            if not args.json:
                cpu = ", ".join(f"{k} {v:.0f}" for k, v in r["cpu_percent"].items())
                print(f"{ex:7s} rate {r['rate_hz']:6.1f} Hz  real-time factor {r['real_time_factor']:.3f}  "
                      f"gaps p50/p99/max {r['gap_ms_p50']:.1f}/{r['gap_ms_p99']:.1f}/{r['gap_ms_max']:.1f} ms  "
                      f"CPU % of a core: {cpu}  (load {r['load_average'][0]:.1f}, alive {r['nodes_alive']})",
                      flush=True)
    if args.json:
        print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
