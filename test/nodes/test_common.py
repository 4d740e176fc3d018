"""reachset_ros.nodes.common: the nodes' shared helpers that talk to DDS (spinning for a future,
calling a parameter service). Real rclpy in this process; the service called has no server,
so every call below must end by its own timeout, never hang."""
import threading

import pytest
import rclpy
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future

from reachset_ros.nodes.common import call_parameter_service, spin_until_complete

pytestmark = pytest.mark.dds   # a real DDS participant

#: bound on a call that must return at once (only catches a hang; nothing is timed)
HANG = 60.0


@pytest.fixture
def node(own_node):
    return own_node


def _returns(fn):
    """Whether ``fn()`` returned within :data:`HANG` s (run on a thread; the fixture's shutdown
    ends a thread that hangs in a spin)."""
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("value", fn()), daemon=True)
    t.start()
    t.join(HANG)
    return (not t.is_alive()), out.get("value")


@pytest.mark.parametrize("timeout", [-0.001, -5.0, 0.0])
def test_a_timeout_at_or_below_zero_spins_once_and_returns(node, timeout):
    # rclpy's spin_until_future_complete waits forever on a negative timeout; a caller's
    # remaining time goes negative when it is preempted at its deadline (a CI hang, issue ci)
    done, _ = _returns(lambda: spin_until_complete(node, Future(), timeout))
    assert done, f"spin_until_complete(..., {timeout}) did not return"


def test_a_parameter_call_nobody_answers_ends_with_none_by_its_timeout(node):
    client = AsyncParameterClient(node, "/no_such_node_for_test_common")
    done, value = _returns(lambda: call_parameter_service(node, lambda: client.get_parameters(["x"]), 0.3))
    assert done and value is None


def test_a_parameter_call_a_node_answers_returns_its_answer(node):
    server = rclpy.create_node("test_common_server", context=node.context)
    server.declare_parameter("x", 2.5)
    node.executor.add_node(server)        # served by the executor the call spins
    try:
        client = AsyncParameterClient(node, "/test_common_server")
        assert client.wait_for_services(timeout_sec=HANG)
        done, value = _returns(lambda: call_parameter_service(node, lambda: client.get_parameters(["x"]), HANG))
        assert done and [v.double_value for v in value.values] == [2.5]
    finally:
        node.executor.remove_node(server)
        server.destroy_node()
