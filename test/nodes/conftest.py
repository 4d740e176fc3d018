"""Fixtures of the node tests: the test's side of DDS (:class:`helpers.Bus`), one per module, and a
monitor_node process per test class."""
import pytest
import rclpy

from helpers import Bus, write_model
from reachset_ros import processes


@pytest.fixture(scope="module")
def bus():
    """An rclpy context and a :class:`helpers.Bus` for one test module (real DDS, this host only)."""
    rclpy.init()
    b = Bus()
    yield b
    b.close()
    rclpy.shutdown()


@pytest.fixture(scope="class")
def monitor(bus, tmp_path_factory):
    """A monitor_node process for one test class (the next class may start its own)."""
    d = tmp_path_factory.mktemp("monitor")
    path = write_model(d / "m.yaml")
    # reset_clean_ticks 0: the tests reset the latched stop as a set-up step, with no data
    # flowing; the rule that a reset waits until the stop's condition has cleared is tested
    # by TestResetNeedsClearedCondition
    proc = processes.start("monitor_node", {"model_file": str(path), "max_missing_ticks": 10000, "reset_clean_ticks": 0,
                                         "window_dir": str(d / "windows")}, d)
    try:
        assert bus.wait(lambda: bus.js.get_subscription_count() and bus.pi.get_subscription_count()
                        and bus.status_matched(), 30), proc.log.read_text()
        bus.clear()
        bus.make_ready()            # the start-up stop released by checked, conformant ticks
        yield proc, path, d
    finally:
        processes.stop([proc])


@pytest.fixture
def own_node(request):
    """A node in an rclpy context of its own, added to an executor of that context (as an
    operator's commander is), named after the test module; shut down afterwards."""
    from rclpy.executors import SingleThreadedExecutor
    context = rclpy.Context()
    rclpy.init(context=context)
    n = rclpy.create_node(request.module.__name__.rsplit(".", 1)[-1], context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(n)
    try:
        yield n
    finally:
        executor.shutdown()
        n.destroy_node()
        rclpy.shutdown(context=context)
