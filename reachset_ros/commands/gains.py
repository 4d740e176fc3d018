"""``reachset gains get|set``: the controller/observer pair's gains of a running suite (issue 36.2).

``get`` reads both nodes' gain parameters: the half each runs (the observer's ``observer``,
``eso_input`` and observer gains, the controller's ``controller``, ``omega``, ``zeta``) and
each node's copy of the whole pair. ``set NAME=VALUE ...`` (one value for every joint, or
``a,b,...`` one per joint; ``observer=hg|eso``, ``controller=static|compensated``,
``eso_input=previous|current``) sets them on both nodes, all or none, through the pair's gate
(:func:`reachset_ros.nodes.pair_gate.set_pair`: each node certifies the pair that will run, and
a node that accepted is set back when the other refuses). Exit status 0 when set, 1 when
refused (one line: which node and why; nothing changed), 2 on bad input (nothing sent). A set
that is applied also says which parts of the class the gate certifies the model was never
validated on (issue 37.3: ``envelope``, naming, not refusing), or ``envelope: none recorded``.
"""
import sys

from . import emit, help_of
from ._suite import add_suite_arguments, operator

NAME = "gains"
HELP = help_of(NAME)


def add_arguments(p):
    sub = p.add_subparsers(dest="action", metavar="get|set", required=True)
    g = sub.add_parser("get", help="the pair's gains", description="the pair's gains")
    add_suite_arguments(g)
    s = sub.add_parser("set", help="set gains on both nodes of the pair, all or none",
                       description="set gains on both nodes of the pair, all or none (exit 1 when refused)")
    s.add_argument("values", nargs="+", metavar="NAME=VALUE",
                   help="e.g. omega=22.6 zeta=0.9, or omega=20,21,22,22,22,22 (one per joint)")
    s.add_argument("--reason", default="", metavar="TEXT", help="why the gains change (logged with the change)")
    add_suite_arguments(s)


def parse_values(items) -> dict:
    """``["omega=12", "h1=10,12", "observer=eso"]`` -> ``{name: value}`` checked
    (:func:`reachset_ros.workflows.operator.check_gains`); a ``ReachsetError`` names the first bad one."""
    from ..errors import ReachsetError
    from ..workflows.operator import check_gains
    out = {}
    for item in items:
        name, eq, text = item.partition("=")
        name, text = name.strip(), text.strip()
        if not eq or not name or not text:
            raise ReachsetError(f"{item!r}: expected NAME=VALUE (e.g. omega=12)")
        if name in out:
            raise ReachsetError(f"{name} given twice")
        out[name] = text.split(",") if "," in text else text
    return check_gains(out)


def fmt(value):
    return ",".join(f"{x:g}" for x in value) if isinstance(value, list) else str(value)


def human(gains) -> str:
    lines = [f"joints: {', '.join(gains['joints'])}", "the pair that runs:"]
    lines += [f"  {k:<11} {fmt(v)}" for k, v in gains["pair"].items()]
    return "\n".join(lines)


def run(args):
    if args.action == "get":
        with operator(args) as op:
            gains = op.get_gains(timeout=args.timeout)
        emit(args, gains, human(gains))
        return 0
    values = parse_values(args.values)           # exit 2 before anything is sent
    with operator(args) as op:
        ok, why = op.set_gains(values, reason=args.reason, timeout=args.timeout)
        gains = op.get_gains(timeout=args.timeout) if ok else None
        envelope = op.envelope(timeout=args.timeout) if ok else None
    if not ok:
        why = " ".join(why.split())
        if args.json:
            emit(args, {"applied": False, "reason": why})
        print(f"reachset gains set: refused: {why}", file=sys.stderr)
        return 1
    emit(args, {"applied": True, "gains": gains, "envelope": envelope},
         "set on observer_node and controller_node\n" + human(gains) + "\n" + envelope["note"])
    return 0
