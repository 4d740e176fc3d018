"""``reachset input-limits``: U_p from torque limits (paper eq. ``deriveInputConstraint``, Table I).

Finds per axis the largest symmetric U_p = [-a, a] with M(Q) U_p (+) psi(Q, dQ) inside
T = [-tau_max, tau_max] for the boxes Q (positions), dQ (velocities), soundly (see
:mod:`reachset_ros.robot.input_limits`). Defaults: the shipped LWA-4P model and the paper's
Table I (tau_max 160/160/160/160/40/40 N m, q_max 140/45/100/140/80/140 deg, qd_max 0.7 rad/s).
``--check A...`` verifies given limits instead (e.g. the paper's 26 26 26 26 100 100).
``--out FILE`` writes a synthesis config fragment (``u_max`` per joint) for
``reachset synthesize --config FILE``.
"""
import math
from pathlib import Path

import numpy as np

from ..atomic import write_yaml
from ..errors import ReachsetError
from ..robot import input_limits as il
from ..robot.dynamics import TABLE1_TAU_MAX, load_model
from . import emit, help_of

NAME = "input-limits"
HELP = help_of(NAME)


def add_arguments(p):
    p.add_argument("--urdf", help="robot URDF (default: the shipped LWA-4P)")
    p.add_argument("--params", help="identified parameters YAML applied over the URDF (e.g. config/lwa4p_nominal.yaml)")
    p.add_argument("--tau-max", type=float, nargs="+", metavar="NM", help="torque limits, N m (default Table I)")
    p.add_argument("--q-max-deg", type=float, nargs="+", metavar="DEG", help="Q = [-q_max, q_max], degrees (default Table I)")
    p.add_argument("--qd-max", type=float, nargs="+", metavar="RAD_S", help="dQ = [-qd_max, qd_max], rad/s (default 0.7)")
    p.add_argument("--splits", type=int, nargs="+", default=[4], metavar="N",
                   help="initial pieces per joint of Q (one value or one per joint; default 4, as the paper)")
    p.add_argument("--method", choices=["taylor", "interval"], default="taylor",
                   help="taylor: exact trigonometric polynomials + second-order bounds with adaptive "
                        "splitting (default); interval: interval Newton-Euler on the uniform split")
    p.add_argument("--refine", type=int, default=6, help="refinement rounds of the binding sub-boxes (taylor)")
    p.add_argument("--max-boxes", type=int, default=16000, help="sub-box budget of the refinement")
    p.add_argument("--weights", nargs="+", default=["inertia"], metavar="W",
                   help="trade-off between axes: inertia (default: a_j proportional to tau_max_j / max M_jj), "
                        "equal, or one positive number per joint")
    p.add_argument("--check", type=float, nargs="+", metavar="A",
                   help="verify U_p = [-A, A] (one value or one per joint) instead of maximising")
    p.add_argument("--samples", type=int, default=20000, help="random samples for the inner estimate")
    p.add_argument("--seed", type=int, default=0, help="seeds the random samples")
    p.add_argument("--out", help="write {u_max: {joint: a}} (a synthesis config fragment) here")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _vec(name, vals, n, scale=1.0, positive=True):
    if vals is None:
        return None
    if len(vals) not in (1, n):
        raise ReachsetError(f"--{name}: give 1 or {n} values, got {len(vals)}")
    v = np.broadcast_to(np.asarray(vals, float) * scale, (n,)).copy()
    if not np.all(np.isfinite(v)) or np.any(v < 0) or (positive and np.any(v <= 0)):
        raise ReachsetError(f"--{name}: values must be finite and {'positive' if positive else 'non-negative'}")
    return v


def _write(path, d):
    p = Path(path)
    if p.is_dir():
        raise ReachsetError(f"{p}: --out is a directory")
    if not p.parent.exists():
        raise ReachsetError(f"{p.parent}: output directory does not exist")
    write_yaml(p, d, "# U_p = [-u_max, u_max] per joint from `reachset input-limits` (sound for the model below).\n")


def run(args):
    model = load_model(args.urdf, args.params)
    n = model.nv
    tau = _vec("tau-max", args.tau_max, n)
    qmax = _vec("q-max-deg", args.q_max_deg, n, math.pi / 180.0, positive=False)
    qdmax = _vec("qd-max", args.qd_max, n, positive=False)
    if len(args.splits) not in (1, n) or min(args.splits) < 1 or max(args.splits) > 64:
        raise ReachsetError(f"--splits: give 1 or {n} values in 1..64")
    if args.refine < 0 or args.max_boxes < 1 or args.samples < 0:
        raise ReachsetError("--refine, --max-boxes and --samples must be non-negative")
    if args.check:
        a = _vec("check", args.check, n)
        ok, worst = il.check_limits(model, a, tau, qmax, qdmax, args.splits if len(args.splits) > 1 else args.splits[0])
        tmax = np.broadcast_to(TABLE1_TAU_MAX if tau is None else tau, (n,))
        result = {"check": True, "ok": ok, "u_max": a.tolist(), "bound_torque": worst.tolist(),
                  "tau_max": list(map(float, tmax)), "joints": list(model.joint_names), "model": model.source}
        emit(args, result, ("certified" if ok else "NOT certified (the sound bound exceeds tau_max; try more --splits)")
             + "\n" + "\n".join(f"{j}: U_p = +-{x:g} rad/s^2, torque bound {w:.4g} of {t:g} N m"
                                for j, x, w, t in zip(model.joint_names, a, worst, tmax)))
        return
    w = args.weights
    if w not in (["inertia"], ["equal"]):
        try:
            w = [float(x) for x in w]
        except ValueError:
            raise ReachsetError("--weights: inertia, equal, or numbers") from None
        w = _vec("weights", w, n)
    else:
        w = w[0]
    res = il.input_limits(model, tau, qmax, qdmax, splits=args.splits if len(args.splits) > 1 else args.splits[0],
                          method=args.method, refine=args.refine, max_boxes=args.max_boxes, weights=w,
                          samples=args.samples, seed=args.seed)
    d = res.as_dict()
    if args.out:
        _write(args.out, {"u_max": {j: float(round(x, 6)) for j, x in zip(model.joint_names, res.a)}})
        d["out"] = str(args.out)
    lines = [f"{j}: U_p = +-{a:.4g} rad/s^2 (sound torque bound {wt:.4g} of {t:g} N m; sampled {s:.4g} N m; "
             f"limited by {b})"
             for j, a, wt, t, s, b in zip(model.joint_names, res.a, res.worst_torque, res.tau_max,
                                          res.sampled_torque, d["binding_axis"])]
    lines.append(f"{res.boxes} sub-boxes after {res.rounds} refinement rounds ({res.method}); model {model.source}")
    emit(args, d, "\n".join(lines))
