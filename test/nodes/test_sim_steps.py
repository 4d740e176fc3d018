"""sim_node's fixed step counts (``measurement_limit``, issue 35.4): a held simulation publishes
exactly the measurements it is let, whatever the machine's load, so that a phase of n steps is
the same n steps in every run."""
import pytest

from helpers import spin_until
from reachset_ros import processes
from reachset_ros.nodes.common import TICK_QOS, get_remote_parameters, set_remote_parameters, stamp_ns
from sensor_msgs.msg import JointState

pytestmark = pytest.mark.dds


def test_a_held_simulation_publishes_exactly_the_measurements_it_is_let(ros, tmp_path):
    """Before: sim_node had no ``measurement_limit`` (the parameter request was refused) and
    stepped from its start on, so a phase's length in steps depended on when the workflow's
    wall-clock spin ended. Now nothing is published before the limit is raised, then exactly
    the initial state and the steps let, with consecutive stamps from ``start_stamp_ns``, and
    nothing more while held (no controller runs here: each step holds the previous command
    after the 10 ms lockstep timeout)."""
    got = []
    sub = ros.create_subscription(JointState, "joint_states", got.append, TICK_QOS)
    sim = processes.start("sim_node", {"realistic": False, "measurement_limit": 0, "lockstep_timeout": 0.01,
                                       "drive_watchdog_steps": 0}, tmp_path)
    try:
        assert spin_until(ros, lambda: sub.get_publisher_count() > 0, 60), sim.log.read_text()[-800:]
        values, why = get_remote_parameters(ros, "sim_node", ["start_stamp_ns", "dt", "measurement_limit"])
        assert values is not None, why
        start, dt_ns = int(values["start_stamp_ns"]), int(round(values["dt"] * 1e9))
        spin_until(ros, lambda: False, 1.0)
        assert got == [], "a simulation held at 0 published before it was let"
        for limit in (10, 25):
            ok, why = set_remote_parameters(ros, "sim_node", {"measurement_limit": limit})
            assert ok, why
            assert spin_until(ros, lambda: len(got) >= limit, 60), (len(got), sim.log.read_text()[-800:])
            spin_until(ros, lambda: False, 1.0)              # held: nothing more comes
            stamps = [stamp_ns(m.header.stamp) for m in got]
            assert stamps == [start + k * dt_ns for k in range(limit)], (limit, len(stamps))
        ok, why = set_remote_parameters(ros, "sim_node", {"measurement_limit": -1})    # runs on
        assert ok, why
        assert spin_until(ros, lambda: len(got) > 40, 60)
    finally:
        ros.destroy_subscription(sub)
        processes.stop([sim])
