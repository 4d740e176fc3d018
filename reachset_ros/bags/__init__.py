"""rosbag2 bags (MCAP by default, sqlite3 readable): writing with rosbags, fast reading.

No rclpy: the custom ``reachset_msgs`` types are registered in a rosbags typestore from
their ``.msg`` texts (installed by ``msg_defs/`` under ``share/reachset_msgs/msg``, or the
repository's ``msg_defs/msg`` in a source checkout), and every bag written here carries
its message definitions, so any rosbags or mcap reader decodes it without this package.

Reading streams: MCAP files are read chunk by chunk (the ``mcap`` library for the file
structure, numpy for the messages: ``sensor_msgs/msg/JointState`` and
``reachset_msgs/msg/PlantInput`` CDR payloads of the same layout are decoded together,
with exactly rosbags' checks); other storage (sqlite3, compressed bag files, unindexed
MCAP) goes through rosbags' reader with the same batch decoder. Only compact arrays of
stamps and values are kept; results equal rosbags' ``deserialize_cdr`` message by message
(``test/test_bags.py``). Timings: ``docs/performance.md``.
"""
from __future__ import annotations

import os
import shutil
import struct
import zlib
from array import array
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ..errors import ReachsetError

#: Topics of the bag layout (../shared/INTERFACES.md).
JOINT_STATES = "/joint_states"
PLANT_INPUT = "/plant_input"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
PLANT_INPUT_TYPE = "reachset_msgs/msg/PlantInput"
REACHSET_MSGS = ("PlantInput", "JointReference", "JointEstimate", "ConformanceStatus",
                 "SafeStop", "JointSynthesis", "SynthesisResult")


def _msg_dirs():
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            yield Path(prefix) / "share" / "reachset_msgs" / "msg"
    yield Path(__file__).resolve().parents[2] / "msg_defs" / "msg"


def msg_definition(name: str) -> str:
    """Text of ``reachset_msgs/msg/<name>.msg``."""
    for d in _msg_dirs():
        p = d / f"{name}.msg"
        if p.is_file():
            return p.read_text()
    raise ReachsetError(f"message definition reachset_msgs/msg/{name}.msg not found "
                        "(is msg_defs/ installed?)")


@lru_cache(maxsize=1)
def typestore():
    """A Jazzy typestore with all ``reachset_msgs`` messages registered."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name in REACHSET_MSGS:
        types.update(get_types_from_msg(msg_definition(name), f"reachset_msgs/msg/{name}"))
    ts.register(types)
    return ts


def stamp_msg(stamp_ns: int):
    """``builtin_interfaces/msg/Time`` of an integer nanosecond stamp."""
    Time = typestore().types["builtin_interfaces/msg/Time"]
    return Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


def header(stamp_ns: int, frame_id: str = ""):
    Header = typestore().types["std_msgs/msg/Header"]
    return Header(stamp=stamp_msg(stamp_ns), frame_id=frame_id)


def joint_state(stamp_ns, names, position, velocity=(), effort=()):
    """A ``sensor_msgs/msg/JointState`` (rosbags object)."""
    JS = typestore().types[JOINT_STATE_TYPE]
    return JS(header=header(stamp_ns), name=list(names),
              position=np.asarray(position, dtype=np.float64),
              velocity=np.asarray(velocity, dtype=np.float64),
              effort=np.asarray(effort, dtype=np.float64))


def plant_input(stamp_ns, names, acceleration):
    """A ``reachset_msgs/msg/PlantInput`` (rosbags object)."""
    PI = typestore().types[PLANT_INPUT_TYPE]
    return PI(header=header(stamp_ns), name=list(names),
              acceleration=np.asarray(acceleration, dtype=np.float64))


class BagWriter:
    """Write a rosbag2 directory atomically: into ``<path>.partial/<name>``, renamed on success.

    Syntax::

        with BagWriter("bags/run1") as bag:
            bag.write("/joint_states", joint_state(t, names, q), t)

    Parameters
    ----------
    path : str or Path
        Bag directory to create; it must not exist.
    storage : {"mcap", "sqlite3"}
        Storage plugin (default MCAP).

    On an exception inside the ``with`` block nothing is left at ``path``.
    """

    TYPES = {JOINT_STATES: JOINT_STATE_TYPE, PLANT_INPUT: PLANT_INPUT_TYPE}

    def __init__(self, path, storage: str = "mcap"):
        self.path = Path(path)
        if self.path.exists():
            raise ReachsetError(f"{self.path}: output bag already exists")
        # written as <path>.partial/<name> and renamed on success, so that the storage
        # file is named after the bag (<name>.mcap), not after the temporary directory
        self._tmp_parent = self.path.with_name(self.path.name + ".partial")
        if self._tmp_parent.exists():
            shutil.rmtree(self._tmp_parent)
        self.tmp = self._tmp_parent / self.path.name
        plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
        self._writer = Writer(self.tmp, version=9, storage_plugin=plugin)
        self._conns = {}

    def __enter__(self):
        try:
            self._writer.open()      # creates the temporary directories
        except BaseException:
            shutil.rmtree(self._tmp_parent, ignore_errors=True)
            raise
        return self

    def connection(self, topic: str, msgtype: str | None = None):
        if topic not in self._conns:
            msgtype = msgtype or self.TYPES[topic]
            self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=typestore())
        return self._conns[topic]

    def write(self, topic: str, msg, timestamp_ns: int, msgtype: str | None = None):
        """Serialize ``msg`` (rosbags object) and write it with receive time ``timestamp_ns``."""
        conn = self.connection(topic, msgtype)
        self._writer.write(conn, int(timestamp_ns), typestore().serialize_cdr(msg, conn.msgtype))

    def write_raw(self, topic: str, data: bytes, timestamp_ns: int, msgtype: str):
        """Write already CDR-serialized bytes (e.g. from rclpy's ``serialize_message``)."""
        self._writer.write(self.connection(topic, msgtype), int(timestamp_ns), data)

    def __exit__(self, exc_type, exc, tb):
        try:
            self._writer.close()
            if exc_type is None:
                os.replace(self.tmp, self.path)
        finally:
            shutil.rmtree(self._tmp_parent, ignore_errors=True)
        return False


# ----------------------------------------------------------------------------------------
# Reading: per-joint series of y (``/joint_states`` position) and u_p (``/plant_input``)
# ----------------------------------------------------------------------------------------
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

    def as_dict(self):
        return {k: v for k, v in self.__dict__.items()}


def _stamp_ns(msg) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


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
    if not path.exists():
        raise ReachsetError(f"{path}: no such bag")
    if not path.is_dir():
        raise ReachsetError(f"{path}: not a rosbag2 directory")
    if not (path / "metadata.yaml").is_file():
        raise ReachsetError(f"{path}: not a rosbag2 directory (no metadata.yaml)")


# ------------------------------------------------------------------ fast CDR decoding
#: Message types decoded without rosbags: type -> (float64 sequences in order, by field name).
FAST_TYPES = {
    JOINT_STATE_TYPE: ("position", "velocity", "effort"),
    PLANT_INPUT_TYPE: ("acceleration",),
}
_U32 = struct.Struct("<I").unpack_from
_STAMP_DTYPE = np.dtype([("sec", "<i4"), ("nanosec", "<u4")])


class CdrError(ValueError):
    """A CDR payload that rosbags' ``deserialize_cdr`` would reject too."""


class _BigEndian(Exception):
    """A valid-looking big-endian payload: decoded by rosbags instead."""


def cdr_layout(payload, nseq):
    """Parse one little-endian CDR payload of a header + ``string[]`` + ``nseq`` float64[] message.

    Mirrors the checks of rosbags' generated ``deserialize_cdr`` exactly (a payload is
    accepted here iff rosbags accepts it), for ``sensor_msgs/msg/JointState`` (``nseq=3``)
    and ``reachset_msgs/msg/PlantInput`` (``nseq=1``).

    Parameters
    ----------
    payload : bytes
        The serialized message including the 4-byte encapsulation header.
    nseq : int
        Number of float64 sequences after ``name``.

    Returns
    -------
    frame_id : str
    names : tuple of str
    seqs : tuple of (offset, count)
        Byte offset in ``payload`` and length of each float64 sequence.

    Raises
    ------
    CdrError
        Damaged or malformed payload.
    """
    p = payload
    n = len(p)
    if n < 4 or p[0] != 0 or p[1] > 1:
        raise CdrError("invalid or unsupported CDR encapsulation")
    if p[1] == 0:
        raise _BigEndian()
    b = n - 4                       # body length; body offset o is payload offset o + 4

    def u32(o):
        if o + 4 > b:
            raise CdrError(f"truncated at offset {o}")
        return _U32(p, o + 4)[0]

    def string(o):
        size = u32(o)
        end = o + 4 + size
        if size < 1 or end > b:
            raise CdrError(f"invalid string length {size} at offset {o}")
        if p[end + 3] != 0:
            raise CdrError(f"missing string terminator at offset {end - 1}")
        try:
            return p[o + 8:end + 3].decode(), end
        except UnicodeDecodeError as e:
            raise CdrError(f"string at offset {o}: {e}") from None

    if b < 8:
        raise CdrError("truncated header stamp")
    frame_id, pos = string(8)
    pos = (pos + 3) & -4
    count = u32(pos)
    pos += 4
    if pos + 5 * count > b:
        raise CdrError(f"invalid sequence length {count} at offset {pos}")
    names = []
    for _ in range(count):
        pos = (pos + 3) & -4
        s, pos = string(pos)
        names.append(s)
    seqs = []
    for _ in range(nseq):
        pos = (pos + 3) & -4
        count = u32(pos)
        pos += 4
        if pos + 8 * count > b:
            raise CdrError(f"invalid sequence length {count} at offset {pos}")
        if count:
            pos = (pos + 7) & -8
            if pos + 8 * count > b:
                raise CdrError(f"sequence of {count} float64 at offset {pos} exceeds the message")
        seqs.append((pos + 4, count))
        pos += 8 * count
    if pos + 7 < n:
        raise CdrError(f"{n - 4 - pos} bytes after the message")
    return frame_id, tuple(names), tuple(seqs)


def _fixed_ranges(length, seqs):
    """Byte ranges of a payload that are neither the stamp nor float64 data."""
    cuts = [(4, 12)] + [(off, off + 8 * cnt) for off, cnt in seqs if cnt]
    out, at = [], 0
    for a, b in cuts:
        if a > at:
            out.append((at, a))
        at = max(at, b)
    if length > at:
        out.append((at, length))
    return out


def _rows_view(buf, starts, L):
    """(N, L) uint8 rows of ``buf`` at ``starts``: a strided view when equally spaced, else a copy."""
    N = len(starts)
    if N > 1:
        d = np.diff(starts)
        step = int(d[0])
        if step >= L and np.all(d == step) and int(starts[-1]) + L <= len(buf):
            base = buf[int(starts[0]):]
            return np.lib.stride_tricks.as_strided(base, shape=(N, L), strides=(step * buf.strides[0], buf.strides[0]),
                                                   writeable=False)
    if L == 0:
        return np.zeros((N, 0), np.uint8)
    return buf[starts[:, None] + np.arange(L)]


def decode_rows(buf, starts, lengths, msgtype, field, emit, deserialize=None):
    """Decode many CDR payloads of ``msgtype`` stored in ``buf`` at once (vectorised).

    Payloads of equal length whose non-data bytes (everything but the stamp and the
    float64 data) equal those of an already parsed payload share its parse; their stamps
    and values are then read for all of them with numpy.

    Parameters
    ----------
    buf : ndarray of uint8
    starts, lengths : ndarray of int64, shape (N,)
        Offset and length of each payload in ``buf``.
    msgtype : str
        A key of :data:`FAST_TYPES`.
    field : str
        The float64 sequence to read (e.g. ``"position"``).
    emit : callable ``emit(rows, stamps, names, values)``
        Called per group of payloads that share names: ``rows`` indexes into ``starts``,
        ``stamps`` int64 ns (len(rows),), ``values`` float64 (len(rows), k).
    deserialize : callable ``deserialize(bytes) -> (stamp, names, values)``, optional
        For payloads the vectorised path does not handle (big-endian CDR).

    Raises
    ------
    CdrError
        A damaged payload (``.row`` holds its index).
    """
    fields = FAST_TYPES[msgtype]
    nseq, which = len(fields), fields.index(field)
    starts = np.asarray(starts, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    if len(starts) == 0:
        return
    if np.all(lengths == lengths[0]):
        groups = [(int(lengths[0]), np.arange(len(starts)))]
    else:
        ulen, inv = np.unique(lengths, return_inverse=True)
        groups = [(int(L), np.flatnonzero(inv == i)) for i, L in enumerate(ulen)]
    for L, rows in groups:
        M = _rows_view(buf, starts[rows], L)
        rem = None                      # None: all rows of M
        while rem is None or rem.size:
            r = 0 if rem is None else int(rem[0])
            row = M[r].tobytes()
            try:
                _, names, seqs = cdr_layout(row, nseq)
            except _BigEndian:
                if deserialize is None:
                    raise CdrError("big-endian CDR") from None
                try:
                    st, nm, vals = deserialize(row)
                except Exception as e:  # noqa: BLE001 (rosbags' SerdeError and others)
                    err = CdrError(str(e).splitlines()[0] if str(e) else type(e).__name__)
                    err.row = int(rows[r])
                    raise err from None
                vals = np.asarray(vals, dtype=np.float64)
                emit(rows[[r]], np.array([st], np.int64), tuple(nm), vals.reshape(1, -1))
                rem = (np.arange(1, len(rows)) if rem is None else rem[1:])
                continue
            except CdrError as e:
                e.row = int(rows[r])
                raise
            sub = M if rem is None else M[rem]
            same = np.ones(len(sub), dtype=bool)
            for a, b in _fixed_ranges(L, seqs):
                same &= (sub[:, a:b] == M[r, a:b]).all(axis=1)
            if same.all():
                G, sel, rem = sub, (rows if rem is None else rows[rem]), np.zeros(0, np.int64)
            else:
                idx = np.flatnonzero(same) if rem is None else rem[same]
                G, sel = M[idx], rows[idx]
                rem = np.flatnonzero(~same) if rem is None else rem[~same]
            st = np.ascontiguousarray(G[:, 4:12]).view(_STAMP_DTYPE)[:, 0]
            stamps = st["sec"].astype(np.int64) * 1_000_000_000 + st["nanosec"].astype(np.int64)
            off, k = seqs[which]
            vals = np.ascontiguousarray(G[:, off:off + 8 * k]).view("<f8").astype(np.float64, copy=False)
            emit(sel, stamps, names, vals.reshape(len(sel), k))


def decode_payloads(payloads, msgtype, field):
    """Decode a list of CDR payloads; returns a list of (stamp_ns, names, values) in order.

    The vectorised decoder of the bag reader, applied to separate payloads (used by tests
    to compare it with rosbags' ``deserialize_cdr``). Raises :class:`CdrError`.
    """
    lengths = np.array([len(p) for p in payloads], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64) if len(payloads) else lengths
    buf = np.frombuffer(b"".join(bytes(p) for p in payloads), dtype=np.uint8)
    out = [None] * len(payloads)

    def emit(rows, stamps, names, values):
        for i, r in enumerate(rows):
            out[r] = (int(stamps[i]), list(names), values[i].copy())

    decode_rows(buf, starts, lengths, msgtype, field, emit, _rosbags_deserializer(msgtype, field))
    return out


def _rosbags_deserializer(msgtype, field):
    def deserialize(raw):   # the typestore is built only when needed (start-up time)
        msg = typestore().deserialize_cdr(raw, msgtype)
        return _stamp_ns(msg), list(msg.name), np.asarray(getattr(msg, field), dtype=np.float64)
    return deserialize


def _value_field(topic):
    return "position" if topic == JOINT_STATES else "acceleration"


class _Sink:
    """Decoded messages of one topic as compact arrays, grouped by joint names.

    Each group holds, per message, its arrival-order key (source, time, position) and its
    stamp, and a (messages, joints) array of values. :meth:`columns` sorts everything into
    arrival order, which is the order rosbags yields the messages in.
    """

    def __init__(self):
        self.groups = []      # (src (N,), t (N,) uint64, pos (N,), stamps (N,), names, values (N, k))
        self.rows = {}        # single messages: names -> [src, t, pos, stamps, values(flat)]

    def mark(self):
        return len(self.groups), {k: [len(a) for a in v] for k, v in self.rows.items()}

    def rollback(self, mark):
        n, rows = mark
        del self.groups[n:]
        for k in list(self.rows):
            if k not in rows:
                del self.rows[k]
            else:
                for a, m in zip(self.rows[k], rows[k]):
                    del a[m:]

    def add_group(self, src, t, pos, stamps, names, values):
        n = len(stamps)
        self.groups.append((np.full(n, src, np.int64), np.asarray(t, np.uint64), np.asarray(pos, np.int64),
                            np.asarray(stamps, np.int64), tuple(names), np.asarray(values, np.float64)))

    def add_row(self, src, t, pos, stamp, names, values):
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


class _Fallback(Exception):
    """The fast MCAP path does not handle this bag; read it through rosbags."""


class _Damaged(Exception):
    """A damaged storage file; the message names the file and the problem."""


# ------------------------------------------------------------------ MCAP (chunk-level, vectorised)
_REC = struct.Struct("<BQ").unpack_from
_MSG = struct.Struct("<HIQ").unpack_from


def _decompress(chunk):
    data = chunk.data
    if chunk.compression == "zstd":
        import zstandard
        data = zstandard.ZstdDecompressor().decompress(data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame
        data = lz4.frame.decompress(data)
    elif chunk.compression != "":
        raise _Damaged(f"unsupported chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise _Damaged(f"chunk at {chunk.message_start_time}: size {len(data)}, expected {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _Damaged("chunk checksum mismatch")
    return data


def _u64_at(B, offs):
    return np.ascontiguousarray(_rows_view(B, offs, 8)).view("<u8")[:, 0]


def _indexed_records(f, ci, B):
    """Message records of a chunk from its message indexes, if they tile the chunk exactly.

    Returns (offsets, channel ids) of all message records, or None when the index is
    missing or does not account for every byte of the chunk (then the chunk is scanned).
    """
    if not ci.message_index_offsets or ci.message_index_length <= 0:
        return None
    start = min(ci.message_index_offsets.values())
    f.seek(start)
    if start + ci.message_index_length > os.fstat(f.fileno()).st_size:
        return None
    region = f.read(ci.message_index_length)
    if len(region) != ci.message_index_length:
        return None
    offs, chans, pos = [], [], 0
    while pos < len(region):
        if pos + 15 > len(region):
            return None
        op, ln = _REC(region, pos)
        if op != 0x07 or pos + 9 + ln > len(region) or ln < 6:
            return None
        cid, rlen = struct.unpack_from("<HI", region, pos + 9)
        if rlen % 16 or 15 + rlen > 9 + ln:
            return None
        pairs = np.frombuffer(region, "<u8", rlen // 8, pos + 15).reshape(-1, 2)
        offs.append(pairs[:, 1].astype(np.int64))
        chans.append(np.full(len(pairs), cid, np.int64))
        pos += 9 + ln
    if not offs:
        return None
    o = np.concatenate(offs)
    c = np.concatenate(chans)
    n = len(B)
    if len(o) == 0:
        return (o, c) if n == 0 else None
    srt = np.argsort(o, kind="stable")
    o, c = o[srt], c[srt]
    if o[0] != 0 or o[-1] + 31 > n or np.any(o < 0):
        return None
    if np.any(B[o] != 0x05):
        return None
    L = _u64_at(B, o + 1).astype(np.int64)
    end = o + 9 + L
    if np.any(L < 22) or end[-1] != n or np.any(end[:-1] != o[1:]):
        return None
    cid = np.ascontiguousarray(_rows_view(B, o + 9, 2)).view("<u2")[:, 0]
    if np.any(cid != c):
        return None
    return o, c


def _scanned_records(B, data):
    """Message records of a chunk by walking its records (as rosbags does)."""
    offs, chans = array("q"), array("q")
    pos, n = 0, len(data)
    while pos < n:
        if pos + 9 > n:
            raise _Damaged(f"truncated record at chunk offset {pos}")
        op, ln = _REC(data, pos)
        if pos + 9 + ln > n:
            raise _Damaged(f"record at chunk offset {pos} exceeds its chunk")
        if op == 0x05:
            if ln < 22:
                raise _Damaged(f"invalid message record length {ln}")
            offs.append(pos)
            chans.append(_MSG(data, pos + 9)[0])
        pos += 9 + ln
    return np.frombuffer(offs, np.int64), np.frombuffer(chans, np.int64)


def _read_mcap_file(fpath, src, wanted, sinks):
    """Read the wanted topics of one MCAP file chunk by chunk into ``sinks``.

    ``wanted``: topic -> (msgtype, field). Uses the mcap library for the file structure
    (summary, chunk index, chunk records) and numpy for the messages.
    """
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk

    with open(fpath, "rb") as f:
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
        except Exception as e:  # noqa: BLE001 (the mcap library raises many types)
            raise _Damaged(f"no valid MCAP summary ({type(e).__name__}: {e})") from None
        if summary is None or not summary.chunk_indexes:
            raise _Fallback("unindexed MCAP")
        chans = {}
        for cid, ch in summary.channels.items():
            if ch.topic in wanted:
                schema = summary.schemas.get(ch.schema_id)
                msgtype, fld = wanted[ch.topic]
                if ch.message_encoding != "cdr" or schema is None or schema.name != msgtype:
                    raise _Fallback(f"channel {ch.topic} is not {msgtype} in CDR")
                chans[cid] = ch.topic
        cis = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        for ordinal, ci in enumerate(cis):
            if ci.message_index_offsets and not any(c in ci.message_index_offsets for c in chans):
                continue
            f.seek(ci.chunk_start_offset)
            head = f.read(9)
            if len(head) != 9 or head[0] != 0x06:
                raise _Damaged(f"no chunk record at offset {ci.chunk_start_offset}")
            try:
                chunk = Chunk.read(ReadDataStream(f))
            except Exception as e:  # noqa: BLE001
                raise _Damaged(f"chunk at offset {ci.chunk_start_offset}: {type(e).__name__}: {e}") from None
            try:
                data = _decompress(chunk)
            except _Damaged:
                raise
            except Exception as e:  # noqa: BLE001 (zstd/lz4 errors, a huge damaged size)
                raise _Damaged(f"chunk at offset {ci.chunk_start_offset}: {type(e).__name__}"
                               + (f": {str(e).splitlines()[0]}" if str(e) else "")) from e
            B = np.frombuffer(data, dtype=np.uint8)
            recs = _indexed_records(f, ci, B)
            if recs is None:
                recs = _scanned_records(B, data)
            offs, cids = recs
            for cid, topic in chans.items():
                o = offs[cids == cid]
                if len(o) == 0:
                    continue
                L = _u64_at(B, o + 1).astype(np.int64) - 22
                logt = _u64_at(B, o + 15)
                msgtype, fld = wanted[topic]
                sink = sinks[topic]
                pos = o + (ordinal << 32)

                def emit(rows, stamps, names, values, sink=sink, logt=logt, pos=pos):
                    sink.add_group(src, logt[rows], pos[rows], stamps, names, values)
                try:
                    decode_rows(B, o + 31, L, msgtype, fld, emit, _rosbags_deserializer(msgtype, fld))
                except CdrError as e:
                    raise _Damaged(f"message on {topic} at log time {int(logt[e.row])} ns: {e}") from None


def _storage_files(path):
    """Storage plugin and storage files of a bag from its ``metadata.yaml``.

    Raises :class:`ReachsetError` naming ``metadata.yaml`` when it is not readable text,
    not YAML, or lacks the storage entries; rosbags checks the rest.
    """
    def bad(why):
        return ReachsetError(f"{path}: unreadable bag (metadata.yaml: {why})")
    try:
        meta = yaml.safe_load((path / "metadata.yaml").read_bytes().decode("utf-8"))
    except UnicodeDecodeError as e:
        raise bad(f"not UTF-8 text ({e.reason} at byte {e.start})") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        raise bad("does not parse as YAML" + (f" (line {mark.line + 1})" if mark else "")) from None
    except (OSError, RecursionError) as e:
        raise bad(type(e).__name__) from None
    info = meta.get("rosbag2_bagfile_information") if isinstance(meta, dict) else None
    if not isinstance(info, dict):
        raise bad("no rosbag2_bagfile_information mapping")
    storage, rel = info.get("storage_identifier"), info.get("relative_file_paths")
    if not isinstance(storage, str):
        raise bad("no storage_identifier")
    if not isinstance(rel, list) or not rel or not all(isinstance(x, str) and x for x in rel):
        raise bad("no relative_file_paths")
    return storage, [path / Path(x).name for x in rel]


_MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Beginnings of rosbags' errors about the contents of metadata.yaml (raised when a bag is opened).
_METADATA_ERRORS = ("A metadata key is missing", "Invalid bag metadata", "Could not load YAML",
                    "Could not read metadata", "Rosbag2 version", "Storage plugin", "Compression format",
                    "Serialization format")


def _preflight(path):
    """Check ``metadata.yaml`` and name a missing, truncated or foreign MCAP storage file
    before rosbags reports it without a name; returns the storage files."""
    storage, files = _storage_files(path)
    for fpath in files:
        if not fpath.is_file():
            raise ReachsetError(f"{path}: unreadable bag ({fpath.name} listed in metadata.yaml is missing)")
    if storage != "mcap":
        return files
    for fpath in files:
        if fpath.suffix != ".mcap" or not fpath.is_file():
            continue
        size = fpath.stat().st_size
        with open(fpath, "rb") as f:
            head = f.read(8)
            f.seek(max(0, size - 8))
            tail = f.read(8)
        if head != _MCAP_MAGIC:
            raise ReachsetError(f"{path}: unreadable bag ({fpath.name}: not an MCAP file)")
        if size < 16 or tail != _MCAP_MAGIC:
            raise ReachsetError(f"{path}: unreadable bag ({fpath.name}: truncated MCAP file, no end magic; "
                                "`mcap recover` may rescue its messages)")
    return files


# ------------------------------------------------------------------ rosbags (sqlite3 and the rest)
def _read_rosbags(reader, src, wanted, sinks, batch=8192):
    """Read the wanted topics through rosbags; known types are decoded in vectorised batches."""
    ts = typestore()
    conns = [c for c in reader.connections if c.topic in wanted]
    pend = {}     # topic -> (payloads, seqs)

    def flush(topic):
        payloads, seqs = pend.pop(topic)
        msgtype, fld = wanted[topic]
        lengths = np.fromiter((len(p) for p in payloads), np.int64, len(payloads))
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        buf = np.frombuffer(b"".join(payloads), dtype=np.uint8)
        seqs = np.frombuffer(seqs, np.int64)
        sink = sinks[topic]

        def emit(rows, stamps, names, values):
            sink.add_group(src, seqs[rows].astype(np.uint64), np.zeros(len(rows), np.int64), stamps, names, values)
        try:
            decode_rows(buf, starts, lengths, msgtype, fld, emit, _rosbags_deserializer(msgtype, fld))
        except CdrError as e:
            raise ReachsetError(f"unreadable message on {topic} (message {int(seqs[e.row])} of the bag): {e}") from None

    for seq, (conn, _t, raw) in enumerate(reader.messages(connections=conns)):
        topic = conn.topic
        msgtype, fld = wanted[topic]
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
            sinks[topic].add_row(src, seq, 0, _stamp_ns(msg), list(msg.name), getattr(msg, fld))
    for topic in list(pend):
        flush(topic)


def read_topics(paths, topics=(JOINT_STATES, PLANT_INPUT)):
    """Stream ``topics`` of the bags into per-joint columns.

    MCAP bags are read chunk by chunk (the mcap library for the file structure, a
    vectorised CDR decoder for ``sensor_msgs/msg/JointState`` and
    ``reachset_msgs/msg/PlantInput``); sqlite3 bags, compressed bag files, unindexed MCAP
    files and other message types go through rosbags. Either way messages are taken in
    the order rosbags yields them and only compact arrays are kept.

    Returns ``{topic: _TopicColumns}``. Raises :class:`ReachsetError` naming the bag (and
    the damaged file) for unreadable bags and the topic when one is missing.
    """
    sinks = {t: _Sink() for t in topics}
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
                wanted = {t: (types[t], _value_field(t)) for t in topics}
                marks = {t: s.mark() for t, s in sinks.items()}
                try:
                    storage, files = _storage_files(path)
                    if storage != "mcap" or reader.compression_mode or any(
                            mt not in FAST_TYPES or fld not in FAST_TYPES[mt] for mt, fld in wanted.values()):
                        raise _Fallback(storage)
                    for fpath in files:
                        try:
                            _read_mcap_file(fpath, src, wanted, sinks)
                        except _Damaged as e:
                            raise ReachsetError(f"{path}: unreadable bag ({fpath.name}: {e})") from None
                        src += 1
                except _Fallback:
                    for t, s in sinks.items():
                        s.rollback(marks[t])
                    src += 1
                    _read_rosbags(reader, src, wanted, sinks)
                    src += 1
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
    for t, s in sinks.items():
        out[t] = s.columns()
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


def read_joint_series(paths, joints=None, dt=0.004):
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

    Returns
    -------
    series : dict name -> JointSeries
    report : ReadReport
    """
    parts = [_read_one(p, joints, dt) for p in paths]
    if len(parts) == 1:
        return parts[0]
    names = list(parts[0][0])
    for ser, _ in parts[1:]:
        if list(ser) != names:
            raise ReachsetError(f"bags have different joints: {names} vs {list(ser)}; pass --joints")
    out = {}
    for n in names:
        stamps, y, u, segs, off = [], [], [], [], 0
        for ser, _ in parts:
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
    rep = ReadReport()
    for _, r in parts:
        for key in ("messages", "duplicates", "out_of_order", "unpaired", "invalid_samples", "gaps",
                    "name_list_changes"):
            acc = getattr(rep, key)
            for k, v in getattr(r, key).items():
                acc[k] = acc.get(k, 0) + v
        rep.ignored_joints = sorted(set(rep.ignored_joints) | set(r.ignored_joints))
    return out, rep


def _read_one(path, joints, dt):
    paths = [path]
    cols = read_topics(paths)
    js, pi = cols[JOINT_STATES], cols[PLANT_INPUT]
    rep = ReadReport()
    rep.messages = {JOINT_STATES: js.count, PLANT_INPUT: pi.count}
    rep.out_of_order = {JOINT_STATES: js.out_of_order, PLANT_INPUT: pi.out_of_order}
    rep.name_list_changes = {JOINT_STATES: js.name_changes, PLANT_INPUT: pi.name_changes}
    common = [n for n in js.order if n in pi.stamps]
    if joints is None or list(joints) == ["all"]:
        joints = common
        rep.ignored_joints = sorted(set(js.order) ^ set(pi.order))
    if not joints:
        raise ReachsetError(f"{', '.join(map(str, paths))}: no joint is on both {JOINT_STATES} and {PLANT_INPUT}")
    out = {}
    joints = list(joints)
    for i, name in enumerate(joints):
        for topic, c in ((JOINT_STATES, js), (PLANT_INPUT, pi)):
            if name not in c.stamps:
                raise ReachsetError(f"joint {name} not found on {topic}")
        ys, yv, ydup = _unique_sorted(np.frombuffer(js.stamps[name], np.int64), np.frombuffer(js.values[name]))
        us, uv, udup = _unique_sorted(np.frombuffer(pi.stamps[name], np.int64), np.frombuffer(pi.values[name]))
        stamps, iy, iu = _pair(ys, us)
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
