"""The reachset_ros node suite for ``ros2 launch`` (a colcon build on a Jazzy install).

    ros2 launch reachset_ros reachset.launch.py sim:=true model:=/abs/path/MODEL.yaml \\
        params_file:=/abs/path/params.yaml workdir:=/abs/path/run1

The same suite and parameters as ``reachset up`` (docs/nodes.md, "Bringing the suite up"),
which stands in for this file in the PyPI-based environment where ``launch`` is not
installed: both take the plan of :func:`reachset_ros.nodes.bringup.plan` (with ``sim:=true``
``sim_node`` and ``reference_node``, then ``observer_node``, ``controller_node``,
``monitor_node`` when there is a model, ``synthesis_node``; the defaults, the parameter
file's ``/**`` and node sections, ``model_file`` and the model's gains; without a model the
suite runs unmonitored). ``workdir:=`` holds the monitor's offending windows and the
synthesis node's models (default ``./reachset_run``). ``ros2 launch`` starts the nodes
together rather than one after the other; the nodes do not depend on the order (the
controller holds the arm until the monitor's latched ``/safe_stop`` state reaches it). The DDS domain is the caller's
``ROS_DOMAIN_ID`` (``reachset up`` picks a fresh one). Ctrl-C stops every node.
"""
import os
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch_ros.actions import Node

PACKAGE = "reachset_ros"


def suite(context):
    """The Node actions, from the resolved launch arguments: ``reachset up``'s plan
    (:func:`reachset_ros.nodes.bringup.plan`, one home for the suite, its defaults, the
    parameter file's sections, the model and its gains), each node with its parameters."""
    from reachset_ros import params_file as pf
    from reachset_ros.nodes import bringup
    arg = context.launch_configurations
    sim = arg.get("sim", "false").lower() in ("true", "1", "yes")
    params_file, model, workdir = arg.get("params_file", ""), arg.get("model", ""), arg.get("workdir", "")
    workdir = os.path.abspath(workdir) if workdir else os.path.join(os.getcwd(), "reachset_run")
    plan = bringup.plan(pf.load(params_file) if params_file else {}, sim, Path(workdir),
                        Path(os.path.abspath(model)) if model else None)
    return [Node(package=PACKAGE, executable=node, name=node, output="screen", emulate_tty=True,
                 parameters=[params] if params else [])
            for node, params in plan.items()]


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
