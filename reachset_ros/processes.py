"""The process supervisor: start and stop nodes as separate processes (ROS 2's ``launch`` is not
on PyPI; ``launch/reachset.launch.py`` is the same suite for ``ros2 launch`` on a Jazzy install).

Each node runs as ``python -m reachset_ros.nodes.<node>`` with a generated parameter file
(``--ros-args --params-file``), its output in a log file, in a session (and so a process
group) of its own: a Ctrl-C in the terminal reaches only the parent, which stops its
children in order. :func:`stop` sends SIGINT, then SIGTERM, then SIGKILL, and kills what
is left of each child's process group, so that nothing a node started outlives it. On a
Jazzy install the same nodes run with ``ros2 run`` (or ``launch/reachset.launch.py``).

:class:`StopRequest` turns SIGINT and SIGTERM into a flag that a parent with children
(``reachset up``, ``reachset demo``) checks at points of its choice, where it raises
:class:`Interrupted` or stops its children: a signal never cuts the bookkeeping of its
children halfway.

:func:`start_background` starts a helper process (the synthesis node's ``reachset
synthesize``) at low priority (nice +10), so that it cannot starve the control loop on a
small machine, in a session of its own, so that its whole tree can be signalled
(:func:`signal_group`), and with SIGTERM as its parent-death signal (Linux), so that it
does not outlive a parent that was killed.
"""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

#: The suite's Fast DDS profile file (participant discovery announcements; the file says why).
DDS_PROFILES = str(Path(__file__).resolve().parent / "data" / "fastdds_profiles.xml")
#: Environment variables through which Fast DDS (2.x, and 3.x) finds a user's profile file.
DDS_PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def use_dds_profiles(environ=None):
    """Point Fast DDS at :data:`DDS_PROFILES` unless a profile file is already named.

    Called before every ``rclpy.init`` of the suite (nodes, drivers, the tests' listener), so
    that a process that starts beside a running loop is discovered within about 50 ms, not
    at Fast DDS's next 3-s announcement (docs/reliability.md, "Start-up discovery"). A
    profile file the user names in ``FASTRTPS_DEFAULT_PROFILES_FILE`` or
    ``FASTDDS_DEFAULT_PROFILES_FILE`` is left alone (then the user's file decides), and
    another RMW ignores the variable. Child processes inherit it.

    Returns
    -------
    bool
        True when this call set the variable.
    """
    environ = os.environ if environ is None else environ
    if any(environ.get(v) for v in DDS_PROFILE_VARS):
        return False
    environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = DDS_PROFILES
    return True


#: niceness added to a background helper (:func:`start_background`)
BACKGROUND_NICE = 10
_PR_SET_PDEATHSIG = 1
try:
    _prctl = ctypes.CDLL(None, use_errno=True).prctl
except (OSError, AttributeError):      # not Linux: no parent-death signal
    _prctl = None


@dataclass
class NodeProcess:
    """A node started by :func:`start`: its name, process and log file.

    The process leads its own process group (``start_new_session``). :meth:`alive` and
    :meth:`exit_status` do not reap it, so its process id (the group's id) stays reserved
    until :func:`stop` has killed what is left of the group.
    """
    name: str
    proc: subprocess.Popen
    log: Path

    def _waitid(self):
        """The child's exit as ``os.waitid_result`` without reaping it; None while it runs."""
        if self.proc.returncode is not None:
            return None
        try:
            return os.waitid(os.P_PID, self.proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:      # reaped elsewhere (Popen.poll): returncode tells
            self.proc.poll()
            return None

    def alive(self) -> bool:
        """True while the process runs (an exited, not yet reaped process is not alive)."""
        if self.proc.returncode is not None:
            return False
        return self._waitid() is None and self.proc.returncode is None

    def exit_status(self) -> int | None:
        """The exit status as ``Popen.returncode`` gives it (``-N``: killed by signal N),
        None while the process runs; does not reap it."""
        if self.proc.returncode is not None:
            return self.proc.returncode
        info = self._waitid()
        if info is None:
            return self.proc.returncode
        return info.si_status if info.si_code == os.CLD_EXITED else -info.si_status

    def last_log_line(self) -> str:
        """The last non-empty line of the log (empty when there is none)."""
        try:
            lines = [ln.strip() for ln in self.log.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return ""
        return lines[-1] if lines else ""


def start(node: str, params: dict | None = None, workdir=".", env=None, node_name=None,
          group: list | None = None, remap: dict | None = None) -> NodeProcess:
    """Start ``reachset_ros.nodes.<node>`` with ``params`` (its ROS parameters).

    Parameters
    ----------
    node : str
        Module under :mod:`reachset_ros.nodes`.
    params : dict, optional
        ROS parameters, written to ``WORKDIR/<node_name>.params.yaml``.
    workdir : str or Path
        Where the parameter file and the log ``<node_name>.log`` go (created).
    env : dict, optional
        The child's environment (default: this process').
    node_name : str, optional
        Node name (``-r __node:=``), default ``node``.
    group : list, optional
        The started :class:`NodeProcess` is appended to it before ``start`` returns, so a
        caller that stops ``group`` on an exception cannot miss it.
    remap : dict, optional
        Topic remappings ``{from: to}`` (``-r from:=to``), e.g. a reader fed by a relay.

    Returns
    -------
    NodeProcess
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    node_name = node_name or node
    cmd = [sys.executable, "-m", f"reachset_ros.nodes.{node}", "--ros-args"]
    if node_name != node:
        cmd += ["-r", f"__node:={node_name}"]
    for a, b in (remap or {}).items():
        cmd += ["-r", f"{a}:={b}"]
    if params:
        pfile = workdir / f"{node_name}.params.yaml"
        pfile.write_text(yaml.safe_dump({node_name: {"ros__parameters": params}}))
        cmd += ["--params-file", str(pfile)]
    log = workdir / f"{node_name}.log"
    with open(log, "w") as f:
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=dict(env or os.environ),
                                start_new_session=True)
    n = NodeProcess(node_name, proc, log)
    if group is not None:
        group.append(n)
    return n


def _kill_group(n: NodeProcess, sig):
    """Send ``sig`` to the process group ``n`` leads (its own session); ignore a group that is gone."""
    try:
        os.killpg(n.proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _wait_exited(n: NodeProcess, timeout: float) -> bool:
    """Wait up to ``timeout`` s for ``n`` to exit, without reaping it; True when it has."""
    end = time.monotonic() + timeout
    while n.alive():
        if time.monotonic() >= end:
            return False
        time.sleep(0.02)
    return True


def stop(nodes, timeout=10.0):
    """Stop processes gracefully (SIGINT lets the recorder close its bag), then their groups.

    SIGINT to every process; after ``timeout`` s (for all together) SIGTERM, 3 s later
    SIGKILL, each to the process' whole group. Once a process has exited (before it is
    reaped, so its group id cannot have been reused) whatever is left in its group gets
    SIGKILL. Finally every process is reaped.
    """
    nodes = [n for n in nodes if n is not None]
    for n in nodes:
        if n.alive():
            n.proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout
    for n in nodes:
        if not _wait_exited(n, max(0.1, deadline - time.monotonic())):
            _kill_group(n, signal.SIGTERM)
            if not _wait_exited(n, 3.0):
                _kill_group(n, signal.SIGKILL)
        if n.proc.returncode is None:
            _kill_group(n, signal.SIGKILL)   # what the node left behind in its group
        n.proc.wait()


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM asked this process to stop (``signum``); a KeyboardInterrupt, so
    code that handles Ctrl-C handles SIGTERM the same way."""

    def __init__(self, signum):
        self.signum = int(signum)
        super().__init__(signal.Signals(self.signum).name)


class StopRequest:
    """SIGINT and SIGTERM recorded, while installed (``with StopRequest() as stop:``).

    The handlers only record the first signal (``signum``); the owner looks at it
    (``if stop:``) or calls :meth:`check` where stopping is safe. The previous handlers are
    restored on exit. Installed only in the main thread (Python runs signal handlers there).
    """

    def __init__(self):
        self.signum = None
        self._previous = {}

    def _handler(self, signum, frame):
        if self.signum is None:
            self.signum = signum

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}
        return False

    def __bool__(self):
        return self.signum is not None

    def check(self):
        """Raise :class:`Interrupted` if a signal has come."""
        if self.signum is not None:
            raise Interrupted(self.signum)


def start_background(cmd, **popen_kwargs) -> subprocess.Popen:
    """Start ``cmd`` at low priority, in a session of its own, ended with its parent.

    Parameters
    ----------
    cmd : list of str
        The command.
    **popen_kwargs
        Passed to ``subprocess.Popen`` (``stdout``, ``stderr``, ``text``, ...).

    Returns
    -------
    subprocess.Popen
        The process, leader of its own process group (:func:`signal_group`).

    Notes
    -----
    In the child, before ``exec``: ``os.nice(BACKGROUND_NICE)`` and, on Linux,
    ``prctl(PR_SET_PDEATHSIG, SIGTERM)`` (the signal comes when the thread that started it
    ends: start it from the thread that lives as long as the process, as the nodes' main
    thread does).
    """
    parent = os.getpid()

    def before_exec():
        os.nice(BACKGROUND_NICE)
        if _prctl is not None:
            _prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
            if os.getppid() != parent:      # the parent died before prctl
                os._exit(1)

    return subprocess.Popen(cmd, start_new_session=True, preexec_fn=before_exec, **popen_kwargs)


def signal_group(proc: subprocess.Popen, sig) -> bool:
    """Send ``sig`` to the process group ``proc`` leads, unless it has been reaped (its id
    may then belong to another process); True when sent. Safe in a signal handler."""
    if proc.returncode is not None:
        return False
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        return False
    return True
