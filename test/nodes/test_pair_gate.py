"""The gate certifies the pair that will run, not each node's copy of it (issue 34.6).

controller_node and observer_node run as separate processes over real DDS with one model
(HG 15/30 + static feedback omega 20, zeta 1; sets for which omega 26 alone and h1 = h2 = 8
alone keep R*_u inside U_p = +-26, but not both together). Before: omega 26 on the controller
alone and h1 = h2 = 8 on the observer alone were both accepted (each node certified its own
copy of the other half), and the pair that ran together had R*_u +-37 > 26.
"""
import pytest

from reachset_ros import processes
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.nodes.common import get_remote_parameters, set_remote_parameters
from reachset_ros.systems.gains import Gains, certify_pair
from reachset_ros.systems.plant import lwa4p_joint_plant
from reachset_ros.synthesis.reference_error import u_e_ff_for_gains

pytestmark = pytest.mark.dds   # real DDS participants / node processes

JOINTS = ["arm_1_joint"]
START = {"observer": "hg", "controller": "static", "omega": [20.0], "zeta": [1.0], "h1": [15.0], "h2": [30.0],
         "eps": [0.01]}


def _model(path):
    g = Gains(omega=20.0, zeta=1.0, h1=15.0, h2=30.0)
    js = mdl.JointSets((0.02, 2.0), (3.49e-5,), (0.0,) * 5, (0.0,), 0, 125,
                       gains={**g.model_dict(), "u_max": 26.0, "u_ff": 2.0}, extra={})
    mdl.save(mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                                  {"arm_1_joint": js}, 0.0), path)
    return path


def _gate(model, **kw):
    """The nodes' gate (certify_pair as validate_pair calls it) for Table-like gains ``kw``."""
    g = Gains(**{"omega": 20.0, "zeta": 1.0, "h1": 15.0, "h2": 30.0, **kw})
    try:
        certify_pair({"arm_1_joint": g}, model, [26.0], 2.0, 0.004, False, u_e_ff_for=u_e_ff_for_gains)
        return ""
    except Exception as e:       # noqa: BLE001 - the reason is what is compared
        return str(e)


@pytest.fixture
def pair(ros, tmp_path):
    path = _model(tmp_path / "m.yaml")
    params = {"joints": JOINTS, **START, "model_file": str(path), "u_max": [26.0]}
    procs = [processes.start("controller_node", params, tmp_path), processes.start("observer_node", params, tmp_path)]
    try:
        for p in procs:
            values, why = get_remote_parameters(ros, p.name, ["omega"], timeout=60.0)
            assert values is not None, f"{why}: {p.log.read_text()[-1500:]}"
        yield procs, mdl.load(path)
    finally:
        processes.stop(procs)


def test_a_single_node_change_is_certified_with_the_other_nodes_running_gains(ros, pair):
    """omega 26 on the controller alone is accepted (its pair with the observer's running h1,
    h2 is certified); h1 = h2 = 8 on the observer alone is then refused naming the gate row
    (R*_u leaves U_p) and the controller's gains; the observer keeps its gains. The same
    change with the controller back at omega 20 is accepted: the refusal was the pair's."""
    procs, model = pair
    assert _gate(model, omega=26.0) == "" and _gate(model, h1=8.0, h2=8.0) == ""
    assert "R*_u" in _gate(model, omega=26.0, h1=8.0, h2=8.0)          # the pair that would run
    ok, why = set_remote_parameters(ros, "controller_node", {"omega": [26.0]})
    assert ok, why
    ok, why = set_remote_parameters(ros, "observer_node", {"h1": [8.0], "h2": [8.0]})
    assert not ok, "the observer accepted h1 = h2 = 8 while the controller runs omega 26"
    assert "controller_node's current controller gains" in why and "joint arm_1_joint" in why, why
    assert "R*_u" in why and "leaves U_p = +-26" in why, why
    got, _ = get_remote_parameters(ros, "observer_node", ["h1", "h2", "omega"])
    assert got == {"h1": [15.0], "h2": [30.0], "omega": [20.0]}
    # the reverse order is refused by the controller, naming the observer's gains
    ok, why = set_remote_parameters(ros, "controller_node", {"omega": [20.0]})
    assert ok, why
    ok, why = set_remote_parameters(ros, "observer_node", {"h1": [8.0], "h2": [8.0]})
    assert ok, why
    ok, why = set_remote_parameters(ros, "controller_node", {"omega": [26.0]})
    assert not ok and "observer_node's current observer gains" in why and "R*_u" in why, why
    assert all(p.alive() for p in procs)


def test_a_node_that_cannot_read_the_other_refuses_gain_changes(ros, tmp_path):
    """Fail closed: a controller whose pair_node does not answer cannot certify the pair that
    will run and refuses a gain change (not a change of another parameter); pair_node '' (a
    node run alone) certifies its own copy only."""
    path = _model(tmp_path / "m.yaml")
    params = {"joints": JOINTS, **START, "model_file": str(path), "u_max": [26.0], "pair_node": "no_such_observer"}
    ctl = processes.start("controller_node", params, tmp_path)
    alone = processes.start("controller_node", {**params, "pair_node": ""}, tmp_path, node_name="lone_controller")
    try:
        for name in ("controller_node", "lone_controller"):
            values, why = get_remote_parameters(ros, name, ["pair_node"], timeout=60.0)
            assert values is not None, why
        # (the controller waits nodes.pair.timeout for the absent node before it answers)
        ok, why = set_remote_parameters(ros, "controller_node", {"omega": [21.0]}, timeout=60.0)
        assert not ok and "the pair that will run cannot be certified" in why and "no_such_observer" in why, why
        ok, why = set_remote_parameters(ros, "controller_node", {"stop_max_time": 0.25})
        assert ok, why
        ok, why = set_remote_parameters(ros, "lone_controller", {"omega": [21.0]})
        assert ok, why
    finally:
        processes.stop([ctl, alone])


def test_a_change_of_both_halves_is_applied_to_both_nodes_or_to_neither(ros, pair):
    """``pair_gate.set_pair`` (the commander's ``apply_gains``): omega 30 with h1 = 20, h2 = 60
    is certified, but omega 30 with the observer's running 15/30 is not: the controller refuses
    first, so the observer is set first and then the controller. omega 26 with h1 = h2 = 8 is
    refused in both orders and neither node changes."""
    from reachset_ros.nodes.pair_gate import set_pair
    procs, model = pair
    assert _gate(model, omega=30.0, h1=20.0, h2=60.0) == "" and _gate(model, h1=20.0, h2=60.0) == ""
    assert "R*_u" in _gate(model, omega=30.0)
    names = ["omega", "h1", "h2"]
    new = {"omega": [30.0], "h1": [20.0], "h2": [60.0]}
    ok, why = set_pair(ros, {"controller_node": new, "observer_node": new})
    assert ok, why
    for node in ("controller_node", "observer_node"):
        assert get_remote_parameters(ros, node, names)[0] == new
    bad = {"omega": [26.0], "h1": [8.0], "h2": [8.0]}
    ok, why = set_pair(ros, {"controller_node": bad, "observer_node": bad})
    assert not ok and why.startswith("controller_node refused:") and "R*_u" in why, why
    for node in ("controller_node", "observer_node"):
        assert get_remote_parameters(ros, node, names)[0] == new
    assert all(p.alive() for p in procs)


def test_a_change_is_certified_under_the_running_monitors_model(ros, pair, tmp_path):
    """Row G19 (issue 34.6): the monitor checks its own model's sets, so the pair that will run
    is certified under the running monitor's model too. With a monitor whose sets are twice the
    nodes' (W (0.04, 4.0)), omega 26 passes both nodes' gates but leaves U_p under the
    monitored sets: refused naming the monitor and the row; omega 22 is certified under both
    and accepted. Before, the monitor's model was never consulted."""
    procs, model = pair
    wide = tmp_path / "monitor_model.yaml"
    g = Gains(omega=20.0, zeta=1.0, h1=15.0, h2=30.0)
    js = mdl.JointSets((0.04, 4.0), (3.49e-5,), (0.0,) * 5, (0.0,), 0, 125,
                       gains={**g.model_dict(), "u_max": 26.0, "u_ff": 2.0}, extra={})
    mdl.save(mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                                  {"arm_1_joint": js}, 0.0, input_source=mdl.PLANT_INPUT), wide)
    assert _gate(model, omega=26.0) == "" and "R*_u" in _gate(mdl.load(wide), omega=26.0)
    assert _gate(mdl.load(wide), omega=22.0) == ""
    mon = processes.start("monitor_node", {"joints": JOINTS, "model_file": str(wide),
                                           "window_dir": str(tmp_path / "windows")}, tmp_path)
    try:
        got, why = get_remote_parameters(ros, "monitor_node", ["model_file"], timeout=60.0)
        assert got == {"model_file": str(wide)}, f"{why}: {mon.log.read_text()[-1500:]}"
        ok, why = set_remote_parameters(ros, "controller_node", {"omega": [26.0]})
        assert not ok, "omega 26 accepted although the monitored sets leave U_p with it"
        assert "the monitor monitor_node's model" in why and "[guarantee G19" in why and "R*_u" in why, why
        got, _ = get_remote_parameters(ros, "controller_node", ["omega"])
        assert got == {"omega": [20.0]}
        ok, why = set_remote_parameters(ros, "controller_node", {"omega": [22.0]})
        assert ok, why
    finally:
        processes.stop([mon])
