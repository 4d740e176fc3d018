"""``reachset selftest``: two real processes exchange PlantInput over DDS."""
from ..errors import ReachsetError
from . import emit, help_of

NAME = "selftest"
HELP = help_of(NAME)


def add_arguments(p):
    p.add_argument("--timeout", type=float, default=30.0, help="seconds before giving up")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args):
    from ..nodes.selftest import run_selftest  # heavy optional dependency: rclpy (cli.py imports every command)
    try:
        res = run_selftest(timeout=args.timeout)
    except RuntimeError as e:
        raise ReachsetError(f"{e}") from e
    emit(args, res, f"selftest: {res['messages']} PlantInput messages received from process "
                    f"{res['talker_pid']}; first {res['first']}, after parameter set {res['after_set']}")
