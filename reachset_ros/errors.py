"""Errors the command line turns into one line and exit status 2."""


class ReachsetError(Exception):
    """A problem with the user's input (file, topic, joint, tick), reported in one line."""


class InfeasibleError(ReachsetError):
    """An optimisation problem has no solution; the message names the binding constraint."""


def first_line(error: BaseException) -> str:
    """The first line of ``error``'s message, or its type's name when it has none: what the
    command line prints after ``error:`` (one line, exit status 2)."""
    text = str(error)
    return text.splitlines()[0] if text else type(error).__name__
