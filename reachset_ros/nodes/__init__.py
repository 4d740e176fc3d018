"""ROS 2 adapters: parse messages, call the pure core, publish. Only this package imports rclpy.

One module per node (``sim_node``, ``reference_node``, ``observer_node``,
``controller_node``, ``monitor_node``, ``synthesis_node``, ``recorder_node``, ``talker``),
plus :mod:`~reachset_ros.nodes.common` (stamps, QoS profiles, parameter descriptors and
services, ``main``), :mod:`~reachset_ros.nodes.gain_params` (the per-joint gain
parameters) and :mod:`~reachset_ros.nodes.selftest` (the DDS self-test). docs/nodes.md
documents each node's interface. The workflows over the suite (``reachset demo``, the fault
campaign, the suite commander they use) are in :mod:`reachset_ros.workflows`.

May import: every pure-core subpackage of reachset_ros and :mod:`reachset_ros.launch`;
nothing in the core imports this package.
"""
