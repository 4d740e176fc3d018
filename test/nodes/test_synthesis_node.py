"""synthesis_node over real DDS: applying a synthesis by joint name, all or nothing.

controller_node, observer_node, monitor_node and synthesis_node run as separate processes
(``reachset_ros.processes``), the synthesis runs on a real bag written with the package's bag
writer from simulated closed-loop recordings (``sim.recordings.simulate_recordings``, as in
test_synthesis.py; 1000 ticks and a small search, a few seconds per synthesis), and every
parameter is read back through the nodes' ``get_parameters`` services.
"""
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
import yaml
from reachset_msgs.srv import Synthesize

from reachset_ros import processes
from reachset_ros.conformance import model as mdl
from reachset_ros.sim import recordings as sr
from reachset_ros.nodes.common import get_remote_parameters, set_remote_parameters


pytestmark = pytest.mark.dds   # real DDS participants / node processes

ALL_JOINTS = [f"arm_{i}_joint" for i in range(1, 7)]
J = "arm_2_joint"                       # the joint synthesised
IDX = ALL_JOINTS.index(J)
SEARCH = {"sobol_log2": 3, "local_starts": 1, "local_maxfev": 20}
GAIN_KEYS = ("omega", "zeta", "h1", "h2", "l1", "l2", "l3", "eps")
#: distinct per-joint values (and some length-1 arrays, "one for all"), so that a value
#: applied to the wrong joint, or to all joints, shows
INITIAL = {"observer": "hg", "controller": "static", "omega": [15.0], "zeta": [1.0, 1.1, 0.9, 1.0, 1.2, 0.8],
           "h1": [16.0, 14.0, 17.0, 15.5, 16.5, 15.0], "h2": [30.0], "l1": [57.1], "l2": [103.3], "l3": [18.1],
           "eps": [0.01]}
INITIAL_U_MAX = [26.0, 24.0, 26.0, 26.0, 100.0, 100.0]
NAMES = {"controller_node": ["joints", "observer", "controller", *GAIN_KEYS, "u_max", "model_file", "u_ff_bound"],
         "observer_node": ["joints", "dt", "observer", "controller", *GAIN_KEYS, "u_max", "model_file"],
         "monitor_node": ["joints", "model_file"],
         "synthesis_node": ["model_file", "observer"]}


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """Simulated closed-loop recordings (4 s) of two arm joints and a joint no node has."""
    recs = sr.simulate_recordings(["arm_1_joint", J, "gripper_joint"], 1000, seed=3)
    path = tmp_path_factory.mktemp("synth_node") / "sim"
    sr.write_recordings(path, recs)
    return path


@pytest.fixture(scope="module")
def extra_args(tmp_path_factory):
    cfg = tmp_path_factory.mktemp("cfg") / "synthesis.yaml"
    cfg.write_text(yaml.safe_dump({"search": SEARCH}))
    return ["--config", str(cfg)]


@pytest.fixture(scope="module")
def nodes(ros, tmp_path_factory, extra_args):
    work = tmp_path_factory.mktemp("nodes")
    procs = [processes.start("controller_node", {"joints": ALL_JOINTS, **INITIAL, "u_max": INITIAL_U_MAX,
                                              "allow_uncertified": True}, work),
             processes.start("observer_node", {"joints": ALL_JOINTS, **INITIAL, "u_max": INITIAL_U_MAX,
                                            "allow_uncertified": True}, work),
             processes.start("synthesis_node", {"workdir": str(work / "synthesis"), "extra_args": extra_args}, work)]
    try:
        for p in procs:
            values, why = get_remote_parameters(ros, p.name, ["use_sim_time"], timeout=60.0)
            assert values is not None, f"{why}: {p.log.read_text()[-500:]}"
        yield procs
    finally:
        processes.stop(procs)


@pytest.fixture
def monitor(ros, nodes, tmp_path):
    """Starts a monitor_node for one test (with the given parameters); stops it afterwards. It
    starts with a model of every joint (issue 34.1: a monitor without a model does not run)."""
    started = []

    def start(**params):
        from helpers import write_model
        model = write_model(tmp_path / "monitor_start.yaml", joints=ALL_JOINTS)
        p = processes.start("monitor_node", {"window_dir": str(tmp_path / "windows"), "model_file": str(model),
                                             **params}, tmp_path)
        started.append(p)
        values, why = get_remote_parameters(ros, "monitor_node", ["model_file"], timeout=60.0)
        assert values is not None, f"{why}: {p.log.read_text()[-500:]}"
        return p

    yield start
    processes.stop(started)


@pytest.fixture
def fresh(ros, nodes):
    """Controller and observer at the initial gains without a model, the synthesis node without one."""
    for node, values in (("controller_node", {**INITIAL, "u_max": INITIAL_U_MAX, "model_file": ""}),
                         ("observer_node", {**INITIAL, "model_file": ""}), ("synthesis_node", {"model_file": "", "observer": "hg"})):
        # (the gate looks for its partner in the graph for up to nodes.pair.discover seconds: in
        # one fresh-clone run a single snapshot, just after a monitor of this module stopped,
        # missed the live observer_node and the gate refused, "is not running")
        ok, why = set_remote_parameters(ros, node, values)
        assert ok, f"{node}: {why}"


def snapshot(ros, nodes=("controller_node", "observer_node", "monitor_node", "synthesis_node")):
    out = {}
    for n in nodes:
        values, why = get_remote_parameters(ros, n, NAMES[n])
        assert values is not None, why
        out[n] = values
    return out


def synthesize(ros, bags, joints, apply=True):
    cli = ros.create_client(Synthesize, "/synthesis_node/synthesize")
    try:
        assert cli.wait_for_service(timeout_sec=60)
        fut = cli.call_async(Synthesize.Request(bags=[str(b) for b in bags], joints=joints, mode="combined",
                                                apply=apply))
        rclpy.spin_until_future_complete(ros, fut, timeout_sec=300)
        assert fut.done(), "no answer from synthesis_node"
        return fut.result()
    finally:
        ros.destroy_client(cli)


def reachset_cli(*argv):
    exe = Path(sys.executable).with_name("reachset")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "reachset_ros.cli"]
    p = subprocess.run(cmd + [str(a) for a in argv], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


def test_single_joint_synthesis_applies_by_joint_name_and_equals_the_cli(ros, nodes, fresh, monitor, bag,
                                                                          extra_args):
    """A synthesis of arm_2_joint alone: each node gets the new values at arm_2_joint's
    index of its own joint order and keeps its values elsewhere (length-1 arrays expanded),
    the monitor and the synthesis node get the new model, and the result is, to the bit,
    what `reachset synthesize BAG --joints arm_2_joint --json` prints."""
    monitor()
    before = snapshot(ros)
    res = synthesize(ros, [bag], [J])
    assert res.success and res.result.applied, res.message
    assert "\n" not in res.message
    after = snapshot(ros)
    model = res.result.model_file
    assert list(mdl.load(model).joints) == [J]
    # issue 37.3: the model records its data's envelope, and the answer names the class against it
    assert mdl.load(model).envelope is not None and "; envelope: " in res.message, res.message
    # the result equals the command line's, bit for bit
    cli = reachset_cli("synthesize", bag, "--joints", J, "--json", *extra_args)
    want = cli["joints"][J]
    assert [m.name for m in res.result.joints] == [J]
    got = res.result.joints[0]
    assert list(got.alpha_w) == want["alpha_w"] and list(got.alpha_v) == want["alpha_v"]
    assert got.re_norm == want["re_norm"]
    g = want["gains"]
    assert (got.observer, got.controller) == (g["observer"], g["controller"]) == ("hg", "static")
    assert dict(zip(got.param_names, got.param_values)) == {k: g[k] for k in GAIN_KEYS if k in g}
    # controller and observer: new values at J's index, the old ones elsewhere
    for node in ("controller_node", "observer_node"):
        keys = [k for k in GAIN_KEYS if k in g]    # both nodes get the whole pair (issue 19.4)
        assert keys
        for k in GAIN_KEYS:
            old = before[node][k] * 6 if len(before[node][k]) == 1 else before[node][k]
            new = after[node][k]
            if k in keys:
                assert new == old[:IDX] + [g[k]] + old[IDX + 1:], (node, k, new)
            else:
                assert new == before[node][k], (node, k)      # not sent: unchanged
        assert (after[node]["observer"], after[node]["controller"]) == ("hg", "static")
        assert after[node]["joints"] == ALL_JOINTS
    assert after["controller_node"]["omega"][IDX] != 15.0         # the synthesis did change something there
    assert after["controller_node"]["h1"][IDX] != before["controller_node"]["h1"][IDX]
    assert after["controller_node"]["u_max"] == INITIAL_U_MAX[:IDX] + [want["u_max"]] + INITIAL_U_MAX[IDX + 1:]
    assert want["u_max"] != INITIAL_U_MAX[IDX]
    assert after["controller_node"]["model_file"] == model
    assert after["observer_node"]["model_file"] == model          # the pair's gate has the model too
    assert after["monitor_node"]["model_file"] == model
    assert after["synthesis_node"]["model_file"] == model
    assert Path(model).is_absolute()                              # handed to other nodes (issue 19.6)
    # the applied values as a ROS 2 params file, so a restart keeps them (issue 19.6)
    m = re.search(r"parameters in (\S+\.params\.yaml)", res.message)
    assert m, res.message
    doc = yaml.safe_load(Path(m.group(1)).read_text())
    for node in ("controller_node", "observer_node"):
        p = doc[node]["ros__parameters"]
        for k in GAIN_KEYS:
            if k in p:
                assert p[k] == after[node][k], (node, k)
        assert p["model_file"] == model and p["u_max"] == after[node]["u_max"]


def test_failed_synthesis_changes_no_parameter(ros, nodes, fresh, monitor, tmp_path):
    monitor()
    before = snapshot(ros)
    res = synthesize(ros, [tmp_path / "no_such_bag"], [J])
    assert not res.success and not res.result.applied and res.result.model_file == ""
    assert res.message and "\n" not in res.message and "no_such_bag" in res.message, res.message
    assert snapshot(ros) == before


def test_refusal_by_the_last_target_rolls_the_others_back(ros, nodes, fresh, monitor, bag):
    """The monitor watches arm_1_joint too, which the new model lacks: it refuses the model.
    The pair running now is certified under the new model, so the monitor is set first (row
    G19: the new gains are not certified under the monitor's old model, 34.6) and nothing is
    applied; before G19 the monitor was set last and controller and observer were set back."""
    monitor(joints=[J, "arm_1_joint"])
    before = snapshot(ros)
    res = synthesize(ros, [bag], [J])
    assert not res.success and not res.result.applied, res.message
    assert res.result.model_file                      # the synthesis itself succeeded
    assert "\n" not in res.message
    assert "monitor_node -> controller_node -> observer_node: monitor_node refused" in res.message, res.message
    assert "arm_1_joint" in res.message and "nothing was applied" in res.message, res.message
    assert "FAILED" not in res.message
    assert snapshot(ros) == before


def test_plans_that_cannot_work_apply_nothing(ros, nodes, fresh, monitor, bag):
    """Refused before anything is set: a synthesised joint no node has, and a partial
    synthesis that would change the nodes' observer type (one per node)."""
    monitor()
    before = snapshot(ros)
    res = synthesize(ros, [bag], ["gripper_joint"])
    assert not res.success and not res.result.applied and res.result.model_file, res.message
    assert "controller_node: joint gripper_joint is not one of its joints" in res.message, res.message
    assert snapshot(ros) == before
    ok, why = set_remote_parameters(ros, "synthesis_node", {"observer": "eso"})
    assert ok, why
    before = snapshot(ros)
    res = synthesize(ros, [bag], [J])
    assert not res.success and not res.result.applied and res.result.model_file, res.message
    assert res.result.joints[0].observer == "eso"
    assert "controller_node: the synthesis' observer is eso, the node's is hg, and joint arm_1_joint" \
        in res.message, res.message
    assert "\n" not in res.message
    assert snapshot(ros) == before
