"""The reachset_ros node suite for ``ros2 launch`` (a colcon build on a Jazzy install).

    ros2 launch reachset_ros reachset.launch.py sim:=true model:=/abs/path/MODEL.yaml \\
        params_file:=/abs/path/params.yaml workdir:=/abs/path/run1

The same suite, parameters and precedence as ``reachset up`` (docs/nodes.md, "Bringing
the suite up"), which stands in for this file in the PyPI-based environment where
``launch`` is not installed: with ``sim:=true`` ``sim_node`` and ``reference_node``, then
``observer_node``, ``controller_node`` (``wait_for_monitor: true``), ``monitor_node``,
``synthesis_node``. Each node gets, lowest precedence first: the defaults below,
``params_file`` (its ``/**`` and node sections, as rcl reads them; none by default, as for
``reachset up``: the nodes' own defaults; the package's ``config/lwa4p.yaml`` is installed
to ``share/reachset_ros/config/``), then ``model_file`` (``model:=``, on the nodes that take a
model) and the paths under ``workdir:=`` (the monitor's offending windows, the synthesis
node's models). ``ros2 launch`` starts the nodes together rather than one after the
other; the nodes do not depend on the order (the controller holds the arm until the
monitor's latched ``/safe_stop`` state reaches it). The DDS domain is the caller's
``ROS_DOMAIN_ID`` (``reachset up`` picks a fresh one). Ctrl-C stops every node.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch_ros.actions import Node

PACKAGE = "reachset_ros"
#: the suite in start-up order; SIM_NODES only with sim:=true
SUITE = ("sim_node", "reference_node", "observer_node", "controller_node", "monitor_node", "synthesis_node")
SIM_NODES = ("sim_node", "reference_node")
#: nodes that get model:= as their model_file (a node that does not declare it ignores it)
MODEL_NODES = ("observer_node", "controller_node", "monitor_node", "synthesis_node")


def defaults(node, workdir, sim=False):
    """Parameters under the parameter file (as ``reachset up``'s ``bringup.defaults``)."""
    pair = {"allow_uncertified": True} if sim else {}
    clock = {"use_sim_time": True} if sim else {}     # the stop without estimates on the simulation's clock
    out = {"controller_node": {"wait_for_monitor": True, **pair, **clock}, "observer_node": dict(pair)}.get(node, {})
    if workdir:
        out = {**out, **{"monitor_node": {"window_dir": os.path.join(workdir, "windows")},
                         "synthesis_node": {"workdir": os.path.join(workdir, "synthesis")}}.get(node, {})}
    return out


def suite(context):
    """The Node actions, from the resolved launch arguments."""
    arg = context.launch_configurations
    sim = arg.get("sim", "false").lower() in ("true", "1", "yes")
    params_file, model, workdir = arg.get("params_file", ""), arg.get("model", ""), arg.get("workdir", "")
    if model:
        model = os.path.abspath(model)
    if workdir:
        workdir = os.path.abspath(workdir)
    actions = []
    for node in SUITE:
        if node in SIM_NODES and not sim:
            continue
        overrides = {"model_file": model} if model and node in MODEL_NODES else {}
        parameters = [p for p in (defaults(node, workdir, sim), params_file, overrides) if p]
        actions.append(Node(package=PACKAGE, executable=node, name=node, output="screen",
                            emulate_tty=True, parameters=parameters))
    return actions


def generate_launch_description():
    config = os.path.join(get_package_share_directory(PACKAGE), "config", "lwa4p.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("sim", default_value="false",
                              description="also start the simulated arm (sim_node) and reference_node"),
        DeclareLaunchArgument("model", default_value="",
                              description="conformance model (identify/synthesize output): model_file of the "
                                          "monitor, the controller, the synthesis node (and the observer)"),
        DeclareLaunchArgument("params_file", default_value="",
                              description=f"ROS 2 parameter file with sections for the nodes (e.g. {config})"),
        DeclareLaunchArgument("workdir", default_value="",
                              description="where the monitor's windows and the synthesis node's models go "
                                          "(default: the nodes' own defaults)"),
        OpaqueFunction(function=suite),
    ])
