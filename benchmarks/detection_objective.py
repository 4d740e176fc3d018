"""Identification objectives against detection power (issue 35.2), both sides at once.

Simulated LWA-4P recordings (:func:`reachset_ros.sim.recordings.simulate_arm_recordings`,
the simulated arm calibrated to the real one, :meth:`SimConfig.calibrated`; the nodes' law),
``--train`` runs for identification and ``--held-out`` runs never used to fit anything, are
written as bags under ``benchmarks/.cache/detection_objective/`` (once). Then, per objective
(``reachset identify --cost``), ``reachset identify TRAIN... --calibrate K --validate HELD...
--fault-accel A --json`` and, per joint: the inflation applied, the held-out violations at
it (false alarms: must be 0), and the detection delay of a constant acceleration fault of
``A`` rad/s^2 added to the held-out measurements (``fault.delay_s``: from its onset to the
first violated test case; the detection-limit note's quantity).

``--real``: the real LWA-4P recordings on the real-data protocol instead (docs/real-data.md:
nominal model, sets and inflation fitted on the 75 runs whose number is not divisible by 4;
the 25 others held out), the same per-joint table.

Run: ``.venv/bin/python benchmarks/detection_objective.py [--costs linear detection]
[--train 6] [--held-out 2] [--seconds 30] [--calibrate 5] [--fault-accel 6] [--estimator lsq:3]
[--initial-state-set] [--real]``.
"""
import argparse
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CACHE = REPO / "benchmarks" / ".cache" / "detection_objective"


def ensure_bags(seeds, seconds):
    """One bag per seed (the simulated, calibrated LWA-4P under the nodes' law), cached."""
    from reachset_ros.sim import recordings
    from reachset_ros.sim.simulator import SimConfig
    out = []
    for s in seeds:
        path = CACHE / f"run_{s}_{seconds:g}s"
        if not path.exists():
            recs = recordings.simulate_arm_recordings(seconds, seed=s, sim_config=SimConfig.calibrated())
            tmp = path.with_name(path.name + ".tmp")
            recordings.write_recordings(tmp, recs, estimate=False)
            tmp.rename(path)
        out.append(path)
    return out


def real_bags():
    """(train bag, held-out bag) of the real LWA-4P, imported once with the nominal model
    fitted on the training runs (benchmarks/real_data.py's protocol)."""
    from reachset_ros.robot import lwa4p
    from reachset_ros.robot.lwa4p import _runs_spec, is_held_out
    data = str(lwa4p.recordings_dir(None))
    train = [r for r in range(1, 101) if not is_held_out(r)]
    held = [r for r in range(1, 101) if is_held_out(r)]
    d = CACHE / "real"
    d.mkdir(parents=True, exist_ok=True)
    nominal = d / "nominal.yaml"
    rs = [sys.executable, "-m", "reachset_ros.cli"]
    if not nominal.exists():
        subprocess.run([*rs, "fit-lwa4p", data, "--runs", _runs_spec(train), "--out", str(nominal)], check=True)
    out = []
    for name, runs in (("train", train), ("heldout", held)):
        bag = d / name
        if not bag.exists():
            subprocess.run([*rs, "import-lwa4p", data, "--runs", _runs_spec(runs), "--out", str(bag), "--model",
                            str(nominal)], check=True, capture_output=True)
        out.append(bag)
    return out


def identify(cost, train, a):
    """``reachset identify TRAIN... --calibrate K --cost COST --out M``; returns M's path.
    ``COST`` ``detection:S``: ``--cost detection --detection-window S`` (``detection`` alone:
    identify's default window)."""
    name, _, window = cost.partition(":")
    est, _, est_window = (a.estimator or "").partition(":")
    tag = (f"_{est}{est_window}" if est else "") + ("_iss" if a.initial_state_set else "")
    out = CACHE / f"model_{name}{'_w' + window if window else ''}{tag}_k{a.calibrate}{'_real' if a.real else ''}.yaml"
    cmd = [str(REPO / ".venv" / "bin" / "reachset"), "identify", *map(str, train), "--calibrate", str(a.calibrate),
           "--cost", name, "--out", str(out)] + (["--detection-window", window] if window else [])
    cmd += (["--estimator", est] if est else []) + (["--estimator-window", est_window] if est_window else [])
    cmd += ["--initial-state-set"] if a.initial_state_set else []
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {p.returncode}: {p.stderr.strip()[-400:]}")
    return out


def judge(model_path, held, accel):
    """Per joint of the model: its inflation, the held-out violating ticks at it, and the
    detection delay (ms) of a constant acceleration fault ``accel`` added to the held-out
    measurements (:func:`reachset_ros.conformance.validation.detection_delay`; None: never)."""
    from reachset_ros.bags import read_joint_series
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.validation import check_many, detection_delay
    m = mdl.load(model_path)
    thm = m.theorem1()
    series, _ = read_joint_series([Path(h) for h in held], list(m.joints), m.plant.dt)
    rows = {}
    for j, js in m.joints.items():
        s = series[j]
        infl = m.joint_inflation(j) if hasattr(m, "joint_inflation") else m.inflation
        xi = js.xi(infl)
        r = check_many(m.plant, thm, m.estimator, [xi], s.y, s.u, s.segments, m.horizon)[0]
        f = detection_delay(m.plant, thm, m.estimator, xi, s.y, s.u, s.segments, m.horizon, accel, m.plant.dt)
        rows[j] = {"inflation": float(infl), "held_out_violations": int(r.violations),
                   "delay_ms": None if f["delay_s"] is None else 1e3 * f["delay_s"],
                   "alpha_w": list(js.alpha_w), "alpha_v": list(js.alpha_v)}
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--costs", nargs="+", default=["linear", "detection"],
                    help="identify's --cost per model; detection:S with --detection-window S (e.g. detection:0, the "
                         "whole horizon)")
    ap.add_argument("--train", type=int, default=6)
    ap.add_argument("--held-out", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--calibrate", type=int, default=5)
    ap.add_argument("--fault-accel", type=float, default=6.0)
    ap.add_argument("--estimator", metavar="NAME[:WINDOW]",
                    help="identify --estimator NAME [--estimator-window WINDOW] (default: identify's)")
    ap.add_argument("--initial-state-set", action="store_true", help="identify --initial-state-set")
    ap.add_argument("--real", action="store_true", help="the real LWA-4P recordings (real-data protocol)")
    a = ap.parse_args(argv)
    if a.real:
        train, held = real_bags()
        train, held = [train], [held]
    else:
        train = ensure_bags(range(1, a.train + 1), a.seconds)
        held = ensure_bags(range(101, 101 + a.held_out), a.seconds)
    rows = {}
    print(f"{'cost':10s} {'joint':12s} {'inflation':>9s} {'held-out viol.':>14s} {'delay ms':>9s}")
    for cost in a.costs:
        rows[cost] = judge(identify(cost, train, a), held, a.fault_accel)
        for j, row in rows[cost].items():
            d = "never" if row["delay_ms"] is None else f"{row['delay_ms']:.0f}"
            print(f"{cost:10s} {j:12s} {row['inflation']:9.3g} {row['held_out_violations']:14d} {d:>9s}")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
