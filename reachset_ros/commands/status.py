"""``reachset status``: one look at a running suite (issue 36.2).

The nodes in the ROS graph, the stop state (the newest ``/safe_stop``: active, kind, reason),
the rates of ``/joint_states`` and ``/conformance/status`` over about a second, the monitor's
model (``model_file``, the model id its status messages carry), the controller/observer pair's
gains and each joint's set use in the newest ``/conformance/status``. Exit status 0 when every
node of the suite is up, 1 when one is missing (the rest is printed all the same), 2 when no
suite is found.
"""
from . import emit, help_of
from ._suite import add_suite_arguments, no_monitor, operator

NAME = "status"
HELP = help_of(NAME)


def add_arguments(p):
    add_suite_arguments(p)
    p.add_argument("--window", type=float, default=1.0, metavar="S",
                   help="seconds over which the rates are measured (default 1)")


def fmt_use(use):
    return "   -  " if use is None else f"{use:6.3f}"


def human(st) -> str:
    """The status as lines of text."""
    out = [f"suite in ROS_DOMAIN_ID={st['ros_domain_id']}"]
    up = [n for n, ok in st["nodes"].items() if ok]
    down = [n for n, ok in st["nodes"].items() if not ok]
    out.append(f"nodes up: {', '.join(up) or 'none'}" + (f"; NOT UP: {', '.join(down)}" if down else ""))
    stop = st["stop"]
    if stop is None:
        out.append("stop: unknown (no /safe_stop received)")
    elif stop["active"]:
        out.append(f"stop: ACTIVE ({stop['kind']}): {stop['reason']}")
    else:
        out.append(f"stop: none active (last: {stop['kind']}: {stop['reason']})")
    out.append("rates: " + ", ".join(f"{t} {hz:.1f} Hz" for t, hz in st["rates"].items())
               + f" (over {st['window_s']:g} s)")
    m = st["model"]
    out.append(f"model: {m['model_file'] or '(none)'}, id {m['model_id'] or '?'}, k*={m['horizon']}")
    if st["gains"]:
        pair = st["gains"]["pair"]
        out.append("gains: " + ", ".join(f"{k}={v if not isinstance(v, list) else ','.join(f'{x:g}' for x in v)}"
                                         for k, v in pair.items()))
    else:
        out.append(f"gains: not read ({st['gains_error']})")
    if st["set_use"]:
        out.append("set use (1.0 = on the boundary of the reachable set):")
        out += [f"  {j:<14} {fmt_use(u)}" for j, u in st["set_use"].items()]
    else:
        out.append("set use: no /conformance/status received")
    return "\n".join(out)


def run(args):
    from ..errors import ReachsetError
    if args.window <= 0:
        raise ReachsetError("--window must be positive")
    with operator(args) as op:
        st = op.status(window_s=args.window, timeout=args.timeout).to_dict()
        if not any(st["nodes"].values()):
            raise ReachsetError(no_monitor(op))
    emit(args, st, human(st))
    return 0 if all(st["nodes"].values()) else 1
