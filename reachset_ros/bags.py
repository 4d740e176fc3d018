"""rosbag2 bags (MCAP by default, sqlite3 readable): writing and reading with rosbags.

No rclpy: the custom ``reachset_msgs`` types are registered in a rosbags typestore from
their ``.msg`` texts (installed by ``msg_defs/`` under ``share/reachset_msgs/msg``, or the
repository's ``msg_defs/msg`` in a source checkout), and every bag written here carries
its message definitions, so any rosbags or mcap reader decodes it without this package.
"""
from __future__ import annotations

import os
import shutil
from functools import lru_cache
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from .errors import ReachsetError

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
    yield Path(__file__).resolve().parent.parent / "msg_defs" / "msg"


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
    """Write a rosbag2 directory atomically: into ``<path>.partial``, renamed on success.

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
        self.tmp = self.path.with_name(self.path.name + ".partial")
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
        self._writer = Writer(self.tmp, version=9, storage_plugin=plugin)
        self._conns = {}

    def __enter__(self):
        self._writer.open()
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
        finally:
            if exc_type is None:
                os.replace(self.tmp, self.path)
            else:
                shutil.rmtree(self.tmp, ignore_errors=True)
        return False


# ----------------------------------------------------------------------------------------
# Reading: per-joint series of y (``/joint_states`` position) and u_p (``/plant_input``)
# ----------------------------------------------------------------------------------------
from array import array  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402

from rosbags.highlevel import AnyReader  # noqa: E402


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

    def as_dict(self):
        return {k: v for k, v in self.__dict__.items()}


def _stamp_ns(msg) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


class _TopicColumns:
    """Per joint name: growing arrays of (stamp, value); no message objects are kept."""

    def __init__(self):
        self.stamps = {}
        self.values = {}
        self.order = []
        self.count = 0
        self.out_of_order = 0
        self._last = None

    def add(self, stamp, names, values):
        self.count += 1
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


def read_topics(paths, topics=(JOINT_STATES, PLANT_INPUT)):
    """Stream ``topics`` of the bags into per-joint columns.

    Returns ``{topic: _TopicColumns}``. Raises :class:`ReachsetError` naming the bag for
    unreadable bags and the topic when one is missing.
    """
    cols = {t: _TopicColumns() for t in topics}
    ts = typestore()
    for p in paths:
        path = Path(p)
        _check_bag_path(path)
        try:
            with AnyReader([path], default_typestore=ts) as reader:
                have = {c.topic for c in reader.connections}
                for t in topics:
                    if t not in have:
                        raise ReachsetError(f"{path}: topic {t} missing")
                conns = [c for c in reader.connections if c.topic in cols]
                for conn, _t, raw in reader.messages(connections=conns):
                    msg = ts.deserialize_cdr(raw, conn.msgtype)
                    vals = msg.position if conn.topic == JOINT_STATES else msg.acceleration
                    cols[conn.topic].add(_stamp_ns(msg), msg.name, vals)
        except ReachsetError:
            raise
        except Exception as e:  # rosbags raises many types for damaged files
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ReachsetError(f"{path}: unreadable bag ({type(e).__name__}: {first})") from e
    return cols


def _unique_sorted(stamps, values):
    order = np.argsort(stamps, kind="stable")
    s, v = stamps[order], values[order]
    keep = np.ones(len(s), dtype=bool)
    keep[1:] = s[1:] != s[:-1]
    return s[keep], v[keep], int((~keep).sum())


def segments_of(stamps, valid, dt):
    """Index ranges ``(start, stop)`` of consecutive valid ticks.

    Consecutive means the stamp step is within ``[0.5 dt, 1.5 dt]``; an invalid sample or a
    larger step (a missing tick, a pause between recordings) ends a segment.
    """
    n = len(stamps)
    if n == 0:
        return ()
    step = np.diff(stamps).astype(np.float64) * 1e-9
    joined = (step >= 0.5 * dt) & (step <= 1.5 * dt) & valid[1:] & valid[:-1]
    segs = []
    start = None
    for i in range(n):
        if not valid[i]:
            if start is not None:
                segs.append((start, i))
                start = None
            continue
        if start is None:
            start = i
        elif not joined[i - 1]:
            segs.append((start, i))
            start = i
    if start is not None:
        segs.append((start, n))
    return tuple(segs)


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
        for key in ("messages", "duplicates", "out_of_order", "unpaired", "invalid_samples", "gaps"):
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
    common = [n for n in js.order if n in pi.stamps]
    if joints is None or list(joints) == ["all"]:
        joints = common
        rep.ignored_joints = sorted(set(js.order) ^ set(pi.order))
    if not joints:
        raise ReachsetError(f"{', '.join(map(str, paths))}: no joint is on both {JOINT_STATES} and {PLANT_INPUT}")
    out = {}
    for name in joints:
        for topic, c in ((JOINT_STATES, js), (PLANT_INPUT, pi)):
            if name not in c.stamps:
                raise ReachsetError(f"joint {name} not found on {topic}")
        ys, yv, ydup = _unique_sorted(np.frombuffer(js.stamps[name], np.int64), np.frombuffer(js.values[name]))
        us, uv, udup = _unique_sorted(np.frombuffer(pi.stamps[name], np.int64), np.frombuffer(pi.values[name]))
        stamps, iy, iu = np.intersect1d(ys, us, assume_unique=True, return_indices=True)
        y, u = yv[iy].copy(), uv[iu].copy()
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
