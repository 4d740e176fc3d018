"""The synthesis node's worker process.

``python -m reachset_ros.commands._synthesis_worker synthesize ARG...``:

The first argument names the workflow (``synthesize``, the one it runs; so the process is
found as the synthesis by its command line, as ``reachset synthesize`` was). Parses
``reachset synthesize`` arguments (the node's own and its ``extra_args`` parameter),
runs the synthesis workflow in this process (:func:`reachset_ros.commands.synthesize.compute`,
the command's own code path, which calls :func:`reachset_ros.workflows.synthesize.synthesize`)
and writes the result, the command's ``--json`` object, to stdout as one pickle: the node
reads the library's values, not printed text. Errors are reported as the command line
reports them: one line on stderr (``reachset synthesize: error: ...``), exit status 2.

The node starts it with :func:`reachset_ros.processes.start_background` (nice +10, a process
group of its own, SIGTERM when the node dies). It is a program run by module name, so that
the node, a layer below the workflows, imports none of them.
"""
import argparse
import contextlib
import pickle
import sys

from ..errors import exit_status
from . import synthesize

PROG = "reachset synthesize"
#: the workflows this worker runs (its first argument)
WORKFLOWS = ("synthesize",)


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors as one line on stderr and exit status 2, as ``reachset`` reports them."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def parser():
    """The ``reachset synthesize`` argument parser."""
    p = _OneLineParser(prog=PROG, description=synthesize.HELP)
    p.add_argument("--debug", action="store_true", help="show full tracebacks")
    synthesize.add_arguments(p)
    return p


def main(argv=None):
    """Run one synthesis; returns the exit status (0, or 2 on a refused input)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] not in WORKFLOWS:
        print(f"{PROG}: error: the worker's first argument names the workflow ({', '.join(WORKFLOWS)})",
              file=sys.stderr)
        return 2
    argv = argv[1:]
    args = parser().parse_args(argv)
    out = sys.stdout.buffer

    def run():
        with contextlib.redirect_stdout(sys.stderr):    # stdout carries the pickle only
            _, result = synthesize.compute(args, command=" ".join([PROG, *argv]))
        pickle.dump(result, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()

    return exit_status(PROG, run, debug=args.debug)

if __name__ == "__main__":
    sys.exit(main())
