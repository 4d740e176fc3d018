"""Benchmark: where the room in ||R*_e|| is (issue 16.1), on simulated recordings with known disturbances.

Six joints of :func:`reachset_ros.sim.recordings.simulate_recordings` (seed 3, 20,000 ticks =
80 s, the recordings' own gains HG h1 15, h2 30, omega 20, zeta 1, with /reference), and per
joint ``||R*_e||`` (Appendix B method 3, every tick) of

* ``plain``: the plain reference pipeline - ``fd`` initial states, a 25 x 10 grid over omega
  in [1, 100] (log) and zeta in [0.3, 3] with h1 = 15, h2 = 30, the inner LP in alpha;
* ``paper``: the paper's parametrisation (Table II: omega, zeta free, h1 = 15, h2 = 30;
  Theorem 1 as eq. 13, ``--no-initial-state-set``) with ``reachset synthesize``'s search
  (Sobol + Nelder-Mead);
* ``free4``: omega, zeta, h1, h2 free (``--free omega,zeta,h1,h2``);
* ``observer``: the default search with the ``observer`` initial-state estimator (d held at 0);
* ``initial_set``: ``reachset synthesize``'s default since issue 16.1: the same search with
  Theorem 1's initial-state set (the ``fd`` estimate's error as a set of the same noise and
  disturbances);
* ``oracle``: the true disturbance sets (the scenario's bounds; not conformance-identified)
  at the plain pipeline's gains - the room there is in the sets, not in the search.

And how far the measured tracking error ``[q_hat - q_d, qd_hat - qd_d]`` (after 2 s) reaches
into ``R*_e`` (largest |e - c| / radius per coordinate; above 1 = outside) for the paper's rows
and for the initial-state set: at the recordings' own gains (``reidentify``), and in the closed
loop run again with each synthesis's gains (the same references and disturbance samples, seed 3,
and new ones, seed 7) against that synthesis's ``R*_e``.

Syntax::

    .venv/bin/python benchmarks/synthesis_room.py [--ticks N]

Prints a Markdown table and ``RESULT {json}``. Asserts nothing.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from reachset_ros import conformance as cf
from reachset_ros import synthesis as sy
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.sim import recordings as sr
from reachset_ros.synthesis.search import Evaluator
from reachset_ros.systems.plant import lwa4p_joint_plant

JOINTS = [f"arm_{i}_joint" for i in range(1, 7)]


def _reach(rec, center, radius, skip=500):
    """Largest ``|e - c| / radius`` per coordinate of the measured tracking error after ``skip`` ticks."""
    iq, iqd = rec.estimate_names.index("q"), rec.estimate_names.index("qd")
    err = np.column_stack([rec.x_hat[:, iq] - rec.q_d, rec.x_hat[:, iqd] - rec.qd_d])[skip:]
    return (np.abs(err - np.asarray(center)).max(axis=0) / np.asarray(radius)).tolist()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=20_000)
    args = ap.parse_args(argv)
    recs = sr.simulate_recordings(JOINTS, args.ticks, seed=3)
    series, refs = sr.recordings_series(recs)
    plant = lwa4p_joint_plant()
    cfg = sy.load_config()
    um = {j: sy.u_max_for(cfg, j) for j in JOINTS}
    pb_fd = sy.problems_from_series(series, plant, Estimator("fd"), 125, um, 2.0, refs, 3)
    pb_ob = sy.problems_from_series(series, plant, Estimator.observer(plant), 125, um, 2.0, refs, 3)
    pb_is = sy.problems_from_series(series, plant, Estimator("fd"), 125, um, 2.0, refs, 3,
                                    thm=cf.Theorem1.build(plant, 125, Estimator("fd")))
    rows = {}
    for i, (pf, po, pi) in enumerate(zip(pb_fd, pb_ob, pb_is)):
        r = {}
        space = sy.SearchSpace.from_config(cfg, "hg")
        ev = Evaluator(pf, space, None, 0.999)
        t = time.perf_counter()
        best = None
        for om in np.geomspace(1, 100, 25):
            for ze in np.linspace(0.3, 3.0, 10):
                e = ev({**space.full(), "omega": om, "zeta": ze})
                if e.feasible and (best is None or e.merit < best.merit):
                    best = e
        r["plain"] = {"re_norm": best.merit, "omega": best.values["omega"], "zeta": best.values["zeta"],
                      "seconds": time.perf_counter() - t}
        for name, pb, free in (("paper", pf, None), ("free4", pf, ["omega", "zeta", "h1", "h2"]),
                               ("observer", po, None), ("initial_set", pi, None)):
            sp = sy.SearchSpace.from_config(cfg, "hg", free=free)
            t = time.perf_counter()
            res = sy.synthesize([pb], sp, with_separate=False)[pb.name]
            g = res.gains()
            r[name] = {"re_norm": res.re_norm, **{k: g[k] for k in ("omega", "zeta", "h1", "h2")},
                       "seconds": time.perf_counter() - t, "conformant": bool(res.conformant),
                       "re_center": list(map(float, res.re_center)), "re_radius": list(map(float, res.re_radius))}
        sc = sr.Scenario.for_joint(i)
        rec = recs[pf.name]
        me = sc.c_visc * rec.qd_d + sc.c_coul * np.tanh(rec.qd_d / 0.05) + sc.c_grav * np.cos(rec.q_d)
        true = np.array([sc.a1, sc.a2 + np.abs(me).max(), sc.av])
        eo = Evaluator(pf, space, true, 0.999)(best.values)
        r["oracle"] = {"re_norm": eo.merit if eo.feasible else None, "alpha_true": true.tolist()}
        r["alpha_plain_over_true"] = (np.asarray(best.alpha) / true).tolist()
        for name, pb in (("paper", pf), ("initial_set", pi)):
            res = sy.reidentify(pb, sr.DEFAULT_GAINS)
            r[f"reach_{name}"] = {"re_norm": res.re_norm, "reach": _reach(rec, res.re_center, res.re_radius),
                                  "conformant": bool(res.conformant)}
        rows[pf.name] = r
        print(f"[synthesis_room] {pf.name} done", flush=True)
    for name in ("paper", "initial_set"):      # the closed loops with the synthesised gains
        gains = {n: {**sr.DEFAULT_GAINS, **{k: r[name][k] for k in ("omega", "zeta", "h1", "h2")}}
                 for n, r in rows.items()}
        for seed in (3, 7):
            runs = sr.simulate_recordings(JOINTS, args.ticks, seed=seed, gains=gains)
            for n, r in rows.items():
                r[name][f"reach_seed{seed}"] = _reach(runs[n], r[name]["re_center"], r[name]["re_radius"])
    print("| joint | plain | paper's parametrisation | free4 (omega, zeta, h1, h2) | observer estimator | "
          "initial-state set (default) | oracle sets | paper/plain | free4/plain | observer/plain | "
          "initial-state set/plain | oracle/plain |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n, r in rows.items():
        p = r["plain"]["re_norm"]
        o = r["oracle"]["re_norm"]
        print(f"| {n} | {p:.4f} | {r['paper']['re_norm']:.4f} | {r['free4']['re_norm']:.4f} | "
              f"{r['observer']['re_norm']:.4f} | {r['initial_set']['re_norm']:.4f} | {o:.4f} | "
              f"{r['paper']['re_norm'] / p:.3f} | {r['free4']['re_norm'] / p:.3f} | "
              f"{r['observer']['re_norm'] / p:.3f} | {r['initial_set']['re_norm'] / p:.3f} | {o / p:.3f} |")
    print("\nseconds per joint (mean): " + ", ".join(
        f"{k} {np.mean([r[k]['seconds'] for r in rows.values()]):.1f}"
        for k in ("plain", "paper", "free4", "observer", "initial_set")))
    print("\n| joint | paper: omega, zeta | reach at its gains (q, qd), seed 3 / seed 7 | initial-state set: omega, zeta "
          "| reach (q, qd), seed 3 / seed 7 |")
    print("|---|---|---|---|---|")
    for n, r in rows.items():
        a, b = r["paper"], r["initial_set"]
        print(f"| {n} | {a['omega']:.2f}, {a['zeta']:.3f} | " + " / ".join(
            ", ".join(f"{x:.3f}" for x in a[f"reach_seed{s}"]) for s in (3, 7))
            + f" | {b['omega']:.2f}, {b['zeta']:.3f} | " + " / ".join(
            ", ".join(f"{x:.3f}" for x in b[f"reach_seed{s}"]) for s in (3, 7)) + " |")
    print("\n| joint | R*_e at the recording's gains, paper rows | reach of the measured error (q, qd) | "
          "initial-state set | reach (q, qd) |")
    print("|---|---|---|---|---|")
    for n, r in rows.items():
        a, b = r["reach_paper"], r["reach_initial_set"]
        print(f"| {n} | {a['re_norm']:.4f} | {a['reach'][0]:.3f}, {a['reach'][1]:.3f} | {b['re_norm']:.4f} | "
              f"{b['reach'][0]:.3f}, {b['reach'][1]:.3f} |")
    print("alpha of the plain optimum / true alpha (W1, W2, V): " + "; ".join(
        f"{n}: " + ", ".join(f"{x:.2f}" for x in r["alpha_plain_over_true"]) for n, r in rows.items()))
    print("RESULT " + json.dumps({"ticks": args.ticks, "seed": 3, "joints": rows}, sort_keys=True, default=float))


if __name__ == "__main__":
    main()
