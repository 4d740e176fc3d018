"""The workflow library (reachset_ros.workflows): the commands are thin users of it.

Pure tests (no DDS): the library's typed results are the commands' ``--json`` objects, the
synthesis node's worker reports errors as the command line does, and the layers the
workflows sit on do not import upwards (synthesis never imports fleet; conformance never
imports bags).
"""
import ast
import json
import pickle
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from reachset_ros.sim import recordings as sr
from reachset_ros.workflows.identify import IdentifyOptions, identify
from reachset_ros.workflows.synthesize import SynthesisOptions, synthesize

PKG = Path(__file__).resolve().parents[2] / "reachset_ros"
JOINT = "arm_2_joint"
SEARCH = {"sobol_log2": 3, "local_starts": 1, "local_maxfev": 20}


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("workflows") / "sim"
    sr.write_recordings(path, sr.simulate_recordings(["arm_1_joint", JOINT], 1500, seed=3))
    return path


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    cfg = tmp_path_factory.mktemp("cfg") / "synthesis.yaml"
    cfg.write_text(yaml.safe_dump({"search": SEARCH}))
    return cfg


def cli(*argv, code=0):
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, argv)], capture_output=True, text=True)
    assert p.returncode == code, p.stderr
    return json.loads(p.stdout) if code == 0 else p.stderr


def test_identify_result_is_the_commands_json(bag):
    res = identify(IdentifyOptions(bags=(bag,), horizon=20, initial_state_set=True))
    assert res.to_json() == cli("identify", bag, "--horizon", 20, "--initial-state-set", "--json")
    assert set(res.model_sets) == {"arm_1_joint", JOINT} and res.model is None


def _without_timings(d):
    d.pop("seconds", None)
    for j in d["joints"].values():
        j.pop("seconds", None)
        (j.get("separate") or {}).pop("seconds", None)
    return d


@pytest.mark.slow
def test_synthesis_result_and_worker_are_the_commands_json(bag, config, tmp_path):
    res = synthesize([bag], SynthesisOptions(joints=[JOINT], horizon=40, config=str(config)))
    want = _without_timings(cli("synthesize", bag, "--joints", JOINT, "--horizon", 40, "--config", config, "--json"))
    assert _without_timings(res.to_json()) == want
    # the synthesis node's worker: the same values, handed back pickled
    p = subprocess.run([sys.executable, "-m", "reachset_ros.commands._synthesis_worker", "synthesize", str(bag),
                        "--joints", JOINT, "--horizon", "40", "--config", str(config), "--out",
                        str(tmp_path / "m.yaml"), "--json"], capture_output=True)
    assert p.returncode == 0, p.stderr
    got = pickle.loads(p.stdout)
    assert got["model"] == str(tmp_path / "m.yaml") and (tmp_path / "m.yaml").is_file()
    got.pop("model")
    assert _without_timings(got) == want


def test_worker_reports_errors_as_the_command_line(tmp_path):
    worker = [sys.executable, "-m", "reachset_ros.commands._synthesis_worker"]
    p = subprocess.run(worker + ["synthesize", str(tmp_path / "no_such_bag")], capture_output=True, text=True)
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.strip().splitlines() == [f"reachset synthesize: error: {tmp_path / 'no_such_bag'}: no such bag"]
    p = subprocess.run(worker + [str(tmp_path / "no_such_bag")], capture_output=True, text=True)
    assert p.returncode == 2 and "names the workflow" in p.stderr


def _imports(path):
    out = set()
    for n in ast.walk(ast.parse(path.read_text())):
        if isinstance(n, ast.ImportFrom) and n.level == 2:      # from ..x import y, from .. import x
            out.update([n.module.split(".")[0]] if n.module else [a.name for a in n.names])
        elif isinstance(n, ast.Import):
            out.update(a.name for a in n.names)
    return out


@pytest.mark.parametrize("package, forbidden", [("synthesis", {"fleet", "workflows", "commands", "nodes", "sim"}),
                                                ("conformance", {"bags", "synthesis", "fleet", "workflows"}),
                                                ("fleet", {"workflows", "commands", "nodes", "sim"}),
                                                ("workflows", {"commands"})])
def test_no_upward_imports(package, forbidden):
    for f in sorted((PKG / package).glob("*.py")):
        bad = _imports(f) & forbidden
        assert not bad, f"{f.name} imports {bad}"


def test_a_workflow_in_a_low_priority_worker_returns_the_same_typed_result(bag):
    """The demo and the campaign identify in a worker process (workflows.worker): the result
    is the workflow's own object, equal to the in-process one, and a bad input raises the
    same one-line error in the caller."""
    from reachset_ros.errors import ReachsetError
    from reachset_ros.workflows.worker import run_in_worker
    opts = IdentifyOptions(bags=(bag,), horizon=20)
    assert run_in_worker(identify, opts).to_json() == identify(opts).to_json()
    with pytest.raises(ReachsetError, match="nowhere"):
        run_in_worker(identify, IdentifyOptions(bags=(bag.parent / "nowhere",), horizon=20))
