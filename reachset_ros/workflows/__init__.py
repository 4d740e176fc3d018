"""Workflows over the suite, as a library: what the commands, the nodes' workers and the
drivers run, as keyword-only functions returning typed, frozen results.

* :mod:`.identify`: reachset-conformant identification from bags (Theorem 1; ``--validate``,
  ``--calibrate``), :func:`.identify.identify` -> :class:`.identify.IdentifyResult`;
* :mod:`.synthesize`: combined synthesis, separate synthesis and re-identification from bags
  (paper eq. 10; the fleet sweep chosen here), :func:`.synthesize.synthesize` ->
  :class:`.synthesize.SynthesisResult`.

Submodules are imported on use (this package imports none of them: no ROS import here).

May import: every core subpackage, nodes, launch; not commands.
"""
