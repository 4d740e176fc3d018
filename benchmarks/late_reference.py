"""How far a late reference carried forward at constant acceleration is from the true one:
the evidence behind the controller's ``reference_max_age`` (docs/reliability.md).

Usage::

    python benchmarks/late_reference.py [--seconds 600] [--seed 1] [--lead 0.5]

On the campaign's reference class (:class:`reachset_ros.sim.reference.ReferenceGenerator`,
``qd_max`` 0.7 rad/s, ``qdd_max`` 2 rad/s^2, trapezoidal and quintic moves, ``lead`` of them
led by one joint at its limits), for each age ``h`` the largest position and velocity error of
:func:`reachset_ros.systems.late_reference.extrapolate` from every 4-ms tick, against the
documented bound ``qdd_max h^2``, and the same for holding the reference (the rule before).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reachset_ros.sim.reference import ReferenceConfig, ReferenceGenerator  # noqa: E402
from reachset_ros.systems import late_reference as lr  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--lead", type=float, default=0.5)
    a = ap.parse_args(argv)
    cfg = ReferenceConfig(lead=a.lead)
    _, Q, QD, QDD = ReferenceGenerator(cfg, seed=a.seed).trajectory(a.seconds)
    qdd_max = float(np.max(cfg.qdd_max))
    print(f"reference class: {a.seconds:g} s, seed {a.seed}, lead {a.lead:g}, qdd_max {qdd_max:g} rad/s^2, "
          f"{len(Q)} ticks x {Q.shape[1]} joints")
    print("| age ms | carried forward: max |q err| rad | max |qd err| rad/s | bound qdd_max h^2 rad "
          "| position held: max |q err| rad |")
    print("|---|---|---|---|---|")
    for k in (1, 2, 5, 10, 15, 20, 25, 50, 75, 125):
        h = 0.004 * k
        q, qd, _ = lr.extrapolate(Q[:-k], QD[:-k], QDD[:-k], h)
        eq, eqd = np.abs(q - Q[k:]).max(), np.abs(qd - QD[k:]).max()
        held = np.abs(Q[:-k] - Q[k:]).max()
        print(f"| {h * 1e3:g} | {eq:.3g} | {eqd:.3g} | {qdd_max * h * h:.3g} | {held:.3g} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
