"""The demo's calibration on its kind of training data, without DDS: how much must the sets grow?

Run: .venv/bin/python benchmarks/demo_training.py [--seconds 20] [--seeds 2 3 4 5] [--lead 1.0 0.0] [--json]

Per seed and reference ``lead`` (reference_node's share of moves led by one joint at the class'
limits): two recordings of the calibrated simulated LWA-4P (``SimConfig.calibrated``; the nominal
model linearizes, as the demo's controller does) in closed loop, ``--seconds`` each after 3 s of
start-up, the first with the demo's initial gains (defaults ``demo.initial_gains``), the second
with the gains the demo's synthesis gives (omega 22.5, zeta 1.13). Then ``reachset identify
BAG1 BAG2 --calibrate K --initial-state-set --inflation-rule per-joint --json`` for K = 2 (the
demo's folds: one recording each) and 4, and each joint's calibrated inflation is printed. The
demo's monitor checks the synthesis' sets, calibrated the same way (docs/performance.md,
"Reproducibility of the demo's calibration"); this is the pure-simulation side of it.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from reachset_ros import defaults
from reachset_ros.workflows import demo  # noqa: F401 (registers demo.initial_gains)
from reachset_ros.sim import simulator as simm
from reachset_ros.sim.recordings import Recording, simulate_arm_recordings, write_recordings
from reachset_ros.sim.reference import ReferenceConfig

START_S = 3.0


def recordings(*, seconds, seed, lead, out):
    """The two training bags (initial gains, synthesised gains) under ``out``; their paths."""
    initial = {k: (v[0] if isinstance(v, list) else v) for k, v in defaults.get("demo.initial_gains").items()}
    synthesised = dict(initial, omega=22.5, zeta=1.13)
    paths = []
    for i, gains in enumerate((initial, synthesised)):
        recs = simulate_arm_recordings(seconds + START_S, gains=gains, seed=seed * 10 + i,
                                       sim_config=simm.SimConfig.calibrated(),
                                       reference_config=ReferenceConfig(lead=lead))
        k0 = int(round(START_S / 0.004))
        recs = {n: Recording(r.stamps[k0:], r.y[k0:], r.u[k0:], r.x_hat[k0:], r.estimate_names, r.q_d[k0:],
                             r.qd_d[k0:], r.qdd_d[k0:]) for n, r in recs.items()}
        path = Path(out) / f"train{i}"
        write_recordings(path, recs)
        paths.append(str(path))
    return paths


def calibrate(bags, folds):
    """Each joint's ``(inflation, [per fold])`` from ``reachset identify --calibrate folds``."""
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "identify", *bags, "--calibrate", str(folds),
                        "--initial-state-set", "--inflation-rule", "per-joint", "--json"],
                       capture_output=True, text=True, check=True)
    d = json.loads(p.stdout)
    return {n: (j["inflation"], [f["chosen_inflation"] for f in j["calibration"]["folds"]])
            for n, j in d["joints"].items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4, 5])
    ap.add_argument("--lead", type=float, nargs="+", default=[1.0, 0.0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for lead in args.lead:
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as tmp:
                bags = recordings(seconds=args.seconds, seed=seed, lead=lead, out=tmp)
                for k in (2, 4):
                    per = calibrate(bags, k)
                    rows.append({"lead": lead, "seed": seed, "folds": k, "largest": max(v for v, _ in per.values()),
                                 "joints": per})
                    if not args.json:
                        print(f"lead {lead:g} seed {seed} folds {k}: largest {rows[-1]['largest']:g}; "
                              + ", ".join(f"{n} {v:g}" for n, (v, _) in per.items()), flush=True)
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
