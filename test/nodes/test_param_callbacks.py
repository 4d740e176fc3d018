"""reachset_ros.nodes.param_callbacks: the request a node's on_set accepted, kept for its
post_set; and which requests repeat the running values. On a real rclpy node (its parameters
are what the functions read)."""
from array import array

import pytest
from rclpy.parameter import Parameter

from reachset_ros.errors import ReachsetError
from rcl_interfaces.msg import SetParametersResult

from reachset_ros.nodes.param_callbacks import StagedRequest, add_parameter_callbacks, repeats_current

#: the tests with a node make a real DDS participant
dds = pytest.mark.dds


@pytest.fixture
def node(own_node):
    own_node.declare_parameter("omega", [12.0, 14.0])
    own_node.declare_parameter("observer", "eso")
    own_node.declare_parameter("model_file", "/tmp/m.yaml")
    return own_node


@dds
def test_a_request_of_the_running_values_is_a_repeat(node):
    assert repeats_current(node, [Parameter("omega", value=[12.0, 14.0]), Parameter("observer", value="eso")])
    assert repeats_current(node, [Parameter("omega", value=array("d", [12.0, 14.0]))])   # as rclpy hands it over


@dds
@pytest.mark.parametrize("params", [
    [Parameter("omega", value=[12.0, 14.5])],                                  # one value differs
    [Parameter("omega", value=[12.0, 14.0]), Parameter("observer", value="luenberger")],
    [Parameter("omega", value=[12.0])],                                         # another length
    [Parameter("zeta", value=[1.0])],                                           # not declared
    [Parameter("model_file", value="/tmp/m.yaml")],                             # read again when set
    [],
])
def test_anything_else_is_not_a_repeat(node, params):
    assert not repeats_current(node, params)


def test_a_staged_request_is_taken_once_and_only_for_its_own_parameters():
    staged, params = StagedRequest(), [Parameter("omega", value=[1.0])]
    staged.hold(params, "cfg")
    with pytest.raises(ReachsetError):
        staged.take([Parameter("omega", value=[1.0])])          # an equal list, not the request
    staged.hold(params, "cfg")
    assert staged.take(params) == "cfg"
    with pytest.raises(ReachsetError):
        staged.take(params)


@dds
def test_take_repeats_keeps_a_repeat_from_both_callbacks_and_passes_the_rest(node):
    seen = []

    def on_set(params):
        seen.append(("on_set", [p.name for p in params]))
        return SetParametersResult(successful=True)

    def post_set(params):
        seen.append(("post_set", [p.name for p in params]))
    add_parameter_callbacks(node, on_set=on_set, post_set=post_set, take_repeats=True)
    assert node.set_parameters_atomically([Parameter("omega", value=[12.0, 14.0])]).successful   # a repeat
    assert seen == []
    assert node.set_parameters_atomically([Parameter("omega", value=[13.0, 14.0])]).successful
    assert seen == [("on_set", ["omega"]), ("post_set", ["omega"])]
    assert node.set_parameters_atomically([Parameter("model_file", value="/tmp/m.yaml")]).successful  # read again
    assert seen[2:] == [("on_set", ["model_file"]), ("post_set", ["model_file"])]
    assert list(node.get_parameter("omega").value) == [13.0, 14.0]
