"""DDS self-test: two processes exchange ``PlantInput`` and a parameter is set across them.

``run_selftest`` starts :mod:`reachset_ros.nodes.talker` as a separate process, receives
its ``/plant_input`` over Fast DDS, sets the talker's ``acceleration`` parameter through its
``set_parameters`` service (rclpy's ``AsyncParameterClient``) and waits until the published
value follows.
"""
import os
import subprocess
import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from reachset_msgs.msg import PlantInput

from ..processes import use_dds_profiles


def run_selftest(timeout: float = 30.0, value: float = 1.5) -> dict:
    """Run the exchange; return counts and the observed values. Raises RuntimeError on failure."""
    use_dds_profiles()
    env = dict(os.environ)
    talker = subprocess.Popen([sys.executable, "-m", "reachset_ros.nodes.talker"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    own_context = not rclpy.ok()
    if own_context:
        rclpy.init()
    node = Node("selftest_listener")
    received = []
    node.create_subscription(PlantInput, "plant_input",
                             lambda m: received.append((tuple(m.name), tuple(m.acceleration))), 10)
    client = AsyncParameterClient(node, "/plant_input_talker")
    result = {"talker_pid": talker.pid}
    try:
        deadline = time.monotonic() + timeout
        while not received and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        if not received:
            raise RuntimeError("no /plant_input received from the talker process")
        result["first"] = {"name": list(received[0][0]), "acceleration": list(received[0][1])}
        if not client.wait_for_services(timeout_sec=max(0.1, deadline - time.monotonic())):
            raise RuntimeError("talker's set_parameters service not available")
        fut = client.set_parameters([Parameter("acceleration", Parameter.Type.DOUBLE, float(value))])
        rclpy.spin_until_future_complete(node, fut, timeout_sec=max(0.1, deadline - time.monotonic()))
        if not fut.done() or not fut.result().results[0].successful:
            raise RuntimeError("setting the talker's parameter failed")
        n_before = len(received)
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
            if any(all(a == value for a in acc) and acc for _, acc in received[n_before:]):
                break
        else:
            raise RuntimeError("the talker did not publish the new parameter value")
        result["after_set"] = {"acceleration": list(received[-1][1])}
        result["messages"] = len(received)
        return result
    finally:
        node.destroy_node()
        if own_context:
            rclpy.try_shutdown()
        talker.terminate()
        try:
            talker.wait(timeout=10)
        except subprocess.TimeoutExpired:
            talker.kill()
            talker.wait()
