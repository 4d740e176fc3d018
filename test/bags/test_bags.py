"""Bag reading: the fast CDR decoder and MCAP path equal rosbags; damaged bags fail cleanly."""
import shutil
import struct
import subprocess
import sys
from array import array
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.serde import SerdeError

from reachset_ros import bags
from reachset_ros.errors import ReachsetError

T0 = 1_700_000_000_000_000_000
DT_NS = 4_000_000
TS = bags.typestore()

# ------------------------------------------------------------------ decoder == rosbags
texts = st.text(max_size=12)
floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
float_lists = st.lists(floats, max_size=7)
stamps = st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1))


@st.composite
def messages(draw):
    """A batch of messages of one type: a few layouts, each used by several messages."""
    js = draw(st.booleans())
    layouts = draw(st.lists(st.tuples(texts, st.lists(texts, max_size=7),
                                      st.tuples(st.integers(0, 7), st.integers(0, 7), st.integers(0, 7))),
                            min_size=1, max_size=3))
    out = []
    for _ in range(draw(st.integers(1, 8))):
        frame, names, lens = draw(st.sampled_from(layouts))
        (sec, nsec), little = draw(stamps), draw(st.sampled_from([True, True, True, False]))
        Time = TS.types["builtin_interfaces/msg/Time"]
        hdr = TS.types["std_msgs/msg/Header"](stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)
        arr = [np.array(draw(st.lists(floats, min_size=n, max_size=n)), dtype=np.float64) for n in lens]
        if js:
            msg = TS.types[bags.JOINT_STATE_TYPE](header=hdr, name=names, position=arr[0], velocity=arr[1],
                                                  effort=arr[2])
        else:
            msg = TS.types[bags.PLANT_INPUT_TYPE](header=hdr, name=names, acceleration=arr[0])
        out.append(bytes(TS.serialize_cdr(msg, msg.__msgtype__, little_endian=little)))
    return (bags.JOINT_STATE_TYPE, "position") if js else (bags.PLANT_INPUT_TYPE, "acceleration"), out


def rosbags_decode(raw, msgtype, field):
    m = TS.deserialize_cdr(raw, msgtype)
    return (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, list(m.name),
            np.asarray(getattr(m, field), dtype=np.float64))


def assert_same(got, want):
    assert got[0] == want[0] and got[1] == want[1]
    # bitwise: NaN payloads and signed zeros included
    assert got[2].view(np.uint64).tolist() == want[2].view(np.uint64).tolist()


@pytest.mark.slow
@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages())
def test_decoder_equals_rosbags_deserialize_cdr(batch):
    (msgtype, field), payloads = batch
    got = bags.decode_payloads(payloads, msgtype, field)
    for g, raw in zip(got, payloads):
        assert_same(g, rosbags_decode(raw, msgtype, field))


@pytest.mark.slow
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages(), st.data())
def test_decoder_rejects_exactly_what_rosbags_rejects(batch, data):
    """Truncated, extended or corrupted payloads: the decoder fails iff rosbags fails."""
    (msgtype, field), payloads = batch
    raw = bytearray(payloads[0])
    how = data.draw(st.sampled_from(["truncate", "byte", "extend"]))
    if how == "truncate":
        raw = raw[:data.draw(st.integers(0, len(raw)))]
    elif how == "byte":
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    else:
        raw += bytes(data.draw(st.integers(1, 9)))
    raw = bytes(raw)
    try:
        want = rosbags_decode(raw, msgtype, field)
    except SerdeError:
        want = None
    try:
        got = bags.decode_payloads([raw] + payloads[1:], msgtype, field)[0]
    except bags.CdrError:
        got = None
    assert (got is None) == (want is None)
    if want is not None:
        assert_same(got, want)


def test_decoder_groups_only_identical_layouts():
    """Equal lengths but different names, frame ids, counts or padding bytes: each payload
    is still decoded as rosbags decodes it."""
    def js(stamp, names, pos, vel=(), frame=""):
        m = bags.joint_state(stamp, names, pos, vel)
        m.header.frame_id = frame
        return bytearray(TS.serialize_cdr(m, bags.JOINT_STATE_TYPE))
    raws = [js(T0, ["ab"], [1.0]), js(T0 + 1, ["cd"], [2.0]), js(T0 + 2, ["ab"], [3.0], frame=""),
            js(T0 + 3, ["ab"], [], [4.0]), js(T0 + 4, ["a", "b"], [5.0, 6.0]), js(T0 + 5, ["ab"], [7.0])]
    raws[5][17:20] = b"\xab\xab\xab"            # non-zero padding after frame_id
    assert len({len(r) for r in raws[:3] + raws[5:]}) == 1
    raws = [bytes(r) for r in raws] * 3
    for g, raw in zip(bags.decode_payloads(raws, bags.JOINT_STATE_TYPE, "position"), raws):
        assert_same(g, rosbags_decode(raw, bags.JOINT_STATE_TYPE, "position"))


# ------------------------------------------------------------------ bag reader == rosbags reader
def reference_columns(path, topics=(bags.JOINT_STATES, bags.PLANT_INPUT), field=None):
    """The reader before the fast path: rosbags' AnyReader and deserialize_cdr, message by message
    (``field``: read this array instead of the type's value field)."""
    cols = {t: bags.topics._TopicColumns() for t in topics}
    with AnyReader([Path(path)], default_typestore=TS) as reader:
        conns = [c for c in reader.connections if c.topic in cols]
        for conn, _t, raw in reader.messages(connections=conns):
            msg = TS.deserialize_cdr(raw, conn.msgtype)
            vals = (getattr(msg, field) if field else
                    msg.position if conn.msgtype == bags.JOINT_STATE_TYPE else msg.acceleration)
            cols[conn.topic].add(bags.header_stamp_ns(msg), msg.name, vals)
    return cols


def assert_columns_equal(got, want):
    for topic in want:
        g, w = got[topic], want[topic]
        assert (g.count, g.out_of_order, g.order) == (w.count, w.out_of_order, w.order), topic
        for n in w.order:
            assert g.stamps[n] == w.stamps[n], (topic, n)
            assert np.frombuffer(g.values[n], np.uint64).tolist() == np.frombuffer(w.values[n], np.uint64).tolist()


def messy_stream(n=400, seed=1):
    """(log time, topic, msgtype, payload): shuffled joint order, an extra joint, a joint that
    comes and goes, duplicates, stamps out of order, NaN, more names than values, an unrelated
    topic, log times out of order."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        stamp = T0 + DT_NS * i
        if i % 50 == 7:
            stamp -= 3 * DT_NS          # out of order / duplicate stamp
        names = ["j1", "j2", "j3"]
        if i % 3 == 1:
            names = names[::-1]
        if i % 7 == 0:
            names = names + ["gripper"]
        if 100 <= i < 140:
            names = [nm for nm in names if nm != "j2"]
        q = rng.normal(size=len(names))
        if i == 222:
            q[0] = np.nan
        pos = q[:-1] if i % 11 == 0 else q      # fewer values than names
        recv = T0 + DT_NS * i + int(rng.integers(0, 3 * DT_NS))     # log times not monotonic
        eff = rng.normal(size=len(names) - (i % 7 == 0)) if i % 3 else []   # effort: often, not always, filled
        out.append((recv, bags.JOINT_STATES, bags.JOINT_STATE_TYPE,
                    bags.joint_state(stamp, names, pos, rng.normal(size=len(names)), eff)))
        out.append((recv + 1000, bags.PLANT_INPUT, bags.PLANT_INPUT_TYPE,
                    bags.plant_input(stamp, names, rng.normal(size=len(names)))))
        if i % 5 == 0:
            out.append((recv, "/reference", bags.PLANT_INPUT_TYPE, bags.plant_input(stamp, ["x"], [1.0])))
    return out


def write_rosbags(path, stream, storage="mcap", compression=None):
    w = Writer(path, version=9, storage_plugin={"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage])
    if compression:
        w.set_compression(compression, CompressionFormat.ZSTD)
    conns = {}
    with w:
        for t, topic, msgtype, msg in stream:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=TS)
            w.write(conns[topic], t, TS.serialize_cdr(msg, msgtype))


def write_mcap_lib(path, stream, compression, index, repeat=True):
    """A rosbag2 directory whose MCAP file is written by the mcap library (small chunks);
    ``repeat=False``: the summary does not repeat the Channel and Schema records (allowed by
    the MCAP spec; they are only in the data section)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, IndexType
    from mcap.writer import Writer as McapWriter
    write_rosbags(path, stream[:3])             # metadata.yaml, schemas, channels
    f = next(Path(path).glob("*.mcap"))
    with open(f, "rb") as fh:
        summary = make_reader(fh).get_summary()
    with open(f, "wb") as fh:
        w = McapWriter(fh, chunk_size=4096, compression=getattr(CompressionType, compression),
                       index_types=getattr(IndexType, index), repeat_channels=repeat, repeat_schemas=repeat)
        w.start("ros2", "test")
        ids = {}
        for cid, ch in summary.channels.items():
            s = summary.schemas[ch.schema_id]
            sid = w.register_schema(s.name, s.encoding, s.data)
            ids[ch.topic] = w.register_channel(ch.topic, ch.message_encoding, sid, dict(ch.metadata))
        for t, topic, msgtype, msg in stream:
            w.add_message(ids[topic], t, bytes(TS.serialize_cdr(msg, msgtype)), t)
        w.finish()


@pytest.fixture
def rosbags_reads(monkeypatch):
    """Counts bags read message by message through rosbags (not by the MCAP fast path)."""
    calls = []
    real = bags.topics._read_rosbags

    def spy(*a, **kw):
        calls.append(a)
        return real(*a, **kw)
    monkeypatch.setattr(bags.topics, "_read_rosbags", spy)
    return calls


def write_layout(path, stream, kind):
    """``stream`` as a bag in one of the real layouts: written by rosbags (``mcap``,
    ``sqlite3``, zstd file mode ``mcap-zstd-chunks``, zstd message mode ``message-compressed``)
    or by the mcap library (summary without Channel/Schema records ``mcap-lib-no-repeat``; no
    index at all ``mcap-lib-unindexed``, messages then in log-time order)."""
    if kind == "mcap-zstd-chunks":
        write_rosbags(path, stream, compression=CompressionMode.STORAGE)
    elif kind == "message-compressed":
        write_rosbags(path, stream, compression=CompressionMode.MESSAGE)
    elif kind == "mcap-lib-no-repeat":
        write_mcap_lib(path, stream, "ZSTD", "ALL", repeat=False)
    elif kind == "mcap-lib-unindexed":
        write_mcap_lib(path, sorted(stream, key=lambda s: s[0]), "NONE", "NONE")
    else:
        write_rosbags(path, stream, storage=kind)


@pytest.mark.parametrize("kind", ["mcap", "sqlite3", "mcap-zstd-chunks", "message-compressed"])
def test_reader_equals_rosbags_on_messy_bags(tmp_path, kind, rosbags_reads):
    path = tmp_path / "b"
    write_layout(path, messy_stream(), kind)
    assert_columns_equal(bags.read_topics([path]), reference_columns(path))
    assert len(rosbags_reads) == (kind in ("sqlite3", "message-compressed"))


@pytest.mark.parametrize("compression,index", [("NONE", "ALL"), ("LZ4", "ALL"), ("ZSTD", "ALL"),
                                               ("ZSTD", "CHUNK"), ("NONE", "NONE")])
@pytest.mark.slow
def test_reader_equals_rosbags_on_many_chunk_mcap(tmp_path, compression, index, rosbags_reads):
    """Many small chunks, overlapping in log time: the order (hence duplicates kept and
    out-of-order counts) is exactly rosbags'. Without message indexes the chunks are
    scanned (rosbags reads no message from such chunks, so the reference is the same stream
    with all indexes); without any index (no chunk index) rosbags reads the file, which
    needs messages in log-time order."""
    stream = messy_stream()
    if index == "NONE":
        stream.sort(key=lambda s: s[0])
    write_mcap_lib(tmp_path / "b", stream, compression, index)
    write_mcap_lib(tmp_path / "ref", stream, "NONE", "ALL")
    want = reference_columns(tmp_path / "ref")
    assert want[bags.JOINT_STATES].count == 400
    assert_columns_equal(bags.read_topics([tmp_path / "b"]), want)
    assert len(rosbags_reads) == (index == "NONE")


@pytest.mark.parametrize("kind", ["mcap", "sqlite3", "mcap-zstd-chunks", "message-compressed", "mcap-lib-no-repeat",
                                  "mcap-lib-unindexed"])
@pytest.mark.slow
def test_several_arrays_of_a_topic_in_one_pass_equal_rosbags(tmp_path, kind):
    """Issue 15.3: ``--input effort`` reads position, velocity and effort of one JointState
    topic in one pass (read_fields); each equals rosbags' message-by-message decoding, on
    bags written by rosbags (both storages, both compression modes) and by the mcap library
    (summary without channels; no index at all)."""
    path = tmp_path / "b"
    write_layout(path, messy_stream(), kind)
    fields = ("position", "velocity", "effort")
    got = bags.read_fields([path], {f: (bags.JOINT_STATES, f) for f in fields})
    for f in fields:
        want = reference_columns(path, (bags.JOINT_STATES,), field=f)
        assert_columns_equal({bags.JOINT_STATES: got[f]}, want)
    assert sum(len(v) for v in got["effort"].values.values()) > 0      # effort was there to read


def test_mcap_whose_summary_does_not_repeat_the_channels_is_read(tmp_path, rosbags_reads):
    """Issue 15.5(a): such an MCAP read as empty (the fast path found no channel in the
    summary); it is read as rosbags reads it (all 400 messages), through rosbags."""
    stream = messy_stream()
    write_mcap_lib(tmp_path / "b", stream, "ZSTD", "ALL", repeat=False)
    want = reference_columns(tmp_path / "b")
    assert want[bags.JOINT_STATES].count == 400
    assert_columns_equal(bags.read_topics([tmp_path / "b"]), want)
    assert len(rosbags_reads) == 1


def test_topics_are_read_by_message_type_not_by_name(tmp_path):
    """Issue 15.5(b): a JointState topic with another name than /joint_states was read as if
    it were a PlantInput ("unreadable bag ... tuple.index"); the value field is chosen by the
    message type. A topic of another type is refused naming it."""
    path = tmp_path / "b"
    with bags.BagWriter(path) as w:
        for i in range(30):
            t = T0 + DT_NS * i
            w.write("/arm/joint_states", bags.joint_state(t, ["a", "b"], [0.1 * i, -0.1 * i]), t,
                    bags.JOINT_STATE_TYPE)
            w.write("/arm/u", bags.plant_input(t, ["a", "b"], [1.0, 2.0]), t + 1000, bags.PLANT_INPUT_TYPE)
            w.write("/arm/onset", bags.header(t), t + 2000, "std_msgs/msg/Header")
    topics = ("/arm/joint_states", "/arm/u")
    got = bags.read_topics([path], topics)
    assert_columns_equal(got, reference_columns(path, topics))
    assert np.frombuffer(got["/arm/joint_states"].values["b"], np.float64)[-1] == -0.1 * 29
    with pytest.raises(ReachsetError, match="topic /arm/onset has type std_msgs/msg/Header; expected"):
        bags.read_topics([path], ("/arm/joint_states", "/arm/onset"))


def test_big_endian_messages_are_read(tmp_path, rosbags_reads):
    path = tmp_path / "b"
    with bags.BagWriter(path) as w:
        for i in range(20):
            t = T0 + DT_NS * i
            for topic, msg in ((bags.JOINT_STATES, bags.joint_state(t, ["a", "b"], [i, -i])),
                               (bags.PLANT_INPUT, bags.plant_input(t, ["a", "b"], [1.0, 2.0]))):
                w.write_raw(topic, bytes(TS.serialize_cdr(msg, msg.__msgtype__, little_endian=i % 2 == 0)), t,
                            msg.__msgtype__)
    assert_columns_equal(bags.read_topics([path]), reference_columns(path))
    assert not rosbags_reads


def test_sqlite3_and_mcap_bags_give_the_same_series(tmp_path):
    stream = [s for s in messy_stream(300, seed=4) if s[1] != "/reference"]
    stream.sort(key=lambda s: s[0])
    write_rosbags(tmp_path / "m", stream)
    write_rosbags(tmp_path / "s", stream, storage="sqlite3")
    a, ra = bags.read_joint_series([tmp_path / "m"])
    b, rb = bags.read_joint_series([tmp_path / "s"])
    assert list(a) == list(b) == ["j1", "j2", "j3", "gripper"]
    for n in a:
        for f in ("stamps", "y", "u"):
            np.testing.assert_array_equal(getattr(a[n], f), getattr(b[n], f))
        assert a[n].segments == b[n].segments
    assert ra.as_dict() == rb.as_dict()


def test_bag_writer_names_storage_file_after_the_bag(tmp_path):
    with bags.BagWriter(tmp_path / "run1") as w:
        w.write(bags.JOINT_STATES, bags.joint_state(T0, ["a"], [0.0]), T0)
    assert sorted(p.name for p in (tmp_path / "run1").iterdir()) == ["metadata.yaml", "run1.mcap"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run1"]


def monitored_bag(path, t0, n, storage="mcap"):
    """A bag as the demo records it: /joint_states, /conformance/status, /safe_stop, /sim/fault_onset."""
    CS, SS = TS.types[bags.STATUS_TYPE], TS.types[bags.SAFE_STOP_TYPE]
    with bags.BagWriter(path, storage=storage) as w:
        for i in range(n):
            t = t0 + DT_NS * i
            w.write(bags.JOINT_STATES, bags.joint_state(t, ["a", "b"], [i, -i]), t + 1)
            w.write(bags.STATUS_TOPIC, CS(header=bags.header(t), conformant=i < n - 2, safe_stop_active=False, tick=i,
                                          horizon=3, active_test_cases=1, name=["a", "b"], margin=np.array([0.5, i]),
                                          deviation=np.zeros(2), tightest_step=np.zeros(2, np.int32),
                                          check_duration=0.0, model_id="m", set_use=np.zeros(2)), t + 2,
                                          bags.STATUS_TYPE)
        w.write(bags.FAULT_ONSET_TOPIC, bags.header(t0 + DT_NS), t0 + DT_NS + 3, bags.FAULT_ONSET_TYPE)
        w.write(bags.SAFE_STOP_TOPIC, SS(header=bags.header(t), active=True, reason="why", kind="violation", joint="a",
                                         step=2, test_case_start_ns=t0, deviation=1.0, bound=0.5, window_bag=""),
                t + 4, bags.SAFE_STOP_TYPE)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_read_messages_decodes_the_topics_in_log_time_order(tmp_path, storage):
    monitored_bag(tmp_path / "b", T0, 5, storage)
    topics = (bags.STATUS_TOPIC, bags.SAFE_STOP_TOPIC, bags.FAULT_ONSET_TOPIC)
    got = list(bags.read_messages([tmp_path / "b"], topics))
    assert [(topic, t) for topic, t, _ in got] == sorted(
        [(bags.STATUS_TOPIC, T0 + DT_NS * i + 2) for i in range(5)] + [(bags.FAULT_ONSET_TOPIC, T0 + DT_NS + 3),
                                                                      (bags.SAFE_STOP_TOPIC, T0 + DT_NS * 4 + 4)],
        key=lambda x: x[1])
    status = [m for topic, _, m in got if topic == bags.STATUS_TOPIC]
    assert [bags.header_stamp_ns(m) for m in status] == [T0 + DT_NS * i for i in range(5)]
    assert [bool(m.conformant) for m in status] == [True, True, True, False, False]
    assert [m.margin.tolist() for m in status] == [[0.5, float(i)] for i in range(5)] and status[2].tick == 2
    (stop,) = [m for topic, _, m in got if topic == bags.SAFE_STOP_TOPIC]
    assert (stop.active, stop.reason, stop.kind, stop.joint, stop.step) == (True, "why", "violation", "a", 2)
    (onset,) = [m for topic, _, m in got if topic == bags.FAULT_ONSET_TOPIC]
    assert onset.stamp.sec * 1_000_000_000 + onset.stamp.nanosec == T0 + DT_NS
    # all topics (None), and two bags merged by log time
    monitored_bag(tmp_path / "c", T0 + DT_NS // 2, 3, storage)
    both = list(bags.read_messages([tmp_path / "b", tmp_path / "c"]))
    assert len(both) == 2 * 5 + 2 + 2 * 3 + 2
    assert [t for _, t, _ in both] == sorted(t for _, t, _ in both)
    js = [m for topic, _, m in both if topic == bags.JOINT_STATES]
    assert [list(m.name) for m in js] == [["a", "b"]] * 8 and js[1].position.tolist() == [0.0, 0.0]
    assert list(bags.read_messages([tmp_path / "b"], ["/reference"])) == []


def test_read_references_and_estimates_through_the_reader(tmp_path):
    """Rows per joint sorted by stamp, duplicate stamps dropped (first kept), NaN for short
    arrays, None without the topic, a damaged bag named."""
    JR = TS.types[bags.REFERENCE_TYPE]
    path = tmp_path / "r"
    with bags.BagWriter(path) as w:
        for i, k in enumerate([0, 1, 3, 2, 2, 4]):         # out of order, stamp 2 twice
            t = T0 + DT_NS * k
            w.write(bags.REFERENCE_TOPIC, JR(header=bags.header(t), name=["a", "b"], position=np.array([k, i + 0.5]),
                                             velocity=np.array([10.0 * k]), acceleration=np.array([i, -i], float)),
                    T0 + i, bags.REFERENCE_TYPE)
    rows = bags.read_topic_rows([path], bags.REFERENCE_TOPIC, ("position", "velocity", "acceleration"))
    st, v = rows["a"]
    assert st.tolist() == [T0 + DT_NS * k for k in range(5)]
    assert v.tolist() == [[0, 0, 0], [1, 10, 1], [2, 20, 3], [3, 30, 2], [4, 40, 5]]
    assert np.isnan(rows["b"][1][:, 1]).all() and rows["b"][1][:, 0].tolist() == [0.5, 1.5, 3.5, 2.5, 5.5]
    assert bags.read_references([path], ["b"]) == {}       # NaN velocities: no valid stretch
    (ref,) = bags.read_references([path])["a"]
    assert ref.q.tolist() == [0, 1, 2, 3, 4] and ref.qdd.tolist() == [0, 1, 3, 2, 5]
    assert bags.read_estimates([path]) is None
    (path / "r.mcap").write_bytes((path / "r.mcap").read_bytes()[:100])
    with pytest.raises(ReachsetError) as e:      # the one wording of a truncated MCAP (issue 36.5)
        bags.read_references([path])
    assert str(e.value) == f"{path}: unreadable bag (r.mcap: {bags.TRUNCATED_MCAP})"


def test_damaged_payload_names_bag_file_and_topic(tmp_path):
    path = tmp_path / "b"
    with bags.BagWriter(path) as w:
        for i in range(10):
            t = T0 + DT_NS * i
            js = bytearray(TS.serialize_cdr(bags.joint_state(t, ["a"], [0.0]), bags.JOINT_STATE_TYPE))
            if i == 6:
                struct.pack_into("<I", js, 16, 1000)       # frame_id length beyond the message
            w.write_raw(bags.JOINT_STATES, bytes(js), t, bags.JOINT_STATE_TYPE)
            w.write(bags.PLANT_INPUT, bags.plant_input(t, ["a"], [0.0]), t)
    with pytest.raises(ReachsetError, match=r"b: unreadable bag \(b\.mcap: message on /joint_states"):
        bags.read_joint_series([path])


# ------------------------------------------------------------------ damaged bags via the CLI
def small_bag(path, storage="mcap", plant_input=True):
    with bags.BagWriter(path, storage=storage) as w:
        for i in range(200):
            t = T0 + DT_NS * i
            w.write(bags.JOINT_STATES, bags.joint_state(t, ["a"], [1e-3 * np.sin(0.1 * i)]), t)
            if plant_input:
                w.write(bags.PLANT_INPUT, bags.plant_input(t, ["a"], [np.cos(0.1 * i)]), t)


def damage(tmp_path, case):
    path = tmp_path / "bag"
    if case == "not_a_bag":
        path.mkdir()
        (path / "notes.txt").write_text("hello")
        return path, ["not a rosbag2 directory"]
    if case in ("no_plant_input", "no_plant_input_sqlite3"):
        small_bag(path, "sqlite3" if case.endswith("sqlite3") else "mcap", plant_input=False)
        return path, ["topic /plant_input missing"]
    small_bag(path)
    mcap = path / "bag.mcap"
    if case == "truncated_mcap":
        data = mcap.read_bytes()
        mcap.write_bytes(data[:len(data) // 2])
        return path, ["bag.mcap", "truncated"]
    if case == "garbage_metadata":
        (path / "metadata.yaml").write_text("rosbag2_bagfile_information: {{{ [")
        return path, ["metadata.yaml"]
    if case == "incomplete_metadata":
        (path / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 9\n")
        return path, ["metadata"]
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["truncated_mcap", "garbage_metadata", "incomplete_metadata", "not_a_bag",
                                  "no_plant_input", "no_plant_input_sqlite3"])
@pytest.mark.slow
def test_cli_damaged_bag_exit_2_one_line_naming_it(tmp_path, case):
    path, words = damage(tmp_path, case)
    out = tmp_path / "model.yaml"
    r = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "identify", str(path), "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("reachset identify: error: "), r.stderr
    assert str(path) in r.stderr and "Traceback" not in r.stderr
    for w in words:
        assert w in r.stderr, r.stderr
    assert r.stdout == ""
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_intact_copy_of_damaged_bag_reads(tmp_path):
    """Control for the cases above: the undamaged bag identifies fine in-process."""
    small_bag(tmp_path / "bag")
    shutil.copytree(tmp_path / "bag", tmp_path / "copy")
    series, rep = bags.read_joint_series([tmp_path / "copy"])
    assert list(series) == ["a"] and len(series["a"].stamps) == 200 and rep.gaps == {"a": 0}
    assert isinstance(bags.read_topics([tmp_path / "copy"])[bags.JOINT_STATES].stamps["a"], array)


def _segments_loop(stamps, valid, dt):
    """The original loop implementation of segments_of (reference)."""
    n = len(stamps)
    if n == 0:
        return ()
    step = np.diff(stamps).astype(np.float64) * 1e-9
    joined = (step >= 0.5 * dt) & (step <= 1.5 * dt) & valid[1:] & valid[:-1]
    segs, start = [], None
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


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([0, 1, 2, 4, 4, 4, 5, 6, 9]), st.booleans()), max_size=40))
def test_vectorised_segments_equal_the_loop(ticks):
    stamps = np.cumsum(np.array([s for s, _ in ticks], dtype=np.int64) * 1_000_000)
    valid = np.array([v for _, v in ticks], dtype=bool)
    assert bags.segments_of(stamps, valid, 0.004) == _segments_loop(stamps, valid, 0.004)
