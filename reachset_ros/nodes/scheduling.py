"""Real-time scheduling of a node's process (the ``realtime_priority`` parameter).

The stop path (simulator or drive -> observer -> controller -> monitor -> controller) runs
in four processes at 250 Hz. At the default (``SCHED_OTHER``) policy they share the CPU
with every other process; on the 2-core machine with a busy process per core (the fault
campaign's burners) a stop reached the controller up to 108 ms after its stamp, at priority
50 at most 24 ms (docs/reliability.md, eighth long campaign; docs/campaign-history.md,
seventh). A node started with ``realtime_priority`` > 0 puts every thread of
its process, the DDS threads included, under ``SCHED_FIFO`` at that priority, as
ros2_control does for its control loop: it then preempts every normal process.

Assumptions and risks (docs/nodes.md "Real-time scheduling"):

- Linux only; needs ``CAP_SYS_NICE`` (root, or an ``rtprio`` limit in
  ``/etc/security/limits.conf``). A node asked for a priority it cannot get does not run
  (exit status 2, one line naming the cause): a deployment that relies on it must know.
- A ``SCHED_FIFO`` thread that never blocks would starve the machine; the kernel's
  real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 950000 of 1000000 by
  default) still leaves normal processes 5 % of each core.
- Threads a process creates later inherit the policy of the thread that creates them;
  those already running are set one by one from ``/proc/self/task``.
"""
import os

from ..errors import ReachsetError

#: the parameter a node declares to offer this (``desc`` range 0..99; 0 = unchanged)
PARAMETER = "realtime_priority"
DESCRIPTION = ("SCHED_FIFO priority of every thread of this process (1-99; 0: the default policy). "
               "Needs CAP_SYS_NICE: a priority the process cannot get is an error (exit 2)")


def process_threads(pid="self"):
    """The thread ids of a process (``/proc/<pid>/task``), sorted."""
    return sorted(int(t) for t in os.listdir(f"/proc/{pid}/task"))


def set_realtime(priority: int, pid="self") -> int:
    """Put every thread of the process under ``SCHED_FIFO`` at ``priority``.

    Parameters
    ----------
    priority : int
        1..99 (``os.sched_get_priority_min/max(SCHED_FIFO)``); 0 does nothing.
    pid : "self" or int
        The process (its threads from ``/proc/<pid>/task``).

    Returns
    -------
    int
        The number of threads set (0 for priority 0).

    Raises
    ------
    ReachsetError
        The priority is out of range, or the kernel refused (no ``CAP_SYS_NICE``): the
        message names the cause. Threads already set stay set; the caller exits.
    """
    priority = int(priority)
    if priority == 0:
        return 0
    lo, hi = os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)
    if not lo <= priority <= hi:
        raise ReachsetError(f"{PARAMETER} {priority} is outside SCHED_FIFO's {lo}..{hi}")
    param = os.sched_param(priority)
    n = 0
    for tid in process_threads(pid):
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
        except ProcessLookupError:      # the thread ended meanwhile
            continue
        except PermissionError as e:
            raise ReachsetError(f"{PARAMETER} {priority}: the kernel refused SCHED_FIFO ({e.strerror}); "
                                "the process needs CAP_SYS_NICE or an rtprio limit") from None
        n += 1
    return n


def thread_policies(pid="self"):
    """``{tid: (policy, priority)}`` of every thread of a process, read back from the kernel."""
    out = {}
    for tid in process_threads(pid):
        try:
            out[tid] = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
        except ProcessLookupError:
            continue
    return out
