"""``reachset check``: batch Theorem-1 conformance check of bags against a model.

Exit status: 0 conformant, 1 not conformant (so it can gate a CI job), 2 bad input."""
from ..conformance import model as mdl
from ..conformance.theorem1 import check, deviation_extremes
from ..errors import ReachsetError
from ..plots import plot_deviations
from . import emit
from ._bagargs import add_bag_arguments, load_series, require_horizon, reader_options, topics_of

NAME = "check"
HELP = "check bags for reachset conformance against a model (batch, vectorised)"


def add_arguments(p):
    add_bag_arguments(p)
    p.add_argument("--model", required=True, help="model YAML (identify/synthesize output)")
    p.add_argument("--plot", metavar="DIR", help="write per joint a PNG of the measured deviations y_a "
                                                  "(envelope over all test cases) against R_a[k]")


def joint_result(stamps, res):
    return {"violations": res.violations,
            "first_violation_ns": int(stamps[res.first_violation_tick]) if res.first_violation_tick >= 0 else None,
            "test_cases": res.test_cases, "checks": res.checks,
            "worst_margin": res.worst_margin if res.checks else None}


def run(args):
    model = mdl.load(args.model)
    series, report = load_series(args.bags, args.joints, model.plant.dt, restrict=list(model.joints),
                                 topics=topics_of(args), options=reader_options(args))
    require_horizon(series, model.estimator.history, model.horizon, args.bags)
    thm = model.theorem1()
    joints = {}
    for name, s in series.items():
        if name not in model.joints:
            raise ReachsetError(f"joint {name} is not in the model {args.model}")
        xi = model.joints[name].xi(model.inflation)
        res = check(model.plant, thm, model.estimator, xi, s.y, s.u, s.segments, model.horizon)
        joints[name] = joint_result(s.stamps, res)
    result = {"conformant": all(j["violations"] == 0 for j in joints.values()), "joints": joints,
              "data": report.as_dict()}
    if args.plot:
        result["plots"] = [plot_deviations(args.plot, name, model, thm, deviation_extremes(
            model.plant, model.estimator, s.y, s.u, s.segments, model.horizon, thm)) for name, s in series.items()]
    emit(args, result, ("conformant" if result["conformant"] else "NOT conformant") + "\n" + "\n".join(
        f"{n}: {j['violations']} violating ticks of {j['test_cases']} test cases"
        + (f", first at {j['first_violation_ns']} ns" if j["first_violation_ns"] is not None else "")
        for n, j in joints.items()))
    return 0 if result["conformant"] else 1
