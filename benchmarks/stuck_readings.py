"""How long a position reading repeats itself while the joint moves: the evidence behind the
monitor's stuck-sensor rule (``stuck_ticks``, ``stuck_speed``; docs/reliability.md).

Usage::

    python benchmarks/stuck_readings.py [--data DIR] [--campaign WORK]

``--data`` (default: the shipped ``reachset_ros/data/lwa4p_iros2018``): the real LWA-4P recordings. For each
joint and speed threshold, the longest run of repeats (a sample bit-identical to the one
before) during which the joint's *measured* speed stayed at or above the threshold, and the
longest run at any speed (at rest a quantized encoder repeats itself for seconds).

``--campaign WORK`` (a fault campaign's work directory): the same on the simulated
system's bags, with the *reference* speed (what the monitor's rule sees), outside the
frozen-sensor events (from a frozen sensor's fault stamp to the end of its block), and the
count of the runs the rule (5 repeats at >= 0.05 rad/s) would have stopped on.
"""
from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reachset_ros.bags import read_joint_series, read_references  # noqa: E402
from reachset_ros.conformance.watches import StuckSensorWatch  # noqa: E402

THRESHOLDS = (0.0, 0.01, 0.02, 0.05)
DT_NS = 4_000_000


def longest_while(y, speed, thr, stamps=None):
    """Longest run of repeats during which ``speed`` (per sample) stayed >= thr; with
    ``stamps``, a step other than one tick ends a run."""
    best = n = 0
    for i in range(1, len(y)):
        if (y[i] == y[i - 1] and speed[i] >= thr and speed[i - 1] >= thr
                and (stamps is None or stamps[i] - stamps[i - 1] == DT_NS)):
            n += 1
            best = max(best, n)
        else:
            n = 0
    return best


def rule_fires(name, st, y, speed, ticks, min_speed):
    """Stamps at which the monitor's own rule (:class:`StuckSensorWatch`, fed the readings and
    the references of the same stamps) starts to fire: one per run of repeats it stops on."""
    watch = StuckSensorWatch([name], DT_NS, ticks, min_speed)
    out, firing = [], False
    for t, yi, v in zip(st, y, speed):
        watch.add_reference(int(t), [v])
        hit = watch.update(int(t), [yi]) is not None
        if hit and not firing:
            out.append(int(t))
        firing = hit
    return out


def real_data(path):
    from reachset_ros.robot.lwa4p import recordings_dir
    path = recordings_dir(path)
    runs = sorted(glob.glob(str(Path(path) / "measurement_*")), key=lambda s: int(s.rsplit("_", 1)[1]))
    if not runs:
        raise SystemExit(f"error: no measurement_* folders in {path}")
    best = np.zeros((6, len(THRESHOLDS)), dtype=np.int64)
    n = 0
    for r in runs:
        T = np.loadtxt(Path(r) / "trajectory.csv", delimiter=",")
        n += len(T)
        for j in range(6):
            for k, thr in enumerate(THRESHOLDS):
                best[j, k] = max(best[j, k], longest_while(T[:, j], np.abs(T[:, 6 + j]), thr))
    print(f"real LWA-4P recordings: {len(runs)} runs, {n} samples ({n * 0.004:.1f} s)")
    print("longest run of repeated position readings (repeats) while the measured speed stayed >= threshold")
    print("joint  " + "  ".join(f">={t:<5g}" if t else "any   " for t in THRESHOLDS))
    for j in range(6):
        print(f"{j + 1:5d}  " + "  ".join(f"{best[j, k]:6d}" for k in range(len(THRESHOLDS))))


def campaign(work, ticks=5, speed=0.05):
    info = json.loads((Path(work) / "campaign.json").read_text())
    frozen_events = [o for o in info["outcomes"] if " frozen " in o["event"]]
    frozen = sorted(o["fault_ns"] for o in frozen_events)
    detect = []         # frozen events: (label, observable -> rule, observable -> the run's first stop), ms
    blocks = sorted(glob.glob(str(Path(work) / "block*")))
    best, fired, samples = {}, [], 0
    for b in blocks:
        series, _ = read_joint_series([b])
        refs = read_references([b])
        for name, s in series.items():
            st, y = s.stamps, s.y
            speed_at = np.zeros(len(st))
            for ref in refs.get(name, []):
                idx = np.searchsorted(st, ref.stamps)
                ok = (idx < len(st)) & (st[np.minimum(idx, len(st) - 1)] == ref.stamps)
                speed_at[idx[ok]] = np.abs(ref.qd[ok])
            lo, hi = st[0], st[-1]
            for o in frozen_events:
                if o["event"].split()[2] != name or not lo <= o["fault_ns"] <= hi:
                    continue
                after = st >= o["fault_ns"]
                fires = rule_fires(name, st[after], y[after], speed_at[after], ticks, speed)
                fire = fires[0] if fires else None
                obs = o.get("observable_ns") or o["fault_ns"]
                stop = o["stops"][0][1] if o["stops"] else None
                detect.append((o["event"], None if fire is None else (fire - obs) / 1e6,
                               None if stop is None else (stop - obs) / 1e6))
            # outside frozen-sensor events: cut from the fault stamp to the block's end
            cut = [f for f in frozen if lo <= f <= hi]
            keep = st < (min(cut) if cut else hi + 1)
            samples += int(keep.sum())
            sk, yy, sp = st[keep], y[keep], speed_at[keep]
            best[name] = max(best.get(name, 0), longest_while(yy, sp, speed, sk))
            fired += [(name, t, Path(b).name) for t in rule_fires(name, sk, yy, sp, ticks, speed)]
    print(f"\ncampaign {work}: {len(blocks)} blocks, {samples} joint samples outside frozen-sensor events")
    print(f"longest run of repeats while the reference speed stayed >= {speed} rad/s, per joint:")
    for name in sorted(best):
        print(f"  {name}: {best[name]}")
    print(f"runs the rule ({ticks} repeats) stops on: {len(fired)}")
    for f in fired[:20]:
        print("  ", *f)
    print(f"\nfrozen-sensor events ({len(detect)}): the rule's stop and the run's first stop, ms after the "
          "joint's reference first moved (|qd_d| > 0.05 rad/s; negative: before)")
    fmt = lambda v: "   none" if v is None else f"{v:7.0f}"   # noqa: E731
    for label, rule, stop in detect:
        print(f"  {label:32s} rule {fmt(rule)}  recorded stop {fmt(stop)}")
    got = [r for _, r, _ in detect if r is not None]
    if got:
        print(f"  rule: {len(got)} of {len(detect)} detected, max {max(got):.0f} ms after the first motion")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=None, help="the LWA-4P recordings (default: the shipped reachset_ros/data/lwa4p_iros2018)")
    p.add_argument("--campaign", help="a fault campaign's work directory (campaign.json and block* bags)")
    a = p.parse_args(argv)
    real_data(a.data)
    if a.campaign:
        campaign(a.campaign)


if __name__ == "__main__":
    main()
