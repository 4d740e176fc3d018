"""`reachset demo` in wall-clock time: how close to real time does the whole system run?

Run: .venv/bin/python benchmarks/bench_demo.py [--runs 1 | --seeds 1 2 3 4 5] [--json]

Runs ``reachset demo --headless --duration 25 --inject-fault-at 18 --record B --json``
(the issue's command; 2.5-4 min each) and reads B back. The demo runs on the simulation's
time (``/clock``; the bag's log time is that clock too), so its acceptance checks hold on a
loaded machine and are a test (``test/workflows/test_demo.py``). This reports what depends on the
machine:

* **real-time factor** of each phase (simulated / wall time, from the demo's JSON): 1.0
  when the closed loop keeps real time;
* **status rate** until the first active ``/safe_stop``, on the stamps and on the bag's
  log time, and the **wall-clock status rate** (stamp rate x real-time factor of the
  monitored run before the fault);
* the detection latency, the wall time of the demo, and the simulator's count of steps
  that held a stale command (``lockstep_timeout`` exceeded; its log);
* the guarantee (issue 16.3; ``--seeds``: one demo per seed of the simulated arm and the
  reference): per joint omega inside its search box, the share of the judged ticks inside
  ``R*_e``, the transient, the calibrated inflation, and the demo's ``guarantee_failures``.

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


def one_run(tmp, seed=1):
    record = Path(tmp) / "B"
    t = time.monotonic()
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "demo", "--headless", "--duration", "25",
                        "--inject-fault-at", "18", "--record", str(record), "--workdir", str(Path(tmp) / "work"),
                        "--seed", str(seed), "--json"], capture_output=True, text=True)
    wall = time.monotonic() - t
    if not p.stdout.strip():
        return {"seed": seed, "exit_status": p.returncode, "stderr": p.stderr.strip().splitlines()[-1:],
                "wall_s": wall}
    res = json.loads(p.stdout)   # also on exit status 1 (story or guarantee failures: in the JSON)
    log = (Path(tmp) / "work" / "sim_node.log").read_text(errors="replace")
    stale = re.findall(r"steps with a stale command (\d+)", log)
    rtf = res["real_time_factor"]
    g = res.get("guarantee") or {}
    return {"seed": seed, "exit_status": p.returncode, "wall_s": wall,
            "failures": res["failures"], "guarantee_failures": res.get("guarantee_failures"),
            "inflation": res.get("inflation"), "omega": {n: j["omega"] for n, j in g.items()},
            "omega_inside_bounds": all(j["omega_inside_bounds"] for j in g.values()) if g else None,
            "inside_share_min": min((j["inside_share"] for j in g.values() if j["inside_share"] is not None),
                                    default=None),
            "transient_s_max": max((j["transient_s"] or 0.0 for j in g.values()), default=None),
            "detection_latency_ms": res["detection_latency_ms"],
            "status_rate_log_hz": res["status_rate_hz_log_time"],
            "status_rate_stamp_hz": res["status_rate_hz_until_stop"],
            "status_rate_wall_hz": res["status_rate_hz_until_stop"] * rtf["monitored before the fault"],
            "real_time_factor": rtf,
            "stale_command_steps": int(stale[-1]) if stale else None,
            "second_iteration_failed": res.get("second_iteration_failed"),
            "load_average": os.getloadavg()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--seeds", type=int, nargs="+", help="one demo per seed (default: --runs demos of seed 1)")
    ap.add_argument("--json", action="store_true")
    args, _ = ap.parse_known_args(argv)
    runs = []
    for i, seed in enumerate(args.seeds or [1] * args.runs):
        with tempfile.TemporaryDirectory(prefix="bench_demo_") as tmp:
            r = one_run(tmp, seed)
        runs.append(r)
        if not args.json:
            if "failures" not in r:
                print(f"run {i + 1} (seed {seed}): demo exit status {r['exit_status']}: {r['stderr']}", flush=True)
                continue
            print(f"run {i + 1} (seed {seed}): exit {r['exit_status']}; omega inside its bounds on every joint: "
                  f"{r['omega_inside_bounds']} ({', '.join(f'{v:.3g}' for v in r['omega'].values())}); "
                  f"smallest share of judged ticks inside R*_e {r['inside_share_min']}; longest transient "
                  f"{r['transient_s_max']:.3g} s; calibrated inflation {r['inflation']}; "
                  f"failures {r['failures'] + (r['guarantee_failures'] or [])}", flush=True)
            print(f"run {i + 1}: status {r['status_rate_stamp_hz']:.1f} Hz on stamps, "
                  f"{r['status_rate_log_hz']:.1f} Hz on log time, {r['status_rate_wall_hz']:.1f} Hz on the wall "
                  f"clock; real-time factor " + ", ".join(f"{k} {v:.2f}" for k, v in r["real_time_factor"].items())
                  + f"; detection {r['detection_latency_ms']:.0f} ms, "
                  f"stale-command steps {r['stale_command_steps']}, wall {r['wall_s']:.0f} s, "
                  f"load {r['load_average'][0]:.1f}", flush=True)
    if args.json:
        print(json.dumps(runs))
    return 0 if all(r["exit_status"] == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
