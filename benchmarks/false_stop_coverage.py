"""Were a fault campaign's false stops motions its training never recorded?

For every false stop in a campaign's log (``FALSE STOP in the fault-free stretch: ...``) this
finds the stop in the block bags of the campaign's work directory and compares the violating
joint's fastest reference (``max |qd_d|`` over the 2 s before the stop) with the fastest
reference of that joint in the training recordings (``train*``) the monitor's model was
identified from. Reads bags only; asserts nothing.

Syntax::

    .venv/bin/python benchmarks/false_stop_coverage.py WORKDIR LOG

``WORKDIR``: ``benchmarks/fault_campaign.py --workdir``; ``LOG``: its standard error.
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from reachset_ros.bags.messages import header_stamp_ns
from reachset_ros.bags.references import read_references
from reachset_ros.bags.series import read_messages

BEFORE_NS = 2_000_000_000


def _fastest(refs, joint, lo=None, hi=None):
    st = np.concatenate([r.stamps for r in refs[joint]])
    qd = np.abs(np.concatenate([r.qd for r in refs[joint]]))
    w = np.ones(len(st), bool) if lo is None else (st > lo) & (st <= hi)
    return float(qd[w].max()) if np.any(w) else float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workdir", type=Path)
    ap.add_argument("log", type=Path)
    args = ap.parse_args(argv)
    false = [ln.split("FALSE STOP in the fault-free stretch: violation: ", 1)[1].strip()
             for ln in args.log.read_text().splitlines() if "FALSE STOP in the fault-free stretch: violation: " in ln]
    train = {}
    for b in sorted(args.workdir.glob("train*")):
        refs = read_references([b], None)
        for n in refs:
            train[n] = max(train.get(n, 0.0), _fastest(refs, n))
    print("training recordings' fastest |qd_d| per joint [rad/s]: "
          + ", ".join(f"{n} {v:.3f}" for n, v in sorted(train.items())))
    print(f"false stops in the log: {len(false)}")
    for blk in sorted(b for b in args.workdir.glob("block*") if (b / "metadata.yaml").exists()):
        stops = {}
        for _, _, m in read_messages([blk], ["/safe_stop"]):
            if m.active and m.kind == "violation":
                stops.setdefault(m.reason, header_stamp_ns(m))
        hits = [(r, s) for r, s in stops.items() if any(f.startswith(r[:60]) or r.startswith(f[:60]) for f in false)]
        if not hits:
            continue
        refs = read_references([blk], None)
        for reason, stamp in hits:
            joint = re.search(r"joint (\S+) left", reason).group(1)
            fast = _fastest(refs, joint, stamp - BEFORE_NS, stamp)
            print(f"| {blk.name} | {reason[:80]} | {joint} | {fast:.3f} | {train.get(joint, float('nan')):.3f} |")


if __name__ == "__main__":
    main()
