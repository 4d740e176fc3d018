"""Every console script answers ``--help`` without starting anything; every node logs a
one-line start summary; start-up-only parameters are read-only (issue 19.6)."""
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy

from helpers import write_model
from reachset_ros import processes
from reachset_ros.nodes.common import set_remote_parameters


pytestmark = pytest.mark.dds   # real DDS participants / node processes

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = dict(re.findall(r'"(\w+)": "(reachset_ros\.nodes\.\w+):main"', (REPO / "setup.py").read_text()))


def test_setup_lists_the_node_scripts():
    assert {"sim_node", "reference_node", "observer_node", "controller_node", "monitor_node", "recorder_node",
            "synthesis_node"} <= set(SCRIPTS)


@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_help_prints_usage_and_starts_nothing(script):
    """Before: ``sim_node --help`` started a simulation (rclpy ignores unknown arguments)."""
    for flag in ("--help", "-h"):
        p = subprocess.run([sys.executable, "-m", SCRIPTS[script], flag], capture_output=True, text=True, timeout=60)
        assert p.returncode == 0, p.stderr
        assert p.stdout.startswith("usage: ")
        assert "--ros-args" in p.stdout and "docs/nodes.md" in p.stdout
        assert "[INFO]" not in p.stdout + p.stderr          # no node came up, nothing logged


def test_start_summary_and_read_only_start_up_parameters(tmp_path):
    procs = [processes.start("sim_node", {"seed": 5}, tmp_path),
             processes.start("observer_node", {"allow_uncertified": True}, tmp_path),
             processes.start("monitor_node", {"window_dir": str(tmp_path / "w"),
                                              "model_file": str(write_model(tmp_path / "m.yaml"))}, tmp_path)]
    rclpy.init()
    node = rclpy.create_node("node_cli_test")
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not all("up: subscribes" in p.log.read_text() for p in procs):
            time.sleep(0.2)
        for p in procs:
            line = next(l for l in p.log.read_text().splitlines() if "up: subscribes" in l)
            assert "publishes" in line, line
        sim_line = next(l for l in procs[0].log.read_text().splitlines() if "up: subscribes" in l)
        assert "/effort_commands" in sim_line and "/joint_states" in sim_line and "Hz" in sim_line
        mon_line = next(l for l in procs[2].log.read_text().splitlines() if "up: subscribes" in l)
        assert "window_dir=" + str(tmp_path / "w") in mon_line
        for target, name, value in (("sim_node", "seed", 6), ("sim_node", "dt", 0.002),
                                    ("observer_node", "joints", ["arm_1_joint"]), ("monitor_node", "dt", 0.002)):
            ok, why = set_remote_parameters(node, target, {name: value})
            assert not ok and ("read-only" in why.lower() or "read only" in why.lower()), (target, name, why)
        ok, why = set_remote_parameters(node, "sim_node", {"fault_magnitude": 2.0})   # not all are read-only
        assert ok, why
        assert all(p.alive() for p in procs)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        processes.stop(procs)
