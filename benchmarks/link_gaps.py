"""The monitor's lossy-link rule (``gap_window``) applied to a fault campaign's recorded stream:
where would it have stopped? The evidence behind its default (docs/reliability.md).

Usage::

    python benchmarks/link_gaps.py WORK [--gap-window N]

``WORK`` is a fault campaign's work directory (``campaign.json`` and the ``block*`` bags). The
stamps of ``/conformance/status`` are the ticks the monitor processed (one status per tick),
so its gaps are the monitor's. A
:class:`~reachset_ros.conformance.watches.CoverageWatch` with only the lossy-link rule
(``gap_window`` N, default 25 ticks; the model's dt 4 ms, missing-data limit 125 ticks as in
the campaign) is fed every block's stamps; each coverage fault it raises is attributed to the
event in progress (the last event whose fault stamp precedes it, or the fault-free stretch
before the first). Printed: the faults per event kind, and each one outside a link loss.
"""
from __future__ import annotations

import argparse
import collections
import glob
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reachset_ros.bags import STATUS_TOPIC, header_stamp_ns, read_messages  # noqa: E402
from reachset_ros.conformance.watches import CoverageWatch  # noqa: E402

DT_NS = 4_000_000


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("work")
    p.add_argument("--gap-window", type=int, default=25)
    a = p.parse_args(argv)
    work = Path(a.work)
    try:
        info = json.loads((work / "campaign.json").read_text())
    except (OSError, ValueError) as e:
        print(f"link_gaps: error: {work / 'campaign.json'}: {e}", file=sys.stderr)
        return 2
    events = sorted((o["fault_ns"], o["event"]) for o in info["outcomes"])
    starts = np.array([f for f, _ in events], dtype=np.int64)
    by_kind, outside, ticks, gaps = collections.Counter(), [], 0, 0
    for block in sorted(glob.glob(str(work / "block*"))):
        stamps = sorted(header_stamp_ns(m) for _, _, m in read_messages([block], [STATUS_TOPIC]))
        # the horizon rule never fires here (longest = k* at every tick): only gaps count
        watch = CoverageWatch(DT_NS, 3, 125, 125, a.gap_window)
        last = None
        for st in stamps:
            if last is not None and st != last and not (DT_NS <= 2 * (st - last) <= 3 * DT_NS) \
                    and st - last <= 125 * DT_NS:
                gaps += 1
            last = st
            ticks += 1
            f = watch.update(st, 125)
            if f is None or "lost again" not in f.reason:
                continue
            i = int(np.searchsorted(starts, st, side="right")) - 1
            label = events[i][1] if i >= 0 else "fault-free start"
            kind = " ".join(label.split()[:2])
            by_kind[kind] += 1
            if not label.startswith("link") or "dropped" not in label:
                outside.append((Path(block).name, st, label, round((st - events[i][0]) / 1e9, 3) if i >= 0 else None))
    print(f"{work}: {ticks} monitored ticks, {gaps} gaps; lossy-link rule (gap_window {a.gap_window}) faults:")
    for k, v in by_kind.most_common():
        print(f"  {v:6d}  {k}")
    print(f"outside the link-loss events: {len(outside)}")
    for row in outside:
        print("  ", *row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
