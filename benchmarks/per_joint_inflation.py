"""Per-joint inflation on the real LWA-4P recordings (issue 35.1): both sides.

Run: .venv/bin/python benchmarks/per_joint_inflation.py [--data DIR] [--calibrate K] [--cost C]
     [--margin N] [--accel A] [--workdir DIR]

Real-data protocol (docs/real-data.md): runs whose number is divisible by 4 are held out; the
nominal model, the sets and the inflation are fitted on the other 75 runs only
(``reachset import-lwa4p --runs train|heldout``, ``reachset identify TRAIN --calibrate K
[--calibrate-margin N]``). The model ``identify`` writes applies each joint's own calibrated
inflation ("after"); the "before" model is the same sets with the largest of them applied to
every joint (what the model file applied before per-joint inflation). Per joint, printed as a
markdown table:

* held-out violating ticks of ``reachset check`` (false stops on fault-free held-out data);
* detection delay of a test fault, a constant acceleration ``--accel`` rad/s^2 added to the
  held-out measured position from the middle of its longest segment
  (:func:`reachset_ros.conformance.validation.detection_delay`, ``reachset check``'s arithmetic);
* for reference only, the smallest grid inflation at which the held-out runs are conformant
  (the held-out runs are not used to fit anything: this says how far each choice is from what
  the held-out data needed).
"""
import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
from reachset_ros.bags import read_joint_series  # noqa: E402
from reachset_ros.conformance import model as mdl  # noqa: E402
from reachset_ros.conformance.validation import detection_delay, validation_grid  # noqa: E402
from reachset_ros.workflows.identify import DEFAULT_GRID  # noqa: E402


def cli(*args):
    argv = [sys.executable, "-m", "reachset_ros.cli", *map(str, args)]
    print("$ reachset " + " ".join(map(str, args)), file=sys.stderr)
    out = subprocess.run(argv, capture_output=True, text=True, cwd=REPO)
    if out.returncode not in ((0, 1) if args[0] in ("check", "replay") else (0,)):
        raise SystemExit(f"reachset {args[0]} failed ({out.returncode}): {out.stderr.strip()}")
    return json.loads(out.stdout) if "--json" in args else out.stdout


def measure(*, data, d, calibrate, margin, accel, cost=None):
    """The before/after rows (module docstring)."""
    for runs in ("train", "heldout"):             # a work directory's bags are reused
        if not (d / runs).exists():
            cli("import-lwa4p", data, "--runs", runs, "--out", d / runs)
    after = d / "per_joint.yaml"
    ident = cli("identify", d / "train", "--calibrate", calibrate, "--calibrate-margin", margin, "--out", after,
                "--inflation-rule", "per-joint",
                "--json", *(["--cost", cost] if cost else []))
    m = mdl.load(after)
    before = d / "largest.yaml"
    mdl.save(replace(m.with_inflation(m.largest_inflation()), calibration=None), before)
    checks = {k: cli("check", d / "heldout", "--model", p, "--json") for k, p in (("before", before), ("after", after))}
    series, _ = read_joint_series([d / "heldout"], list(m.joints), m.plant.dt)
    thm = m.theorem1()
    rows = {}
    for n, s in series.items():
        row = {"calibrated": ident["joints"][n]["calibration"]["inflation"]}
        for k, model in (("before", mdl.load(before)), ("after", m)):
            f = detection_delay(m.plant, thm, m.estimator, model.checked_xi(n), s.y, s.u, s.segments, m.horizon,
                                accel, m.plant.dt)
            row[k] = {"inflation": model.joint_inflation(n), "violations": checks[k]["joints"][n]["violations"],
                      "delay_ms": None if f["delay_s"] is None else 1e3 * f["delay_s"]}
        _, needed, flagged = validation_grid(m.plant, thm, m.estimator, m.joints[n], s.y, s.u, s.segments, m.horizon,
                                             DEFAULT_GRID)
        row["held_out_needs"] = None if flagged else needed
        rows[n] = row
    return rows


def table(rows, accel):
    ms = lambda v: "not detected" if v is None else f"{v:.0f}"   # noqa: E731
    out = ["| joint | cross-validated | inflation before / after | held-out violating ticks before / after "
           f"| +{accel:g} rad/s² fault detected after [ms] before / after | held-out runs need |",
           "|---|---|---|---|---|---|"]
    for n, r in rows.items():
        b, a = r["before"], r["after"]
        out.append(f"| {n} | {r['calibrated']:g} | {b['inflation']:g} / {a['inflation']:g} | {b['violations']} / "
                   f"{a['violations']} | {ms(b['delay_ms'])} / {ms(a['delay_ms'])} | "
                   f"{'none of the grid' if r['held_out_needs'] is None else format(r['held_out_needs'], 'g')} |")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(REPO / "reachset_ros" / "data" / "lwa4p_iros2018"))
    ap.add_argument("--calibrate", type=int, default=5)
    ap.add_argument("--margin", type=int, default=0, help="--calibrate-margin")
    ap.add_argument("--accel", type=float, default=5.0)
    ap.add_argument("--cost", default=None, choices=["linear", "quadratic", "detection"],
                    help="identify --cost (default: identify's; linear: the numbers measured before issue 35.2)")
    ap.add_argument("--workdir", default=None)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(a.workdir or tmp)
        d.mkdir(parents=True, exist_ok=True)
        rows = measure(data=a.data, d=d, calibrate=a.calibrate, margin=a.margin, accel=a.accel, cost=a.cost)
    print(json.dumps(rows, indent=1) if a.json else table(rows, a.accel))


if __name__ == "__main__":
    main()
