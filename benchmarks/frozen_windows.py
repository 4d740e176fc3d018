"""When could the stuck-sensor rule fire on each frozen sensor of a fault campaign, and when did
the stop come? (issue 35: the long campaign's event 44, a frozen sensor stopped 2.84 s late)

Usage::

    python benchmarks/frozen_windows.py WORK [--json]
    python benchmarks/frozen_windows.py --generator [--seconds 3000]

``WORK`` (a ``benchmarks/fault_campaign.py`` work directory): for every ``sim frozen`` event,
from its block's bag, in ms after the fault's stamp:

* ``fast``: the first reference of the joint faster than ``FROZEN_MOTION`` (where the campaign
  started the freeze's detection window before 2026-11-28);
* ``window``: the first such reference that begins a run of ``FROZEN_RUN`` consecutive ones (where
  the campaign starts the window now, :func:`reachset_ros.sim.campaign.frozen_observable_ns`);
  ``fast`` earlier than ``window`` with a rest between: the fault landed on a move's tail;
* ``rule``: the first tick at which the monitor's stuck-sensor rule could fire: the joint's
  reference at ``>= stuck_speed`` on ``stuck_ticks + 1`` consecutive 4-ms ticks, counted from the
  tick before the fault (the reading the freeze holds) up to the stop (after a stop the reference rests, so the rule's condition is
  not looked for there: None);
* ``stop``: the stop's own stamp and its kind (``violation``: the sets; ``invalid_sample``:
  the rule).

A stop by the rule later than ``rule`` + one tick would be a rule that missed its chance (event
44's kind). ``--generator``: the reference generator alone (the campaign's ``lead`` and none),
the shortest run of ticks at ``>= stuck_speed`` per joint over ``--seconds`` of moves: a run
shorter than ``stuck_ticks + 1`` would open the campaign's window with the rule unable to fire.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reachset_ros.bags import read_references  # noqa: E402
from reachset_ros.conformance.monitor_core import MonitorCore  # noqa: E402
from reachset_ros.sim import campaign as cp  # noqa: E402

DT_NS = 4_000_000
NEED = MonitorCore.STUCK_TICKS + 1          # consecutive ticks at >= speed (the rule's last stamps)
SPEED = MonitorCore.STUCK_SPEED


def first_rule_tick(refs, fault_ns, until_ns):
    """The stamp at which ``NEED`` consecutive references have |qd_d| >= SPEED, counted from
    the tick before ``fault_ns`` (the reading the freeze holds, the first of the rule's stamps)
    up to ``until_ns``, or None."""
    best = None
    for r in refs:
        run, last = 0, None
        for st, v in zip(r.stamps, r.qd):
            if st < fault_ns - DT_NS or st > until_ns:     # from the last reading the freeze holds
                continue
            if abs(v) >= SPEED:
                run = run + 1 if (run and st - last == DT_NS) else 1
            else:
                run = 0
            last = st
            if run >= NEED:
                best = int(st) if best is None else min(best, int(st))
                break
    return best


def campaign(work: Path):
    res = json.loads((work / "campaign.json").read_text())
    rows = []
    for o in res["outcomes"]:
        if not o["event"].startswith("sim frozen") or not o.get("fault_ns"):
            continue
        joint, f = o["event"].split()[2], int(o["fault_ns"])
        stops = o.get("stops") or []
        stop_ns = int(stops[0][0]) if stops else None
        refs = read_references([o["bag"]], joints=[joint]).get(joint, [])
        window = cp.frozen_observable_ns(refs, f)
        fast = cp.frozen_observable_ns(refs, f, run=1)
        rule = first_rule_tick(refs, f, stop_ns if stop_ns is not None else 2 ** 63)
        ms = (lambda x: None if x is None else (x - f) / 1e6)
        rows.append({"event": o["event"], "fast_ms": ms(fast), "window_ms": ms(window), "rule_ms": ms(rule), "stop_ms": ms(stop_ns),
                     "stop_kind": stops[0][2].split(":")[0] if stops else None})
    return rows


def generator(seconds: float):
    from reachset_ros.sim.reference import ReferenceConfig, ReferenceGenerator
    from reachset_ros.workflows.campaign import REFERENCE_LEAD
    out = {}
    for lead in (0.0, REFERENCE_LEAD, 1.0):
        for seed in range(3):
            _, _, qd, _ = ReferenceGenerator(ReferenceConfig(lead=lead), seed=seed).trajectory(seconds)
            shortest = []
            for j in range(qd.shape[1]):
                d = np.diff(np.r_[0, (np.abs(qd[:, j]) >= SPEED).astype(int), 0])
                lengths = np.flatnonzero(d == -1) - np.flatnonzero(d == 1)
                shortest.append(int(lengths.min()) if lengths.size else None)
            out[f"lead {lead:g}, seed {seed}"] = shortest
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", nargs="?", type=Path, help="a fault campaign's work directory")
    ap.add_argument("--generator", action="store_true", help="the reference generator alone")
    ap.add_argument("--seconds", type=float, default=3000.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.generator:
        res = generator(args.seconds)
        if args.json:
            print(json.dumps(res, indent=1))
        for k, v in res.items():
            print(f"{k}: shortest run of ticks at >= {SPEED:g} rad/s per joint {v} (the rule needs {NEED})")
        return res
    if args.work is None:
        ap.error("a campaign's work directory or --generator")
    rows = campaign(args.work)
    if args.json:
        print(json.dumps(rows, indent=1))
        return rows
    fmt = (lambda x: "-" if x is None else f"{x:.0f}")
    for r in rows:
        print(f"{r['event']:28s} fast {fmt(r['fast_ms']):>6s}  window {fmt(r['window_ms']):>6s}  rule {fmt(r['rule_ms']):>6s}  "
              f"stop {fmt(r['stop_ms']):>6s} ({r['stop_kind']})")
    by_rule = [r for r in rows if r["stop_kind"] == "invalid_sample"]
    late = [r for r in by_rule if r["rule_ms"] is not None and r["stop_ms"] > r["rule_ms"] + DT_NS / 1e6]
    print(f"{len(rows)} frozen sensors: {sum(r['stop_kind'] == 'violation' for r in rows)} stopped by the sets, "
          f"{len(by_rule)} by the stuck-sensor rule, {len(rows) - sum(r['stop_ms'] is not None for r in rows)} "
          f"not stopped; rule stops more than one tick after the rule could fire: {len(late)}")
    return rows


if __name__ == "__main__":
    main()
