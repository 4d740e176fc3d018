"""Issue 37.3: ``reachset synthesize`` records the validated envelope of its data in the model it
writes (as ``identify`` does: every mode identifies the sets from the data) and reports the parts
of its reference class (|qdd_d| and the certified R*_u) the model was never validated on."""
import json

import pytest
import yaml

from reachset_ros import cli
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.envelope import axis_range
from reachset_ros.sim import recordings as sr

JOINT = "arm_1_joint"
SEARCH = {"sobol_log2": 3, "local_starts": 1, "local_maxfev": 20}


def run_cli(argv, capsys):
    code = cli.main(list(map(str, argv)))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    recs = sr.simulate_recordings((JOINT,), 3000, seed=5)
    path = tmp_path_factory.mktemp("synth_env") / "sim"
    sr.write_recordings(path, {JOINT: recs[JOINT]}, reference=False, estimate=False)
    return path


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    p = tmp_path_factory.mktemp("cfg_env") / "synthesis.yaml"
    p.write_text(yaml.safe_dump({"search": SEARCH}))
    return p


def test_synthesize_records_the_envelope_and_names_the_class_beyond_it(bag, config, tmp_path, capsys):
    """On the old code the model had no envelope and the JSON no ``envelope`` key. The
    simulated recordings move u_p by a few rad/s^2, R*_u spans over +-10: the u_p line names it.
    The qdd_max=40 class reaches beyond the data's accelerations: a second line; mode
    reidentify records an envelope too."""
    out = tmp_path / "m.yaml"
    code, so, se = run_cli(["synthesize", bag, "--config", config, "--json", "--out", out, "--horizon", 40,
                            "--u-ff", 40, "--u-max", 400, "--reference-class", "qdd_max=40,step_max=0.05"], capsys)
    assert code == 0, se
    d = json.loads(so)
    env = d["envelope"]
    assert env["recorded"] is True and env["hold"] == 40 and env["ticks"][JOINT] > 0
    m = mdl.load(out)
    assert m.envelope is not None and set(m.envelope.joints) == {JOINT}
    ru = d["joints"][JOINT]["ru"]
    lo, hi = axis_range(m.envelope.joints[JOINT], "u")
    assert ru[0] < lo and hi < ru[1]                 # R*_u beyond the data's u_p on both sides
    lines = env["unvalidated"][JOINT]
    u_line = [x for x in lines if " u_p reaches " in x]
    assert len(u_line) == 1 and u_line[0].startswith(f"{JOINT}: u_p reaches ")
    assert u_line[0].endswith(f"but the model was validated on u_p in [{lo:.4g}, {hi:.4g}]")
    q_lo, q_hi = axis_range(m.envelope.joints[JOINT], "qdd")
    assert q_hi < 40
    assert f"{JOINT}: |qdd_d| reaches 40 rad/s^2 (the reference class' qdd_max) but the model was validated on " \
           f"qdd in [{q_lo:.4g}, {q_hi:.4g}]" in lines
    assert env["note"].startswith("envelope: NOT VALIDATED") and u_line[0] in env["note"]
    # the text output names them too
    code, so, se = run_cli(["synthesize", bag, "--config", config, "--horizon", 40, "--u-ff", 40, "--u-max", 400,
                            "--reference-class", "qdd_max=40,step_max=0.05"], capsys)
    assert code == 0, se
    assert "envelope: NOT VALIDATED" in so and f"  {u_line[0]}" in so.splitlines()
    # reidentify identifies the sets from the data too: its model records an envelope
    out2 = tmp_path / "re.yaml"
    code, so, se = run_cli(["synthesize", bag, "--mode", "reidentify", "--model", out, "--json", "--out", out2,
                            "--u-ff", 40], capsys)
    assert code == 0, se
    assert json.loads(so)["envelope"]["recorded"] is True and mdl.load(out2).envelope is not None
