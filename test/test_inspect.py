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
    assert d["identify"]["command"] is None and "no /plant_input" in d["identify"]["reason"]
    assert "effort" in d["identify"]["reason"] and d["topics"][bags.JOINT_STATES]["filled"]["effort"]
    d = json.loads(run("inspect", renamed, "--json").stdout)
    assert d["identify"]["command"] is None and "/arm/joint_states" in d["identify"]["reason"]
    p = run("inspect", tmp_path / "missing")
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "no such bag" in p.stderr
