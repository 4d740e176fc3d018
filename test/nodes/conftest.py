"""Fixtures of the node tests: the test's side of DDS (:class:`helpers.Bus`), one per module."""
import pytest
import rclpy

from helpers import Bus


@pytest.fixture(scope="module")
def bus():
    """An rclpy context and a :class:`helpers.Bus` for one test module (real DDS, this host only)."""
    rclpy.init()
    b = Bus()
    yield b
    b.close()
    rclpy.shutdown()
