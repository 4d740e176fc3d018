"""Arguments and the client shared by the operator commands (``status``, ``watch``, ``reset``,
``stop``, ``gains``): which running suite, and an :class:`~reachset_ros.workflows.operator.Operator`
in its DDS domain (:func:`reachset_ros.domain.suite_domain`: ``--domain``, else ``--workdir``'s
``up.json``, else ``ROS_DOMAIN_ID``, else 0)."""
import sys
from contextlib import contextmanager

from ..domain import STATE_FILE, suite_domain


def add_suite_arguments(p, *, json=True):
    p.add_argument("--workdir", metavar="DIR",
                   help=f"the --workdir of a running `reachset up`: its domain from DIR/{STATE_FILE}")
    p.add_argument("--domain", type=int, metavar="N",
                   help="the suite's ROS_DOMAIN_ID (default: from --workdir, else the environment's "
                        "ROS_DOMAIN_ID, else 0)")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for the suite's nodes and for each answer (default 10)")
    if json:
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


@contextmanager
def operator(args):
    """The :class:`~reachset_ros.workflows.operator.Operator` of the suite ``args`` name
    (a ``ReachsetError`` when they name none that runs)."""
    from ..errors import ReachsetError
    from ..workflows.operator import open_operator
    if args.timeout <= 0:
        raise ReachsetError("--timeout must be positive")
    domain, source, state = suite_domain(domain=args.domain, workdir=args.workdir)
    expected = [n["name"] for n in state.get("nodes", [])] or None
    if getattr(args, "verbose_domain", False):
        print(f"ROS_DOMAIN_ID={domain} (from {source})", file=sys.stderr)
    with open_operator(domain_id=domain, expected=expected) as op:
        op.source = source
        yield op


def no_monitor(op):
    """The one line of a suite whose monitor was not found."""
    return (f"no monitor_node in ROS_DOMAIN_ID={op.domain_id} (from {op.source}): is the suite running there? "
            "(give the --workdir of `reachset up`, or --domain)")
