"""``reachset check``: batch Theorem-1 conformance check of bags against a model.

Exit status: 0 conformant, 1 not conformant (so it can gate a CI job), 2 bad input.

``--workers N`` / ``--scheduler ADDRESS``: one task per bag on Dask (:mod:`reachset_ros.fleet`),
merged exactly: the same answer to the bit."""
from ..conformance import envelope
from ..conformance import model as mdl
from ..conformance.theorem1 import check, deviation_extremes
from ..errors import ReachsetError
from ..plots import plot_deviations
from . import emit, help_of
from ._bagargs import (add_bag_arguments, add_fleet_arguments, fleet_of, load_series, parse_joints, read_spec,
                       reader_options, require_horizon, topics_of)
from ._progress import bag_count, progress

NAME = "check"
HELP = help_of(NAME)


def add_arguments(p):
    add_bag_arguments(p)
    add_fleet_arguments(p)
    p.add_argument("--model", required=True, help="model YAML (identify/synthesize output)")
    p.add_argument("--plot", metavar="DIR", help="write per joint a PNG of the measured deviations y_a "
                                                  "(envelope over all test cases) against R_a[k]")


def joint_result(first_violation_ns, res, report=None):
    """The JSON of one joint's :class:`~reachset_ros.conformance.CheckResult`; with the read
    ``report``, ``first_violation_s``: seconds from the start of the bag holding the violation."""
    first_s = None
    if first_violation_ns is not None and report is not None:
        first_s = report.seconds_from_start(int(first_violation_ns))
    return {"violations": res.violations,
            "first_violation_ns": None if first_violation_ns is None else int(first_violation_ns),
            "first_violation_s": first_s,
            "test_cases": res.test_cases, "checks": res.checks,
            "worst_margin": res.worst_margin if res.checks else None}


def _fleet(args, model, thm, fleet):
    """``--workers``/``--scheduler``: one check task per bag (and, for ``--plot``, one sweep),
    merged exactly (:mod:`reachset_ros.fleet`). Returns (joints JSON, report, devs or None)."""
    from .. import fleet as fl
    names = parse_joints(args.joints)
    if names is not None:
        for n in names:
            if n not in model.joints:
                raise ReachsetError(f"joint {n} is not in the model {args.model}")
    read = read_spec(args, names, model.plant.dt)
    sweep = fl.SweepSpec(model.plant, model.estimator, model.horizon, thm)
    xis = {n: model.checked_xi(n) for n in (names or model.joints)}
    devs = None
    with fleet:
        checked, report = fl.check(fleet, args.bags, read, sweep, xis, model.envelope)
        if args.plot:             # a second pass: the envelopes of the deviations
            devs = {n: d for n, d in fl.extremes(fleet, args.bags, read, sweep).devs.items() if n in xis}
    joints = {n: joint_result(first, res, report) for n, (res, first) in checked.items()}
    for n, (res, _) in checked.items():
        joints[n].update(res.envelope or envelope.tick_counts(None, n, None, None))
    return joints, report, devs


def _envelope_text(j):
    """The joint's envelope counts in the text output (nothing without an envelope)."""
    if j.get("outside_envelope_ticks") is None:
        return ""
    return (f"; {j['outside_envelope_ticks']} ticks outside the validated envelope, "
            f"{j['violations_inside_envelope']} violating ticks inside it")


def _seconds(s):
    return "" if s is None else f"{s:.3f} s from the bag's start, stamp "


def _local(args, model, thm, options, p):
    """The single-process check: (joints JSON, report, devs or None)."""
    p.phase(f"reading {bag_count(args.bags)}")
    series, report = load_series(args.bags, args.joints, model.plant.dt, restrict=list(model.joints),
                                 topics=topics_of(args), options=options)
    require_horizon(series, model.estimator.history, model.horizon, args.bags)
    joints = {}
    for i, (name, s) in enumerate(series.items(), 1):
        if name not in model.joints:
            raise ReachsetError(f"joint {name} is not in the model {args.model}")
        p.phase(f"checking {name} ({i} of {len(series)}, {len(s.stamps)} ticks)")
        xi = model.checked_xi(name)
        res = check(model.plant, thm, model.estimator, xi, s.y, s.u, s.segments, model.horizon)
        joints[name] = joint_result(s.stamps[res.first_violation_tick] if res.first_violation_tick >= 0 else None,
                                    res, report)
        joints[name].update(envelope.tick_counts(model.envelope, name, s, res.violating))   # issue 37
    devs = None
    if args.plot:
        p.phase("sweeping the deviations for the plots")
        devs = {name: deviation_extremes(model.plant, model.estimator, s.y, s.u, s.segments, model.horizon, thm)
                for name, s in series.items()}
    return joints, report, devs


def run(args):
    model = mdl.load(args.model)
    options = reader_options(args)
    mdl.require_input_source(model, options["effort"], source=args.model)   # u_p as the model's (34.10)
    fleet = fleet_of(args)
    thm = model.theorem1()
    with progress(args) as p:
        if fleet is not None:
            p.phase(f"checking {bag_count(args.bags)} on the fleet")
            joints, report, devs = _fleet(args, model, thm, fleet)
        else:
            joints, report, devs = _local(args, model, thm, options, p)
    result = {"conformant": all(j["violations"] == 0 for j in joints.values()), "joints": joints,
              "data": report.as_dict(), "envelope": envelope.summary(model.envelope)}
    if args.plot:
        result["plots"] = [plot_deviations(args.plot, name, model, thm, d) for name, d in devs.items()]
    emit(args, result, ("conformant" if result["conformant"] else "NOT conformant") + "\n" + "\n".join(
        f"{n}: {j['violations']} violating ticks of {j['test_cases']} test cases"
        + (f", first at {_seconds(j['first_violation_s'])}{j['first_violation_ns']} ns"
           if j["first_violation_ns"] is not None else "") + _envelope_text(j)
        for n, j in joints.items()) + ("" if model.envelope else "\nno envelope recorded in the model: ticks not "
                                                                 "classified inside or outside"))
    return 0 if result["conformant"] else 1
