"""``reachset stop``: a manual, audited safe stop of a running suite (issue 36.2).

Calls the monitor's ``~/stop`` (reachset_msgs/ResetStop: this command's node as the caller,
``--reason``): the monitor latches ``/safe_stop`` with kind ``manual`` and the reason, the
controller carries out its category-1 stop (the braking law, then the holding brakes), and only
the audited reset (``reachset reset``) clears it. A stop latched already stays as it is (the
answer says which). Exit status 0 once a stop is latched, 1 when the monitor does not latch one.
"""
from . import emit, help_of
from ._suite import add_suite_arguments, operator

NAME = "stop"
HELP = help_of(NAME)


def add_arguments(p):
    add_suite_arguments(p)
    p.add_argument("--reason", default="", metavar="TEXT", help="why the arm is stopped (logged, and in /safe_stop)")


def run(args):
    with operator(args) as op:
        ok, message = op.stop(reason=args.reason, timeout=args.timeout)
    emit(args, {"latched": ok, "message": message, "ros_domain_id": op.domain_id},
         f"stop {'latched' if ok else 'NOT latched'}: {message}")
    return 0 if ok else 1
