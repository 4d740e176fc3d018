"""The ``reachset`` command line (docs/interfaces.md).

Subcommands live in :mod:`reachset_ros.commands`, one module each. Errors in the user's
input raise :class:`reachset_ros.errors.ReachsetError`; ``main`` prints them as one line
and exits with status 2 (a traceback only with ``--debug``).
"""
import argparse
import importlib
import sys

from .commands import MODULES
from .errors import exit_status


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors as one line on stderr and exit status 2 (``--help`` shows the usage)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser():
    parser = _OneLineParser(
        prog="reachset",
        description="Reachset-conformant identification, controller synthesis and conformance "
                    "checking for feedback-linearized robots (Liu, Schuermann, Althoff, IEEE T-RO).")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_OneLineParser)
    for modname in MODULES:
        mod = importlib.import_module(f".commands.{modname}", __package__)
        sp = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        sp.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show full tracebacks")
        mod.add_arguments(sp)
        sp.set_defaults(_run=mod.run)
    return parser




def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    return exit_status(f"reachset {args.command}", lambda: args._run(args), debug=args.debug)


if __name__ == "__main__":
    sys.exit(main())
