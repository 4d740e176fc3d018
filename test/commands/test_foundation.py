"""Foundation: real DDS between processes, real bags, the command line."""
import subprocess
import sys

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader

from reachset_ros import bags


def test_reachset_help_runs():
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "--help"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    assert "usage: reachset" in out.stdout


@pytest.mark.dds
def test_plant_input_between_processes_and_parameter_set_across_them():
    from reachset_ros.nodes.selftest import run_selftest
    res = run_selftest(timeout=60.0, value=2.25)
    assert res["first"]["name"] == ["joint_1", "joint_2"]
    assert res["first"]["acceleration"] == [0.0, 0.0]
    assert res["after_set"]["acceleration"] == [2.25, 2.25]


def _sample_stream(n=50):
    rng = np.random.default_rng(0)
    names = ["arm_1_joint", "arm_2_joint", "arm_3_joint"]
    t0 = 1_700_000_000_000_000_000
    rows = []
    for k in range(n):
        t = t0 + 4_000_000 * k
        rows.append((t, names, rng.normal(size=3), rng.normal(size=3)))
    return rows


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_roundtrip_rosbags(tmp_path, storage):
    rows = _sample_stream()
    path = tmp_path / "bag"
    with bags.BagWriter(path, storage=storage) as w:
        for t, names, q, u in rows:
            w.write(bags.JOINT_STATES, bags.joint_state(t, names, q), t)
            w.write(bags.PLANT_INPUT, bags.plant_input(t, names, u), t)
    assert not (tmp_path / "bag.partial").exists()
    ts = bags.typestore()
    got = {bags.JOINT_STATES: [], bags.PLANT_INPUT: []}
    with Reader(path) as r:
        for conn, t, raw in r.messages():
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert stamp == t
            vals = msg.position if conn.topic == bags.JOINT_STATES else msg.acceleration
            got[conn.topic].append((t, list(msg.name), np.array(vals)))
    for topic, idx in ((bags.JOINT_STATES, 2), (bags.PLANT_INPUT, 3)):
        assert len(got[topic]) == len(rows)
        for (t, names, vals), row in zip(got[topic], rows):
            assert t == row[0] and names == row[1]
            np.testing.assert_array_equal(vals, row[idx])


def test_bag_read_by_mcap_library(tmp_path):
    rows = _sample_stream(20)
    path = tmp_path / "bag"
    with bags.BagWriter(path) as w:
        for t, names, q, u in rows:
            w.write(bags.JOINT_STATES, bags.joint_state(t, names, q), t)
            w.write(bags.PLANT_INPUT, bags.plant_input(t, names, u), t)
    files = list(path.glob("*.mcap"))
    assert len(files) == 1
    seen = {"/joint_states": 0, "/plant_input": 0}
    with open(files[0], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            k = seen[channel.topic]
            t, names, q, u = rows[k]
            assert list(decoded.name) == names
            vals = decoded.position if channel.topic == "/joint_states" else decoded.acceleration
            np.testing.assert_array_equal(np.array(vals), q if channel.topic == "/joint_states" else u)
            seen[channel.topic] += 1
    assert seen == {"/joint_states": len(rows), "/plant_input": len(rows)}


def test_bag_writer_leaves_nothing_on_error(tmp_path):
    path = tmp_path / "bag"
    with pytest.raises(RuntimeError):
        with bags.BagWriter(path) as w:
            w.write(bags.JOINT_STATES, bags.joint_state(1, ["a"], [0.0]), 1)
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
