"""What a process that seems hung is doing: every thread's Python stack on SIGUSR1.

Every ``reachset`` command (:func:`reachset_ros.cli.main`), every node process
(:func:`reachset_ros.nodes.common.spin_node`) and the long benchmark runners call
:func:`dump_on_sigusr1` when they start. ``kill -USR1 PID`` then writes the stacks of all of
the process' threads to its standard error (a node's: its log file) and the process goes on.
A test that gives up on a process sends SIGUSR1 to it and to the nodes it started before it
kills them (``test/helpers.py``, ``run_or_explain``), so a hang names the line it hangs on.
"""
from __future__ import annotations

import sys


def dump_on_sigusr1():
    """Register :func:`faulthandler.dump_traceback` (all threads, to ``sys.__stderr__``) on
    SIGUSR1. Silently nothing where there is no real stderr (an embedding host) or no SIGUSR1.

    Returns
    -------
    bool
        Whether the handler is registered.
    """
    import faulthandler
    import signal
    try:
        faulthandler.register(signal.SIGUSR1, file=sys.__stderr__, all_threads=True)
    except (AttributeError, ValueError, OSError, RuntimeError):
        return False
    return True
