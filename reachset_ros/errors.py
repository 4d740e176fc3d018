"""Errors the command line turns into one line and exit status 2."""
import signal
import sys


class ReachsetError(Exception):
    """A problem with the user's input (file, topic, joint, tick), reported in one line."""


class InfeasibleError(ReachsetError):
    """An optimisation problem has no solution; the message names the binding constraint."""


def first_line(error: BaseException) -> str:
    """The first line of ``error``'s message, or its type's name when it has none: what the
    command line prints after ``error:`` (one line, exit status 2)."""
    text = str(error)
    return text.splitlines()[0] if text else type(error).__name__


def exit_status(prog, run, *, debug=False):
    """``run()``'s exit status as the command line reports it: 0 (or what ``run`` returns), 2 with
    ``PROG: error: MESSAGE`` (:func:`first_line`) on stderr for a :class:`ReachsetError` (raised
    with ``debug``), 128 + the signal number for an interrupt (Ctrl-C, or
    ``processes.Interrupted`` after SIGINT/SIGTERM stopped the children)."""
    try:
        return int(run() or 0)
    except ReachsetError as e:
        if debug:
            raise
        print(f"{prog}: error: {first_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        return 128 + getattr(e, "signum", signal.SIGINT)
