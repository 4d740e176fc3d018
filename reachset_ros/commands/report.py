"""``reachset report``: one self-contained HTML page of bags checked against a model.

Per joint the measured deviations against the reachable sets (``check --plot``'s figure), the
set use over time (|deviation| / bound per tick, 1.0 the boundary, above 1 a violation), the
violations and safe stops in seconds from each bag's start; the guarantee table (inflation,
R*_e, R*_u against U_p per joint) and the model's provenance. Computed by the core ``check``
uses (:mod:`reachset_ros.report`); no network: the figures are inlined, nothing is fetched.

Exit status: 0 the page was written (its verdict is on it and in ``--json``), 2 bad input (one
line; nothing written: the page is written atomically).
"""
import sys

from ..report import write_report
from . import emit, help_of
from ._bagargs import add_bag_arguments, parse_joints, reader_options, topics_of

NAME = "report"
HELP = help_of(NAME)


def add_arguments(p):
    add_bag_arguments(p)
    p.add_argument("--model", required=True, help="model YAML (identify/synthesize output)")
    p.add_argument("--out", required=True, metavar="HTML", help="the page to write (e.g. report.html)")


def run(args):
    options = reader_options(args)
    command = " ".join(["reachset report", *map(str, args.bags), "--model", str(args.model), "--out", str(args.out)])
    log = (lambda s: print(f"reachset report: {s}", file=sys.stderr, flush=True)) \
        if sys.stderr.isatty() and not args.json else None
    res = write_report(args.bags, args.model, args.out, joints=parse_joints(args.joints), topics=topics_of(args),
                       options=options, command=command, log=log)
    emit(args, res, ("conformant" if res["conformant"] else "NOT conformant") + "\n" + "\n".join(
        f"{n}: {j['violations']} violating ticks of {j['test_cases']} test cases"
        + (f", first at {j['first_violation']['t_s']:.3f} s in {j['first_violation']['bag']}"
           if j["first_violation"] else "") for n, j in res["joints"].items())
        + "".join(f"\nsafe stop at {s['t_s']:.3f} s in {s['bag']}: {s['reason']}" for s in res["stops"])
        + f"\nreport: {res['report']}")
    return 0
