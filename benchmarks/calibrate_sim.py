"""Calibrate the simulated LWA-4P's unmodelled effects to the real robot (issue 16.2).

Run: .venv/bin/python benchmarks/calibrate_sim.py [--data ../shared/data/lwa4p_iros2018] [--runs 1-40:train]
     [--horizon 125]

The real runs' sets (Theorem 1, min ‖W‖ + ‖V‖, estimator fd, k* = ``--horizon``) are
identified from the runs imported with the nominal model (as ``reachset import-lwa4p`` does);
the simulated arm (nominal model = config/lwa4p_nominal.yaml, truth = nominal perturbed by a
ModelError, measurement noise) follows the same runs' trajectories under the project's
control law (:mod:`reachset_ros.sim.calibration`), and its sets are identified the same
way. Over a grid of model-error sizes and position-noise levels the script prints, per
candidate, the per-joint ratios sim/real of alpha_W (largest component) and alpha_V, and
the candidate whose worst ratio (max over joints of max(r, 1/r)) is smallest; goal: within
a factor 1.5 on every joint. The chosen values are those of ``SimConfig.calibrated``
(docs/robot.md, "A simulated arm calibrated to the real one").
"""
import argparse
import itertools
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
from reachset_ros import bags  # noqa: E402
from reachset_ros.robot import ModelError, lwa4p  # noqa: E402
from reachset_ros.sim import calibration as cal  # noqa: E402
from reachset_ros.sim.simulator import SimConfig  # noqa: E402


def candidate(nominal, size, noise, friction):
    err = ModelError(mass_scale=1 + size, inertia_scale=1 + size, com_shift=0.1 * size, armature_scale=1 + size,
                     viscous_scale=1 + friction, coulomb_scale=1 + friction, relative_std=0.5 * size, seed=0)
    return SimConfig(robot=nominal, model_error=err, position_noise=noise, velocity_noise=20 * noise,
                     quantization=3.5e-5)


def worst(r):
    return max(max(v["alpha_w"], 1 / v["alpha_w"], v["alpha_v"], 1 / v["alpha_v"]) for v in r.values())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data" / "lwa4p_iros2018"))
    ap.add_argument("--runs", default="1-40:train")
    ap.add_argument("--horizon", type=int, default=125)
    ap.add_argument("--size", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2])
    ap.add_argument("--noise", type=float, nargs="+", default=[2e-5, 5e-5, 8e-5])
    ap.add_argument("--friction", type=float, nargs="+", default=[0.0, 0.3])
    a = ap.parse_args()
    runs = lwa4p.read_runs(a.data, a.runs)
    nominal = lwa4p.load_nominal()
    with tempfile.TemporaryDirectory() as d:
        lwa4p.import_runs(a.data, [r.index for r in runs], Path(d) / "real", nominal)
        real_series, _ = bags.read_joint_series([Path(d) / "real"])
    real = cal.identified_alphas(real_series, a.horizon)
    print(f"real runs {a.runs} ({len(runs)} runs), k* = {a.horizon}")
    print("| joint | real alpha_W | real alpha_V |\n|---|---|---|")
    for n, (w, v) in real.items():
        print(f"| {n} | {np.round(w, 4).tolist()} | {v[0]:.3g} |")
    best = None
    print("\n| model error | position noise | friction | worst ratio | alpha_W ratios | alpha_V ratios | s |")
    print("|---|---|---|---|---|---|---|")
    for size, noise, fr in itertools.product(a.size, a.noise, a.friction):
        t0 = time.perf_counter()
        sim = cal.identified_alphas(cal.simulate_real_runs(runs, candidate(nominal, size, noise, fr)), a.horizon)
        r = cal.alpha_ratios(sim, real)
        w = worst(r)
        print(f"| {size} | {noise:g} | {fr} | {w:.2f} | {[round(v['alpha_w'], 2) for v in r.values()]} | "
              f"{[round(v['alpha_v'], 2) for v in r.values()]} | {time.perf_counter() - t0:.0f} |", flush=True)
        if best is None or w < best[0]:
            best = (w, size, noise, fr)
    print(f"\nbest: model error {best[1]}, position noise {best[2]:g}, friction {best[3]}: worst ratio {best[0]:.2f}"
          f" ({'within' if best[0] <= 1.5 else 'NOT within'} a factor 1.5)")


if __name__ == "__main__":
    main()
