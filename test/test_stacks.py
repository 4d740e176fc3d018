"""reachset_ros.stacks: SIGUSR1 prints every thread's stack and the process goes on; a node
process registers it before rclpy starts (so a hung node names its line in its log)."""
import signal
import subprocess
import sys
import time

PROGRAM = """
import sys, threading, time
from reachset_ros.stacks import dump_on_sigusr1
assert dump_on_sigusr1()
def waiting_in_a_thread():
    time.sleep(30)
def waiting_in_main():
    print("ready", flush=True)
    time.sleep(3.0)
    print("went on", flush=True)
threading.Thread(target=waiting_in_a_thread, daemon=True).start()
waiting_in_main()
"""


def test_sigusr1_prints_every_threads_stack_and_the_process_goes_on():
    p = subprocess.Popen([sys.executable, "-c", PROGRAM], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(0.2)
    p.send_signal(signal.SIGUSR1)
    out, err = p.communicate(timeout=300)   # bounds a hang only (make test OVERLAP=1 runs it at the idle priority)
    assert p.returncode == 0 and "went on" in out       # without the handler SIGUSR1 ends it (-10)
    assert "waiting_in_main" in err and "waiting_in_a_thread" in err


def test_node_processes_and_the_cli_register_it():
    from reachset_ros import cli
    from reachset_ros.nodes import common
    import inspect
    assert "dump_on_sigusr1()" in inspect.getsource(common.spin_node)
    assert "dump_on_sigusr1()" in inspect.getsource(cli.main)
