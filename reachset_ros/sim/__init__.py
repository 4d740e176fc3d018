"""Simulation: the simulated LWA-4P, its reference trajectories and simulated recordings (pure core, no ROS).

What stands in for the real robot in the demo, the tests and the benchmarks:

* :mod:`~reachset_ros.sim.simulator` - a torque-controlled arm with the paper's timing
  (Appendix A: one sample of input and output delay), model error, friction, noise and
  injectable faults (:class:`~reachset_ros.sim.simulator.SimulatedArm`);
* :mod:`~reachset_ros.sim.reference` - random trapezoidal / quintic point-to-point
  references inside the paper's limits (Sec. IV, ``U_ref``), and the stream
  ``reference_node`` publishes;
* :mod:`~reachset_ros.sim.recordings` - simulated closed-loop recordings (written as bags)
  for tests, benchmarks and tools.

May import: :mod:`reachset_ros.robot`, :mod:`reachset_ros.systems`,
:mod:`reachset_ros.synthesis` (only the recordings, for the reference-error loop) and
:mod:`reachset_ros.bags` (to write recordings), plus :mod:`reachset_ros.errors`.
"""
