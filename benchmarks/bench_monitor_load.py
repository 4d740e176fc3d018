"""monitor_node under CPU load: does every 4 ms tick still get its verdict, and how late?

Run: .venv/bin/python benchmarks/bench_monitor_load.py [--seconds 20] [--burners 2] [--input topic|effort] [--json]

Three processes talk over DDS (localhost): ``monitor_node`` (6 joints, k* = 125, the
model of a real run), a publisher process that sends ``/joint_states`` and ``/plant_input``
at 250 Hz, and this process, which listens to ``/conformance/status``. Two phases of
``--seconds`` each: quiet, then with ``--burners`` busy-loop processes (``while True:
pass``, same priority as the nodes) burning the cores.

Definitions (all clocks are the host's CLOCK_REALTIME, ``time.time_ns()``):

* tick k has stamp t_k = t_0 + k * 4 ms (t_0 chosen by the publisher once its topics are
  matched); the publisher sleeps until t_k and then publishes
  the tick's /joint_states and /plant_input, both stamped t_k (if it wakes up late it
  publishes at once, stamps stay on the grid, so the monitor never sees a gap it did not
  cause);
* latency of tick k = the time this process's status callback ran for the status stamped
  t_k, minus t_k. It contains the publisher's wake-up delay, DDS both ways, the monitor's
  queueing and check, and this listener's own scheduling delay: what a subscriber of
  /conformance/status sees;
* a tick is **late** when its latency exceeds 4 ms (its verdict arrives after the next
  tick's measurement is due); a tick is **missing** when no status with its stamp arrives.

The monitor and the publisher each run in a session of their own (as ``processes.start``
and a separate driver would), the burners in a third one: with the kernel's autogroup
scheduling (``/proc/sys/kernel/sched_autogroup_enabled`` = 1 here) CPU time is shared
between sessions first, so the burners compete as one program, as intended.

Also reported: the publisher's wake-up lag (publish time - t_k), the path monitor+DDS alone
(status received - publish time), the monitor's own check time (``check_duration``: the
compiled tick), and **the monitor node's whole tick** (issue 38.4,
:mod:`reachset_ros.nodes.monitor_status`: from the entry of the callback that receives the
message completing a tick to its return, the status published; timed in the node, read from
its ``/diagnostics``). Each phase has a monitor process of its own, so the whole-tick times
are that phase's.

``--input effort``: the monitor runs with ``input_source: effort`` (the LWA-4P's URDF), and
the publisher sends ``/joint_states`` with position, velocity and effort only, the effort
being the feedback-linearizing torque of the stream's u_p (``robot.dynamics.feedback_linearization``),
so the monitor recovers u_p by Pinocchio's ABA per message.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

DT_NS = 4_000_000
JOINTS = [f"arm_{i}_joint" for i in range(1, 7)]
HORIZON = 125


def stream(n, seed=0):
    """(Y, U), shape (n, 6): the per-joint plant in closed loop, bounded disturbances."""
    from reachset_ros.systems.plant import lwa4p_joint_plant
    p = lwa4p_joint_plant()
    rng = np.random.default_rng(seed)
    J = len(JOINTS)
    X = np.zeros((5, J))
    Y, U = np.empty((n, J)), np.empty((n, J))
    w = rng.uniform(-1, 1, (n, 2, J)) * np.array([0.01, 1.0])[None, :, None]
    for k in range(n):
        Y[k] = X[0] + 2e-5 * rng.uniform(-1, 1, J)
        U[k] = np.sin(0.003 * k + np.arange(J)) - 50 * X[1] - 10 * X[2]
        X = p.A @ X + p.B * U[k] + p.Gw @ w[k]
    return Y, U


def effort_source():
    """The ``input_source: effort`` of ``--input effort``: the LWA-4P's URDF."""
    from reachset_ros.robot.dynamics import DEFAULT_URDF
    from reachset_ros.robot.effort import load_effort_input
    return load_effort_input(str(DEFAULT_URDF))


def write_model(path, route="topic"):
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.estimators import Estimator
    from reachset_ros.systems.plant import lwa4p_joint_plant
    js = {j: mdl.JointSets((0.15, 0.0), (4e-4,), (0.0,) * 5, (0.0,), 0, HORIZON) for j in JOINTS}
    mdl.save(mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"),
                                  HORIZON, js, input_source=mdl.input_source_of(
                                      effort_source() if route == "effort" else None)), path)


def messages(Y, U, route):
    """The ticks' messages: [(JointState, PlantInput or None)], stamps set by the publisher."""
    from reachset_msgs.msg import PlantInput
    from sensor_msgs.msg import JointState
    if route != "effort":
        return [(JointState(name=JOINTS, position=y.tolist()), PlantInput(name=JOINTS, acceleration=u.tolist()))
                for y, u in zip(Y, U)]
    from reachset_ros.robot.dynamics import create_data, feedback_linearization
    model = effort_source().model
    data, qd = create_data(model), np.zeros(len(JOINTS))
    out = []
    for y, u in zip(Y, U):
        q = 0.3 + y          # away from the URDF's zero configuration
        tau = feedback_linearization(model, data, q, qd, u) / model.torque_scale
        out.append((JointState(name=JOINTS, position=q.tolist(), velocity=qd.tolist(), effort=tau.tolist()), None))
    return out


# ---------------------------------------------------------------- publisher process
def publisher(seconds, out, seed, route):
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from reachset_msgs.msg import PlantInput
    from sensor_msgs.msg import JointState
    n = int(round(seconds * 1e9 / DT_NS))
    Y, U = stream(n, seed)
    msgs = messages(Y, U, route)
    rclpy.init()
    node = Node("load_bench_publisher")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    js_pub = node.create_publisher(JointState, "joint_states", qos)
    pi_pub = node.create_publisher(PlantInput, "plant_input", qos)
    end = time.monotonic() + 30
    while not (js_pub.get_subscription_count() and (route == "effort" or pi_pub.get_subscription_count())) \
            and time.monotonic() < end:
        time.sleep(0.05)
    time.sleep(0.5)
    t0 = (time.time_ns() // DT_NS + 50) * DT_NS          # on the grid, 0.2 s from now: ready
    sent = np.zeros(n, dtype=np.int64)
    for k in range(n):
        t = t0 + k * DT_NS
        delay = (t - time.time_ns()) * 1e-9
        if delay > 0:
            time.sleep(delay)
        js, pi = msgs[k]
        js.header.stamp.sec, js.header.stamp.nanosec = divmod(t, 1_000_000_000)
        sent[k] = time.time_ns()
        js_pub.publish(js)
        if pi is not None:
            pi.header.stamp = js.header.stamp
            pi_pub.publish(pi)
    np.savez(out, t0=t0, sent=sent)
    time.sleep(1.0)        # let reliable delivery finish before the participant goes
    node.destroy_node()
    rclpy.shutdown()


# ---------------------------------------------------------------- benchmark
class Listener:
    def __init__(self):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from reachset_msgs.msg import ConformanceStatus, SafeStop
        from reachset_ros.nodes.common import SAFE_STOP_QOS
        self.node = Node("load_bench_listener")
        self.status = []         # (stamp, receive time, check_duration, conformant)
        self.stops = []
        self.diag = {}
        self.node.create_subscription(ConformanceStatus, "conformance/status", self.on_status,
                                      QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(SafeStop, "safe_stop", self.stops.append, SAFE_STOP_QOS)
        self.node.create_subscription(DiagnosticArray, "diagnostics", self.on_diag, 10)
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self.ex.spin, daemon=True)
        self.thread.start()

    def on_status(self, m):
        now = time.time_ns()
        self.status.append((m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, now,
                            m.check_duration, m.conformant))

    def on_diag(self, arr):
        for st in arr.status:
            if "monitor" in st.name:
                self.diag = {kv.key: kv.value for kv in st.values}


def run_phase(name, seconds, burners, workdir, listener, seed, route):
    out = workdir / f"sent_{name}.npz"
    loadavg = os.getloadavg()[0]
    # the load: one program in its own session (as if started from another terminal), with
    # `burners` busy-loop processes at the default niceness
    load = None
    if burners:
        code = ("import os\nos.setpriority(os.PRIO_PROCESS, 0, 0)\n"
                f"for _ in range({burners - 1}):\n    if os.fork() == 0:\n        break\n"
                "while True:\n    pass\n")
        load = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
    try:
        pub = subprocess.run([sys.executable, __file__, "--publisher", "--seconds", str(seconds),
                              "--out", str(out), "--seed", str(seed), "--input", route], capture_output=True, text=True,
                             timeout=seconds + 120, start_new_session=True)
    finally:
        if load is not None:
            os.killpg(load.pid, signal.SIGKILL)     # the burners' own process group
            load.wait()
    if pub.returncode != 0:
        raise RuntimeError(f"publisher failed: {pub.stderr[-2000:]}")
    time.sleep(1.0)
    z = np.load(out)
    t0, sent = int(z["t0"]), z["sent"]
    n = len(sent)
    stamps = t0 + DT_NS * np.arange(n)
    got = {s: (r, d, c) for s, r, d, c in listener.status if t0 <= s <= stamps[-1]}
    have = np.array([s in got for s in stamps.tolist()])
    recv = np.array([got[s][0] for s in stamps[have].tolist()], dtype=np.int64)
    dur = np.array([got[s][1] for s in stamps[have].tolist()])
    lat = (recv - stamps[have]) * 1e-6
    path = (recv - sent[have]) * 1e-6
    lag = (sent - stamps) * 1e-6
    pct = lambda a, q: float(np.percentile(a, q)) if len(a) else None   # noqa: E731
    np.savez(workdir / f"ticks_{name}.npz", stamps=stamps, sent=sent, have=have, recv=recv, check=dur)
    return {
        "phase": name, "burners": burners, "loadavg_1min_before": loadavg, "seconds": seconds, "ticks": int(n),
        "last_stamp": int(stamps[-1]),
        "statuses": int(have.sum()), "missing": int(n - have.sum()),
        "non_conformant": int(sum(not got[s][2] for s in stamps[have].tolist())),
        "late_share": float(np.mean(lat > 4.0)) if len(lat) else None,
        "late_ticks": int(np.sum(lat > 4.0)),
        "latency_ms": {"p50": pct(lat, 50), "p99": pct(lat, 99), "max": float(lat.max()) if len(lat) else None},
        "publisher_lag_ms": {"p50": pct(lag, 50), "p99": pct(lag, 99), "max": float(lag.max())},
        "monitor_path_ms": {"p50": pct(path, 50), "p99": pct(path, 99),
                            "max": float(path.max()) if len(path) else None},
        "check_us": {"p50": pct(dur * 1e6, 50), "p99": pct(dur * 1e6, 99), "max": float(dur.max() * 1e6)},
        "route": route,
    }


def monitored_phase(name, a, burners, workdir, listener, seed):
    """One phase with a monitor process of its own: :func:`run_phase`, then the monitor's
    diagnostics (its whole-tick times, counters) and the safe stops before the last tick."""
    from reachset_ros import processes
    params = {"model_file": str(workdir / "model.yaml"), "max_missing_ticks": 125,
              "window_dir": str(workdir / "windows")}
    if a.input == "effort":
        from reachset_ros.robot.dynamics import DEFAULT_URDF
        params |= {"input_source": "effort", "robot_urdf": str(DEFAULT_URDF)}
    listener.diag, listener.stops[:] = {}, []
    mon = processes.start("monitor_node", params, workdir, node_name=f"monitor_node_{name}")
    try:
        end = time.monotonic() + 30
        while not listener.node.count_publishers("/conformance/status") and time.monotonic() < end:
            time.sleep(0.05)
        r = run_phase(name, a.seconds, burners, workdir, listener, seed, a.input)
        end = time.monotonic() + 5         # the diagnostics (1 Hz) with every tick of the phase
        while int(listener.diag.get("tick_wall_ticks", 0)) < r["statuses"] and time.monotonic() < end:
            time.sleep(0.1)
    finally:
        processes.stop([mon])
    # the watchdog's stop 0.5 s after the last tick is expected (the publisher ended)
    r["safe_stops"] = [f"{m.kind}: {m.reason}" for m in listener.stops if m.active and m.kind != "not_ready" and
                       m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec < r["last_stamp"]]
    r["monitor_counters"] = dict(listener.diag)
    for key, name in (("tick_wall", "whole_tick_us"), ("publish_wall", "publish_us")):   # None: not reported
        r[name] = {q: float(listener.diag[f"{key}_us_{q}"]) if f"{key}_us_{q}" in listener.diag else None
                   for q in ("p50", "p99", "max")}
    while listener.node.count_publishers("/conformance/status") and time.monotonic() < end + 10:
        time.sleep(0.05)             # the next phase's monitor is the only one
    return r


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--burners", type=int, default=os.cpu_count() or 2, help="busy-loop processes in the load phase")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--publisher", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--input", choices=("topic", "effort"), default="topic",
                    help="the monitor's input route: /plant_input (topic) or input_source: effort")
    a = ap.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if a.publisher:
        return publisher(a.seconds, a.out, a.seed, a.input)
    if "ROS_DOMAIN_ID" not in os.environ:
        import random
        os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(101, 200))
    import rclpy
    workdir = Path(tempfile.mkdtemp(prefix="bench_monitor_load_"))
    print(f"work directory (logs, per-tick arrays): {workdir}", file=sys.stderr)
    write_model(workdir / "model.yaml", a.input)
    rclpy.init()
    listener = Listener()
    results = []
    try:
        for i, (name, burners) in enumerate((("quiet", 0), ("load", a.burners))):
            results.append(monitored_phase(name, a, burners, workdir, listener, seed=i))
    finally:
        listener.ex.shutdown()
        listener.thread.join(timeout=5)
        listener.node.destroy_node()
        rclpy.try_shutdown()
    if a.json:
        print(json.dumps(results, indent=1))
        return
    for r in results:
        lat, lag, path, chk = r["latency_ms"], r["publisher_lag_ms"], r["monitor_path_ms"], r["check_us"]
        print(f"{r['phase']:5s} ({r['burners']} burners, {r['seconds']:.0f} s, load average before "
              f"{r['loadavg_1min_before']:.2f}): {r['statuses']}/{r['ticks']} ticks "
              f"with a status ({r['missing']} missing), {100 * r['late_share']:.2f} % late (> 4 ms, "
              f"{r['late_ticks']} ticks); latency p50 {lat['p50']:.2f} / p99 {lat['p99']:.2f} / "
              f"max {lat['max']:.1f} ms; "
              f"publisher lag p99 {lag['p99']:.2f} / max {lag['max']:.1f} ms; monitor+DDS p99 {path['p99']:.2f} / "
              f"max {path['max']:.1f} ms; check p50 {chk['p50']:.0f} / p99 {chk['p99']:.0f} / max {chk['max']:.0f} us; "
              f"WHOLE TICK ({r['route']}) p50 {r['whole_tick_us']['p50']} / p99 {r['whole_tick_us']['p99']} / "
              f"max {r['whole_tick_us']['max']} us (of which publishing the status p50 {r['publish_us']['p50']} / "
              f"p99 {r['publish_us']['p99']} us); "
              f"non-conformant {r['non_conformant']}; safe stops {r['safe_stops'] or 'none'}")


if __name__ == "__main__":
    sys.exit(main())
