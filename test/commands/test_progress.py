"""Progress of long commands on stderr at a terminal, quiet otherwise (issue 36.6;
``reachset_ros/commands/_progress.py``). The terminal is a real pseudo-terminal (``pty``)."""
import io
import json
import os
import pty
import subprocess
import sys
import threading

import pytest

from reachset_ros.commands._progress import Progress, bag_count, progress, wanted
from reachset_ros.sim import recordings as sr


class _Tty(io.StringIO):
    def isatty(self):
        return True


class _Args:
    def __init__(self, json=False):
        self.json, self.command = json, "check"


def test_shown_only_at_a_terminal_without_json():
    assert wanted(_Args(), _Tty()) and not wanted(_Args(json=True), _Tty())
    assert not wanted(_Args(), io.StringIO())
    out = _Tty()
    with progress(_Args(), out) as p:
        p.phase(f"reading {bag_count([1, 2])}")
        p.phase("checking a (1 of 1)")
    text = out.getvalue()
    assert "reachset check: reading 2 bags (0 s)\n" in text and text.endswith("checking a (1 of 1) (0 s)\n")
    quiet = io.StringIO()
    with Progress("check", False, quiet) as p:
        p.phase("x")
    assert quiet.getvalue() == ""


def _run_with_stderr(argv, tty):
    """``argv``'s exit status, stdout and stderr, stderr a pseudo-terminal when ``tty``."""
    if not tty:
        p = subprocess.run(argv, capture_output=True, text=True, timeout=300)
        return p.returncode, p.stdout, p.stderr
    master, slave = pty.openpty()
    chunks = []

    def drain():
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:          # EIO: the child closed the terminal
                return
            if not data:
                return
            chunks.append(data)
    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=slave, text=True)
        os.close(slave)
        out = p.communicate(timeout=300)[0]
        reader.join(timeout=30)
    finally:
        os.close(master)
    return p.returncode, out, b"".join(chunks).decode(errors="replace")


@pytest.fixture(scope="module")
def bag_and_model(tmp_path_factory):
    d = tmp_path_factory.mktemp("progress")
    bag, model = d / "bag", d / "m.yaml"
    sr.write_recordings(bag, sr.simulate_recordings(("arm_1_joint",), 1500, seed=2))
    code, _, err = _run_with_stderr([sys.executable, "-m", "reachset_ros.cli", "identify", str(bag), "--horizon",
                                     "5", "--out", str(model)], tty=True)
    assert code == 0, err
    assert "reachset identify: reading 1 bag and identifying the sets" in err, err
    return bag, model


@pytest.mark.slow
def test_check_shows_progress_at_a_terminal_only(bag_and_model):
    """The old check said nothing for the minute a large bag takes; now at a terminal it says
    which phase runs, and stays exactly as quiet as before in a pipe or with --json."""
    bag, model = bag_and_model
    argv = [sys.executable, "-m", "reachset_ros.cli", "check", str(bag), "--model", str(model)]
    code, out, err = _run_with_stderr(argv, tty=True)
    assert code == 0 and out.startswith("conformant"), err
    assert "reachset check: reading 1 bag" in err and "checking arm_1_joint (1 of 1, " in err, err
    assert "reachset check" not in out                                  # stdout is the command's own
    code, out, err = _run_with_stderr(argv + ["--json"], tty=True)
    assert code == 0 and json.loads(out)["conformant"] and "reachset check" not in err, err
    code, out, err = _run_with_stderr(argv, tty=False)
    assert code == 0 and err == "", err
    code, out, err = _run_with_stderr([sys.executable, "-m", "reachset_ros.cli", "replay", str(bag), "--model",
                                       str(model)], tty=True)
    assert code == 0 and "reachset replay: replaying 1 joint tick by tick" in err, err
