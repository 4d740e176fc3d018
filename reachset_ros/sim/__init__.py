"""Simulation: the simulated arm, its reference trajectories and simulated recordings (pure core, no ROS).

What stands in for the real robot in the demo, the tests and the benchmarks. The arm is the
LWA-4P by default and any serial arm's URDF model otherwise (``reachset simulate --robot``):
limits, effort limits, brakes and the reference box come from the model
(:meth:`~reachset_ros.sim.reference.ReferenceConfig.for_robot`); only the defaults name the LWA-4P.

* :mod:`~reachset_ros.sim.simulator` - a torque-controlled arm with the paper's timing
  (Appendix A: one sample of input and output delay), model error, friction, noise and
  injectable faults (:class:`~reachset_ros.sim.simulator.SimulatedArm`);
* :mod:`~reachset_ros.sim.reference` - random trapezoidal / quintic point-to-point
  references inside the paper's limits (Sec. IV, ``U_ref``; Table I for the LWA-4P, the
  URDF's limits for any other arm), and the stream
  ``reference_node`` publishes;
* :mod:`~reachset_ros.sim.excite` - identification references that reach the reference
  class' limits on every joint (``reachset excite``) and their player (``reference_node``'s
  ``trajectory_file``);
* :mod:`~reachset_ros.sim.recordings` - simulated closed-loop recordings (written as bags)
  for tests, benchmarks and tools;
* :mod:`~reachset_ros.sim.safe_stop` - a safe stop on the simulated arm (the nodes' code path
  without ROS);
* :mod:`~reachset_ros.sim.real_runs` - the simulated arm along the real LWA-4P runs'
  trajectories (its calibration to the real arm, ``benchmarks/calibrate_sim.py``);
* :mod:`~reachset_ros.sim.campaign` - the fault campaign's schedule, judge and score;
* :mod:`~reachset_ros.sim.evidence` - the campaign's safety evidence sheet (issue 35.6);
* :mod:`~reachset_ros.sim.detectability` - the minimum detectable fault by bisection (issue 35.5);
* :mod:`~reachset_ros.sim.link` - a lossy, delaying link that never reorders.

May import: :mod:`reachset_ros.robot`, :mod:`reachset_ros.systems` (the control law and the
closed loop driven by references), :mod:`reachset_ros.conformance` (``real_runs`` identifies
sets), :mod:`reachset_ros.bags` (to write and read recordings), :mod:`reachset_ros.defaults` (the recording gains) and
:mod:`reachset_ros.errors`; never ``synthesis`` or ``fleet``.
"""
