"""Fast CDR decoding: many ``JointState``/``PlantInput`` payloads at once, with numpy.

Payloads of one layout (header, ``string[] name``, float64 sequences) share one parse
(:func:`cdr_layout`, which accepts a payload iff rosbags' ``deserialize_cdr`` does); their
stamps and values are then read for all of them at once (:func:`decode_rows`). Big-endian
payloads go through rosbags. Results equal rosbags' ``deserialize_cdr`` message by message
(``test/bags/test_bags.py``).
"""
from __future__ import annotations

import struct

import numpy as np

from ..errors import first_line
from .messages import JOINT_STATE_TYPE, PLANT_INPUT_TYPE, header_stamp_ns, typestore

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
                    err = CdrError(first_line(e))
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
        return header_stamp_ns(msg), list(msg.name), np.asarray(getattr(msg, field), dtype=np.float64)
    return deserialize
