"""How far the monitor's verdicts trailed the simulated arm, read from recorded bags.

Usage::

    python benchmarks/monitor_lag.py BAG [BAG ...]

Each ``BAG`` is a rosbag2 directory with ``/joint_states`` and ``/conformance/status`` (a
fault campaign's ``block*`` bags, the demo's bag), or a fault campaign's work directory (its
``block*`` bags are taken). For every ``/conformance/status`` (the monitor's verdict of the
tick with that stamp) the lag is the newest ``/joint_states`` stamp the recorder had logged
at or before the status's log time, minus the status's stamp: how much stamp time (the arm's
time) the simulated arm had run ahead of the monitor's checks. Printed per bag and overall:
p50 / p99 / max in ms and the share of verdicts more than 20 ms (5 ticks) behind.

Approximation: both topics are timed by the recorder's arrival (its log time), one process
that receives both; a recorder that falls behind delays both alike, but its own queues can
reorder the two topics by a few ms. The evidence behind the simulator's
``monitor_lockstep_ticks`` (docs/reliability.md, "The monitor trailing the simulated arm").
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reachset_ros.bags import read_messages  # noqa: E402
from reachset_ros.nodes.common import stamp_ns  # noqa: E402

BEHIND_MS = 20.0


def lags_ms(bag):
    """The monitor's lag behind the arm at each of the bag's verdicts, ms (stamp time)."""
    newest, out = None, []
    for topic, _, msg in read_messages([bag], ["/joint_states", "/conformance/status"]):
        s = stamp_ns(msg.header.stamp)
        if topic == "/joint_states":
            newest = s if newest is None else max(newest, s)
        elif newest is not None:
            out.append((newest - s) * 1e-6)
    return np.asarray(out)


def summary(lags):
    if lags.size == 0:
        return "no verdicts"
    p50, p99 = np.percentile(lags, [50, 99])
    return (f"{p50:.0f} / {p99:.0f} / {lags.max():.0f} ms (n = {lags.size}; "
            f"{np.mean(lags > BEHIND_MS):.1%} more than {BEHIND_MS:g} ms behind)")


def bags_of(paths):
    out = []
    for p in map(Path, paths):
        blocks = sorted(p.glob("block*"))
        out += [b for b in blocks if b.is_dir()] if blocks else [p]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bags", nargs="+", help="rosbag2 directories, or fault campaign work directories")
    args = ap.parse_args(argv)
    missing = [p for p in args.bags if not Path(p).is_dir()]
    if missing:
        print(f"monitor_lag: not a directory: {missing[0]}", file=sys.stderr)
        return 2
    bags = bags_of(args.bags)
    if not bags:
        print("monitor_lag: no bag found", file=sys.stderr)
        return 2
    every = []
    for b in bags:
        lags = lags_ms(b)
        every.append(lags)
        print(f"{b}: the monitor's verdicts behind the arm, p50 / p99 / max {summary(lags)}")
    if len(bags) > 1:
        print(f"all {len(bags)} bags: {summary(np.concatenate(every))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
