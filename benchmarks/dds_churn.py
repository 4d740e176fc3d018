"""Participant churn against the running loop: does a process that joins or is SIGKILLed stall the others?

The loop (sim_node in lockstep, reference, observer, controller; no monitor: none runs without a model)
runs in a fresh DDS domain while, every ``--period`` s, a subscriber process (a bare rclpy
node subscribed to ``/joint_states``, ``/effort_commands`` and ``/brake_command``, as a
recorder is) starts, runs ``--life`` s and is killed with SIGKILL (or SIGINT with
``--clean``). Measured by a listener in this process: the largest wall-time gap between
two ``/plant_input`` messages, how many gaps exceed 100 ms and 300 ms, and the simulator's
steps on a stale command (its ``/diagnostics``). Run once with the default transports
(shared memory + UDP) and once with ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4`` (``--udp``)
to see which part of a stall the shared-memory transport makes. One JSON object on stdout.

Run: ``.venv/bin/python benchmarks/dds_churn.py --seconds 60 [--udp] [--clean]``.
"""
import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from reachset_msgs.msg import PlantInput

from reachset_ros import processes
from reachset_ros.domain import pick_domain_id
from reachset_ros.nodes.common import TICK_QOS
from reachset_ros.workflows.demo import INITIAL_GAINS, JOINTS, LOCKSTEP_TIMEOUT

SUBSCRIBER = """
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from reachset_msgs.msg import BrakeCommand
from reachset_ros.nodes.common import TICK_QOS
rclpy.init()
n = Node("churn_subscriber")
for t, ty in (("joint_states", JointState), ("effort_commands", Float64MultiArray), ("brake_command", BrakeCommand)):
    n.create_subscription(ty, t, lambda m: None, TICK_QOS)
try:
    rclpy.spin(n)
except BaseException:
    pass
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--period", type=float, default=2.0)
    ap.add_argument("--life", type=float, default=1.0)
    ap.add_argument("--udp", action="store_true", help="FASTDDS_BUILTIN_TRANSPORTS=UDPv4 for every process")
    ap.add_argument("--clean", action="store_true", help="end the subscribers with SIGINT, not SIGKILL")
    a = ap.parse_args()
    os.environ["ROS_DOMAIN_ID"] = str(pick_domain_id())
    if a.udp:
        os.environ["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    work = Path(tempfile.mkdtemp(prefix="dds_churn_"))
    rclpy.init()
    node = Node("churn_listener")
    arrivals, stale = [], [0]
    node.create_subscription(PlantInput, "plant_input", lambda m: arrivals.append(time.monotonic()), TICK_QOS)

    def on_diag(arr):
        for st in arr.status:
            if st.name == "reachset_ros: simulator":
                stale[0] = int({kv.key: kv.value for kv in st.values}.get("stale_effort", 0))
    node.create_subscription(DiagnosticArray, "diagnostics", on_diag, 50)
    common = {"joints": JOINTS, "allow_uncertified": True}
    procs = []
    subs = []
    try:
        processes.start("sim_node", {"seed": 1, "calibrated": True, "lockstep_timeout": LOCKSTEP_TIMEOUT}, work,
                     group=procs)
        processes.start("reference_node", {"seed": 1}, work, group=procs)
        processes.start("observer_node", {**common, **INITIAL_GAINS}, work, group=procs)
        processes.start("controller_node", {**common, **INITIAL_GAINS}, work, group=procs)
        end = time.monotonic() + 60.0
        while len(arrivals) < 500 and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        stale0 = stale[0]
        t0 = time.monotonic()
        n0 = len(arrivals)
        next_start = t0
        while time.monotonic() - t0 < a.seconds:
            now = time.monotonic()
            if now >= next_start:
                subs.append((subprocess.Popen([sys.executable, "-c", SUBSCRIBER], start_new_session=True), now))
                next_start = now + a.period
            for p, born in list(subs):
                if now - born >= a.life:
                    p.send_signal(signal.SIGINT if a.clean else signal.SIGKILL)
                    p.wait()
                    subs.remove((p, born))
            rclpy.spin_once(node, timeout_sec=0.01)
        gaps = [b - x for x, b in zip(arrivals[n0:], arrivals[n0 + 1:])]
        out = {"transport": "UDPv4" if a.udp else "default (SHM + UDPv4)", "end": "SIGINT" if a.clean else "SIGKILL",
               "seconds": a.seconds, "subscribers": int(a.seconds / a.period), "plant_input": len(gaps) + 1,
               "max_gap_ms": round(1e3 * max(gaps), 1) if gaps else None,
               "gaps_over_100ms": sum(g > 0.1 for g in gaps), "gaps_over_300ms": sum(g > 0.3 for g in gaps),
               "stale_steps": stale[0] - stale0, "load_average": os.getloadavg()[0]}
        print(json.dumps(out))
    finally:
        for p, _ in subs:
            p.kill()
            p.wait()
        processes.stop(procs)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
