"""A simulated fault set in one parameter request uses that request's joint and magnitude,
whatever their order in the request (issue 36.6; ``sim_node.fault_request``)."""
import pytest
from std_msgs.msg import Header

from helpers import Recorder
from reachset_ros import processes
from reachset_ros.nodes.common import get_remote_parameters, set_remote_parameters

pytestmark = pytest.mark.dds   # real DDS participants / node processes


def test_a_fault_request_uses_its_own_values_in_any_order(ros, tmp_path):
    """``fault`` first, then ``fault_magnitude`` and ``fault_joint`` (not the defaults arm_1_joint
    and 5): the fault injected, its onset message, the check of the joint all use the request's."""
    sim = processes.start("sim_node", {"seed": 5}, tmp_path)
    rec = Recorder("fault_request_listener", {"sim/fault_onset": Header})
    try:
        ok, why = set_remote_parameters(ros, "sim_node", {"fault": "acceleration", "fault_joint": "no_such_joint"})
        assert not ok and "no_such_joint" in why, why       # the request's joint is the one checked
        ok, why = set_remote_parameters(ros, "sim_node", {"fault": "acceleration", "fault_magnitude": 7.5,
                                                          "fault_joint": "arm_2_joint"})
        assert ok, why
        onsets = rec.msgs["sim/fault_onset"]
        assert rec.wait(lambda: len(onsets) >= 1, 60), sim.log.read_text()[-800:]
        assert [m.frame_id for _, m in onsets] == ["acceleration on arm_2_joint, magnitude 7.5"]
        values, why = get_remote_parameters(ros, "sim_node", ["fault", "fault_joint", "fault_magnitude"])
        assert values == {"fault": "acceleration", "fault_joint": "arm_2_joint", "fault_magnitude": 7.5}, why
        assert "fault injected: acceleration on arm_2_joint, magnitude 7.5" in sim.log.read_text()
    finally:
        rec.close()
        processes.stop([sim])
