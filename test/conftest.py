"""Shared test set-up: DDS isolated per test session, the real recordings shipped in the package."""
import os
import random
from pathlib import Path

import pytest

from reachset_ros.processes import use_dds_profiles

# Real DDS, but only on this host and in a domain of our own, so that parallel test runs
# (and other ROS 2 programs on the machine) do not see each other.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
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
