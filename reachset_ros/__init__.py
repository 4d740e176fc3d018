"""reachset_ros: guarantees for real robots (Liu, Schuermann, Althoff, IEEE T-RO).

The pure core (no rclpy import) holds all mathematics: :mod:`zonotope`,
:mod:`reachability`, :mod:`plant`, :mod:`observers`, :mod:`controllers`,
:mod:`closedloop`, :mod:`conformance`, :mod:`synthesis`, :mod:`monitor`, :mod:`bags`.
ROS 2 nodes in :mod:`reachset_ros.nodes` are thin adapters over it.
"""

__version__ = "0.1.0"
