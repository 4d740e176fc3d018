"""Progress of long commands on stderr, for a person at a terminal only (issue 36.6).

``identify``, ``check``, ``replay`` and ``synthesize`` run for tens of seconds to minutes; at a
terminal they say what they are doing and how long it has taken, one line rewritten in place
about once a second. Nothing is written when stderr is not a terminal (a pipe, a file, CI) or
with ``--json``, so scripts and logs see exactly what they saw before.

Syntax::

    with progress(args) as p:
        p.phase("reading 3 bags")
        ...
        p.phase("checking arm_1_joint (1 of 6)")
"""
from __future__ import annotations

import sys
import threading
import time

#: seconds between two rewrites of the progress line
EVERY_S = 1.0


def wanted(args, stream=None) -> bool:
    """Progress is shown iff ``stream`` (default stderr) is a terminal and ``--json`` is not given."""
    stream = sys.stderr if stream is None else stream
    if getattr(args, "json", False):
        return False
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):       # no isatty, or a closed stream
        return False


class Progress:
    """One progress line, rewritten in place by a daemon thread while a phase runs.

    Parameters
    ----------
    command : str
        The subcommand's name (the line starts ``reachset COMMAND:``).
    enabled : bool
        False: every method does nothing (the output is exactly the command's own).
    stream : text stream, optional
        Where the line goes (default: stderr at the time of the call).
    """

    def __init__(self, command, enabled, stream=None):
        self.command, self.enabled = command, bool(enabled)
        self.stream = sys.stderr if stream is None else stream
        self._text, self._since, self._t0 = None, 0.0, time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None

    def _write(self, end=""):
        line = f"reachset {self.command}: {self._text} ({time.monotonic() - self._since:.0f} s)"
        try:
            self.stream.write("\r\x1b[K" + line + end)
            self.stream.flush()
        except (OSError, ValueError):           # the terminal went away: stop showing progress
            self.enabled = False

    def _tick(self):
        while not self._stop.wait(EVERY_S):
            with self._lock:
                if self.enabled and self._text is not None:
                    self._write()

    def phase(self, text):
        """Start a phase: the previous one's line is kept (with its time), the new one shown."""
        if not self.enabled:
            return
        with self._lock:
            if self._text is not None:
                self._write("\n")
            self._text, self._since = text, time.monotonic()
            self._write()
        if self._thread is None:
            self._thread = threading.Thread(target=self._tick, name="progress", daemon=True)
            self._thread.start()

    def close(self):
        """End the last phase's line (the command's own output follows on a fresh line)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        with self._lock:
            if self.enabled and self._text is not None:
                self._write("\n")
            self._text = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def bag_count(bags) -> str:
    """``1 bag`` / ``3 bags``: what a phase reads."""
    n = len(bags)
    return f"{n} bag" + ("" if n == 1 else "s")


def progress(args, stream=None) -> Progress:
    """The :class:`Progress` of a command run with ``args`` (its ``command`` and ``json``):
    shown only at a terminal without ``--json`` (:func:`wanted`)."""
    return Progress(getattr(args, "command", None) or "", wanted(args, stream), stream)
