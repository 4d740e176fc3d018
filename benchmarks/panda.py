"""A second robot end to end: the Franka Panda of example-robot-data through the generic URDF path.

Run: .venv/bin/python benchmarks/panda.py [--train-seconds 120] [--clean-seconds 60]

Every step is a ``reachset`` command (printed with ``--verbose``):

1. ``reachset simulate`` the Panda (7 arm joints, fingers locked) for ``--train-seconds`` and
   record only ``/joint_states`` (position, velocity, effort);
2. ``reachset inspect --robot`` prints the identify command; it is run with ``--calibrate 5``;
3. three fault-free recordings of other seeds are checked (false alarms);
4. one recording per fault kind of the simulator, the fault from 10 s on, is checked: the
   first violation (or invalid sample) against the fault's onset stamp.

Prints markdown tables (docs/any-arm.md).
"""
import argparse
import json
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
ROBOT = "example-robot-data:panda_description/urdf/panda.urdf"
ARM = ",".join(f"panda_joint{i}" for i in range(1, 8))
EFF = ["--input", "effort", "--robot", ROBOT, "--lock-joints", "panda_finger_joint1,panda_finger_joint2"]
FAULTS = [("payload", None, 3.0), ("payload", None, 10.0), ("torque", "panda_joint2", 5.0),
          ("acceleration", "panda_joint4", 5.0), ("acceleration", "panda_joint4", 20.0),
          ("bias", "panda_joint1", 0.01), ("frozen", "panda_joint3", None), ("nan", "panda_joint5", 1)]
VERBOSE = False


def cli(*args):
    if VERBOSE:
        print("$ reachset " + " ".join(map(str, args)), file=sys.stderr)
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, args)], capture_output=True,
                         text=True, cwd=REPO)
    if out.returncode not in ((0, 1) if args[0] in ("check", "replay") else (0,)):
        raise SystemExit(f"reachset {args[0]} failed ({out.returncode}): {out.stderr.strip()}")
    return json.loads(out.stdout) if "--json" in args else out.stdout


def main():
    global VERBOSE
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-seconds", type=float, default=120.0)
    ap.add_argument("--clean-seconds", type=float, default=60.0)
    ap.add_argument("--verbose", action="store_true")
    a = ap.parse_args()
    VERBOSE = a.verbose
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        t0 = time.perf_counter()
        sim = cli("simulate", "--robot", ROBOT, "--joints", ARM, "--seconds", a.train_seconds, "--seed", 1,
                  "--out", d / "train", "--json")
        t_sim = time.perf_counter() - t0
        cmd = cli("inspect", d / "train", "--robot", ROBOT, "--json")["identify"]["command"]
        t0 = time.perf_counter()
        ident = cli(*shlex.split(cmd)[1:], "--calibrate", 5, "--out", d / "model.yaml", "--json")
        t_id = time.perf_counter() - t0
        print(f"Training: {a.train_seconds:g} s simulated in {t_sim:.1f} s ({sim['ticks']} ticks); identify "
              f"--calibrate 5 in {t_id:.1f} s; model inflation {ident['inflation']}.\n")
        print("| joint | alpha_W | alpha_V | inflation (CV) | max tracking error [rad] | max effort / limit [N m] |")
        print("|---|---|---|---|---|---|")
        for j, v in ident["joints"].items():
            print(f"| {j} | {[round(x, 4) for x in v['alpha_w']]} | {v['alpha_v'][0]:.3g} | {v['inflation']} | "
                  f"{sim['max_tracking_error_rad'][j]:.4f} | {sim['max_abs_effort'][j]:.1f} / "
                  f"{sim['effort_limit'][j]:g} |")
        print(f"\nFault-free recordings of other seeds ({a.clean_seconds:g} s each), checked with the model:\n")
        print("| seed | ticks | violating ticks (all joints) | conformant |")
        print("|---|---|---|---|")
        for seed in (11, 12, 13):
            cli("simulate", "--robot", ROBOT, "--joints", ARM, "--seconds", a.clean_seconds, "--seed", seed,
                "--out", d / f"clean{seed}")
            c = cli("check", d / f"clean{seed}", "--model", d / "model.yaml", "--json", *EFF)
            ticks = c["data"]["messages"]["/joint_states"]
            print(f"| {seed} | {ticks} | {sum(j['violations'] for j in c['joints'].values())} | {c['conformant']} |")
        print("\nOne fault per recording (20 s, seed 21+, fault from 10 s); first violation after the fault's "
              "onset stamp (`reachset simulate` reports it):\n")
        print("| fault | joint | magnitude | violation before the onset | first violation after the onset [ms] "
              "| joints violated | invalid samples |")
        print("|---|---|---|---|---|---|---|")
        for i, (kind, joint, mag) in enumerate(FAULTS):
            extra = ([] if joint is None else ["--fault-joint", joint]) + ([] if mag is None else
                                                                             ["--fault-magnitude", mag])
            f = cli("simulate", "--robot", ROBOT, "--joints", ARM, "--seconds", 20, "--seed", 21 + i, "--out",
                    d / f"{kind}{i}", "--fault", kind, "--fault-at", 10, *extra, "--json")
            c = cli("check", d / f"{kind}{i}", "--model", d / "model.yaml", "--json", *EFF)
            onset = f["fault"]["onset_ns"]
            firsts = [j["first_violation_ns"] for j in c["joints"].values() if j["first_violation_ns"]]
            first = min(firsts) if firsts else None
            hit = [n for n, j in c["joints"].items() if j["violations"]]
            inv = sum(c["data"]["invalid_samples"].values())
            print(f"| {kind} | {joint or 'last link'} | {'' if mag is None else mag} {f['fault']['unit']} | "
                  f"{'yes' if first is not None and first < onset else 'no'} | "
                  f"{'-' if first is None else f'{(first - onset) / 1e6:.0f}'} | {len(hit)} | {inv} |")


if __name__ == "__main__":
    main()
