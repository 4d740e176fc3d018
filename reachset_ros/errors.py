"""Errors the command line turns into one line and exit status 2."""


class ReachsetError(Exception):
    """A problem with the user's input (file, topic, joint, tick), reported in one line."""


class InfeasibleError(ReachsetError):
    """An optimisation problem has no solution; the message names the binding constraint."""
