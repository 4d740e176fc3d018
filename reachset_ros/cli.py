"""The ``reachset`` command line (docs/interfaces.md).

Subcommands live in :mod:`reachset_ros.commands`, one module each. Errors in the user's
input raise :class:`reachset_ros.errors.ReachsetError`; ``main`` prints them as one line
and exits with status 2 (a traceback only with ``--debug``). A reader that closes the pipe
early (``reachset check ... | head -1``) does not change the exit status: output written after
that is dropped (:class:`_ClosedPipeSafe`, on stdout and stderr) and the command's own status is
returned.
"""
import argparse
import importlib
import os
import sys

from .commands import COMMANDS
from .errors import exit_status


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors as one line on stderr and exit status 2 (``--help`` shows the usage)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


class _ClosedPipeSafe:
    """A text stream that drops what is written once its reader has closed the pipe.

    Python ignores SIGPIPE, so a write to a closed pipe raises BrokenPipeError; uncaught, a
    conformant ``reachset check BAG --model M | true`` ended with a traceback and exit status 1.
    On the first such error the stream's descriptor is pointed at /dev/null (so the final flush
    at exit cannot fail either) and the rest of the output is discarded.
    """

    def __init__(self, stream):
        self._stream = stream

    def _closed(self):
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, self._stream.fileno())
        finally:
            os.close(devnull)

    def write(self, text):
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._closed()
            return len(text)

    def flush(self):
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._closed()

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _shown(value):
    """A default as ``--help`` shows it: ``none`` for None or an empty list, lists space-separated."""
    if value is None or (isinstance(value, (list, tuple)) and not value):
        return "none"
    if isinstance(value, (list, tuple)):
        return " ".join(map(str, value))
    return str(value)


class _DefaultsFormatter(argparse.HelpFormatter):
    """``--help`` shows every option's default (argparse's ArgumentDefaultsHelpFormatter, but
    ``none`` for an unset option, ``required`` for a required one, and unchanged when the help
    text already says its default); flags (``--json``) and positionals are as written."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (not action.option_strings or action.nargs == 0 or action.default is argparse.SUPPRESS
                or "default" in text.lower()):
            return text
        if action.required:
            return text + " (required)"
        return text + f" (default: {_shown(action.default)})".replace("%", "%%")


def build_parser(only=None):
    """The ``reachset`` parser.

    Parameters
    ----------
    only : str, optional
        Import and add the options of this command only (``""``: of none); every command is
        still listed with its help (:data:`reachset_ros.commands.COMMANDS`). Default: all of
        them (the docs and tests that walk every option).

    Start-up (issue 38.1): a command's module imports what its options need; ``main`` builds
    the parser of the one command on the command line, so ``reachset --help`` and a usage
    error import no command at all.
    """
    parser = _OneLineParser(
        prog="reachset", formatter_class=_DefaultsFormatter,
        description="Reachset-conformant identification, controller synthesis and conformance "
                    "checking for feedback-linearized robots (Liu, Schuermann, Althoff, IEEE T-RO).")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_OneLineParser)
    for name, (modname, text) in COMMANDS.items():
        sp = sub.add_parser(name, help=text, description=text, formatter_class=_DefaultsFormatter)
        sp.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show full tracebacks")
        if only is None or only == name:
            mod = importlib.import_module(f".commands.{modname}", __package__)
            mod.add_arguments(sp)
            sp.set_defaults(_run=mod.run)
    return parser


def command_in(argv) -> str:
    """The command named on the command line ``argv`` (``""`` when there is none): the first
    word that is not an option (the top-level parser's options take no value)."""
    word = next((a for a in argv if not a.startswith("-")), "")
    return word if word in COMMANDS else ""


def _json_only_stdout():
    """For a ``--json`` process: file descriptor 1 goes to stderr, and ``sys.stdout`` writes to
    the original stdout, so that only the command's JSON is on it. Libraries below Python (the
    DDS middleware's log) write to descriptor 1; one such line before the JSON made
    ``reachset gains get --json`` unparseable in a loaded test run. Returns the restore function."""
    original = sys.stdout
    original.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    out = open(saved, "w", encoding=original.encoding or "utf-8", closefd=False)
    sys.stdout = out

    def restore():
        sys.stdout = original
        out.flush()
        os.dup2(saved, 1)
        os.close(saved)
    return restore


def main(argv=None):
    restore = None
    if argv is None:                # a process of its own (the console script, python -m)
        from .stacks import dump_on_sigusr1
        dump_on_sigusr1()
        if "--json" in sys.argv[1:]:
            restore = _json_only_stdout()
    streams = sys.stdout, sys.stderr
    # both: ``reachset ... 2>&1 | true`` closes the pipe stderr writes to as well
    sys.stdout, sys.stderr = (_ClosedPipeSafe(s) if not isinstance(s, _ClosedPipeSafe) and hasattr(s, "fileno")
                              else s for s in streams)
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        parser = build_parser(only=command_in(argv))
        args = parser.parse_args(argv)
        if not getattr(args, "command", None):
            parser.print_help()
            return 2
        return exit_status(f"reachset {args.command}", lambda: args._run(args), debug=args.debug)
    finally:
        sys.stdout, sys.stderr = streams
        if restore is not None:
            try:
                restore()
            except BrokenPipeError:     # the reader is gone: nothing left to keep
                pass

if __name__ == "__main__":
    sys.exit(main())
