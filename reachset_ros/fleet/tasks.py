"""The per-bag tasks of a fleet run and their exact merges (pure: no Dask, no ROS).

A fleet run (``--workers N`` / ``--scheduler ADDRESS``, :mod:`reachset_ros.fleet.cluster`)
splits the Theorem-1 sweep by bag. Each task reads one bag with the project's one bag reader
(:func:`~reachset_ros.bags.read_joint_series`, the bag on its own, as a single-process run
reads it: a test case never spans two bags) and returns per joint what the single-process
run would compute from that bag's part of the concatenated series:

* :func:`bag_extremes`: the deviation extremes (Theorem 1's left-hand sides,
  :func:`~reachset_ros.conformance.deviation_extremes`), the longest run of consecutive valid
  ticks, the read report and (``synthesize``) the recorded references;
* :func:`bag_check`: the batch check (:func:`~reachset_ros.conformance.check`) of given sets.

The merges are exact, so the client's model is the single-process model to the bit for any
split of the bags among workers: the extremes merge by elementwise max
(:func:`~reachset_ros.conformance.combine`), counts by integer sums, the first violation by
bag order, reports by :func:`~reachset_ros.bags.series.merge_reports`. :func:`bag_header`
(the first messages of a bag) lets the client refuse bags that disagree before any sweep is
sent.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..bags import read_estimates, read_references
from ..bags.messages import header_stamp_ns
from ..bags import PERIOD_TOLERANCE, ReadReport, merge_reports, read_joint_series
from ..conformance.coverage import merge_motion, motion_extremes
from ..conformance.envelope import tick_counts
from ..conformance.kernels import require_runs
from ..conformance.model import file_sha256
from ..conformance.theorem1 import CheckResult, Deviations, check, combine, deviation_extremes
from ..errors import ReachsetError
from ..synthesis.recorded_loop import merge as merge_loops
from ..synthesis.recorded_loop import series_loop_extremes

#: messages of each topic :func:`bag_header` reads
HEADER_MESSAGES = 256


@dataclass(frozen=True)
class ReadSpec:
    """How every task reads its bag: the command line's reader options, as plain values.

    Attributes
    ----------
    joints : tuple of str or None
        ``None``: every joint on both topics (``--joints all``).
    dt : float
    topics : (str, str)
        Measurement and plant-input topic.
    effort : (urdf, nominal, lock) or None
        ``--input effort``: the robot model, rebuilt once per worker process.
    joint_names : tuple of str or None
        ``--joint-names``.
    """

    joints: tuple | None
    dt: float
    topics: tuple
    effort: tuple | None = None
    joint_names: tuple | None = None

    def read(self, path):
        """``read_joint_series([path], ...)``: this bag's series and report."""
        opts = {"joint_names": None if self.joint_names is None else list(self.joint_names)}
        if self.effort is not None:
            opts["effort"] = _effort_input(*self.effort)
        return read_joint_series([Path(path)], None if self.joints is None else list(self.joints), self.dt,
                                 tuple(self.topics), **opts)


@functools.lru_cache(maxsize=4)
def _effort_input(urdf, nominal, lock):
    from ..robot.effort import load_effort_input   # Pinocchio: only for --input effort
    return load_effort_input(urdf, nominal, lock=None if lock is None else list(lock))


@dataclass(frozen=True)
class SweepSpec:
    """What the Theorem-1 sweep of every task needs: plant, estimator, horizon and rows."""

    plant: object
    estimator: object
    horizon: int
    thm: object


@dataclass(frozen=True)
class BagHeader:
    """The first messages of a bag: the joints a full read would pair, and the period."""

    path: str
    joints: tuple
    period_s: float | None


@dataclass(frozen=True)
class BagExtremes:
    """One bag's part of a fleet sweep (:func:`bag_extremes`)."""

    path: str
    joints: tuple
    devs: dict              # name -> Deviations (test_cases 0 and -inf without a test case)
    longest: dict           # name -> longest run of consecutive valid ticks
    report: ReadReport
    references: dict | None
    sha256: str             # of the bag's files (the model's provenance)
    messages: int
    loops: dict | None = None   # name -> LoopExtremes or None (reidentify: the recorded closed loop)
    motion: dict | None = None  # name -> MotionExtremes (identify's coverage of the reference class)


@dataclass(frozen=True)
class BagCheck:
    """One bag's batch check (:func:`bag_check`): name -> (CheckResult, first violation stamp)."""

    path: str
    joints: tuple
    results: dict
    ticks: dict             # name -> length of the bag's series (to index the concatenation)
    longest: dict           # name -> longest run of consecutive valid ticks
    report: ReadReport
    messages: int


def _messages(report):
    return int(sum(report.messages.values()))


def bag_header(path, read: ReadSpec, count=HEADER_MESSAGES):
    """The joints and sampling period of a bag from its first ``count`` messages per topic.

    Cheap (the reader stops after ``count`` messages of each topic); the client compares
    the headers of all bags before sending any sweep. A joint that first appears later in
    a bag is still caught when the parts are merged (:func:`merge_extremes`).
    """
    from ..bags import check_bag_path as _check_bag_path, read_messages
    p = Path(path)
    _check_bag_path(p)
    y_topic, u_topic = read.topics
    wanted = (y_topic,) if read.effort is not None else (y_topic, u_topic)
    names = {t: [] for t in wanted}
    stamps, seen = [], {t: 0 for t in wanted}
    try:
        for t, _, msg in read_messages([p], wanted):
            if seen[t] >= count:
                if all(v >= count for v in seen.values()):
                    break
                continue
            seen[t] += 1
            for n in (list(msg.name) or list(read.joint_names or ())):
                if n not in names[t]:
                    names[t].append(n)
            if t == y_topic:
                stamps.append(header_stamp_ns(msg))
    except ReachsetError:
        raise
    except Exception as e:          # rosbags' own errors: a damaged or unreadable bag
        raise ReachsetError(f"{p}: cannot read the bag: {e}") from None
    for t in wanted:
        if not seen[t]:
            raise ReachsetError(f"{p}: no {t} messages")
    joints = [n for n in names[y_topic] if read.effort is not None or n in names[u_topic]]
    if read.joints is not None:
        joints = [n for n in read.joints if n in joints]
    st = np.unique(np.asarray(stamps, np.int64))
    period = float(np.median(np.diff(st))) * 1e-9 if len(st) > 1 else None
    return BagHeader(str(p), tuple(joints), period)


def require_agreement(headers, read: ReadSpec):
    """Refuse bags that disagree (joints, sampling period) before any sweep is sent.

    Raises :class:`ReachsetError` naming the first bag that differs from the first one, or
    whose period is not ``dt`` (within :data:`~reachset_ros.bags.series.PERIOD_TOLERANCE`).
    """
    first = headers[0]
    for h in headers:
        if read.joints is not None:
            missing = [n for n in read.joints if n not in h.joints]
            if missing:
                raise ReachsetError(f"{h.path}: joint {missing[0]} not found in the bag's first "
                                    f"{HEADER_MESSAGES} messages (--joints)")
        elif h.joints != first.joints:
            raise ReachsetError(f"bags have different joints: {first.path} has {list(first.joints)}, "
                                f"{h.path} has {list(h.joints)}; pass --joints")
        if h.period_s is not None and abs(h.period_s - read.dt) > PERIOD_TOLERANCE * read.dt:
            raise ReachsetError(f"{h.path}: the sampling period of {read.topics[0]} is {h.period_s * 1e3:.4g} ms, "
                                f"not dt = {read.dt * 1e3:.4g} ms like the other bags' (--dt, or the model's dt)")


def bag_extremes(path, read: ReadSpec, sweep: SweepSpec, references=False, loops=None):
    """Read one bag and reduce each joint's test cases to Theorem 1's left-hand sides.

    Returns
    -------
    BagExtremes
        ``devs[name]`` is :func:`~reachset_ros.conformance.deviation_extremes` of the bag's
        series (``allow_empty``: a bag too short for a test case contributes nothing);
        ``references``: :func:`~reachset_ros.bags.read_references` of the bag when asked;
        ``loops`` ({name: (observer, controller)}, reidentify): per joint the recorded closed
        loop's :func:`~reachset_ros.synthesis.recorded_loop.series_loop_extremes`; ``motion``: per
        joint :func:`~reachset_ros.conformance.coverage.motion_extremes` (with the bag's
        ``/reference``), for identify's coverage of the reference class.
    """
    series, report = read.read(path)
    devs, longest = {}, {}
    for name, s in series.items():
        try:
            devs[name] = deviation_extremes(sweep.plant, sweep.estimator, s.y, s.u, s.segments, sweep.horizon,
                                            sweep.thm, allow_empty=True)
        except ReachsetError as e:
            raise ReachsetError(f"{path}: joint {name}: {e}") from None
        longest[name] = max((b - a for a, b in s.segments), default=0)
    refs = read_references([Path(path)], list(series), read.dt)
    motion = {n: motion_extremes(s.y, s.segments, s.dt, reference_qdd=[r.qdd for r in refs[n]] if n in refs else None)
              for n, s in series.items()}
    loop_ext = None
    if not (references or loops):
        refs = None
    if loops:
        est = read_estimates([Path(path)], list(series)) or {}
        loop_ext = {n: series_loop_extremes(sweep.plant, *loops[n], series[n], est.get(n), refs.get(n, ()))
                    for n in loops if n in series}
    return BagExtremes(path=str(path), joints=tuple(series), devs=devs, longest=longest, report=report,
                       references=refs, sha256=file_sha256(path), messages=_messages(report), loops=loop_ext,
                       motion=motion)


def bag_check(path, read: ReadSpec, sweep: SweepSpec, xis, envelope=None):
    """Batch-check one bag: per joint of ``xis`` (name -> xi) the :class:`CheckResult` of
    :func:`~reachset_ros.conformance.check` and the stamp of its first violation (or None);
    with ``envelope`` (:class:`~reachset_ros.conformance.envelope.Envelope`), the result's
    ``envelope`` holds the joint's :func:`~reachset_ros.conformance.envelope.tick_counts` (a
    segment never spans two bags: the counts add up to the single process')."""
    series, report = read.read(path)
    out = {}
    for name, xi in xis.items():
        if name not in series:
            raise ReachsetError(f"{path}: joint {name} of the model not found in the bag")
        s = series[name]
        r = check(sweep.plant, sweep.thm, sweep.estimator, xi, s.y, s.u, s.segments, sweep.horizon)
        r = replace(r, violating=None, envelope=None if envelope is None else tick_counts(envelope, name, s, r.violating))
        out[name] = (r, int(s.stamps[r.first_violation_tick]) if r.first_violation_tick >= 0 else None)
    return BagCheck(str(path), tuple(series), out, {n: len(series[n].stamps) for n in out},
                    {n: max((b - a for a, b in series[n].segments), default=0) for n in out}, report,
                    _messages(report))


def _same_joints(parts):
    names = list(parts[0].joints)
    for p in parts[1:]:
        if list(p.joints) != names:
            raise ReachsetError(f"bags have different joints: {names} vs {list(p.joints)}; pass --joints")
    return names


@dataclass(frozen=True)
class FleetSweep:
    """The merged sweep of a fleet's bags (:func:`merge_extremes`)."""

    devs: dict              # name -> Deviations, as the single-process sweep of all bags
    report: ReadReport
    references: dict | None  # name -> [Reference, ...] in bag order (synthesize), else None
    sha256: tuple            # per bag, in bag order
    loops: dict | None = None  # name -> merged LoopExtremes or None (reidentify), else None
    motion: dict | None = None  # name -> merged MotionExtremes (identify's coverage of the reference class)


def merge_extremes(parts, history, horizon, bags):
    """The single-process run's inputs from the bags' parts (in bag order), exactly.

    Returns a :class:`FleetSweep`. Raises as the single-process run does when the bags have
    different joints or some joint has no test case that reaches the horizon.
    """
    names = _same_joints(parts)
    require_runs({n: max(p.longest[n] for p in parts) for n in names}, history, horizon, bags)
    devs = {n: combine([p.devs[n] for p in parts]) for n in names}
    refs = None
    if parts[0].references is not None:
        refs = {}
        for p in parts:
            for n, rs in p.references.items():
                refs.setdefault(n, []).extend(rs)
    loops = None
    if parts[0].loops is not None:
        loops = {n: merge_loops([p.loops.get(n) for p in parts]) for n in parts[0].loops}
    motion = None
    if all(p.motion is not None for p in parts):
        motion = {n: merge_motion([p.motion[n] for p in parts]) for n in names}
    return FleetSweep(devs, merge_reports([p.report for p in parts]), refs, tuple(p.sha256 for p in parts),
                      loops, motion)


def merge_checks(parts, history, horizon, bags):
    """The batch check of all bags (in bag order) as of their concatenated series.

    Returns ``(results, report)``: per joint ``(CheckResult, stamp of the first violation or
    None)`` (the first bag with a violation), and the merged read report. Raises as the
    single-process run does when some joint has no test case that reaches the horizon."""
    _same_joints(parts)
    require_runs({n: max(p.longest[n] for p in parts) for n in parts[0].results}, history, horizon, bags)
    out = {}
    for name in parts[0].results:
        rs = [p.results[name] for p in parts]
        first = next((st for r, st in rs if st is not None), None)
        off, tick = 0, -1
        for p, (r, _) in zip(parts, rs):
            if r.first_violation_tick >= 0:
                tick = off + r.first_violation_tick
                break
            off += p.ticks[name]
        res = CheckResult(sum(r.violations for r, _ in rs), tick, sum(r.test_cases for r, _ in rs),
                          sum(r.checks for r, _ in rs), min(r.worst_margin for r, _ in rs),
                          envelope=None if rs[0][0].envelope is None else
                          {k: None if rs[0][0].envelope[k] is None else sum(r.envelope[k] for r, _ in rs)
                           for k in rs[0][0].envelope})
        out[name] = (res, first)
    return out, merge_reports([p.report for p in parts])


__all__ = ["ReadSpec", "SweepSpec", "BagHeader", "BagExtremes", "BagCheck", "bag_header", "require_agreement",
           "bag_extremes", "bag_check", "FleetSweep", "merge_extremes", "merge_checks", "Deviations"]
