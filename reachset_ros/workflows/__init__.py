"""Workflows over the suite, as a library: what the commands, the nodes' workers, the demo and
the fault campaign run, as keyword-only functions returning typed, frozen results.

* :mod:`.identify`: reachset-conformant identification from bags (Theorem 1; ``--validate``,
  ``--calibrate``), :func:`.identify.identify` -> :class:`.identify.IdentifyResult`;
* :mod:`.synthesize`: combined synthesis, separate synthesis and re-identification from bags
  (paper eq. 10; the fleet sweep chosen here), :func:`.synthesize.synthesize` ->
  :class:`.synthesize.SynthesisResult`;
* :mod:`.commander`: the suite commander (start and stop the nodes' processes, record, apply a
  model or gains, reset the monitor, inject a fault, wait for a stop, spin in simulated time;
  in the way navigation2's ``nav2_simple_commander.BasicNavigator`` drives Nav2);
* :mod:`.demo`: the story of ``reachset demo``; :mod:`.campaign`: the fault campaign; both
  users of the commander.

Submodules are imported on use (this package imports none of them: no ROS import here;
:mod:`.identify` and :mod:`.synthesize` import no rclpy at all).

May import: the pure core (:mod:`reachset_ros.errors`, :mod:`reachset_ros._lazy`, :mod:`reachset_ros.atomic`,
:mod:`reachset_ros.defaults`, :mod:`reachset_ros.guarantees`, :mod:`reachset_ros.sets`, :mod:`reachset_ros.systems`,
:mod:`reachset_ros.robot`, :mod:`reachset_ros.conformance`, :mod:`reachset_ros.bags`,
:mod:`reachset_ros.synthesis`, :mod:`reachset_ros.fleet`, :mod:`reachset_ros.sim`,
:mod:`reachset_ros.plots`, :mod:`reachset_ros.report`), the processes (:mod:`reachset_ros.domain`,
:mod:`reachset_ros.params_file`, :mod:`reachset_ros.processes`, :mod:`reachset_ros.stacks`) and the ROS adapters
(:mod:`reachset_ros.nodes`); only the commands and the CLI import this package.
"""
