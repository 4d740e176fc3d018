"""Normal running without false stops (issue 19.3), measured on the whole node suite.

The protocol of the paper and of issue 19: record the test cases on the motions that then
run, calibrate the monitor's inflation on held-out recordings, then run.

1. The suite (sim, reference, observer, controller, synthesis node; no monitor before its model)
   in a fresh DDS domain; ``--runs`` recordings of ``--train`` s of simulated time each.
2. ``reachset identify`` on every run but the last, ``--validate`` on the last (held out):
   the model's inflation is the calibrated one (``validation.validation_grid``).
3. The monitor starts with that model (its start-up stop released by checked ticks); then ``--minutes`` of simulated time of normal
   running with a topic listener attached (a separate process subscribed to
   ``/joint_states`` and ``/conformance/status``, like ``ros2 topic echo``) and a synthesis
   running beside it (the synthesis node's ``~/synthesize`` on the training bags, apply
   false, again and again; its ``reachset synthesize`` child runs at nice 10).
4. Counted: safe stops (every one is a false stop: no fault is injected), status messages,
   synthesis runs, simulated and wall time, load average. One JSON object on stdout.

Run: ``.venv/bin/python benchmarks/false_stops.py [--minutes 10] [--train 40] [--runs 3]``.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from reachset_msgs.msg import ConformanceStatus
from reachset_msgs.srv import Synthesize

from reachset_ros import processes
from reachset_ros.domain import pick_domain_id
from reachset_ros.nodes.common import STATUS_QOS, stamp_ns
from reachset_ros.workflows.commander import CORE_TOPICS, JOINTS, SuiteCommander

LISTENER = """
import sys, rclpy
from rclpy.node import Node
from reachset_msgs.msg import ConformanceStatus
from sensor_msgs.msg import JointState
from reachset_ros.nodes.common import STATUS_QOS, TICK_QOS
rclpy.init()
n = Node("topic_listener")
count = [0]
def cb(m):
    count[0] += 1
    sys.stdout.write(str(m)[:200] + "\\n")        # what `ros2 topic echo` does: format and print
n.create_subscription(JointState, "joint_states", cb, TICK_QOS)
n.create_subscription(ConformanceStatus, "conformance/status", cb, STATUS_QOS)
try:
    rclpy.spin(n)
except BaseException:
    pass
"""


def _record_run(driver, path, *, node, seconds):
    """One recording of the core topics, ``seconds`` of simulated time; its path."""
    rec = driver.record(path, CORE_TOPICS, node_name=node, wait_s=120.0)
    driver.spin_sim(seconds)
    processes.stop([rec])
    print(f"recorded {path}", file=sys.stderr, flush=True)
    return path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="simulated minutes of normal running")
    ap.add_argument("--train", type=float, default=40.0, help="simulated seconds per recording")
    ap.add_argument("--runs", type=int, default=3, help="recordings (the last one held out)")
    ap.add_argument("--workdir", default=None)
    a = ap.parse_args()
    work = Path(a.workdir or tempfile.mkdtemp(prefix="false_stops_")).resolve()
    work.mkdir(parents=True, exist_ok=True)
    domain = pick_domain_id()
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    print(f"ROS_DOMAIN_ID={domain} workdir {work}", file=sys.stderr, flush=True)
    load0 = os.getloadavg()
    procs = []
    rclpy.init()
    driver = SuiteCommander(workdir=work)
    out = {"domain": domain, "workdir": str(work), "load_average_before": load0}
    try:
        common = {"joints": JOINTS, "allow_uncertified": True}
        processes.start("sim_node", {"seed": 7, "realistic": True, "lockstep_timeout": 0.3}, work, group=procs)
        processes.start("reference_node", {"seed": 7}, work, group=procs)
        processes.start("observer_node", dict(common), work, group=procs)
        processes.start("controller_node", dict(common), work, group=procs)    # training: no monitor yet
        processes.start("synthesis_node", {"workdir": str(work / "synthesis")}, work, group=procs)
        bags = [_record_run(driver, work / f"run{i + 1}", node=f"recorder_{i + 1}", seconds=a.train)
                for i in range(a.runs)]
        model = work / "model.yaml"
        p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "identify", *map(str, bags[:-1]),
                            "--validate", str(bags[-1]), "--out", str(model), "--json"],
                           capture_output=True, text=True)
        if p.returncode != 0:
            raise RuntimeError(f"identify: {p.stderr.strip()}")
        ident = json.loads(p.stdout)
        out["inflation"] = ident["inflation"]
        out["chosen_inflation_per_joint"] = {n: j["validation"]["chosen_inflation"] for n, j in ident["joints"].items()}
        print(f"calibrated inflation {ident['inflation']}", file=sys.stderr, flush=True)
        # the monitor starts with its model (issue 34.1: none without one); its start-up stop is
        # released by checked ticks of the held arm
        procs.append(driver.start_monitor({"window_dir": str(work / "windows"), "model_file": str(model)}))
        driver.stops.clear()
        statuses = []
        driver.create_subscription(ConformanceStatus, "conformance/status", lambda m: statuses.append(m.conformant),
                                   STATUS_QOS)
        listener = subprocess.Popen([sys.executable, "-c", LISTENER], stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL, start_new_session=True)
        synth = {"runs": 0, "failed": 0}
        client = driver.create_client(Synthesize, "/synthesis_node/synthesize")
        client.wait_for_service(timeout_sec=30.0)
        pending = [None]

        def keep_synthesising():
            f = pending[0]
            if f is not None and not f.done():
                return
            if f is not None:
                res = f.result()
                synth["runs" if res is not None and res.success else "failed"] += 1
            pending[0] = client.call_async(Synthesize.Request(bags=[str(b) for b in bags[:-1]], joints=JOINTS,
                                                              mode="combined", apply=False))
        wall0 = time.monotonic()
        sim0 = driver.sim_now()
        end = sim0 + int(a.minutes * 60e9)
        loads = []
        while driver.sim_now() < end:
            keep_synthesising()
            driver.spin_for(1.0)
            loads.append(os.getloadavg()[0])
            if time.monotonic() - wall0 > 6 * a.minutes * 60 + 300:
                raise RuntimeError("the simulation does not advance")
        listener.terminate()
        listener.wait(timeout=10)
        out.update({
            "simulated_minutes": (driver.sim_now() - sim0) / 60e9, "wall_minutes": (time.monotonic() - wall0) / 60,
            "status_messages": len(statuses), "conformant_share": sum(statuses) / max(len(statuses), 1),
            # the monitor repeats an active stop every tick until a reset: one entry per stop
            "safe_stops": list({(stamp_ns(s.header.stamp), s.kind, s.reason): {"kind": s.kind, "reason": s.reason}
                                for s in driver.stops if s.active}.values()),
            "synthesis_runs_completed": synth["runs"], "synthesis_runs_failed": synth["failed"],
            "load_average_1min_max": max(loads, default=0.0),
            "load_average_1min_mean": sum(loads) / max(len(loads), 1)})
        out["false_stops"] = len(out["safe_stops"])
    finally:
        processes.stop(procs)
        driver.own_executor.shutdown(timeout_sec=1.0)
        driver.destroy_node()
        rclpy.try_shutdown()
    print(json.dumps(out, indent=1))
    return 0 if out.get("false_stops", 1) == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
