"""Fleet scale: the bag-reading commands on Dask distributed (issue 18).

``reachset identify|check|synthesize BAG... --workers N`` (a local cluster of N processes)
or ``--scheduler ADDRESS`` (an existing Dask cluster) split the Theorem-1 sweep by bag: each
task reads one bag and returns per joint its deviation extremes (or its batch check), the
client merges them exactly and solves the linear programmes itself. The model is the
single-process model to the bit (provenance aside) for any split of the bags.

* :mod:`.tasks`: the per-bag tasks and their exact merges (no Dask import);
* :mod:`.cluster`: :class:`~.cluster.Fleet`, the Dask client (imported only with the options).

:func:`extremes` and :func:`check` are the two client-side entry points the commands and
the workflows (:mod:`reachset_ros.workflows`) use; the synthesis package never imports this one:
the workflow hands the fleet's sweep to it (:func:`reachset_ros.workflows.synthesize.sweep_on_fleet`).

May import: :mod:`reachset_ros.bags`, :mod:`reachset_ros.conformance`,
:mod:`reachset_ros.synthesis` (a re-identification's recorded loop, per bag),
:mod:`reachset_ros.robot` (``--input effort``) and :mod:`reachset_ros.errors`; never ``sim``
or the ROS layers. The synthesis never imports this package.
"""
from .tasks import (BagCheck, BagExtremes, BagHeader, FleetSweep, ReadSpec, SweepSpec, bag_check, bag_extremes, bag_header,
                    merge_checks, merge_extremes, require_agreement)


def _headers(fleet, bags, read):
    """Every bag's first messages, compared before any sweep is sent (:func:`.tasks.require_agreement`)."""
    headers = fleet.map(bag_header, list(map(str, bags)), read, what="header")
    require_agreement(headers, read)
    return headers


def extremes(fleet, bags, read: ReadSpec, sweep: SweepSpec, references=False, loops=None):
    """The deviation extremes of all bags, one task per bag, merged exactly.

    Returns
    -------
    FleetSweep
        ``devs`` {name: Deviations}, ``report``, ``references`` ({name: [Reference, ...]} in
        bag order when ``references`` is true: ``synthesize``), the bags' ``sha256`` and, with
        ``loops`` ({name: (observer, controller)}, reidentify), the recorded loops' extremes.
    """
    _headers(fleet, bags, read)
    parts = fleet.map(bag_extremes, list(map(str, bags)), read, sweep, what="sweep", references=references,
                      loops=loops)
    return merge_extremes(parts, sweep.estimator.history, sweep.horizon, bags)


def check(fleet, bags, read: ReadSpec, sweep: SweepSpec, xis, envelope=None):
    """The batch check of all bags against ``xis`` ({name: xi}), one task per bag.

    Returns ``({name: (CheckResult, first violation stamp or None)}, report)``; with
    ``envelope``, each CheckResult's ``envelope`` holds the joint's tick counts (issue 37).
    """
    _headers(fleet, bags, read)
    parts = fleet.map(bag_check, list(map(str, bags)), read, sweep, xis, envelope, what="check")
    return merge_checks(parts, sweep.estimator.history, sweep.horizon, bags)


class Checker:
    """``checker(name, xi)``: the batch check of one joint of a fleet's bags, one task per bag
    (what :meth:`reachset_ros.synthesis.problem.JointProblem.check` calls for a
    non-conformant xi of a fleet run). The fleet must stay open while it is used."""

    def __init__(self, fleet, bags, read: ReadSpec, sweep: SweepSpec):
        self.fleet, self.bags, self.read, self.sweep = fleet, list(bags), read, sweep

    def __call__(self, name, xi):
        return check(self.fleet, self.bags, self.read, self.sweep, {name: xi})[0][name][0]


__all__ = ["Checker", "FleetSweep", "ReadSpec", "SweepSpec", "BagHeader", "BagExtremes", "BagCheck", "bag_header", "bag_extremes",
           "bag_check", "merge_extremes", "merge_checks", "require_agreement", "extremes", "check"]
