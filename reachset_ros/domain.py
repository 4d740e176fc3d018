"""A fresh DDS domain (``ROS_DOMAIN_ID``) for a suite of nodes: ``reachset up`` and ``reachset demo``.

Two suites in one DDS domain see each other's topics: a second ``make demo`` on the machine
made the first fail with "stamp went backwards" (issue 19). So each run picks a domain that
nothing else on the machine uses, and its nodes inherit it through the environment.

The rule (:func:`pick_domain_id`): a domain id in ``1..101`` (0 is everybody's default;
above 101 the RTPS ports of a domain reach the Linux ephemeral port range, 32768 and up,
ROS 2 docs "The ROS_DOMAIN_ID") that is not *in use*, chosen at random among those free,
so that two runs started at the same moment are unlikely to pick the same one. A domain
is in use (:func:`domains_in_use`) when

* a process of this user has ``ROS_DOMAIN_ID=N`` in its environment (``/proc/PID/environ``,
  the environment it was started with; other users' environments are not readable), or
* any process on the machine (any user) has a UDP socket bound in the domain's RTPS port
  range ``7400 + 250 N .. 7400 + 250 N + 249`` (``/proc/net/udp``, ``/proc/net/udp6``): the
  well-known ports of the DDS specification (port base 7400, domain gain 250), which Fast
  DDS and Cyclone DDS use for discovery and user traffic of every participant in domain N.

What the rule cannot see: a process that set ``ROS_DOMAIN_ID`` after it started and has no
DDS participant yet, and a run that picks its domain at the very same moment (the random
choice makes that unlikely, not impossible).
"""
from __future__ import annotations

import os
import random
from pathlib import Path

from .errors import ReachsetError

#: the domain ids a fresh domain is picked from (both ends included)
DOMAIN_RANGE = (1, 101)
#: RTPS well-known ports (DDS-RTPS 2.x, 9.6.1.1): port base PB and domain gain DG
PORT_BASE, DOMAIN_GAIN = 7400, 250
#: the largest domain id whose ports fit below 65536
MAX_DOMAIN_ID = 232


def domain_of_port(port: int) -> int | None:
    """The DDS domain whose RTPS port range holds UDP ``port``, or None."""
    d = (port - PORT_BASE) // DOMAIN_GAIN
    return d if port >= PORT_BASE and d <= MAX_DOMAIN_ID else None


def _environ_domains(proc: Path, uid: int) -> set[int]:
    """``ROS_DOMAIN_ID`` values in the start-up environment of ``uid``'s processes."""
    out = set()
    for d in proc.iterdir():
        if not d.name.isdigit():
            continue
        try:
            if d.stat().st_uid != uid:
                continue
            env = (d / "environ").read_bytes()
        except OSError:               # gone meanwhile, or not readable
            continue
        for entry in env.split(b"\0"):
            if entry.startswith(b"ROS_DOMAIN_ID="):
                value = entry[len(b"ROS_DOMAIN_ID="):].strip()
                if value.isdigit():
                    out.add(int(value))
    return out


def _socket_domains(proc: Path) -> set[int]:
    """Domains whose RTPS port range has a bound UDP socket (``/proc/net/udp``, ``udp6``)."""
    out = set()
    for name in ("udp", "udp6"):
        try:
            lines = (proc / "net" / name).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            try:
                port = int(fields[1].rsplit(":", 1)[1], 16)
            except (IndexError, ValueError):
                continue
            d = domain_of_port(port)
            if d is not None:
                out.add(d)
    return out


def domains_in_use(proc="/proc", uid=None) -> set[int]:
    """The DDS domain ids in use on this machine, by the rule of the module docstring.

    Parameters
    ----------
    proc : str or Path
        The proc file system (a directory of the same layout in tests).
    uid : int, optional
        Whose processes' environments are read (default: this process' user).

    Returns
    -------
    set of int
    """
    proc = Path(proc)
    return _environ_domains(proc, os.getuid() if uid is None else uid) | _socket_domains(proc)


def pick_domain_id(proc="/proc", rng=None) -> int:
    """A fresh ``ROS_DOMAIN_ID``: random among ``DOMAIN_RANGE`` minus :func:`domains_in_use`.

    Parameters
    ----------
    proc : str or Path
        The proc file system.
    rng : random.Random, optional
        Source of the choice (default: ``random.SystemRandom``).

    Returns
    -------
    int

    Raises
    ------
    ReachsetError
        When every domain id of the range is in use.
    """
    used = domains_in_use(proc)
    lo, hi = DOMAIN_RANGE
    free = [d for d in range(lo, hi + 1) if d not in used]
    if not free:
        raise ReachsetError(f"no free ROS_DOMAIN_ID in {lo}..{hi}: every one is used by a process on this machine")
    return (rng or random.SystemRandom()).choice(free)


# ---------------------------------------------------------------- a running suite's domain
#: the file ``reachset up`` writes in its working directory: its domain, its pid, its nodes
STATE_FILE = "up.json"


def write_suite_state(workdir, *, domain_id: int, pid: int, nodes=()) -> Path:
    """Write ``WORKDIR/up.json`` (through a temporary file and a rename): the domain of a
    ``reachset up`` run, its process id and the nodes it started (``[{name, pid, log}]``),
    so that the operator commands (``reachset status --workdir DIR``) find the suite."""
    import json
    import tempfile
    path = Path(workdir) / STATE_FILE
    doc = {"ros_domain_id": int(domain_id), "pid": int(pid), "workdir": str(workdir), "nodes": list(nodes)}
    fd, tmp = tempfile.mkstemp(prefix=STATE_FILE + ".", suffix=".partial", dir=path.parent)
    with os.fdopen(fd, "w") as f:
        json.dump(doc, f, sort_keys=True)
    os.replace(tmp, path)
    return path


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def suite_domain(*, domain=None, workdir=None, environ=None) -> tuple[int, str, dict]:
    """The ``ROS_DOMAIN_ID`` of a running suite, for the operator commands.

    In this order: ``domain`` (``--domain``); ``WORKDIR/up.json`` of a ``reachset up`` that
    is still running (``--workdir``); ``ROS_DOMAIN_ID`` of ``environ``; else 0, ROS 2's default.

    Returns
    -------
    domain_id : int
    source : str
        Where it came from, for the output (``--domain``, the file, ``ROS_DOMAIN_ID``, ``default``).
    state : dict
        The ``up.json`` document (empty without ``workdir``).

    Raises
    ------
    ReachsetError
        A domain id outside ``0..MAX_DOMAIN_ID``; a ``workdir`` without ``up.json`` (not a
        working directory of ``reachset up``), with an unreadable one, or whose ``reachset up``
        is no longer running; a ``ROS_DOMAIN_ID`` that is not a number.
    """
    import json
    environ = os.environ if environ is None else environ

    def checked(value, what):
        try:
            d = int(str(value).strip())
        except ValueError:
            raise ReachsetError(f"{what} {value!r} is not a domain id (0..{MAX_DOMAIN_ID})") from None
        if not 0 <= d <= MAX_DOMAIN_ID:
            raise ReachsetError(f"{what} {d} is outside 0..{MAX_DOMAIN_ID}")
        return d

    if domain is not None:
        return checked(domain, "--domain"), "--domain", {}
    if workdir is not None:
        path = Path(workdir) / STATE_FILE
        try:
            state = json.loads(path.read_text())
            d = checked(state["ros_domain_id"], f"{path}: ros_domain_id")
        except FileNotFoundError:
            raise ReachsetError(f"{path} not found: {workdir} is not the --workdir of a `reachset up` "
                                "(or of one older than this command)") from None
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ReachsetError(f"{path}: unreadable ({type(e).__name__}: {e})") from None
        if not _alive(int(state.get("pid", -1))):
            raise ReachsetError(f"{path}: the `reachset up` of that directory (pid {state.get('pid')}) is not "
                                "running any more")
        return d, str(path), state
    if environ.get("ROS_DOMAIN_ID", "").strip():
        return checked(environ["ROS_DOMAIN_ID"], "ROS_DOMAIN_ID"), "ROS_DOMAIN_ID", {}
    return 0, "default", {}
