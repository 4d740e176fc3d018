"""``reachset watch``: a live terminal view of a running suite (issue 36.2).

Refreshes every ``--period`` seconds (default 0.33 s, about 3 Hz): a STOP banner with the kind
and reason while ``/safe_stop`` is active, the rates of ``/joint_states`` and
``/conformance/status`` (over the last second), the monitor's model id and, per joint, the
largest set use seen in ``/conformance/status`` since the previous frame (1.0 on the boundary
of the reachable set, above 1 a violation) with a bar. On a terminal the screen is redrawn; else
(a pipe, a file) each frame is plain text followed by an empty line, and ``--json`` prints one
JSON object per frame. ``--once`` prints one frame after a second of listening, ``--duration
S`` stops after S seconds; Ctrl-C stops it (exit status 0).
"""
import json
import sys
import time

from . import help_of
from ._suite import add_suite_arguments, no_monitor, operator

NAME = "watch"
HELP = help_of(NAME)
#: width of the set-use bar, characters, for a use of 1.0 (the boundary)
BAR = 30
#: seconds over which the rates are measured
RATE_WINDOW = 1.0


def add_arguments(p):
    add_suite_arguments(p, json=False)
    p.add_argument("--json", action="store_true", help="one JSON object per frame (a line each) instead of text")
    p.add_argument("--once", action="store_true", help="print one frame (after a second of listening) and exit")
    p.add_argument("--duration", type=float, metavar="S", help="exit after S seconds")
    p.add_argument("--period", type=float, default=0.33, metavar="S",
                   help="seconds between frames (default 0.33: about 3 Hz)")


def bar(use):
    if use is None:
        return ""
    n = max(0, min(round(use * BAR), BAR + 10))
    return ("#" * min(n, BAR)).ljust(BAR) + ("|" + "!" * (n - BAR) if n > BAR else "|")


def frame(op) -> dict:
    """What one frame shows (the ``--json`` object)."""
    from ..workflows.operator import set_use_of, stop_of
    st = op.seen.status
    latest = set_use_of(st) if st is not None else {}
    peak = op.take_peak()
    return {"time": time.strftime("%H:%M:%S"), "ros_domain_id": op.domain_id, "stop": stop_of(op.latest_stop()),
            "rates": op.rates(RATE_WINDOW), "model_id": st.model_id if st is not None else None,
            "set_use": latest, "set_use_peak": {j: peak.get(j, u) for j, u in latest.items()}}


def text(fr) -> str:
    out = [f"reachset watch  ROS_DOMAIN_ID={fr['ros_domain_id']}  model {fr['model_id'] or '?'}  {fr['time']}"]
    stop = fr["stop"]
    if stop is not None and stop["active"]:
        out.append(f"*** STOP ({stop['kind']}): {stop['reason']} ***")
    elif stop is None:
        out.append("stop state unknown (no /safe_stop received)")
    else:
        out.append("running: no safe stop active")
    out.append("rates: " + "  ".join(f"{t} {hz:.1f} Hz" for t, hz in fr["rates"].items()))
    if not fr["set_use"]:
        out.append("no /conformance/status received")
    else:
        out.append(f"{'joint':<14} {'use':>6}  (largest since the last frame; | = the set's boundary)")
        for j, u in fr["set_use_peak"].items():
            out.append(f"{j:<14} {'-' if u is None else format(u, '6.3f'):>6}  {bar(u)}")
    return "\n".join(out)


def run(args):
    from ..errors import ReachsetError
    if args.period <= 0 or (args.duration is not None and args.duration <= 0):
        raise ReachsetError("--period and --duration must be positive")
    tty = sys.stdout.isatty() and not args.json
    with operator(args) as op:
        if not op.wait_for_suite(args.timeout):
            raise ReachsetError(no_monitor(op))
        op.spin(RATE_WINDOW)
        end = None if args.duration is None else time.monotonic() + args.duration
        try:
            while True:
                fr = frame(op)
                if args.json:
                    print(json.dumps(fr, sort_keys=True), flush=True)
                elif tty:
                    sys.stdout.write("\x1b[H\x1b[2J" + text(fr) + "\n")
                    sys.stdout.flush()
                else:
                    print(text(fr) + "\n", flush=True)
                if args.once or (end is not None and time.monotonic() >= end):
                    return 0
                op.spin(args.period if end is None else max(0.0, min(args.period, end - time.monotonic())))
        except KeyboardInterrupt:
            return 0
