"""Joint series: the paired (y, u_p) samples of each joint of rosbag2 bags, cut into segments.

* :func:`read_joint_series`: per joint, the paired samples of y (``/joint_states``
  position) and u_p (``/plant_input`` acceleration), sorted by stamp, split into segments
  of consecutive valid ticks (:class:`JointSeries`), with a :class:`ReadReport` of what was
  skipped or repaired. Every command that identifies or checks a model reads bags with it.
* :func:`segments_of`: the one definition of "consecutive ticks"; :func:`measured_period`
  and :func:`check_period`: the sampling period a bag must have.
* :func:`merge_reports`, :func:`concat_series`: several bags' series and reports as one.

The columns are read by :mod:`.topics`. Unreadable bags raise
:class:`~reachset_ros.errors.ReachsetError` naming the bag (and the damaged file, or the topic).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ReachsetError
from .messages import JOINT_STATE_TYPE, JOINT_STATES, PLANT_INPUT, PLANT_INPUT_TYPE
from .topics import read_fields, read_topics


@dataclass(frozen=True)
class JointSeries:
    """One joint's paired samples, sorted by stamp (an immutable value).

    Attributes
    ----------
    name : str
    stamps : ndarray of int64, shape (T,)
        Header stamps (ns) at which both a position and a plant input exist.
    y : ndarray, shape (T,)
        ``/joint_states`` position, rad (NaN/inf kept; they are invalid samples).
    u : ndarray, shape (T,)
        ``/plant_input`` acceleration u_p, rad/s^2.
    segments : tuple of (start, stop)
        Index ranges of consecutive valid ticks (stamp step within ``[0.5, 1.5] dt``, all
        values finite). Test cases never span two segments.
    """

    name: str
    stamps: np.ndarray
    y: np.ndarray
    u: np.ndarray
    segments: tuple
    dt: float

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.y) & np.isfinite(self.u)


@dataclass
class ReadReport:
    """What the reader skipped or repaired, per topic and joint (reported in the JSON)."""

    messages: dict = field(default_factory=dict)
    duplicates: dict = field(default_factory=dict)
    out_of_order: dict = field(default_factory=dict)
    unpaired: dict = field(default_factory=dict)
    invalid_samples: dict = field(default_factory=dict)
    gaps: dict = field(default_factory=dict)
    ignored_joints: list = field(default_factory=list)
    #: per topic: messages whose joint-name list (names and order) differs from the first
    #: message's (joints reordered, added or left out); paired by name, so only reported
    name_list_changes: dict = field(default_factory=dict)
    #: the measured sampling period [s] of each bag, in order (median stamp step)
    period_s: object = None
    #: where u_p came from: "topic", or the effort source's description
    input: object = "topic"
    #: the first paired stamp [ns] of each bag, in order (None for a bag without one): stamps
    #: are shown as seconds from their bag's start beside the ns (:meth:`seconds_from_start`)
    start_ns: object = None

    def seconds_from_start(self, stamp_ns):
        """Seconds of ``stamp_ns`` from the start of the bag that holds it: the latest bag start
        at or before it (bags need not be given in time order), or None."""
        if stamp_ns is None:
            return None
        starts = [s for s in (self.start_ns or ()) if s is not None and s <= stamp_ns]
        return (int(stamp_ns) - max(starts)) * 1e-9 if starts else None

    def as_dict(self):
        return {k: v for k, v in self.__dict__.items()}


def _unique_sorted(stamps, values):
    """Sorted by stamp, duplicate stamps dropped (first in arrival order kept)."""
    if len(stamps) > 1 and np.all(stamps[1:] > stamps[:-1]):
        return stamps, values, 0
    order = np.argsort(stamps, kind="stable")
    s, v = stamps[order], values[order]
    keep = np.ones(len(s), dtype=bool)
    keep[1:] = s[1:] != s[:-1]
    return s[keep], v[keep], int((~keep).sum())


def _pair(ys, us):
    """``np.intersect1d(ys, us, assume_unique=True, return_indices=True)`` of sorted unique stamps."""
    if len(ys) == len(us) and np.array_equal(ys, us):
        idx = np.arange(len(ys))
        return ys, idx, idx
    return np.intersect1d(ys, us, assume_unique=True, return_indices=True)


def segments_of(stamps, valid, dt):
    """Index ranges ``(start, stop)`` of consecutive valid ticks.

    Consecutive means the stamp step is within ``[0.5 dt, 1.5 dt]``; an invalid sample or a
    larger step (a missing tick, a pause between recordings) ends a segment.
    """
    n = len(stamps)
    if n == 0:
        return ()
    valid = np.asarray(valid, dtype=bool)
    step = np.diff(np.asarray(stamps)).astype(np.float64) * 1e-9
    joined = (step >= 0.5 * dt) & (step <= 1.5 * dt) & valid[1:] & valid[:-1]
    # a segment starts at a valid tick not joined to its predecessor and stops after a
    # valid tick not joined to its successor
    prev_joined = np.concatenate([[False], joined])
    next_joined = np.concatenate([joined, [False]])
    starts = np.flatnonzero(valid & ~prev_joined)
    stops = np.flatnonzero(valid & ~next_joined) + 1
    return tuple(zip(starts.tolist(), stops.tolist()))


#: A bag whose measured sampling period (median stamp step) differs from dt by more than this
#: share of dt is refused: its test cases would not be the model's (k steps of dt). The
#: monitor's coverage watch uses the same 5 %.
PERIOD_TOLERANCE = 0.05


def measured_period(stamps):
    """The sampling period of sorted unique stamps [s]: the median positive step (pauses
    between recordings and single lost ticks do not move it); None with fewer than 2 stamps."""
    st = np.asarray(stamps, np.int64)
    if len(st) < 2:
        return None
    return float(np.median(np.diff(st))) * 1e-9


def check_period(path, topic, stamps, dt):
    """Refuse a stream whose :func:`measured_period` is not ``dt`` (within :data:`PERIOD_TOLERANCE`)."""
    per = measured_period(stamps)
    if per is not None and abs(per - dt) > PERIOD_TOLERANCE * dt:
        raise ReachsetError(f"{path}: the measured sampling period of {topic} is {per * 1e3:.4g} ms "
                            f"(median stamp step), not dt = {dt * 1e3:.4g} ms (--dt, or the model's dt); "
                            "use data recorded at dt or a model identified for this period")
    return per


def read_joint_series(paths, joints=None, dt=0.004, topics=(JOINT_STATES, PLANT_INPUT), effort=None,
                      joint_names=None):
    """Per-joint paired (y, u_p) series from rosbag2 bags (MCAP or sqlite3).

    Each bag is read on its own and the bags' series are concatenated; a test case never
    spans two bags (each bag starts a new segment).

    Samples are paired by header stamp and joint name, never by index or arrival order;
    sorted by stamp; duplicate stamps dropped (first kept); segments split at gaps and at
    invalid (NaN/inf) samples, which are reported, not fatal.

    Parameters
    ----------
    paths : sequence of path
        rosbag2 directories; their messages are merged by stamp.
    joints : sequence of str or None
        Joint names; ``None`` or ``["all"]`` = every joint present on both topics, in the
        order of ``/joint_states``.
    dt : float
        Sampling time, s.
    topics : (str, str)
        The measurement topic (sensor_msgs/msg/JointState, its ``position`` is y_p) and the
        plant-input topic (reachset_msgs/msg/PlantInput); default ``/joint_states``,
        ``/plant_input`` (the CLI's ``--joint-states-topic``, ``--input-topic``).
    effort : EffortInput, optional
        ``--input effort``: u_p is computed from the measurement topic's position, velocity
        and effort with the nominal model (:func:`reachset_ros.robot.effort.plant_inputs`,
        eq. 6 inverted) at every stamp where all of the model's joints have all three;
        the plant-input topic is not read.
    joint_names : sequence of str, optional
        Names for JointState messages with an empty ``name`` array (``--joint-names``).

    The sampling period is measured from the stamps (:func:`measured_period`) and a bag
    whose period is not ``dt`` is refused (:func:`check_period`); the report has it as
    ``period_s``.

    Returns
    -------
    series : dict name -> JointSeries
    report : ReadReport
    """
    if effort is not None:
        parts = [_read_one_effort(p, joints, dt, topics[0], effort, joint_names) for p in paths]
    else:
        parts = [_read_one(p, joints, dt, tuple(topics), joint_names) for p in paths]
    for ser, r in parts:
        r.period_s = [r.period_s]
        firsts = [int(x.stamps[0]) for x in ser.values() if len(x.stamps)]
        r.start_ns = [min(firsts) if firsts else None]
    if len(parts) == 1:
        return parts[0]
    names = list(parts[0][0])
    for ser, _ in parts[1:]:
        if list(ser) != names:
            raise ReachsetError(f"bags have different joints: {names} vs {list(ser)}; pass --joints")
    return concat_series([ser for ser, _ in parts], dt), merge_reports([r for _, r in parts])


def merge_reports(reports):
    """One :class:`ReadReport` of several bags' (in bag order; ``period_s`` a list each):
    counts summed per topic and joint, periods listed, ignored joints united. The report of
    :func:`read_joint_series` over several bags, and of the fleet's per-bag tasks
    (:mod:`reachset_ros.fleet`)."""
    if len(reports) == 1:
        return reports[0]
    rep = ReadReport()
    rep.input = reports[0].input
    rep.period_s = [v for r in reports for v in r.period_s]
    rep.start_ns = [v for r in reports for v in (r.start_ns or [None])]
    for r in reports:
        for key in ("messages", "duplicates", "out_of_order", "unpaired", "invalid_samples", "gaps",
                    "name_list_changes"):
            acc = getattr(rep, key)
            for k, v in getattr(r, key).items():
                acc[k] = acc.get(k, 0) + v
        rep.ignored_joints = sorted(set(rep.ignored_joints) | set(r.ignored_joints))
    return rep


def concat_series(parts, dt):
    """Per-joint series of several recordings one after the other (``{name: JointSeries}``
    each, the same joints): arrays concatenated, segments offset, so a test case never spans
    two recordings. The stamps are kept as they are."""
    out = {}
    for n in parts[0]:
        stamps, y, u, segs, off = [], [], [], [], 0
        for ser in parts:
            s = ser[n]
            stamps.append(s.stamps)
            y.append(s.y)
            u.append(s.u)
            segs.extend((a + off, b + off) for a, b in s.segments)
            off += len(s.stamps)
        arrs = [np.concatenate(a) for a in (stamps, y, u)]
        for a in arrs:
            a.setflags(write=False)
        out[n] = JointSeries(n, *arrs, tuple(segs), dt)
    return out


def _read_one(path, joints, dt, topics=(JOINT_STATES, PLANT_INPUT), joint_names=None):
    paths = [path]
    y_topic, u_topic = topics
    if y_topic == u_topic:
        raise ReachsetError(f"the measurement and the plant-input topic are both {y_topic}")
    cols = read_topics(paths, topics, expect={y_topic: JOINT_STATE_TYPE, u_topic: PLANT_INPUT_TYPE},
                       joint_names=joint_names)
    js, pi = cols[y_topic], cols[u_topic]
    rep = ReadReport()
    rep.messages = {y_topic: js.count, u_topic: pi.count}
    rep.out_of_order = {y_topic: js.out_of_order, u_topic: pi.out_of_order}
    rep.name_list_changes = {y_topic: js.name_changes, u_topic: pi.name_changes}
    common = [n for n in js.order if n in pi.stamps]
    if joints is None or list(joints) == ["all"]:
        joints = common
        rep.ignored_joints = sorted(set(js.order) ^ set(pi.order))
    if not joints:
        raise ReachsetError(f"{', '.join(map(str, paths))}: no joint is on both {y_topic} and {u_topic}")
    out = {}
    joints = list(joints)
    for i, name in enumerate(joints):
        for topic, c in ((y_topic, js), (u_topic, pi)):
            if name not in c.stamps:
                raise ReachsetError(f"joint {name} not found on {topic}")
        ys, yv, ydup = _unique_sorted(np.frombuffer(js.stamps[name], np.int64), np.frombuffer(js.values[name]))
        us, uv, udup = _unique_sorted(np.frombuffer(pi.stamps[name], np.int64), np.frombuffer(pi.values[name]))
        stamps, iy, iu = _pair(ys, us)
        if i == 0:
            rep.period_s = check_period(path, y_topic, stamps, dt)
        y, u = yv[iy].copy(), uv[iu].copy()
        if name not in joints[i + 1:]:      # free this joint's columns (peak memory)
            for c in (js, pi):
                del c.stamps[name], c.values[name]
        valid = np.isfinite(y) & np.isfinite(u)
        segs = segments_of(stamps, valid, dt)
        for a in (stamps, y, u):
            a.setflags(write=False)
        out[name] = JointSeries(name, stamps, y, u, segs, dt)
        rep.duplicates[name] = ydup + udup
        rep.unpaired[name] = int(len(ys) + len(us) - 2 * len(stamps))
        rep.invalid_samples[name] = int((~valid).sum())
        rep.gaps[name] = max(0, len(segs) - 1)
    return out, rep


def _read_one_effort(path, joints, dt, y_topic, effort, joint_names=None):
    """:func:`_read_one` for ``--input effort``: u_p from position, velocity and effort."""
    robot = list(effort.joint_names)
    req = {f: (y_topic, f) for f in ("position", "velocity", "effort")}
    cols = read_fields([path], req, expect={y_topic: JOINT_STATE_TYPE}, joint_names=joint_names)
    pos = cols["position"]
    rep = ReadReport()
    rep.input = effort.describe()
    rep.messages = {y_topic: pos.count}
    rep.out_of_order = {y_topic: pos.out_of_order}
    rep.name_list_changes = {y_topic: pos.name_changes}
    rep.ignored_joints = sorted(set(pos.order) - set(robot))
    for nm in robot:
        for f, c in cols.items():
            if nm not in c.stamps:
                raise ReachsetError(f"{path}: joint {nm} of the robot model has no {f} on {y_topic} "
                                    "(--input effort needs position, velocity and effort of every joint "
                                    "of the model; lock the joints the bag lacks with --lock-joints)")
    if joints is None or list(joints) == ["all"]:
        joints = robot
    for nm in joints:
        if nm not in robot:
            raise ReachsetError(f"joint {nm} is not a joint of the robot model {effort.urdf}")
    data, dups, common = {}, {}, None
    for f, c in cols.items():
        for nm in robot:
            st, v, d = _unique_sorted(np.frombuffer(c.stamps[nm], np.int64), np.frombuffer(c.values[nm]))
            data[f, nm] = (st, v)
            dups[nm] = dups.get(nm, 0) + d
            common = st if common is None else np.intersect1d(common, st, assume_unique=True)
    n_pos = {nm: len(data["position", nm][0]) for nm in robot}
    rep.period_s = check_period(path, y_topic, common, dt)
    mats = {}
    for f in cols:
        m = np.empty((len(common), len(robot)))
        for j, nm in enumerate(robot):
            st, v = data[f, nm]
            m[:, j] = v[np.searchsorted(st, common)]
        mats[f] = m
    U = effort.plant_inputs(mats["position"], mats["velocity"], mats["effort"])
    out = {}
    for name in joints:
        j = robot.index(name)
        stamps = common.copy()
        y, u = mats["position"][:, j].copy(), U[:, j].copy()
        valid = np.isfinite(y) & np.isfinite(u)
        segs = segments_of(stamps, valid, dt)
        for a in (stamps, y, u):
            a.setflags(write=False)
        out[name] = JointSeries(name, stamps, y, u, segs, dt)
        rep.duplicates[name] = dups[name]
        rep.unpaired[name] = int(n_pos[name] - len(stamps))
        rep.invalid_samples[name] = int((~valid).sum())
        rep.gaps[name] = max(0, len(segs) - 1)
    return out, rep
