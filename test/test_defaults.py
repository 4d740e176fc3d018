"""One home for defaults (reachset_ros/defaults.py): every copy a user sees agrees with the table.

The YAML files in config/ stay files users edit, the argparse options, the nodes' declared
parameters and docs/nodes.md are derived or generated: each is compared with the registered
defaults here, so a copy that drifts fails this test.
"""
import argparse
import importlib.util
import re
from pathlib import Path

import pytest
import yaml

from reachset_ros import defaults
from reachset_ros.commands import analyze
from reachset_ros.errors import ReachsetError
from reachset_ros.robot.dynamics import JOINT_NAMES
from reachset_ros.sim import recordings
from reachset_ros.synthesis import config as syncfg
from reachset_ros.systems import gains as gm

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"
GAIN_NODES = ("observer_node", "controller_node")
#: the gain nodes' parameters whose defaults the table holds
NODE_PARAMS = ("u_max", "u_ff_bound", *defaults.get("gains.types"), *defaults.get("gains.keys"))


def _startup_param(name, joints=JOINT_NAMES):
    """The value a gain node's parameter ``name`` takes by default, from the table."""
    if name == "u_max":
        return [defaults.get("lwa4p.u_max")[j] for j in joints]
    if name == "u_ff_bound":
        return defaults.get("gains.u_ff")
    value = defaults.get("gains.startup")[name]
    return [value] if name in defaults.get("gains.keys") else value


# ---------------------------------------------------------------- the registry itself
def test_every_default_says_what_it_means():
    assert defaults.entries(), "nothing registered"
    for d in defaults.entries():
        assert d.doc and d.owner.startswith("reachset_ros."), d.name


def test_a_name_holds_one_value():
    defaults.register("test_defaults", {"x": (1.0, "a test value")}, owner=__name__)
    defaults.register("test_defaults", {"x": (1.0, "a test value")}, owner=__name__)      # again: no-op
    with pytest.raises(ReachsetError, match="registered twice"):
        defaults.register("test_defaults", {"x": (2.0, "another")}, owner=__name__)
    with pytest.raises(ReachsetError, match="no default"):
        defaults.get("test_defaults.nothing")
    v = defaults.get("lwa4p.u_max")
    v["arm_1_joint"] = -1.0
    assert defaults.get("lwa4p.u_max")["arm_1_joint"] == 26.0          # callers get copies


def test_lwa4p_u_max_is_paper_table_i():
    assert defaults.get("lwa4p.u_max") == {f"arm_{i}_joint": 26.0 if i <= 4 else 100.0 for i in range(1, 7)}


# ---------------------------------------------------------------- gains: one meaning per name
def test_gain_keys_are_one_list():
    from reachset_ros.nodes import gain_params
    from reachset_ros.nodes import synthesis_node
    keys = defaults.get("gains.keys")
    assert gm.GAIN_KEYS == keys and tuple(gain_params.GAIN_DOCS) == keys and synthesis_node.GAIN_KEYS == keys
    assert gm.TYPE_KEYS == defaults.get("gains.types") == gain_params.TYPE_PARAMS == synthesis_node.TYPE_KEYS
    assert set(gm.DEFAULTS) == set(keys) | set(gm.TYPE_KEYS)


def test_startup_gains_are_the_gains_defaults():
    assert gm.Gains() == gm.Gains.from_dict({}) == gm.Gains.from_dict(gm.DEFAULTS)
    assert gm.Gains().as_dict() == gm.DEFAULTS == defaults.get("gains.startup")


@pytest.mark.parametrize("observer", ["hg", "eso"])
def test_family_controller_is_the_one_default_of_every_path(observer):
    """The ESO's feedback law is the compensated one wherever none is named: Gains, from_dict,
    from_model, the synthesis configuration and ``reachset analyze`` (paper Sec. IV-C)."""
    want = defaults.get(f"gains.{observer}.controller")
    assert want == {"hg": "static", "eso": "compensated"}[observer]
    fam = {n: 1.0 for n in gm.FAMILY_PARAMS[observer]} | {"eps": 0.01}
    assert gm.Gains(observer=observer).controller == want
    assert gm.Gains.from_dict({"observer": observer}).controller == want
    assert gm.Gains.from_model({"observer": observer, **fam}).controller == want
    assert syncfg.DEFAULT_CONFIG["structures"][observer]["controller"] == want
    assert analyze._DEFAULTS[observer]["controller"] == want


def test_distinct_gain_defaults_are_distinct_names():
    """The nodes' start-up gains, the simulator's recording gains and the synthesis' start
    values are different concepts: each has its own name, built from the family tables."""
    assert recordings.DEFAULT_GAINS == defaults.get("sim.recording_gains")
    assert gm.Gains.from_model(recordings.DEFAULT_GAINS).omega == defaults.get("gains.feedback.paper")["omega"]
    assert gm.DEFAULTS["omega"] == defaults.get("gains.feedback.startup")["omega"]
    for obs in ("hg", "eso"):
        values = syncfg.DEFAULT_CONFIG["structures"][obs]["values"]
        assert {k: values[k] for k in ("omega", "zeta")} == defaults.get("gains.feedback.paper")
        for k, v in values.items():
            if k not in ("omega", "zeta"):
                assert v == defaults.get(f"gains.{obs}.{k}"), (obs, k)


# ---------------------------------------------------------------- the YAML files users edit
def test_lwa4p_yaml_gain_nodes_agree():
    cfg = yaml.safe_load((CONFIG / "lwa4p.yaml").read_text())
    for node in GAIN_NODES:
        params = cfg[node]["ros__parameters"]
        joints = params.get("joints", list(JOINT_NAMES))
        for name in NODE_PARAMS:
            if name in params:
                assert params[name] == _startup_param(name, joints), f"config/lwa4p.yaml {node}.{name}"


@pytest.mark.parametrize("name", ["synthesis.yaml", "demo_synthesis.yaml"])
def test_synthesis_yaml_agrees(name):
    """config/synthesis.yaml is the built-in configuration; the demo's differs in its search only."""
    got = yaml.safe_load((CONFIG / name).read_text())
    want = syncfg.DEFAULT_CONFIG
    if name == "demo_synthesis.yaml":
        got, want = ({k: v for k, v in d.items() if k != "search"} for d in (got, want))
    assert got == want
    assert syncfg.load_config(CONFIG / name)["u_max"] == {"default": defaults.get("synthesis.u_max_unlisted"),
                                                          **defaults.get("lwa4p.u_max")}


# ---------------------------------------------------------------- argparse
def test_analyze_argparse_defaults_agree():
    p = argparse.ArgumentParser()
    analyze.add_arguments(p)
    args = p.parse_args([])
    hg, eso = defaults.table("gains.hg"), defaults.table("gains.eso")
    assert (args.h1, args.h2, args.eps) == (hg["h1"], hg["h2"], hg["eps"]) and eso["eps"] == hg["eps"]
    assert (args.l1, args.l2, args.l3, args.eso_input) == (eso["l1"], eso["l2"], eso["l3"], eso["eso_input"])
    assert args.u_ff == defaults.get("gains.u_ff") == syncfg.DEFAULT_CONFIG["u_ff"]
    assert analyze._DEFAULTS["hg"] == {"controller": "static", **defaults.get("gains.feedback.table_ii"),
                                       **defaults.table("analyze.hg")}
    assert analyze._DEFAULTS["eso"] == {"controller": "compensated", **defaults.get("gains.feedback.paper"),
                                        **defaults.table("analyze.eso")}
    text = p.format_help()
    assert "default 24.40 hg / 20 eso" in text and "0.0348 3.59 hg / 0.0234 3.587 eso" in text


# ---------------------------------------------------------------- the nodes and docs/nodes.md
@pytest.fixture(scope="module")
def declared(tmp_path_factory):
    """``{node: {parameter: declared default}}`` of the observer and controller nodes."""
    import os
    import rclpy
    from reachset_ros.nodes.controller_node import ControllerNode
    from reachset_ros.nodes.observer_node import ObserverNode
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("nodes"))
    rclpy.init(args=["--ros-args", "-p", "allow_uncertified:=true"])   # the start-up gains run uncertified
    out = {}
    try:
        for name, cls in (("observer_node", ObserverNode), ("controller_node", ControllerNode)):
            node = cls()
            try:
                out[name] = {n: node.get_parameter(n).value for n in node._descriptors}
            finally:
                node.destroy_node()
    finally:
        rclpy.shutdown()
        os.chdir(cwd)
    return out


def _plain(v):
    return list(v) if isinstance(v, (list, tuple)) or hasattr(v, "tolist") else v


@pytest.mark.parametrize("node", GAIN_NODES)
def test_node_declared_defaults_agree(declared, node):
    params = declared[node]
    for name in NODE_PARAMS:
        assert _plain(params[name]) == _startup_param(name, params["joints"]), f"{node}.{name}"


def _doc_rows(node):
    text = (REPO / "docs" / "nodes.md").read_text(encoding="utf-8")
    block = re.search(rf"<!-- params:{node} -->\n(.*?)<!-- /params:{node} -->", text, re.S).group(1)
    return {m.group(1): m.group(2) for m in re.finditer(r"^\| `([^`]+)` \| [^|]+ \| `([^`]*)` \|", block, re.M)}


@pytest.mark.parametrize("node", GAIN_NODES)
def test_docs_nodes_md_agrees(node):
    spec = importlib.util.spec_from_file_location("node_docs", REPO / "tools" / "node_docs.py")
    node_docs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(node_docs)
    rows = _doc_rows(node)
    for name in NODE_PARAMS:
        assert rows[name] == node_docs.literal(_startup_param(name)), f"docs/nodes.md {node}.{name}"
