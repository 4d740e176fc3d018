"""Bring-ups that run: `reachset up` from a demo's outputs, left running, with every stop counted.

Run: .venv/bin/python benchmarks/bringup_soak.py --workdir W [--runs 5] [--seconds 600] [--json] [--keep DIR]

W is a `reachset demo --workdir W` directory: each run is the command the demo printed,
``reachset up --sim --params-file W/bringup.params.yaml --model W/monitor_model.yaml`` (issue
36.1), left running ``--seconds`` of wall time, then stopped with SIGINT. Per run, from the nodes'
logs: the safe stops the controller saw, by kind (the monitor's start-up hold, ``not_ready``, is
expected once), the simulated seconds (sim_node's ticks x 4 ms) and its stale-command steps.
Nothing is asserted; the numbers go to docs/performance.md.
"""
from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path


def one_run(workdir: Path, seconds: float, out: Path):
    cmd = [sys.executable, "-m", "reachset_ros.cli", "up", "--sim", "--params-file",
           str(workdir / "bringup.params.yaml"), "--model", str(workdir / "monitor_model.yaml"),
           "--workdir", str(out)]
    with open(out.with_suffix(".out"), "w") as log:
        p = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        time.sleep(seconds)
        p.send_signal(signal.SIGINT)
        p.wait(timeout=120)
    ctl = (out / "controller_node.log").read_text(errors="replace")
    kinds = Counter(re.findall(r"safe stop active: \w+ \((\w+)", ctl))
    sim = (out / "sim_node.log").read_text(errors="replace")
    ticks = re.findall(r"ticks (\d+), steps with a stale command (\d+)", sim)
    return {"exit_status": p.returncode, "stops_by_kind": dict(kinds),
            "stops_after_start_up": sum(n for k, n in kinds.items() if k != "not_ready"),
            "simulated_s": int(ticks[-1][0]) * 0.004 if ticks else None,
            "stale_command_steps": int(ticks[-1][1]) if ticks else None, "wall_s": seconds}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", required=True, type=Path, help="a reachset demo --workdir")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--keep", type=Path, default=None, metavar="DIR",
                    help="keep each run's `up` work directory (logs, windows) under DIR (default: a temporary one)")
    args = ap.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) if args.keep is None else args.keep
        base.mkdir(parents=True, exist_ok=True)
        for i in range(args.runs):
            r = one_run(args.workdir.resolve(), args.seconds, base / f"up{i + 1}")
            runs.append(r)
            if not args.json:
                print(f"run {i + 1}: stops after the start-up hold {r['stops_after_start_up']} "
                      f"({r['stops_by_kind']}); {r['simulated_s']:.0f} s simulated in {r['wall_s']:.0f} s; "
                      f"stale-command steps {r['stale_command_steps']}", flush=True)
    if args.json:
        print(json.dumps(runs))


if __name__ == "__main__":
    main()
