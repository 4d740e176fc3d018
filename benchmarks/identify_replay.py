"""Benchmark: ``reachset identify`` of the 33-minute, 6-joint bag and ``reachset replay`` of its first
30,000 ticks, wall time of fresh processes including start-up (issue 38.2, 38.3).

The bags are ``benchmarks/bench_conformance.py``'s (:mod:`simbag`, generated once under
``benchmarks/.cache/``). Each command runs ``--repeat`` times (default 5); the median and the
fastest wall time are reported, and replay's per tick (the issue's goals: identify at most 3 s,
replay at most 40 us per tick). ``--phases`` also times the steps of ``identify`` and ``replay`` in
this process (the same functions the commands call, one after the other: where the time goes).
Every run's model file and replay JSON are compared: they must be the same but for the model's
creation time and command line and replay's timing (the script says so if not).

Syntax::

    .venv/bin/python benchmarks/identify_replay.py [--repeat N] [--phases] [--checkout DIR] [--json FILE]

``--checkout DIR`` times another checkout of the package (e.g. ``git archive COMMIT | tar -x -C DIR``
with its compiled kernel copied in): the before of a change; ``--model FILE`` writes the model the
first identify run made (to compare two checkouts' models). Benchmarks assert nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import simbag  # noqa: E402

TICKS = 497_883          # bench_conformance.py's 33-minute bag
REPLAY_TICKS = 30_000


def run(argv, env):
    t = time.perf_counter()
    r = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t
    if r.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(map(str, argv))} failed ({r.returncode}): {r.stderr.strip()[-500:]}")
    return wall, r.stdout


def model_text(path):
    """The model file without its creation time and command line (which differ between runs)."""
    import yaml
    m = yaml.safe_load(Path(path).read_text())
    for key in ("created", "command"):
        m.get("provenance", {}).pop(key, None)
    return json.dumps(m, sort_keys=True)


def phases(bag, short):
    """Wall seconds of identify's and replay's steps, in this process (module docstring)."""
    out = {}
    t = time.perf_counter()
    from reachset_ros import defaults
    from reachset_ros.bags import read_joint_series
    from reachset_ros.commands.replay import replay_joints
    from reachset_ros.conformance import envelope
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.estimators import Estimator
    from reachset_ros.conformance.identify import detection_cost, identify_sets, stable_horizon
    from reachset_ros.conformance.theorem1 import Theorem1, deviation_extremes_many
    from reachset_ros.systems.plant import lwa4p_joint_plant
    from reachset_ros.workflows import identify as _registers_defaults  # noqa: F401 (identify.envelope.*)
    from reachset_ros.workflows.coverage import series_motion
    out["imports"] = time.perf_counter() - t

    def step(name, fn, *a, **kw):
        t0 = time.perf_counter()
        r = fn(*a, **kw)
        out[name] = time.perf_counter() - t0
        return r

    series, _ = step("identify: read the bag", read_joint_series, [bag], None, 0.004)
    plant, est = lwa4p_joint_plant(), Estimator("fd")
    thm = step("identify: Theorem 1's rows (k* = 125)", Theorem1.build, plant, 125)
    devs = step("identify: Theorem-1 sweep, 6 joints", deviation_extremes_many, plant, est, series, 125, thm)
    step("identify: import scipy.optimize", __import__, "scipy.optimize")
    cvec = detection_cost(plant, thm)
    step("identify: LPs (detection cost)", lambda: [identify_sets(plant, thm, d, cost_vector=cvec) for d in devs.values()])
    step("identify: Remark 3 (stable horizon)", lambda: [stable_horizon(plant, thm, d) for d in devs.values()])
    step("identify: coverage of the class", series_motion, series, [bag])
    step("identify: validated envelope", envelope.fit, series, bins=defaults.get("identify.envelope.bins"),
         dilation=defaults.get("identify.envelope.dilation"), hold=125)
    with tempfile.TemporaryDirectory() as d:
        subprocess.run([sys.executable, "-m", "reachset_ros.cli", "identify", str(bag), "--out", f"{d}/m.yaml"],
                       capture_output=True, check=True)
        model = step("replay: load the model", mdl.load, f"{d}/m.yaml")
    rseries, _ = step("replay: read 30,000 ticks", read_joint_series, [short], None, 0.004)
    rthm = step("replay: Theorem 1's rows", model.theorem1)
    step("replay: the monitor over 30,000 ticks", replay_joints, model, rseries, rthm)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--phases", action="store_true", help="also time the steps in this process")
    ap.add_argument("--checkout", help="time the package in this directory instead")
    ap.add_argument("--model", help="write the model of the first identify run here")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    bag = simbag.ensure_bag("sim6_33min", TICKS)
    short = simbag.ensure_bag("sim6_33min", TICKS, first=REPLAY_TICKS)
    env = dict(os.environ, PYTHONPATH=os.path.abspath(args.checkout)) if args.checkout else None
    cli = [sys.executable, "-m", "reachset_ros.cli"]
    res = {"load_average_before": os.getloadavg()[0], "cores": os.cpu_count()}
    tmp_dir = tempfile.TemporaryDirectory(prefix="reachset-bench-")   # removed at the end, or on an error
    tmp = Path(tmp_dir.name)
    ident, rep, models, reps = [], [], set(), set()
    for i in range(args.repeat):
        m = tmp / f"m{i}.yaml"
        wall, _ = run(cli + ["identify", str(bag), "--out", str(m)], env)
        ident.append(wall)
        models.add(model_text(m))
        if i == 0 and args.model:
            Path(args.model).write_text(m.read_text())
        wall, out = run(cli + ["replay", str(short), "--model", str(tmp / "m0.yaml"), "--json"], env)
        rep.append(wall)
        r = json.loads(out)
        r.pop("timing_us_per_tick", None)
        reps.add(json.dumps(r, sort_keys=True))
        print(f"run {i + 1}: identify {ident[-1]:.2f} s, replay {rep[-1]:.2f} s "
              f"({rep[-1] / REPLAY_TICKS * 1e6:.1f} us per tick)", flush=True)
    res["identify_s"] = {"median": statistics.median(ident), "min": min(ident), "runs": ident}
    res["replay_s"] = {"median": statistics.median(rep), "min": min(rep), "runs": rep,
                       "median_us_per_tick": statistics.median(rep) / REPLAY_TICKS * 1e6,
                       "min_us_per_tick": min(rep) / REPLAY_TICKS * 1e6}
    res["same_results_every_run"] = len(models) == 1 and len(reps) == 1
    print(f"identify (33 min, 6 joints, k* = 125): median {res['identify_s']['median']:.2f} s, "
          f"min {res['identify_s']['min']:.2f} s")
    print(f"replay ({REPLAY_TICKS} ticks, 6 joints): median {res['replay_s']['median']:.2f} s = "
          f"{res['replay_s']['median_us_per_tick']:.1f} us per tick, min {res['replay_s']['min_us_per_tick']:.1f} us")
    print("model files and replay JSON the same in every run: " + ("yes" if res["same_results_every_run"] else "NO"))
    if args.phases:
        res["phases_s"] = phases(bag, short)
        for k, v in res["phases_s"].items():
            print(f"  {k:45s} {v:6.3f} s")
    res["load_average_after"] = os.getloadavg()[0]
    print(f"load average before {res['load_average_before']:.2f}, after {res['load_average_after']:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    tmp_dir.cleanup()
    return res


if __name__ == "__main__":
    main()
