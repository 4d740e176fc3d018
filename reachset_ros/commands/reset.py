"""``reachset reset``: the monitor's audited reset of a running suite's safe stop (issue 36.2).

Calls the monitor's ``~/reset_stop`` (reachset_msgs/ResetStop) naming this command's node as
the caller and ``--reason``; the monitor grants it only once the stop's condition has cleared
(its ``reset_clean_ticks``) and logs the request either way (``PRIVILEGED``). ``--wait S`` asks
again every 0.25 s while refused, for up to S seconds (the arm coming to rest). Prints the
monitor's answer; exit status 0 when granted, 1 when refused.
"""
from . import emit, help_of
from ._suite import add_suite_arguments, operator

NAME = "reset"
HELP = help_of(NAME)


def add_arguments(p):
    add_suite_arguments(p)
    p.add_argument("--reason", default="", metavar="TEXT", help="why the arm may move again (logged by the monitor)")
    p.add_argument("--wait", type=float, default=0.0, metavar="S",
                   help="while refused, ask again for up to S seconds (default 0: ask once)")


def run(args):
    from ..errors import ReachsetError
    if args.wait < 0:
        raise ReachsetError("--wait must not be negative")
    with operator(args) as op:
        ok, message = op.reset(reason=args.reason, patience_s=args.wait, timeout=args.timeout)
    emit(args, {"granted": ok, "message": message, "ros_domain_id": op.domain_id},
         f"reset {'granted' if ok else 'REFUSED'}: {message}")
    return 0 if ok else 1
