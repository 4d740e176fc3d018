"""`reachset demo` in wall-clock time: how close to real time does the whole system run?

Run: .venv/bin/python benchmarks/bench_demo.py [--runs 1] [--json]

Runs ``reachset demo --headless --duration 25 --inject-fault-at 18 --record B --json``
(the issue's command; about 2.5 min each) and reads B back. The acceptance checks on the
stamp clock are a test (``test/test_demo.py``); this reports what depends on the machine:

* **status rate on log time**: ``/conformance/status`` messages per second of the
  recorder's receive time, from the start of the recording to the first active
  ``/safe_stop`` (250 Hz when the loop keeps real time);
* **real-time factor**: simulated time (stamp span) / log-time span of ``/joint_states``
  over the monitored run;
* **largest gap** between consecutive ``/joint_states`` on log time;
* the detection latency (stamp clock), the wall time of the demo, and the simulator's
  count of steps that held a stale command (``lockstep_timeout`` exceeded; its log).

Nothing is asserted; the numbers go to docs/performance.md.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def read_times(record):
    from rosbags.highlevel import AnyReader

    from reachset_ros.bags import typestore
    ts = typestore()
    out = {"/conformance/status": [], "/safe_stop": [], "/joint_states": []}
    with AnyReader([Path(record)], default_typestore=ts) as reader:
        conns = [c for c in reader.connections if c.topic in out]
        for c, t, raw in reader.messages(connections=conns):
            m = ts.deserialize_cdr(raw, c.msgtype)
            st = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            out[c.topic].append((st, t, bool(getattr(m, "active", False))))
    return out


def one_run(tmp):
    record = Path(tmp) / "B"
    t = time.monotonic()
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "demo", "--headless", "--duration", "25",
                        "--inject-fault-at", "18", "--record", str(record), "--workdir", str(Path(tmp) / "work"),
                        "--json"], capture_output=True, text=True)
    wall = time.monotonic() - t
    if p.returncode != 0:
        return {"exit_status": p.returncode, "stderr": p.stderr.strip().splitlines()[-1:], "wall_s": wall}
    res = json.loads(p.stdout)
    times = read_times(record)
    stop_log = min((lt for _, lt, a in times["/safe_stop"] if a), default=None)
    status_log = np.array(sorted(lt for _, lt, _ in times["/conformance/status"]
                                 if stop_log is None or lt <= stop_log))
    js = sorted(times["/joint_states"], key=lambda x: x[1])
    js_log = np.array([lt for _, lt, _ in js if stop_log is None or lt <= stop_log])
    js_st = np.array([st for st, lt, _ in js if stop_log is None or lt <= stop_log])
    log = (Path(tmp) / "work" / "sim_node.log").read_text(errors="replace")
    stale = re.findall(r"steps with a stale command (\d+)", log)
    return {"exit_status": 0, "wall_s": wall, "detection_latency_ms": res["detection_latency_ms"],
            "status_rate_log_hz": (len(status_log) - 1) / ((status_log[-1] - status_log[0]) * 1e-9),
            "status_rate_stamp_hz": res["status_rate_hz_until_stop"],
            "real_time_factor": float((js_st[-1] - js_st[0]) / (js_log[-1] - js_log[0])),
            "largest_gap_ms": float(np.diff(js_log).max() / 1e6),
            "stale_command_steps": int(stale[-1]) if stale else None,
            "second_iteration_failed": res.get("second_iteration_failed"),
            "load_average": os.getloadavg()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args, _ = ap.parse_known_args(argv)
    runs = []
    for i in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="bench_demo_") as tmp:
            r = one_run(tmp)
        runs.append(r)
        if not args.json:
            if r["exit_status"] != 0:
                print(f"run {i + 1}: demo exit status {r['exit_status']}: {r['stderr']}", flush=True)
                continue
            print(f"run {i + 1}: status {r['status_rate_log_hz']:.1f} Hz on log time "
                  f"({r['status_rate_stamp_hz']:.1f} Hz on stamps), real-time factor {r['real_time_factor']:.3f}, "
                  f"largest gap {r['largest_gap_ms']:.0f} ms, detection {r['detection_latency_ms']:.0f} ms, "
                  f"stale-command steps {r['stale_command_steps']}, wall {r['wall_s']:.0f} s, "
                  f"load {r['load_average'][0]:.1f}", flush=True)
    if args.json:
        print(json.dumps(runs))
    return 0 if all(r["exit_status"] == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
