"""reachset_ros.cli: the exit status survives a reader that closes the pipe early."""
import os
import subprocess
import sys

import pytest


@pytest.mark.parametrize("args, status", [(["analyze"], 0), (["analyze", "--json"], 0),
                                          (["analyze", "--omega", "-1"], 2)])
def test_a_closed_pipe_keeps_the_commands_exit_status(args, status):
    """``reachset analyze | true``: the reader is gone before the command writes. HEAD ended with a
    BrokenPipeError traceback and exit status 1 whatever the command's verdict."""
    read, write = os.pipe()
    os.close(read)                                   # the reader has gone before anything is written
    try:
        p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *args], stdout=write,
                           stderr=subprocess.PIPE, text=True, timeout=300)
    finally:
        os.close(write)
    assert p.returncode == status, p.stderr
    assert "Traceback" not in p.stderr and "BrokenPipe" not in p.stderr
