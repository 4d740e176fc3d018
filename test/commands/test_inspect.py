"""``reachset inspect`` (issue 15, item 1): what a bag holds, and the identify command for it."""
import json
import shlex
import subprocess
import sys

from reachset_ros import bags
from reachset_ros.sim import recordings as sr

T0, DT_NS = 1_700_000_000_000_000_000, 4_000_000


def run(*argv):
    return subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, argv)], capture_output=True,
                          text=True, timeout=300)


def test_inspect_reports_topics_and_a_command_that_works(tmp_path):
    recs = sr.simulate_recordings(("arm_1_joint", "arm_2_joint"), 3000, seed=2)
    bag = tmp_path / "b"
    sr.write_recordings(bag, recs)
    p = run("inspect", bag, "--json")
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    js = d["topics"][bags.JOINT_STATES]
    assert js["type"] == bags.JOINT_STATE_TYPE and js["count"] == 3000
    assert abs(js["stamps"]["period_ms"] - 4.0) < 1e-9 and js["stamps"]["jitter_ms"]["max_abs_dev"] < 1e-6
    assert js["joint_names"] == [["arm_1_joint", "arm_2_joint"]] and js["filled"]["position"]
    assert d["topics"][bags.PLANT_INPUT]["filled"] == {"acceleration": True}
    cmd = d["identify"]["command"]
    assert cmd and "--dt 0.004" in cmd
    # the command it prints works on the bag
    argv = shlex.split(cmd)
    assert argv[:2] == ["reachset", "identify"]
    r = run(*argv[1:], "--json")
    assert r.returncode == 0, r.stderr
    assert set(json.loads(r.stdout)["joints"]) == {"arm_1_joint", "arm_2_joint"}


def test_inspect_says_why_no_command_works(tmp_path):
    only_js, renamed = tmp_path / "only_js", tmp_path / "renamed"
    with bags.BagWriter(only_js) as w, bags.BagWriter(renamed) as v:
        for i in range(20):
            t = T0 + DT_NS * i
            w.write(bags.JOINT_STATES, bags.joint_state(t, ["a"], [0.1 * i], [0.0], [1.5]), t)
            v.write("/arm/joint_states", bags.joint_state(t, ["a"], [0.1 * i]), t, bags.JOINT_STATE_TYPE)
            v.write(bags.PLANT_INPUT, bags.plant_input(t, ["a"], [0.0]), t)
    d = json.loads(run("inspect", only_js, "--json").stdout)
    assert d["identify"]["command"] is None and "no reachset_msgs/msg/PlantInput topic" in d["identify"]["reason"]
    assert "effort" in d["identify"]["reason"] and d["topics"][bags.JOINT_STATES]["filled"]["effort"]
    d = json.loads(run("inspect", renamed, "--json").stdout)       # issue 15.2: the topic is mapped
    assert "--joint-states-topic /arm/joint_states" in d["identify"]["command"], d["identify"]
    p = run("inspect", tmp_path / "missing")
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "no such bag" in p.stderr


def test_topic_mapping_reads_renamed_topics_as_the_standard_ones(tmp_path):
    """Issue 15.2: ``--joint-states-topic`` and ``--input-topic`` on identify/check/replay/
    synthesize: a bag whose topics have other names gives the same model as the same data
    under the standard names; a topic of the wrong type is refused naming it (exit 2)."""
    recs = sr.simulate_recordings(("arm_1_joint",), 2500, seed=5)
    std, ren = tmp_path / "std", tmp_path / "ren"
    sr.write_recordings(std, recs, reference=False, estimate=False)
    from rosbags.rosbag2 import Reader
    with Reader(std) as r, bags.BagWriter(ren) as w:
        rename = {bags.JOINT_STATES: "/robot/joint_states", bags.PLANT_INPUT: "/robot/u"}
        for conn, t, raw in r.messages():
            w.write_raw(rename[conn.topic], bytes(raw), t, conn.msgtype)
    a = run("identify", std, "--json")
    b = run("identify", ren, "--joint-states-topic", "/robot/joint_states", "--input-topic", "/robot/u", "--json")
    assert a.returncode == 0 and b.returncode == 0, (a.stderr, b.stderr)
    ja, jb = json.loads(a.stdout)["joints"], json.loads(b.stdout)["joints"]
    assert ja["arm_1_joint"]["alpha_w"] == jb["arm_1_joint"]["alpha_w"]
    assert ja["arm_1_joint"]["alpha_v"] == jb["arm_1_joint"]["alpha_v"]
    p = run("identify", ren, "--json")                       # without the mapping: missing topic
    assert p.returncode == 2 and "topic /joint_states missing" in p.stderr
    p = run("identify", ren, "--joint-states-topic", "/robot/joint_states", "--input-topic",
            "/robot/joint_states")
    assert p.returncode == 2 and "both /robot/joint_states" in p.stderr
    p = run("identify", ren, "--joint-states-topic", "/robot/u", "--input-topic", "/robot/joint_states")
    assert p.returncode == 2 and "topic /robot/u has type reachset_msgs/msg/PlantInput; expected " \
                                 "sensor_msgs/msg/JointState" in p.stderr, p.stderr
