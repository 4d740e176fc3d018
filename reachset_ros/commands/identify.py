"""``reachset identify``: reachset-conformant identification (Theorem 1, HiGHS LP)."""
import sys

from .. import conformance as cf
from .. import model as mdl
from ..errors import ReachsetError
from ..estimators import ESTIMATORS, Estimator
from ..plant import lwa4p_joint_plant
from . import emit
from ._bagargs import add_bag_arguments, check_out_path, load_series

NAME = "identify"
HELP = "identify a reachset-conformant model (min ||W||+||V||, Theorem 1) from bags"


def add_arguments(p):
    add_bag_arguments(p)
    p.add_argument("--horizon", type=int, default=125, help="k*, ticks (default 125, the paper's)")
    p.add_argument("--out", help="write the model YAML here")
    p.add_argument("--estimator", default="fd", choices=sorted(ESTIMATORS),
                   help="initial-state estimator of the test cases (stored in the model)")
    p.add_argument("--centers", default="zero", choices=["zero", "free"],
                   help="set centers fixed at 0 (paper) or identified")
    p.add_argument("--alpha-lower", type=float, nargs="+", metavar="F",
                   help="lower bounds on [alpha_W..., alpha_V...] (e.g. encoder resolution)")
    p.add_argument("--dt", type=float, default=0.004, help="sampling time, s")


def identify_series(plant, est, series, horizon, centers="zero", alpha_lower=None, thm=None):
    """Identify each joint of ``series``; returns {name: (IdentifiedSets, Deviations, settled_k)}."""
    thm = thm or cf.Theorem1.build(plant, horizon)
    out = {}
    for name, s in series.items():
        try:
            dev = cf.deviation_extremes(plant, est, s.y, s.u, s.segments, horizon, thm)
        except ReachsetError as e:
            raise ReachsetError(f"joint {name}: {e}") from None
        try:
            sets = cf.identify(plant, thm, dev, centers=centers, alpha_lower=alpha_lower)
            settled, _ = cf.stable_horizon(plant, thm, dev, centers=centers, alpha_lower=alpha_lower)
        except ReachsetError as e:
            raise ReachsetError(f"joint {name}: {e}") from None
        out[name] = (sets, dev, settled)
    return out, thm


def run(args):
    if args.horizon < 0:
        raise ReachsetError("--horizon must be >= 0")
    if args.dt <= 0:
        raise ReachsetError("--dt must be positive")
    out = check_out_path(args.out)
    plant = lwa4p_joint_plant(dt=args.dt)
    est = Estimator(args.estimator)
    series, report = load_series(args.bags, args.joints, args.dt)
    results, _ = identify_series(plant, est, series, args.horizon, args.centers, args.alpha_lower)
    joints, js = {}, {}
    for name, (sets, dev, settled) in results.items():
        joints[name] = mdl.JointSets(tuple(sets.alpha_w.tolist()), tuple(sets.alpha_v.tolist()),
                                     tuple(sets.c_w.tolist()), tuple(sets.c_v.tolist()),
                                     dev.test_cases, args.horizon)
        js[name] = {"alpha_w": sets.alpha_w.tolist(), "alpha_v": sets.alpha_v.tolist(),
                    "c_w": sets.c_w.tolist(), "c_v": sets.c_v.tolist(),
                    "test_cases": dev.test_cases, "horizon": args.horizon,
                    "checks": dev.checks, "stable_horizon": settled,
                    "soundness_inflation": sets.soundness_bump}
    result = {"joints": js, "data": report.as_dict()}
    if out is not None:
        m = mdl.ConformanceModel(plant, {"kind": "lwa4p_joint", "dt": args.dt}, est, args.horizon, joints,
                                 0.0, mdl.provenance(args.bags, "reachset " + " ".join(sys.argv[1:])))
        mdl.save(m, out)
        result["model"] = str(out)
    emit(args, result, "\n".join(
        f"{n}: alpha_w={v['alpha_w']} alpha_v={v['alpha_v']} test_cases={v['test_cases']} "
        f"(sets stop changing at k={v['stable_horizon']})" for n, v in js.items())
        + (f"\nmodel written to {out}" if out else ""))
