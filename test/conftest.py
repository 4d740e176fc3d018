"""Shared test set-up: DDS isolated per test session, the real recordings shipped in the package."""
import os
from pathlib import Path

import pytest

from reachset_ros.domain import pick_domain_id
from reachset_ros.processes import use_dds_profiles

# Real DDS, but only on this host and in a domain of our own, so that parallel test runs
# (and other ROS 2 programs on the machine) do not see each other.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# A domain nothing else on the machine uses (reachset_ros.domain, as `reachset up` and the demo
# pick theirs): a random one once met a leftover node of an earlier run publishing /plant_input
os.environ.setdefault("ROS_DOMAIN_ID", str(pick_domain_id()))


def _worker_domain(worker: str, inherited: int) -> int:
    """The domain of pytest-xdist worker ``gwN``: workers inherit the controller's
    ``ROS_DOMAIN_ID`` (D, which the controller itself never uses), so each takes the free domain
    at position ``D + N`` of the sorted free ids: two workers computing the list at the same
    moment get different positions, and one computing it after the other's participants exist
    no longer sees that domain as free."""
    from reachset_ros.domain import DOMAIN_RANGE, domains_in_use
    lo, hi = DOMAIN_RANGE
    free = sorted(set(range(lo, hi + 1)) - domains_in_use() - {inherited})
    return free[(inherited + int(worker.removeprefix("gw"))) % len(free)]


# pytest-xdist runs the DDS tests on several workers (make test): each in a domain of its own
if os.environ.get("PYTEST_XDIST_WORKER", "").startswith("gw"):
    os.environ["ROS_DOMAIN_ID"] = str(_worker_domain(os.environ["PYTEST_XDIST_WORKER"],
                                                     int(os.environ["ROS_DOMAIN_ID"])))
# and the suite's Fast DDS discovery profile, as every node and driver uses it, for the
# tests' own participants and every process they start (docs/reliability.md, start-up discovery)
use_dds_profiles()

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def lwa4p_dir():
    """The real LWA-4P recordings shipped in the package: a missing copy fails, never skips."""
    from reachset_ros.robot.lwa4p import recordings_dir
    return recordings_dir()


@pytest.fixture(scope="module")
def ros():
    """An rclpy context and a driver node for one test module (real DDS, this host only)."""
    import rclpy
    from rclpy.node import Node
    rclpy.init()
    node = Node("test_driver")
    yield node
    node.destroy_node()
    rclpy.shutdown()


@pytest.fixture(autouse=True)
def _dds_only_where_marked(request, monkeypatch):
    """A test that starts a DDS participant (``rclpy.init``) or a node process
    (:func:`reachset_ros.processes.start`) must carry the ``dds`` marker, so that
    ``make test-pure`` (``-m "not dds"``) runs none: an unmarked one fails, naming the rule."""
    if request.node.get_closest_marker("dds") is not None:
        yield
        return
    import rclpy

    import reachset_ros.processes as processes

    def refuse(*args, **kwargs):
        raise RuntimeError("this test starts DDS or a node process: mark it @pytest.mark.dds "
                           "(setup.cfg, markers)")
    monkeypatch.setattr(rclpy, "init", refuse)
    monkeypatch.setattr(processes, "start", refuse)
    yield
