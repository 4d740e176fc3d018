"""Start-up discovery: how long does a newly started controller's command take to reach the simulator?

Each trial starts, in a fresh DDS domain and in this order, the simulator in lockstep (the
demo's ``lockstep_timeout`` 0.3 s), the reference, the observer and the controller (initial
gains), lets them run ``--seconds`` of wall time and stops them. Until the simulator has
discovered the controller it receives no command and steps on a stale one every 0.3 s
(logged and counted, docs/reliability.md); the measure is the simulator's count of such
steps (its shutdown log line), which includes the few before the controller's first command.
Two variants, each ``--trials`` times: ``suite`` (the suite's Fast DDS profile,
``reachset_ros/data/fastdds_profiles.xml``: 20 participant announcements at 50 ms, then every
0.5 s) and ``defaults`` (a profile file with no profile: Fast DDS's 5 at 100 ms, then every 3 s).
One JSON object on stdout.

Run: ``.venv/bin/python benchmarks/dds_discovery.py --trials 8``.
"""
import argparse
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

from reachset_ros import processes
from reachset_ros.domain import pick_domain_id
from reachset_ros.workflows.demo import INITIAL_GAINS, JOINTS, LOCKSTEP_TIMEOUT

EMPTY_PROFILES = ('<?xml version="1.0" encoding="UTF-8" ?>\n'
                  '<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles></profiles></dds>\n')
STALE = re.compile(r"steps with a stale command (\d+) \(longest run (\d+)\)")


def trial(workdir: Path, profile_file: str, seconds: float) -> dict:
    env = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=profile_file,
               ROS_DOMAIN_ID=str(pick_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    common = {"joints": JOINTS, **INITIAL_GAINS, "allow_uncertified": True}
    procs = []
    try:
        processes.start("sim_node", {"seed": 3, "realistic": True, "lockstep_timeout": LOCKSTEP_TIMEOUT}, workdir,
                     env=env, group=procs)
        processes.start("reference_node", {"seed": 3}, workdir, env=env, group=procs)
        processes.start("observer_node", common, workdir, env=env, group=procs)
        processes.start("controller_node", common, workdir, env=env, group=procs)
        time.sleep(seconds)
    finally:
        processes.stop(procs)
    m = STALE.search(procs[0].log.read_text(errors="replace"))
    if m is None:
        raise RuntimeError(f"no shutdown line in {procs[0].log}: {procs[0].last_log_line()}")
    return {"stale_steps": int(m.group(1)), "longest_run": int(m.group(2))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=8.0, help="wall time each loop runs (default 8)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="dds_discovery_") as tmp:
        empty = Path(tmp) / "no_profile.xml"
        empty.write_text(EMPTY_PROFILES)
        out = {}
        for name, profile in (("suite", processes.DDS_PROFILES), ("defaults", str(empty))):
            runs = [trial(Path(tmp) / f"{name}{i}", profile, args.seconds) for i in range(args.trials)]
            stale = [r["stale_steps"] for r in runs]
            out[name] = {"stale_steps": stale, "trials_over_5": sum(s > 5 for s in stale),
                         "longest_run_max": max(r["longest_run"] for r in runs)}
            print(name, out[name], file=sys.stderr, flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
