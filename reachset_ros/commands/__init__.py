"""Subcommands of the ``reachset`` command line, one module per command.

Each module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args)``;
``run`` prints its result (through :func:`emit`) and raises
:class:`reachset_ros.errors.ReachsetError` for bad input.

May import: everything below the command line: the pure core (:mod:`reachset_ros.errors`, :mod:`reachset_ros.defaults`, :mod:`reachset_ros.guarantees`,
:mod:`reachset_ros.atomic`, :mod:`reachset_ros.sets`, :mod:`reachset_ros.systems`,
:mod:`reachset_ros.robot`, :mod:`reachset_ros.conformance`, :mod:`reachset_ros.bags`,
:mod:`reachset_ros.synthesis`, :mod:`reachset_ros.fleet`, :mod:`reachset_ros.sim`), the
processes (:mod:`reachset_ros.domain`, :mod:`reachset_ros.params_file`,
:mod:`reachset_ros.processes`), :mod:`reachset_ros.nodes`, :mod:`reachset_ros.workflows`,
:mod:`reachset_ros.plots` and :mod:`reachset_ros.report`. Only the command line (``reachset_ros.cli``) imports this package.
"""
import json
import sys

#: Modules under reachset_ros.commands, in the order ``reachset --help`` lists them.
MODULES = ["selftest", "analyze", "inspect", "identify", "check", "replay", "report", "fit_lwa4p", "import_lwa4p", "synthesize", "input_limits", "simulate", "excite", "demo", "up", "status", "watch", "reset", "stop", "gains"]


def emit(args, result, human=None):
    """Print ``result`` as one JSON object with ``--json``, else ``human`` (or indented JSON)."""
    if getattr(args, "json", False):
        json.dump(result, sys.stdout, sort_keys=True, allow_nan=False)
        sys.stdout.write("\n")
    elif human is not None:
        print(human)
    else:
        print(json.dumps(result, indent=2, sort_keys=True, allow_nan=False))
