"""Helpers of the pure tests that run the command line as a user does (no ROS import).

* :func:`run_cli` - ``python -m reachset_ros.cli ARGS`` in a real subprocess.
"""
import subprocess
import sys


def run_cli(*args):
    """``reachset ARGS`` as a subprocess; the :class:`subprocess.CompletedProcess` (text)."""
    return subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300)
