"""The bag reader: the one entry point for reading ``reachset_ros`` bags.

* :func:`read_joint_series`: per joint, the paired samples of y (``/joint_states``
  position) and u_p (``/plant_input`` acceleration), sorted by stamp, split into segments
  of consecutive valid ticks (:class:`JointSeries`), with a :class:`ReadReport` of what was
  skipped or repaired. Every command that identifies or checks a model reads bags with it.
* :func:`read_topics`: per-joint columns of stamps and values of ``JointState`` and
  ``PlantInput`` topics, streamed: MCAP bags chunk by chunk (:mod:`.mcap`, decoded by
  :mod:`.cdr`), other storage (sqlite3, compressed bag files, unindexed MCAP) and other
  message types through rosbags' reader with the same batch decoder. Messages are taken in
  the order rosbags yields them and only compact arrays are kept.
* :func:`read_topic_rows`: per joint, the rows of several float arrays of a topic with
  ``name[]`` (``/reference``, ``/observer/estimate``; see :mod:`.references`).
* :func:`read_messages`: the decoded messages of some topics in log-time order (small bags:
  the demo's status and safe stops, tests).

Unreadable bags raise :class:`~reachset_ros.errors.ReachsetError` naming the bag (and the
damaged file, or the topic).
"""
from __future__ import annotations

from array import array
from contextlib import ExitStack
from dataclasses import dataclass, field
from heapq import merge
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from ..errors import ReachsetError
from .cdr import FAST_TYPES, CdrError, _rosbags_deserializer, decode_rows
from .mcap import BARE_STORAGE, _Damaged, _Fallback, _preflight, _read_mcap_file, _storage_files
from .messages import JOINT_STATE_TYPE, JOINT_STATES, PLANT_INPUT, PLANT_INPUT_TYPE, header_stamp_ns, typestore


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

    def as_dict(self):
        return {k: v for k, v in self.__dict__.items()}


class _TopicColumns:
    """Per joint name: arrays of (stamp, value) in arrival order; no message objects are kept.

    ``stamps[name]`` (``array('q')``) and ``values[name]`` (``array('d')``) per joint;
    ``order``: joint names in order of first appearance; ``count``: messages;
    ``out_of_order``: messages whose header stamp is older than an earlier one's;
    ``name_changes``: messages whose joint-name list differs from the first message's.
    """

    def __init__(self):
        self.stamps = {}
        self.values = {}
        self.order = []
        self.count = 0
        self.out_of_order = 0
        self.name_changes = 0
        self._last = None
        self._first_names = None

    def add(self, stamp, names, values):
        """Append one message (used for single messages; bulk reading fills the arrays directly)."""
        self.count += 1
        if self._first_names is None:
            self._first_names = tuple(names)
        elif tuple(names) != self._first_names:
            self.name_changes += 1
        if self._last is not None and stamp < self._last:
            self.out_of_order += 1
        self._last = stamp if self._last is None else max(self._last, stamp)
        n = min(len(names), len(values))
        for i in range(n):
            nm = names[i]
            st = self.stamps.get(nm)
            if st is None:
                st = self.stamps[nm] = array("q")
                self.values[nm] = array("d")
                self.order.append(nm)
            st.append(stamp)
            self.values[nm].append(float(values[i]))


def _check_bag_path(path: Path):
    """A bag is a rosbag2 directory (with metadata.yaml) or, as ``ros2 bag`` accepts it, a
    bare ``.mcap`` / ``.db3`` storage file."""
    if not path.exists():
        raise ReachsetError(f"{path}: no such bag")
    if path.is_file() and path.suffix in BARE_STORAGE:
        return
    if not path.is_dir():
        raise ReachsetError(f"{path}: not a rosbag2 bag (a directory with metadata.yaml, or a .mcap or .db3 file)")
    if not (path / "metadata.yaml").is_file():
        raise ReachsetError(f"{path}: not a rosbag2 directory (no metadata.yaml)")


#: the value array read from each message type: the joints' positions (y_p) of a JointState,
#: the plant input u_p of a PlantInput
VALUE_FIELDS = {JOINT_STATE_TYPE: "position", PLANT_INPUT_TYPE: "acceleration"}


def _value_field(topic, msgtype):
    """The field read from ``topic``, chosen by its message type (not by its name: a
    JointState topic may have any name); ReachsetError for another type."""
    if msgtype not in VALUE_FIELDS:
        raise ReachsetError(f"topic {topic} has type {msgtype}; expected "
                            + " or ".join(sorted(VALUE_FIELDS)))
    return VALUE_FIELDS[msgtype]


class _Sink:
    """Decoded messages of one topic as compact arrays, grouped by joint names.

    Each group holds, per message, its arrival-order key (source, time, position) and its
    stamp, and a (messages, joints) array of values. :meth:`columns` sorts everything into
    arrival order, which is the order rosbags yields the messages in.
    """

    def __init__(self, unnamed=None):
        self.groups = []      # (src (N,), t (N,) uint64, pos (N,), stamps (N,), names, values (N, k))
        self.rows = {}        # single messages: names -> [src, t, pos, stamps, values(flat)]
        #: joint names given to messages with an empty ``name`` array (``--joint-names``)
        self.unnamed = None if unnamed is None else tuple(unnamed)
        #: messages with values but no joint names (when ``unnamed`` is None): refused later
        self.unnamed_messages = 0

    def _names(self, names, k, n):
        """The names of a message group: its own, or ``unnamed`` when it has none."""
        if len(names) or not k:
            return tuple(names)
        if self.unnamed is None:
            self.unnamed_messages += n
            return ()
        if len(self.unnamed) != k:
            raise ReachsetError(f"messages without joint names have {k} values; --joint-names gives "
                                f"{len(self.unnamed)} names")
        return self.unnamed

    def mark(self):
        return len(self.groups), {k: [len(a) for a in v] for k, v in self.rows.items()}, self.unnamed_messages

    def rollback(self, mark):
        n, rows, self.unnamed_messages = mark
        del self.groups[n:]
        for k in list(self.rows):
            if k not in rows:
                del self.rows[k]
            else:
                for a, m in zip(self.rows[k], rows[k]):
                    del a[m:]

    def add_group(self, src, t, pos, stamps, names, values):
        n = len(stamps)
        values = np.asarray(values, np.float64)
        names = self._names(names, values.shape[1] if values.ndim == 2 else 0, n)
        self.groups.append((np.full(n, src, np.int64), np.asarray(t, np.uint64), np.asarray(pos, np.int64),
                            np.asarray(stamps, np.int64), tuple(names), values))

    def add_row(self, src, t, pos, stamp, names, values):
        names = self._names(names, len(values), 1)
        k = min(len(names), len(values))
        key = (tuple(names), k)
        acc = self.rows.get(key)
        if acc is None:
            acc = self.rows[key] = [array("q"), array("Q"), array("q"), array("q"), array("d")]
        acc[0].append(src)
        acc[1].append(t)
        acc[2].append(pos)
        acc[3].append(stamp)
        acc[4].extend(float(v) for v in values[:k])

    def columns(self):
        groups = list(self.groups)
        for (names, k), a in self.rows.items():
            n = len(a[0])
            groups.append((np.frombuffer(a[0], np.int64), np.frombuffer(a[1], np.uint64),
                           np.frombuffer(a[2], np.int64), np.frombuffer(a[3], np.int64), names,
                           np.frombuffer(a[4], np.float64).reshape(n, k)))
        cols = _TopicColumns()
        if not groups:
            return cols
        src = np.concatenate([g[0] for g in groups])
        t = np.concatenate([g[1] for g in groups])
        pos = np.concatenate([g[2] for g in groups])
        stamps = np.concatenate([g[3] for g in groups])
        N = len(stamps)
        if _ascending((src, t, pos)):
            rank = np.arange(N)
            s = stamps
        else:
            order = np.lexsort((pos, t, src))
            rank = np.empty(N, np.int64)
            rank[order] = np.arange(N)
            s = stamps[order]
        cols.count = N
        first_names, at = None, 0
        for g in groups:                # the names of the first message in arrival order
            n = len(g[3])
            if n and int(rank[at:at + n].min()) == 0:
                first_names = g[4]
            at += n
        cols.name_changes = sum(len(g[3]) for g in groups if g[4] != first_names)
        cols.out_of_order = int(np.count_nonzero(s[1:] < np.maximum.accumulate(s)[:-1])) if N > 1 else 0
        cols._last = int(s.max())
        first, parts, at = {}, {}, 0
        for g in groups:
            n = len(g[3])
            r = rank[at:at + n]
            at += n
            names, vals = g[4], g[5]
            k = min(len(names), vals.shape[1])
            if n == 0 or k == 0:
                continue
            rmin = int(r.min())
            for j in range(k):
                nm = names[j]
                if (rmin, j) < first.get(nm, (N, 0)):
                    first[nm] = (rmin, j)
                parts.setdefault(nm, []).append((r, j, g[3], vals[:, j]))
        for nm in sorted(first, key=first.get):
            ps = parts[nm]
            r = np.concatenate([p[0] for p in ps])
            stv = np.concatenate([p[2] for p in ps]).astype(np.int64, copy=False)
            vav = np.concatenate([p[3] for p in ps]).astype(np.float64, copy=False)
            if not (len(r) < 2 or np.all(r[1:] > r[:-1])):
                j = np.concatenate([np.full(len(p[0]), p[1], np.int64) for p in ps])
                o = np.lexsort((j, r))
                stv, vav = stv[o], vav[o]
            st = array("q")
            st.frombytes(stv.tobytes())
            va = array("d")
            va.frombytes(vav.tobytes())
            cols.stamps[nm], cols.values[nm] = st, va
            cols.order.append(nm)
        return cols


def _ascending(keys):
    """Whether the rows of the key columns (most significant first) are in ascending order."""
    n = len(keys[0])
    if n < 2:
        return True
    undecided = np.ones(n - 1, dtype=bool)
    for k in keys:
        d_lt = k[1:] < k[:-1]
        if np.any(d_lt & undecided):
            return False
        undecided &= k[1:] == k[:-1]
    return True


#: Beginnings of rosbags' errors about the contents of metadata.yaml (raised when a bag is opened).
_METADATA_ERRORS = ("A metadata key is missing", "Invalid bag metadata", "Could not load YAML",
                    "Could not read metadata", "Rosbag2 version", "Storage plugin", "Compression format",
                    "Serialization format")



# ------------------------------------------------------------------ rosbags (sqlite3 and the rest)
def _read_rosbags(reader, src, wanted, sinks, batch=8192):
    """Read the wanted topics through rosbags; known types are decoded in vectorised batches.

    ``wanted``: topic -> (msgtype, [(key, field), ...]); each field goes to ``sinks[key]``."""
    ts = typestore()
    conns = [c for c in reader.connections if c.topic in wanted]
    pend = {}     # topic -> (payloads, seqs)

    def flush(topic):
        payloads, seqs = pend.pop(topic)
        msgtype, outs = wanted[topic]
        lengths = np.fromiter((len(p) for p in payloads), np.int64, len(payloads))
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        buf = np.frombuffer(b"".join(payloads), dtype=np.uint8)
        seqs = np.frombuffer(seqs, np.int64)
        for key, fld in outs:
            sink = sinks[key]

            def emit(rows, stamps, names, values, sink=sink):
                sink.add_group(src, seqs[rows].astype(np.uint64), np.zeros(len(rows), np.int64), stamps, names, values)
            try:
                decode_rows(buf, starts, lengths, msgtype, fld, emit, _rosbags_deserializer(msgtype, fld))
            except CdrError as e:
                raise ReachsetError(f"unreadable message on {topic} (message {int(seqs[e.row])} of the bag): {e}") from None

    for seq, (conn, _t, raw) in enumerate(reader.messages(connections=conns)):
        topic = conn.topic
        msgtype, outs = wanted[topic]
        if not isinstance(raw, (bytes, bytearray, memoryview)):   # e.g. NULL in a damaged sqlite3 row
            raise ReachsetError(f"unreadable message on {topic} (message {seq} of the bag): no data")
        if conn.msgtype == msgtype and msgtype in FAST_TYPES:
            p = pend.get(topic)
            if p is None:
                p = pend[topic] = ([], array("q"))
            p[0].append(bytes(raw))
            p[1].append(seq)
            if len(p[0]) >= batch:
                flush(topic)
        else:
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            for key, fld in outs:
                sinks[key].add_row(src, seq, 0, header_stamp_ns(msg), list(msg.name), getattr(msg, fld))
    for topic in list(pend):
        flush(topic)


def read_topics(paths, topics=(JOINT_STATES, PLANT_INPUT), expect=None, joint_names=None):
    """Stream ``topics`` of the bags into per-joint columns.

    MCAP bags are read chunk by chunk (the mcap library for the file structure, a
    vectorised CDR decoder for ``sensor_msgs/msg/JointState`` and
    ``reachset_msgs/msg/PlantInput``); sqlite3 bags, compressed bag files, unindexed MCAP
    files and other message types go through rosbags. Either way messages are taken in
    the order rosbags yields them and only compact arrays are kept.

    The array read from each topic is chosen by its message type (``VALUE_FIELDS``), not
    by its name; ``expect`` (``{topic: msgtype}``) refuses a topic of another type.
    ``joint_names``: the names of messages whose ``name`` array is empty (without it such
    messages are refused, not dropped).

    Returns ``{topic: _TopicColumns}``. Raises :class:`ReachsetError` naming the bag (and
    the damaged file) for unreadable bags and the topic when one is missing.
    """
    return read_fields(paths, {t: (t, None) for t in topics}, expect, joint_names)


def read_fields(paths, requests, expect=None, joint_names=None):
    """Several float arrays of several topics in one pass: the engine of :func:`read_topics`.

    Parameters
    ----------
    paths : sequence of path
        Bags (directories, or bare ``.mcap`` / ``.db3`` files).
    requests : dict key -> (topic, field or None)
        What to read: the array ``field`` of ``topic``'s messages (``None``: the type's
        value field, ``VALUE_FIELDS``), e.g. ``{"q": ("/joint_states", "position"),
        "tau": ("/joint_states", "effort")}``.
    expect : dict topic -> msgtype, optional
        Refuse a topic of another type.
    joint_names : sequence of str, optional
        Names for messages with an empty ``name`` array.

    Returns
    -------
    dict key -> _TopicColumns
    """
    topics = list(dict.fromkeys(t for t, _ in requests.values()))
    sinks = {k: _Sink(joint_names) for k in requests}
    src = 0
    for p in paths:
        path = Path(p)
        _check_bag_path(path)
        where = "metadata.yaml"
        try:
            files = _preflight(path)
            where = ", ".join(f.name for f in files)
            with Reader(path) as reader:
                types = {}
                for c in reader.connections:
                    if not (isinstance(c.topic, str) and isinstance(c.msgtype, str)):
                        raise ReachsetError(f"{path}: unreadable bag (metadata.yaml: bad topic entry "
                                            f"{c.topic!r} of type {c.msgtype!r})")
                    types.setdefault(c.topic, c.msgtype)
                for t in topics:
                    if t not in types:
                        raise ReachsetError(f"{path}: topic {t} missing")
                for t, want in (expect or {}).items():
                    if types.get(t) != want:
                        raise ReachsetError(f"{path}: topic {t} has type {types.get(t)}; expected {want}")
                wanted = {}
                for key, (t, fld) in requests.items():
                    fld = _value_field(t, types[t]) if fld is None else fld
                    wanted.setdefault(t, (types[t], []))[1].append((key, fld))
                marks = {k: s.mark() for k, s in sinks.items()}
                try:
                    storage, files = _storage_files(path)
                    if storage != "mcap" or reader.compression_mode or any(
                            mt not in FAST_TYPES or fld not in FAST_TYPES[mt]
                            for mt, outs in wanted.values() for _, fld in outs):
                        raise _Fallback(storage)
                    for fpath in files:
                        try:
                            _read_mcap_file(fpath, src, wanted, sinks)
                        except _Damaged as e:
                            raise ReachsetError(f"{path}: unreadable bag ({fpath.name}: {e})") from None
                        src += 1
                except _Fallback:
                    for k, s in sinks.items():
                        s.rollback(marks[k])
                    src += 1
                    _read_rosbags(reader, src, wanted, sinks)
                    src += 1
                for key, s in sinks.items():
                    if s.unnamed_messages:
                        raise ReachsetError(f"{path}: {s.unnamed_messages} messages on {requests[key][0]} have "
                                            "no joint names; pass --joint-names a,b,... (the names of their "
                                            "arrays, in order)")
        except ReachsetError as e:
            msg = str(e)
            raise ReachsetError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
        except Exception as e:  # rosbags raises many types for damaged files
            first = str(e).splitlines()[0] if str(e) else ""
            if isinstance(e, MemoryError):
                first = "a record larger than the memory (damaged length field?)"
            if first.startswith(_METADATA_ERRORS):
                where = "metadata.yaml"
            raise ReachsetError(f"{path}: unreadable bag ({where}: {type(e).__name__}"
                                + (f": {first})" if first else ")")) from e
    out = {}
    for k, s in sinks.items():
        out[k] = s.columns()
        s.groups.clear()            # free the decoded groups before the next topic's columns
        s.rows.clear()
    return out


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
    for _, r in parts:
        r.period_s = [r.period_s]
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


# ------------------------------------------------------------------ messages decoded one by one
def _decoded(reader, conns, ts):
    """``(topic, log_time_ns, msg)`` of the connections ``conns`` of an open rosbags reader,
    in the order it yields them, each message decoded with ``ts``."""
    for conn, t, raw in reader.messages(connections=conns):
        yield conn.topic, t, ts.deserialize_cdr(raw, conn.msgtype)


def read_messages(paths, topics=None):
    """Decoded messages of the bags in log-time order: yields ``(topic, log_time_ns, msg)``.

    Parameters
    ----------
    paths : sequence of path
        rosbag2 directories (MCAP or sqlite3); several bags are merged by log time.
    topics : sequence of str or None
        Topics to read (``None``: all); a bag without any of them yields nothing.

    Messages are decoded one by one with rosbags' ``deserialize_cdr`` and the typestore of
    :mod:`.messages` (every type of the bag layout), so this is for small bags (the demo's
    status and safe stops, tests); rosbags' exceptions pass unchanged.
    """
    ts = typestore()
    wanted = None if topics is None else set(topics)
    with ExitStack() as stack:
        gens = []
        for p in paths:
            reader = stack.enter_context(Reader(Path(p)))
            conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
            if conns:
                gens.append(_decoded(reader, conns, ts))
        yield from merge(*gens, key=lambda m: m[1])


def read_topic_rows(paths, topic, fields, joints=None):
    """Per-joint ``(stamps, values (T, len(fields)))`` of a topic with ``name[]`` and float arrays.

    Decoded with rosbags (the bag's own message definitions); sorted by header stamp,
    duplicate stamps dropped. Returns ``None`` when no bag has the topic.
    """
    ts = typestore()
    cols, found = {}, False
    for p in paths:
        path = Path(p)
        try:
            with Reader(path) as reader:
                conns = [c for c in reader.connections if c.topic == topic]
                if not conns:
                    continue
                found = True
                for _topic, _t, msg in _decoded(reader, conns, ts):
                    st = header_stamp_ns(msg)
                    arrs = [np.asarray(getattr(msg, f), float) for f in fields]
                    for i, nm in enumerate(msg.name):
                        if joints is not None and nm not in joints:
                            continue
                        row = [a[i] if i < len(a) else np.nan for a in arrs]
                        cols.setdefault(nm, ([], []))
                        cols[nm][0].append(st)
                        cols[nm][1].append(row)
        except ReachsetError:
            raise
        except Exception as e:  # rosbags raises many types for damaged files
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ReachsetError(f"{path}: cannot read {topic} ({type(e).__name__}: {first})") from None
    if not found:
        return None
    out = {}
    for nm, (st, rows) in cols.items():
        st = np.asarray(st, np.int64)
        vals = np.asarray(rows, float).reshape(len(st), len(fields))
        order = np.argsort(st, kind="stable")
        st, vals = st[order], vals[order]
        keep = np.ones(len(st), bool)
        keep[1:] = st[1:] != st[:-1]
        out[nm] = (st[keep], vals[keep])
    return out
