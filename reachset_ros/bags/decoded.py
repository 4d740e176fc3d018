"""Messages decoded one by one: whole messages of small bags, and the rows of a topic with ``name[]``.

* :func:`read_messages`: the decoded messages of some topics in log-time order (small bags:
  the demo's status and safe stops, tests).
* :func:`read_topic_rows`: per joint, the rows of several float arrays of a topic with
  ``name[]`` (``/reference``, ``/observer/estimate``; see :mod:`.references`).

Both decode with rosbags' ``deserialize_cdr`` and the typestore of :mod:`.messages`; the
streamed reading of the large topics is :mod:`.topics`.
"""
from __future__ import annotations

from contextlib import ExitStack
from heapq import merge
from pathlib import Path

import numpy as np

from ..errors import ReachsetError, first_line
from .messages import header_stamp_ns, typestore
from .topics import check_bag


#: (message type, the bag's definition text) -> the typestore to decode it with (None: ours)
_OWN_TYPESTORES = {}


def _own_typestore(conn, ts):
    """``ts``, or, for a connection whose bag defines its ``reachset_msgs`` type otherwise (a bag
    recorded before a field was added, e.g. ConformanceStatus.set_use of issue 36.3), a typestore
    with the bag's own definition (its messages then lack the new field)."""
    md = getattr(conn, "msgdef", None)
    data = getattr(md, "data", "") or ""
    if not conn.msgtype.startswith("reachset_msgs/") or getattr(getattr(md, "format", None), "name", "") != "MSG" \
            or not data.strip():
        return ts
    key = (conn.msgtype, data)
    cache = _OWN_TYPESTORES
    if key not in cache:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
        try:
            types = get_types_from_msg(data, conn.msgtype)
            if types[conn.msgtype] == ts.fielddefs.get(conn.msgtype):
                cache[key] = None
            else:
                own = get_typestore(Stores.ROS2_JAZZY)
                own.register(types)
                cache[key] = own
        except Exception:  # noqa: BLE001 (a definition rosbags cannot parse: decode with ours)
            cache[key] = None
    return ts if cache[key] is None else cache[key]


def _decoded(reader, conns, ts, path=""):
    """``(topic, log_time_ns, msg)`` of the connections ``conns`` of an open rosbags reader,
    in the order it yields them, each message decoded with ``ts`` (or the bag's own definition
    of a ``reachset_msgs`` type where it differs, :func:`_own_typestore`). A message that is not
    valid CDR for its type raises :class:`ReachsetError` naming the bag, the topic and the log time."""
    for conn, t, raw in reader.messages(connections=conns):
        try:
            msg = _own_typestore(conn, ts).deserialize_cdr(raw, conn.msgtype)
        except Exception as e:  # noqa: BLE001 (rosbags raises SerdeError, struct.error, ...)
            raise ReachsetError(f"{path}: malformed message on {conn.topic} at log time {t} ns "
                                f"(not valid CDR for {conn.msgtype}: {type(e).__name__}: {first_line(e)})") from None
        yield conn.topic, t, msg


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
    status and safe stops, tests). A bag that is not one, or whose storage is missing or
    truncated, raises :class:`ReachsetError` (:func:`~.topics.check_bag`) before any message
    is yielded, and so does a message of the topics read that is not valid CDR for its type
    (naming the topic; the other topics of the bag can still be read); other rosbags exceptions
    while reading pass unchanged.
    """
    from rosbags.rosbag2 import Reader  # lazy: rosbags.rosbag2's start-up (issue 38.1)
    ts = typestore()
    wanted = None if topics is None else set(topics)
    with ExitStack() as stack:
        gens = []
        for p in paths:
            check_bag(p)
            reader = stack.enter_context(Reader(Path(p)))
            conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
            if conns:
                gens.append(_decoded(reader, conns, ts, p))
        yield from merge(*gens, key=lambda m: m[1])


def read_topic_rows(paths, topic, fields, joints=None):
    """Per-joint ``(stamps, values (T, len(fields)))`` of a topic with ``name[]`` and float arrays.

    Decoded with rosbags (the bag's own message definitions); sorted by header stamp,
    duplicate stamps dropped. Returns ``None`` when no bag has the topic.
    """
    from rosbags.rosbag2 import Reader  # lazy: rosbags.rosbag2's start-up (issue 38.1)
    ts = None                           # the typestore (0.1 s: rosbags' stores) only for a bag with the topic
    cols, found = {}, False
    for p in paths:
        path = Path(p)
        check_bag(path)
        try:
            with Reader(path) as reader:
                conns = [c for c in reader.connections if c.topic == topic]
                if not conns:
                    continue
                found = True
                ts = ts or typestore()
                for _topic, _t, msg in _decoded(reader, conns, ts, path):
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
            first = first_line(e)
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
