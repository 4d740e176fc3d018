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

May import: every subpackage below it (the pure core, :mod:`reachset_ros.nodes`) and
:mod:`reachset_ros.launch`; only :mod:`reachset_ros.commands` and the CLI import this package.
"""
