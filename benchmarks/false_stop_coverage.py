"""Were a fault campaign's false stops motions its training never recorded?

For every false stop of a campaign that is a violation (from its ``campaign.json``; for a
partial run, the log's ``FALSE STOP in the fault-free stretch: ...`` lines, found in the block
bags by their whole reason) this compares the violating
joint's fastest reference (``max |qd_d|`` over the 2 s before the stop) with the fastest
reference of that joint in the training recordings (``train*``) the monitor's model was
identified from, and the joint's largest tracking error |q - q_d| in the second before the stop
with the largest in the training where |qd_d| > 0.6 rad/s (and how long the training was
that fast). Reads bags only; asserts nothing.

Syntax::

    .venv/bin/python benchmarks/false_stop_coverage.py WORKDIR [LOG]

``WORKDIR``: ``benchmarks/fault_campaign.py --workdir``; ``LOG``: its standard error (needed
only when the run did not finish).
"""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from reachset_ros.bags.messages import header_stamp_ns
from reachset_ros.bags.references import read_references
from reachset_ros.bags import read_messages, read_topic_rows

BEFORE_NS = 2_000_000_000
#: "fast" for the tracking-error comparison: |qd_d| above this share of the class' 0.7 rad/s
FAST_QD = 0.6


def _tracking(bag, refs, joint):
    """``(stamps, |q - q_d|, |qd_d|)`` of a joint at the stamps both ``/joint_states`` and its
    references (``read_references`` of ``bag``, already read) have."""
    js = read_topic_rows([bag], "/joint_states", ("position",), [joint])[joint]
    rs, rq, rqd = (np.concatenate([getattr(r, f) for r in refs[joint]]) for f in ("stamps", "q", "qd"))
    st, a, b = np.intersect1d(js[0], rs, return_indices=True)
    return st, np.abs(js[1][a, 0] - rq[b]), np.abs(rqd[b])


def _fastest(refs, joint, lo=None, hi=None):
    st = np.concatenate([r.stamps for r in refs[joint]])
    qd = np.abs(np.concatenate([r.qd for r in refs[joint]]))
    w = np.ones(len(st), bool) if lo is None else (st > lo) & (st <= hi)
    return float(qd[w].max()) if np.any(w) else float("nan")


def _false_stops(workdir, log):
    """``[(bag, stamp_ns, reason)]`` of the campaign's violation false stops: from
    ``campaign.json``'s score when the run finished, else from the log (a partial run), each
    found in the block bags by its whole reason."""
    res = workdir / "campaign.json"
    if res.exists():
        return [(Path(f["bag"]).name, int(f["stop"][0]), f["stop"][2].split("violation: ", 1)[1])
                for f in json.loads(res.read_text())["score"]["false"] if f["stop"][2].startswith("violation: ")]
    if log is None:
        raise SystemExit(f"false_stop_coverage: error: {res} does not exist; give the campaign's LOG")
    tag = "FALSE STOP in the fault-free stretch: violation: "
    false = [ln.split(tag, 1)[1].strip() for ln in log.read_text().splitlines() if tag in ln]
    out = []
    for blk in sorted(b for b in workdir.glob("block*") if (b / "metadata.yaml").exists()):
        for _, _, m in read_messages([blk], ["/safe_stop"]):
            if m.active and m.kind == "violation" and m.reason in false:
                out.append((blk.name, header_stamp_ns(m), m.reason))
                false.remove(m.reason)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workdir", type=Path)
    ap.add_argument("log", type=Path, nargs="?", default=None)
    args = ap.parse_args(argv)
    false = _false_stops(args.workdir, args.log)
    # each bag's references read once: {bag: {joint: [Reference, ...]}}
    training = {b: read_references([b], None) for b in sorted(args.workdir.glob("train*"))}
    blocks = {args.workdir / name: read_references([args.workdir / name], None) for name, _, _ in false}
    train = {}
    for refs in training.values():
        for n in refs:
            train[n] = max(train.get(n, 0.0), _fastest(refs, n))
    print("training recordings' fastest |qd_d| per joint [rad/s]: "
          + ", ".join(f"{n} {v:.3f}" for n, v in sorted(train.items())))
    print(f"false stops (violations): {len(false)}")
    print("| block | false stop | joint | fastest reference in the 2 s before [rad/s] | "
          "fastest reference in the training [rad/s] |")
    print("|---|---|---|---|---|")
    for name, stamp, reason in false:
        joint = re.search(r"joint (\S+) left", reason).group(1)
        fast = _fastest(blocks[args.workdir / name], joint, stamp - BEFORE_NS, stamp)
        print(f"| {name} | {reason[:80]} | {joint} | {fast:.3f} | {train.get(joint, float('nan')):.3f} |")
    # the tracking error before each false stop against the training's at fast moves
    print(f"\n| joint | training: s with abs(qd_d) > {FAST_QD} | training: max abs(q - q_d) there [rad] | "
          "false stop | max abs(q - q_d) in the 1 s before [rad] |")
    print("|---|---|---|---|---|")
    for joint in sorted({re.search(r"joint (\S+) left", r).group(1) for _, _, r in false}):
        err, n = 0.0, 0
        for b, refs in training.items():
            _, e, v = _tracking(b, refs, joint)
            f = v > FAST_QD
            n += int(f.sum())
            err = max(err, float(e[f].max()) if f.any() else 0.0)
        for name, stamp, reason in false:
            if f"joint {joint} left" in reason:
                st, e, _ = _tracking(args.workdir / name, blocks[args.workdir / name], joint)
                w = (st > stamp - 1_000_000_000) & (st <= stamp)
                print(f"| {joint} | {n * 0.004:.1f} | {err:.5f} | {name} | {float(e[w].max()):.5f} |")


if __name__ == "__main__":
    main()
