"""MCAP storage files read chunk by chunk, and the checks of a bag's storage before reading.

The ``mcap`` library reads the file structure (summary, chunk index, chunk records); the
message records of a chunk are located with numpy (from the chunk's message indexes when
they tile it exactly, else by walking its records as rosbags does) and decoded in batches
by :mod:`.cdr`. A bag this path does not handle (unindexed MCAP, other message encodings)
raises :class:`_Fallback` and is read through rosbags instead (:mod:`.series`); a damaged
file raises :class:`_Damaged`. :func:`_preflight` checks ``metadata.yaml`` and names a
missing, truncated or foreign storage file before rosbags would report it without a name.
"""
from __future__ import annotations

import os
import struct
import zlib
from array import array
from pathlib import Path

import lz4.frame
import numpy as np
import yaml
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk

from ..errors import ReachsetError
from .cdr import CdrError, _rosbags_deserializer, _rows_view, decode_rows


class _Fallback(Exception):
    """The fast MCAP path does not handle this bag; read it through rosbags."""


class _Damaged(Exception):
    """A damaged storage file; the message names the file and the problem."""


_REC = struct.Struct("<BQ").unpack_from
_MSG = struct.Struct("<HIQ").unpack_from


def _decompress(chunk):
    data = chunk.data
    if chunk.compression == "zstd":
        data = zstandard.ZstdDecompressor().decompress(data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
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

    ``wanted``: topic -> (msgtype, [(key, field), ...]): each field of the topic's
    messages goes to ``sinks[key]``. Uses the mcap library for the file structure
    (summary, chunk index, chunk records) and numpy for the messages.
    """
    with open(fpath, "rb") as f:
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
        except Exception as e:  # noqa: BLE001 (the mcap library raises many types)
            raise _Damaged(f"no valid MCAP summary ({type(e).__name__}: {e})") from None
        if summary is None or not summary.chunk_indexes:
            raise _Fallback("unindexed MCAP")
        if not set(wanted) <= {ch.topic for ch in summary.channels.values()}:
            # a summary need not repeat the Channel/Schema records (the MCAP spec makes them
            # optional there): they are in the data section, which rosbags reads
            raise _Fallback("MCAP summary without the wanted channels")
        chans = {}
        for cid, ch in summary.channels.items():
            if ch.topic in wanted:
                schema = summary.schemas.get(ch.schema_id)
                msgtype = wanted[ch.topic][0]
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
                msgtype, outs = wanted[topic]
                pos = o + (ordinal << 32)
                for key, fld in outs:
                    sink = sinks[key]

                    def emit(rows, stamps, names, values, sink=sink, logt=logt, pos=pos):
                        sink.add_group(src, logt[rows], pos[rows], stamps, names, values)
                    try:
                        decode_rows(B, o + 31, L, msgtype, fld, emit, _rosbags_deserializer(msgtype, fld))
                    except CdrError as e:
                        raise _Damaged(f"message on {topic} at log time {int(logt[e.row])} ns: {e}") from None


#: Storage plugin of a bare storage file (read without metadata.yaml, as ``ros2 bag`` does).
BARE_STORAGE = {".mcap": "mcap", ".db3": "sqlite3"}
#: The rosbag2 metadata versions this reader handles (rosbags' DirectoryReader: 1-9).
METADATA_VERSIONS = (1, 9)


def _storage_files(path):
    """Storage plugin and storage files of a bag from its ``metadata.yaml``.

    A bare ``.mcap`` or ``.db3`` file is its own single storage file. Raises
    :class:`ReachsetError` naming ``metadata.yaml`` when it is not readable text, not YAML,
    of an unsupported version, or lacks the storage entries; rosbags checks the rest.
    """
    if path.is_file():
        if path.suffix not in BARE_STORAGE:
            raise ReachsetError(f"{path}: not a rosbag2 bag (a directory with metadata.yaml, "
                                "or a .mcap or .db3 file)")
        return BARE_STORAGE[path.suffix], [path]

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
    ver = info.get("version")
    lo, hi = METADATA_VERSIONS
    if not isinstance(ver, int) or isinstance(ver, bool) or not lo <= ver <= hi:
        raise ReachsetError(f"{path}: rosbag2 metadata version {ver!r} is not supported "
                            f"(this reader handles versions {lo}-{hi}); convert the bag with a "
                            "newer `ros2 bag convert` or report it")
    storage, rel = info.get("storage_identifier"), info.get("relative_file_paths")
    if not isinstance(storage, str):
        raise bad("no storage_identifier")
    if not isinstance(rel, list) or not rel or not all(isinstance(x, str) and x for x in rel):
        raise bad("no relative_file_paths")
    return storage, [path / Path(x).name for x in rel]


_MCAP_MAGIC = b"\x89MCAP0\r\n"

#: The one wording of a truncated MCAP storage file (no end magic), whichever reader meets it
#: (``reachset inspect``, identify/check's reader, the decoded messages of the demo and plots).
TRUNCATED_MCAP = "truncated MCAP file, no end magic; `mcap recover` may rescue its messages"


def truncated_mcap(path, fname):
    """The error of a truncated MCAP storage file ``fname`` of the bag ``path``
    (:data:`TRUNCATED_MCAP`)."""
    return ReachsetError(f"{path}: unreadable bag ({fname}: {TRUNCATED_MCAP})")


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
            raise truncated_mcap(path, fpath.name)
    return files
