"""Topic reading: per-joint columns of stamps and float arrays of some topics of rosbag2 bags.

* :func:`read_topics`: per-joint columns of stamps and values of ``JointState`` and
  ``PlantInput`` topics, streamed: MCAP bags chunk by chunk (:mod:`.mcap`, decoded by
  :mod:`.cdr`), other storage (sqlite3, compressed bag files, unindexed MCAP) and other
  message types through rosbags' reader with the same batch decoder. Messages are taken in
  the order rosbags yields them and only compact arrays are kept.
* :func:`read_fields`: several float arrays of several topics in one pass (the engine of
  :func:`read_topics`).
* :func:`check_bag_path`: what a bag path may be (a rosbag2 directory or a bare storage file);
  :func:`check_bag`: that and its storage files checked before rosbags opens them.

The pairing of these columns into per-joint series is :mod:`.series`. Unreadable bags raise
:class:`~reachset_ros.errors.ReachsetError` naming the bag (and the damaged file, or the topic).
"""
from __future__ import annotations

from array import array
from pathlib import Path

import numpy as np

from ..errors import ReachsetError
from .cdr import FAST_TYPES, CdrError, _rosbags_deserializer, decode_rows
from .mcap import BARE_STORAGE, _Damaged, _Fallback, _preflight, _read_mcap_file, _storage_files
from .messages import JOINT_STATE_TYPE, JOINT_STATES, PLANT_INPUT, PLANT_INPUT_TYPE, header_stamp_ns, typestore


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


def check_bag_path(path: Path):
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


def check_bag(path) -> list:
    """:func:`check_bag_path`, then the bag's storage files checked before rosbags opens them:
    ``metadata.yaml`` and a missing, foreign or truncated MCAP file are named in one
    :class:`ReachsetError` (a truncated MCAP in the one wording :data:`~.mcap.TRUNCATED_MCAP`,
    whichever reader meets it). Returns the storage files."""
    path = Path(path)
    check_bag_path(path)
    return _preflight(path)


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
        check_bag_path(path)
        where = "metadata.yaml"
        try:
            files = _preflight(path)
            where = ", ".join(f.name for f in files)
            from rosbags.rosbag2 import Reader  # lazy: rosbags.rosbag2's start-up (issue 38.1)
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
