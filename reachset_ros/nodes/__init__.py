"""ROS 2 adapters: parse messages, call the pure core, publish. Only this package imports rclpy.

One module per node (``sim_node``, ``reference_node``, ``observer_node``,
``controller_node``, ``monitor_node``, ``synthesis_node``, ``recorder_node``, ``talker``),
plus :mod:`~reachset_ros.nodes.common` (stamps, QoS profiles, parameter descriptors and
services, ``main``), :mod:`~reachset_ros.nodes.gain_params` (the per-joint gain
parameters) and :mod:`~reachset_ros.nodes.selftest` (the DDS self-test). docs/nodes.md
documents each node's interface. The workflows over the suite (``reachset demo``, the fault
campaign, the suite commander they use) are in :mod:`reachset_ros.workflows`.

May import: the pure core (:mod:`reachset_ros.errors`, :mod:`reachset_ros._lazy`, :mod:`reachset_ros.atomic`, :mod:`reachset_ros.defaults`, :mod:`reachset_ros.guarantees`,
:mod:`reachset_ros.sets`, :mod:`reachset_ros.systems`, :mod:`reachset_ros.robot`,
:mod:`reachset_ros.conformance`, :mod:`reachset_ros.bags`, :mod:`reachset_ros.synthesis`,
:mod:`reachset_ros.fleet`, :mod:`reachset_ros.sim`) and the processes
(:mod:`reachset_ros.domain`, :mod:`reachset_ros.params_file`, :mod:`reachset_ros.processes`, :mod:`reachset_ros.stacks`);
not the workflows, commands or the command line. Nothing in the core imports this package.
"""
