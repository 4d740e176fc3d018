"""Workflows over the suite: what a user (the CLI, the demo, the fault campaign, a benchmark)
does with the nodes, as a library of keyword-only functions. :mod:`.commander` is the suite
commander (start and stop the nodes' processes, record, apply a model or gains, reset the
monitor, inject a fault, wait for a stop, spin in simulated time; in the way navigation2's
``nav2_simple_commander.BasicNavigator`` drives Nav2), :mod:`.demo` the story of ``reachset
demo`` and :mod:`.campaign` the fault campaign, both users of the commander.

May import: every subpackage below it (the pure core, :mod:`reachset_ros.nodes`) and
:mod:`reachset_ros.launch`; only :mod:`reachset_ros.commands` and the CLI import this package.
"""
