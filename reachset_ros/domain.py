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
