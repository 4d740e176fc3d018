"""Benchmark: start-up of the command line and of the nodes (issue 38.1).

Each case is a fresh process, run ``--repeat`` times (default 7); the table gives the median
and the fastest wall time and the ratio of the median to a bare ``python -c "import numpy"``
(the issue's yardstick: at most 2.5). Cases: ``reachset --help``, a usage error, each
command's ``--help``, a bad-input error (a bag that does not exist) of the bag commands, and
the import of each node module (what a node pays before its first line runs).

Syntax::

    .venv/bin/python benchmarks/startup.py [--repeat N] [--json FILE] [--checkout DIR]

``--checkout DIR`` times another checkout of the package (``git worktree add DIR COMMIT``; its
compiled kernel copied in) with the same cases: the before of a change.

Benchmarks assert nothing; the import counts behind these times are tested in
``test/test_lazy.py``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from reachset_ros.commands import COMMANDS

NODES = ["controller_node", "observer_node", "monitor_node", "sim_node", "reference_node", "recorder_node",
         "synthesis_node"]
BAG_COMMANDS = ["inspect", "identify", "check", "replay", "report", "synthesize"]


def timed(argv, repeat, env=None):
    """Median and fastest wall time (s) of ``argv`` as a fresh process."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        # from a neutral directory: ``python -m`` puts the working directory first on sys.path
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False, env=env,
                       cwd=tempfile.gettempdir())
        times.append(time.perf_counter() - t)
    return statistics.median(times), min(times)


def cases():
    cli = [sys.executable, "-m", "reachset_ros.cli"]
    yield "python -c 'import numpy'", [sys.executable, "-c", "import numpy"]
    yield "reachset --help", cli + ["--help"]
    yield "reachset no-such-command", cli + ["no-such-command"]
    for name in COMMANDS:
        yield f"reachset {name} --help", cli + [name, "--help"]
    for name in BAG_COMMANDS:
        extra = ["--model", "/nonexistent/model.yaml"] if name in ("check", "replay", "report") else []
        yield f"reachset {name} /nonexistent (exit 2)", cli + [name, "/nonexistent/bag", *extra]
    for node in NODES:
        yield f"import reachset_ros.nodes.{node}", [sys.executable, "-c", f"import reachset_ros.nodes.{node}"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--checkout", help="time the package in this directory instead")
    args = ap.parse_args(argv)
    env = None
    if args.checkout:
        env = dict(os.environ, PYTHONPATH=os.path.abspath(args.checkout))
    rows = []
    base = None
    for label, cmd in cases():
        med, best = timed(cmd, args.repeat, env)
        base = base or med
        rows.append({"case": label, "median_s": med, "min_s": best, "x_numpy": med / base})
        print(f"{label:55s} {med:6.3f} s  (min {best:6.3f})  {med / base:4.1f}x", flush=True)
    print(f"load average at the end: {os.getloadavg()[0]:.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
