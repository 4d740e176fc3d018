"""Start and stop nodes as separate processes (``launch`` is not on PyPI).

Each node runs as ``python -m reachset_ros.nodes.<node>`` with a generated parameter file
(``--ros-args --params-file``), its output in a log file; :func:`stop` sends SIGINT, then
SIGTERM, then SIGKILL. On a Jazzy install the same nodes run with ``ros2 run``.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml


@dataclass
class NodeProcess:
    name: str
    proc: subprocess.Popen
    log: Path

    def alive(self) -> bool:
        return self.proc.poll() is None


def start(node: str, params: dict | None = None, workdir=".", env=None, node_name=None) -> NodeProcess:
    """Start ``reachset_ros.nodes.<node>`` with ``params`` (its ROS parameters)."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    node_name = node_name or node
    cmd = [sys.executable, "-m", f"reachset_ros.nodes.{node}", "--ros-args"]
    if node_name != node:
        cmd += ["-r", f"__node:={node_name}"]
    if params:
        pfile = workdir / f"{node_name}.params.yaml"
        pfile.write_text(yaml.safe_dump({node_name: {"ros__parameters": params}}))
        cmd += ["--params-file", str(pfile)]
    log = workdir / f"{node_name}.log"
    f = open(log, "w")
    proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=dict(env or os.environ),
                            start_new_session=True)
    f.close()
    return NodeProcess(node_name, proc, log)


def stop(nodes, timeout=10.0):
    """Stop processes gracefully (SIGINT lets the recorder close its bag)."""
    nodes = [n for n in nodes if n is not None]
    for n in nodes:
        if n.alive():
            n.proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout
    for n in nodes:
        try:
            n.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            n.proc.terminate()
            try:
                n.proc.wait(timeout=3)
            except subprocess.TimeoutExpired:
                n.proc.kill()
                n.proc.wait()
