"""The simulated LWA-4P along the real runs' trajectories, for calibrating it to the real arm: sets
from simulated runs of the real runs' own trajectories against the sets from the real runs
(issue 16.2). Not to be confused with :mod:`reachset_ros.conformance.calibration` (the
inflation's cross-validation).

Pure core. :func:`simulate_real_runs` drives the simulated arm (:mod:`.simulator`; the
controller's nominal model is the identified ``config/lwa4p_nominal.yaml``, the simulated
truth that model perturbed by a :class:`~reachset_ros.robot.ModelError`) along the measured
trajectories of real recordings (q_d = the measured position, q̇_d its zero-phase filtered
velocity, q̈_d the derivative of that) with the project's control law, and returns the
per-joint series the identification reads. :func:`identified_alphas` identifies the sets
(Theorem 1, min ‖W‖ + ‖V‖, estimator ``fd``) of such series; :func:`alpha_ratios` compares
two of them per joint. The calibration itself (which effects, how large) is
``benchmarks/calibrate_sim.py``; its result is :meth:`reachset_ros.sim.simulator.SimConfig.calibrated`.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..bags import concat_series
from ..conformance.estimators import Estimator
from ..conformance.identify import identify_sets
from ..conformance.theorem1 import Theorem1, deviation_extremes_many
from ..robot import lwa4p
from ..systems.plant import lwa4p_joint_plant
from .recordings import recordings_series, simulate_arm_recordings

__all__ = ["run_reference", "simulate_real_runs", "identified_alphas", "alpha_ratios"]


def run_reference(run, prep=lwa4p.Preprocessing()):
    """(Qd, QDd, QDDd) of a real run: its measured positions, their zero-phase low-passed
    velocities (the nominal fit's filter) and the central differences of those."""
    qd = lwa4p._lowpass(run.qd, prep)
    return run.q.copy(), qd, np.gradient(qd, lwa4p.DT, axis=0)


def simulate_real_runs(runs, sim_config, gains=None, seed=0):
    """Per-joint series of the simulated arm along each real run's trajectory, concatenated
    (each run a segment of its own, separated by a pause in the stamps)."""
    parts, t0 = [], None
    for i, r in enumerate(runs):
        recs = simulate_arm_recordings(0.0, gains, seed=seed + i, sim_config=sim_config, reference=run_reference(r))
        ser = recordings_series(recs)[0]
        # each run after the previous one's last stamp plus a 1 s pause (every simulated run
        # starts at the simulator's start stamp)
        first = int(next(iter(ser.values())).stamps[0])
        shift = 0 if t0 is None else t0 - first
        parts.append({n: replace(s, stamps=s.stamps + shift) for n, s in ser.items()})
        t0 = int(next(iter(parts[-1].values())).stamps[-1]) + 1_000_000_000
    return concat_series(parts, next(iter(parts[0].values())).dt)


def identified_alphas(series, horizon=125, estimator="fd"):
    """``{joint: (alpha_W, alpha_V)}`` identified (Theorem 1, min ‖W‖ + ‖V‖) on ``series``."""
    plant = lwa4p_joint_plant()
    est = Estimator.named(estimator, plant)
    thm = Theorem1.build(plant, horizon)
    devs = deviation_extremes_many(plant, est, series, horizon, thm)
    out = {}
    for n in series:
        sets = identify_sets(plant, thm, devs[n])
        out[n] = (np.asarray(sets.alpha_w, float), np.asarray(sets.alpha_v, float))
    return out


def alpha_ratios(sim, real):
    """Per joint ``{"alpha_w": sim/real of the largest alpha_W, "alpha_v": sim/real}``."""
    return {n: {"alpha_w": float(np.max(sim[n][0]) / np.max(real[n][0])),
                "alpha_v": float(sim[n][1][0] / real[n][1][0])} for n in real}
