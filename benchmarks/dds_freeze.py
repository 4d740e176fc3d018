"""Does a frozen or killed subscriber process block the publisher's ``publish()``?

The suspect of the short campaign's stall (docs/reliability.md, "The test suite's own races"):
a writer blocked by a reader that was stopped (Fast DDS' shared-memory port of a frozen
process). A publisher in this process sends ``--topics`` topics of ``JointState`` at ``--rate``
Hz with the loop's ``TICK_QOS`` to one subscriber process (the suite's DDS profile), which is
frozen (SIGSTOP) for 0.35 s and 1.5 s, SIGKILLed, restarted, and frozen again for 0.35 s and
1.5 s, as the campaign's events 1-2 did to the observer. Printed: the longest ``publish()``
per phase, ms, as one JSON object. Run it once with the default transports (shared memory +
UDP) and once with ``--udp`` (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4`` for both processes).

Run: ``.venv/bin/python benchmarks/dds_freeze.py [--udp] [--topics 4] [--rate 250]``.
"""
import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

SUBSCRIBER = r"""
import os, sys
sys.path.insert(0, sys.argv[1])
from reachset_ros import processes
processes.use_dds_profiles(os.environ)
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState
from reachset_ros.nodes.common import TICK_QOS
rclpy.init()
node = Node("dds_freeze_subscriber")
subs = [node.create_subscription(JointState, f"dds_freeze_{i}", lambda m: None, TICK_QOS) for i in range(int(sys.argv[2]))]
print("ready", flush=True)
rclpy.spin(node)
"""
#: (seconds after the start, action, argument): the campaign's events 1-2 on the observer, then more
PLAN = ((3.0, "freeze", 0.35), (6.0, "freeze", 1.5), (10.0, "kill", 0), (11.0, "restart", 0),
        (14.0, "freeze", 0.35), (17.0, "freeze", 1.5))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--udp", action="store_true", help="FASTDDS_BUILTIN_TRANSPORTS=UDPv4 for both processes")
    ap.add_argument("--topics", type=int, default=4)
    ap.add_argument("--rate", type=float, default=250.0)
    ap.add_argument("--seconds", type=float, default=21.0)
    a = ap.parse_args(argv)
    from reachset_ros import processes
    from reachset_ros.domain import pick_domain_id
    os.environ.setdefault("ROS_DOMAIN_ID", str(pick_domain_id()))
    if a.udp:
        os.environ["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    processes.use_dds_profiles(os.environ)
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from reachset_ros.nodes.common import TICK_QOS

    def start():
        p = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(ROOT), str(a.topics)], stdout=subprocess.PIPE,
                             text=True, env=os.environ)
        if p.stdout.readline().strip() != "ready":
            raise SystemExit("the subscriber process did not start")
        return p

    rclpy.init()
    node = Node("dds_freeze_publisher")
    pubs = [node.create_publisher(JointState, f"dds_freeze_{i}", TICK_QOS) for i in range(a.topics)]
    child = start()
    try:
        t_end = time.monotonic() + 30.0
        while any(p.get_subscription_count() == 0 for p in pubs):
            if time.monotonic() > t_end:
                raise SystemExit("the subscriber did not match within 30 s")
            time.sleep(0.05)
        time.sleep(1.0)
        msg = JointState(name=[f"j{i}" for i in range(6)], position=[0.0] * 6)
        worst, phase, plan, k = {}, "running", list(PLAN), 0
        t0 = time.monotonic()
        while (now := time.monotonic() - t0) < a.seconds:
            while plan and now >= plan[0][0]:
                at, act, arg = plan.pop(0)
                phase = f"{act} {arg:g} s at {at:g} s" if act == "freeze" else f"{act} at {at:g} s"
                if act == "freeze":
                    os.kill(child.pid, signal.SIGSTOP)
                    threading.Timer(arg, os.kill, (child.pid, signal.SIGCONT)).start()
                elif act == "kill":
                    child.kill()
                    child.wait()
                else:
                    child = start()
            for p in pubs:
                s = time.perf_counter()
                p.publish(msg)
                worst[phase] = max(worst.get(phase, 0.0), time.perf_counter() - s)
            k += 1
            time.sleep(max(0.0, t0 + k / a.rate - time.monotonic()))
    finally:
        child.kill()
        child.wait()
    print(json.dumps({"transports": "UDPv4" if a.udp else "default", "topics": a.topics, "rate_hz": a.rate,
                      "longest_publish_ms": {ph: round(v * 1e3, 2) for ph, v in worst.items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
