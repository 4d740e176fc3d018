"""Bags from the wild (issue 36.5): ``reachset inspect`` names malformed topics and reads on, does
not count the gap between two bags as jitter, warns about a stop or a fault before it suggests
``identify``; every reader words a truncated MCAP file the same way."""
import json
import subprocess
import sys

import pytest

from reachset_ros import bags
from reachset_ros.errors import ReachsetError

T0, DT_NS = 1_700_000_000_000_000_000, 4_000_000
#: what a data collector's leader topic held: bytes that are not CDR of sensor_msgs/msg/JointState
GARBAGE = b"\x00\x01\x00\x00garbage"


def run(*argv):
    return subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, argv)], capture_output=True,
                          text=True, timeout=300)


def good_bag(path, n=300, t0=T0, extra=None):
    """/joint_states and /plant_input at 250 Hz; ``extra(writer, i, t)`` adds more per tick."""
    with bags.BagWriter(path) as w:
        for i in range(n):
            t = t0 + DT_NS * i
            w.write(bags.JOINT_STATES, bags.joint_state(t, ["a"], [1e-3 * i], [0.0], [0.0]), t)
            w.write(bags.PLANT_INPUT, bags.plant_input(t, ["a"], [0.0]), t)
            if extra is not None:
                extra(w, i, t)
    return path


def test_inspect_names_a_malformed_topic_and_reads_the_rest(tmp_path):
    """A bare MCAP with a good JointState topic and one whose payloads are not valid CDR: the old
    inspect refused the whole bag ("unreadable bag (SerdeError ...)", exit 2)."""
    bag = good_bag(tmp_path / "wild", extra=lambda w, i, t: w.write_raw(
        "/leader/joint_states", GARBAGE + bytes([i % 256]), t, bags.JOINT_STATE_TYPE))
    bare = bag / "wild.mcap"
    p = run("inspect", bare, "--json")
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert list(d["malformed_topics"]) == ["/leader/joint_states"]
    assert "SerdeError" in d["malformed_topics"]["/leader/joint_states"]
    leader = d["topics"]["/leader/joint_states"]
    assert leader["count"] == 300 and leader["malformed"]["messages"] == 300
    js = d["topics"][bags.JOINT_STATES]
    assert js["count"] == 300 and "malformed" not in js and abs(js["stamps"]["period_ms"] - 4.0) < 1e-9
    cmd = d["identify"]["command"]
    assert cmd and "--dt 0.004" in cmd and "leader" not in cmd, d["identify"]
    text = run("inspect", bare)
    assert text.returncode == 0, text.stderr
    assert "malformed topic /leader/joint_states" in text.stdout and "SerdeError" in text.stdout
    # the reader reads the good topics of the same bag; the malformed one is refused naming it
    cols = bags.read_topics([bare])
    assert len(cols[bags.JOINT_STATES].stamps["a"]) == 300
    with pytest.raises(ReachsetError, match="/leader/joint_states"):
        bags.read_topics([bag], ["/leader/joint_states"])
    assert sum(1 for _ in bags.read_messages([bare], [bags.JOINT_STATES, bags.PLANT_INPUT])) == 600
    with pytest.raises(ReachsetError, match="malformed message on /leader/joint_states"):
        list(bags.read_messages([bag]))


def test_the_gap_between_two_bags_is_not_jitter(tmp_path):
    """Two bags of 4 ms steps, the second 60 s after the first: the old inspect reported a
    jitter of 60 s (max) and a rate of a few Hz."""
    a = good_bag(tmp_path / "a")
    b = good_bag(tmp_path / "b", t0=T0 + 60_000_000_000)
    d = json.loads(run("inspect", a, b, "--json").stdout)
    for topic in (bags.JOINT_STATES, bags.PLANT_INPUT):
        r = d["topics"][topic]
        assert r["count"] == 600
        for stats in (r["stamps"], r["log_time"]):
            assert abs(stats["period_ms"] - 4.0) < 1e-9
            assert stats["jitter_ms"]["max_abs_dev"] < 1e-6, stats
            assert abs(stats["rate_hz"] - 250.0) < 1e-6, stats


def _safe_stop(t, kind, reason):
    return bags.typestore().types[bags.SAFE_STOP_TYPE](
        header=bags.header(t), active=True, reason=reason, kind=kind, joint="a", step=3, test_case_start_ns=t,
        deviation=0.1, bound=0.01, window_bag="")


def _stop_and_fault(w, i, t):
    if i == 100:
        w.write(bags.FAULT_ONSET_TOPIC, bags.header(t), t, bags.FAULT_ONSET_TYPE)
    if i == 120:
        w.write(bags.SAFE_STOP_TOPIC, _safe_stop(t, "violation", "a left its reachable set"), t, bags.SAFE_STOP_TYPE)


def _start_up_hold(w, i, t):
    if i == 0:      # the monitor's stop until its model is loaded: the start of every monitored run
        w.write(bags.SAFE_STOP_TOPIC, _safe_stop(t, "not_ready", "monitor not ready"), t, bags.SAFE_STOP_TYPE)


def test_a_stop_or_a_fault_is_flagged_before_identify_is_suggested(tmp_path):
    """The old inspect printed a plain ``identify: reachset identify ...`` for a bag with a
    simulated fault and a safe stop in it."""
    bag = good_bag(tmp_path / "faulty", extra=_stop_and_fault)
    p = run("inspect", bag)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    warn = [n for n, line in enumerate(lines) if line.startswith("WARNING:")]
    ident = [n for n, line in enumerate(lines) if line.startswith("identify")]
    assert len(warn) == 2 and len(ident) == 1 and max(warn) < ident[0], p.stdout
    assert not lines[ident[0]].startswith("identify: "), "a plain suggestion without the warning"
    assert "safe stop" in p.stdout and "fault onset" in p.stdout and "violation" in p.stdout
    d = json.loads(run("inspect", bag, "--json").stdout)
    assert len(d["warnings"]) == 2 and d["identify"]["warnings"] == d["warnings"] and d["identify"]["command"]
    clean = json.loads(run("inspect", good_bag(tmp_path / "clean"), "--json").stdout)   # control
    assert clean["warnings"] == [] and clean["malformed_topics"] == {}
    held = json.loads(run("inspect", good_bag(tmp_path / "held", extra=_start_up_hold), "--json").stdout)
    assert held["warnings"] == [] and held["topics"][bags.SAFE_STOP_TOPIC]["count"] == 1


def test_a_truncated_mcap_is_worded_the_same_by_every_reader(tmp_path):
    """inspect said "unreadable bag (ReaderError: File end magic is invalid.)", the decoded
    readers "cannot read /joint_states (ReaderError ...)" or rosbags' bare ReaderError, while
    identify's reader named the truncated file."""
    bag = good_bag(tmp_path / "bag")
    mcap = bag / "bag.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    expected = f"{bag}: unreadable bag (bag.mcap: {bags.TRUNCATED_MCAP})"
    for argv in (("inspect", bag), ("identify", bag)):
        p = run(*argv)
        assert p.returncode == 2 and expected in p.stderr, (argv, p.stderr)
    for read in (lambda: list(bags.read_messages([bag])),
                 lambda: bags.read_topic_rows([bag], bags.JOINT_STATES, ["position"]),
                 lambda: bags.read_joint_series([bag])):
        with pytest.raises(ReachsetError) as e:
            read()
        assert str(e.value) == expected
