"""reachset_ros: guarantees for real robots (Liu, Schuermann, Althoff, IEEE T-RO).

The pure core (no rclpy import) holds all mathematics, one concept per subpackage:
:mod:`~reachset_ros.sets` (zonotopes, reachable and invariant sets),
:mod:`~reachset_ros.systems` (plant, observers, controllers, closed loop, gains),
:mod:`~reachset_ros.conformance` (Theorem 1, identification, the online monitor),
:mod:`~reachset_ros.synthesis` (the combined synthesis of Sec. III-D and Appendix B),
:mod:`~reachset_ros.robot` (rigid-body dynamics of the LWA-4P, input limits),
:mod:`~reachset_ros.bags` (rosbag2 reading and writing), :mod:`~reachset_ros.sim` (the
simulated arm and its references), :mod:`~reachset_ros.fleet` (the per-bag tasks of a fleet
run on Dask distributed, and their exact merges). ROS 2 nodes in :mod:`reachset_ros.nodes` are thin
adapters over it; :mod:`reachset_ros.cli` and :mod:`reachset_ros.commands` are the
``reachset`` command line, :mod:`reachset_ros.plots` its figures. Processes and their
environment: :mod:`reachset_ros.processes` (node processes: start, stop, signals),
:mod:`reachset_ros.domain` (a fresh DDS domain), :mod:`reachset_ros.params_file` (ROS 2
parameter files).
"""

__version__ = "0.1.0"
