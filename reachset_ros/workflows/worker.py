"""Run a workflow function in a worker process at low priority, returning its typed result.

The demo and the fault campaign identify while the suite runs on the same cores: the
identification must not starve the control loop, so it runs in a child process at nice +10,
in a process group of its own (as the synthesis node's worker), and what comes back is the
workflow's own frozen result object (pickled), not a command line's text.

The child is started with the ``spawn`` method: the caller holds an rclpy context and DDS
threads, which a forked child must not inherit.
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

__all__ = ["LOW_PRIORITY_NICE", "run_in_worker"]

#: the worker's niceness increment (the synthesis node's child runs at the same)
LOW_PRIORITY_NICE = 10


def _lower_priority():
    os.setpgid(0, 0)
    os.nice(LOW_PRIORITY_NICE)


def run_in_worker(fn, /, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a fresh low-priority process; its return value or its exception.

    Parameters
    ----------
    fn : callable
        A module-level function (picklable by reference), e.g.
        :func:`reachset_ros.workflows.identify.identify`.
    *args, **kwargs
        Picklable arguments.

    Returns
    -------
    object
        What ``fn`` returned (unpickled in the caller).

    Raises
    ------
    Exception
        What ``fn`` raised (a :class:`~reachset_ros.errors.ReachsetError` keeps its one line).
    """
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_lower_priority) as pool:
        return pool.submit(fn, *args, **kwargs).result()
