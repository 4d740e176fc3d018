"""How far a late reference carried forward at constant acceleration is from the true one:
the evidence behind the controller's ``reference_max_age`` (docs/reliability.md).

Usage::

    python benchmarks/late_reference.py [--seconds 600] [--seed 1] [--lead 0.5]

On the campaign's reference class (:class:`reachset_ros.sim.reference.ReferenceGenerator`,
``qd_max`` 0.7 rad/s, ``qdd_max`` 2 rad/s^2, trapezoidal and quintic moves, ``lead`` of them
led by one joint at its limits), for each age ``h`` the largest position and velocity error of
:func:`reachset_ros.systems.late_reference.extrapolate` from every 4-ms tick, against the
documented bound ``qdd_max h^2``, and the same for holding the reference (the rule before).

``--reentry``: what the return of the references does (issue 34.3). In the noise-free nominal
loop (:func:`reachset_ros.systems.reference_loop.simulate_closed_loop`, HG observer h1 15,
h2 30, omega 20, zeta 1, U_p 26, u_ff 2) tracking a trapezoid whose acceleration switches
from +2 to -2 rad/s^2, references late for ``n`` ticks ending ``after`` ticks past the
switch: the largest ``|u_p|`` and tracking error when the controller switches back to the
returned reference (a re-entry out of the certified class, :mod:`reachset_ros.systems.reentry`),
against U_p and ``Y_e,ref`` of the class; and how far a bounded-acceleration blend onto the
returned reference (``|qdd_d| <= u_ff``, the rejected alternative) stays from the published
reference, and for how long.
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
from reachset_ros.systems.reentry import switching_reference  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--lead", type=float, default=0.5)
    ap.add_argument("--reentry", action="store_true", help="the re-entry table (issue 34.3) instead")
    a = ap.parse_args(argv)
    if a.reentry:
        return reentry()
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


def _blend(ref, k0, n, dt, u_ff, omega=10.0):
    """The rejected alternative: the carried reference, then a PD (omega, damping 1) saturated to
    ``|qdd_d| <= u_ff`` onto the returned reference, handing over when that is a step of the class.
    Returns the largest distance to the published reference and the ticks until the handover."""
    from reachset_ros.systems.reentry import class_step
    q, qd, acc = ref
    c = lr.extrapolate(q[k0 - 1], qd[k0 - 1], acc[k0 - 1], (n + 1) * dt)   # carried to the first tick back
    dev, k = 0.0, k0 + n
    while k < len(q) - 1:
        dev = max(dev, abs(c[0] - q[k]))
        gov = np.clip(acc[k] + omega ** 2 * (q[k] - c[0]) + 2 * omega * (qd[k] - c[1]), -u_ff, u_ff)
        c = lr.extrapolate(c[0], c[1], gov, dt)
        k += 1
        if class_step((c[0] - c[1] * dt + 0.5 * gov * dt * dt, c[1] - gov * dt, gov), (q[k], qd[k], acc[k]), dt,
                      u_ff):
            return dev, k - k0 - n
    return dev, None


def reentry():
    from reachset_ros.synthesis.reference_error import ReferenceClass, class_reference_error
    from reachset_ros.systems.gains import Gains
    from reachset_ros.systems.plant import lwa4p_joint_plant
    from reachset_ros.systems.reference_loop import simulate_closed_loop
    dt, u_ff, u_p, switch = 0.004, 2.0, 26.0, 250
    plant = lwa4p_joint_plant()
    obs, ctl = Gains(omega=20.0, zeta=1.0, h1=15.0, h2=30.0).build()
    y_e_ref = float(class_reference_error(plant, obs, ctl, ReferenceClass(qdd_max=u_ff)).e_hi[0])
    ref = switching_reference(dt=dt, u_ff=u_ff, switch=switch)
    print(f"nominal loop: HG h1 15, h2 30, omega 20, zeta 1; U_p {u_p:g}, u_ff {u_ff:g}, Y_e,ref {y_e_ref:.4g} rad")
    print("| late ticks | back ticks after the switch | max |u_p| rad/s^2 | max |e| rad "
          "| blend: max distance to /reference rad | blend: ticks until on it |")
    print("|---|---|---|---|---|---|")
    for n, after in ((2, 1), (10, 5), (25, 10), (50, 30), (50, 50)):
        k0 = switch + after - n
        c = [x.copy() for x in ref]
        for k in range(k0, k0 + n):
            for x, v in zip(c, lr.extrapolate(ref[0][k0 - 1], ref[1][k0 - 1], ref[2][k0 - 1], (k - k0 + 1) * dt)):
                x[k] = v
        out = simulate_closed_loop(plant, obs, ctl, *c)
        dev, ticks = _blend(ref, k0, n, dt, u_ff)
        print(f"| {n} | {after} | {np.abs(out['u']).max():.3g} | {np.abs(out['y'][:, 0] - ref[0]).max():.3g} "
              f"| {dev:.3g} | {ticks if ticks is not None else 'not within 3 s'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
