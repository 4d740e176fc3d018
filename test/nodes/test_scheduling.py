"""reachset_ros.nodes.scheduling: SCHED_FIFO for a node's process (``realtime_priority``),
checked on real node processes over real DDS, read back from the kernel."""
import os
import shutil
import subprocess
import sys
import time

import pytest

from reachset_ros import processes
from reachset_ros.errors import ReachsetError
from reachset_ros.nodes.scheduling import set_realtime, thread_policies


pytestmark = pytest.mark.dds   # real DDS participants / node processes


def test_priority_zero_changes_nothing_and_out_of_range_is_refused():
    before = thread_policies()
    assert set_realtime(0) == 0
    assert thread_policies() == before
    with pytest.raises(ReachsetError, match="outside SCHED_FIFO's 1..99"):
        set_realtime(100)
    assert thread_policies() == before


def _wait_log(proc, text, timeout=30.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.alive():
        if text in proc.log.read_text():
            return True
        time.sleep(0.1)
    return text in proc.log.read_text()


def _fifo_allowed():
    """Whether a child of this process may take SCHED_FIFO (CAP_SYS_NICE or an rtprio limit)."""
    r = subprocess.run([sys.executable, "-c", "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"],
                       capture_output=True, timeout=30)
    return r.returncode == 0


@pytest.mark.skipif(not _fifo_allowed(), reason="this process may not use SCHED_FIFO (no CAP_SYS_NICE)")
def test_every_thread_of_a_node_runs_at_the_priority_it_was_given(tmp_path):
    """The DDS threads too (Fast DDS starts several per participant): each thread of the
    process is SCHED_FIFO at the priority; a node without the parameter keeps the default."""
    procs = []
    try:
        rt = processes.start("observer_node", {"realtime_priority": 20, "allow_uncertified": True}, tmp_path, group=procs)
        plain = processes.start("observer_node", {"allow_uncertified": True}, tmp_path, node_name="plain_observer", group=procs)
        assert _wait_log(rt, "SCHED_FIFO priority 20"), rt.log.read_text()[-800:]
        assert _wait_log(plain, "up: subscribes"), plain.log.read_text()[-800:]
        pol = thread_policies(rt.proc.pid)
        assert len(pol) > 3, pol                                   # python + rcl + DDS threads
        assert set(pol.values()) == {(os.SCHED_FIFO, 20)}, pol
        assert {p for p, _ in thread_policies(plain.proc.pid).values()} == {os.SCHED_OTHER}
    finally:
        processes.stop(procs)


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="util-linux setpriv not installed")
def test_a_node_that_cannot_get_its_priority_does_not_run(tmp_path):
    """Without CAP_SYS_NICE (dropped with setpriv) and no rtprio limit the kernel refuses:
    the node exits 2 with one line naming the parameter and the cause."""
    pfile = tmp_path / "p.yaml"
    pfile.write_text("observer_node:\n  ros__parameters:\n    realtime_priority: 20\n    allow_uncertified: true\n")
    env = dict(os.environ, ROS_LOG_DIR=str(tmp_path / "log"))
    r = subprocess.run(["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice",
                        "prlimit", "--rtprio=0", "--",
                        sys.executable, "-m", "reachset_ros.nodes.observer_node", "--ros-args",
                        "--params-file", str(pfile)], capture_output=True, text=True, timeout=60, env=env)
    if r.returncode != 2 and "setpriv" in r.stderr:
        pytest.skip(f"setpriv cannot drop capabilities here: {r.stderr.strip()}")
    assert r.returncode == 2, (r.returncode, r.stdout[-500:], r.stderr[-500:])
    err = [ln for ln in r.stderr.splitlines() if "error" in ln]
    assert len(err) == 1 and "realtime_priority 20" in err[0] and "CAP_SYS_NICE" in err[0], r.stderr
