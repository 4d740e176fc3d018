"""R*_u inside U_p is certified for the sets the monitor actually checks (issue 14.6).

The monitor accepts data conformant to the sets scaled by 1 + inflation, so the reachable
input must be certified with alpha scaled by 1 + inflation, plus U_ff and the model's
recorded U_e,ff, wherever gains meet sets: ``systems.gains.certify`` (``check_gains``), the
controller node's gate, the synthesis node's apply path, the demo's monitored model.
"""
import rclpy
import pytest

from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.errors import ReachsetError
from reachset_ros.nodes.synthesis_node import certify_synthesis
from reachset_ros.systems.gains import Gains, certified_inflation, certify, check_gains, max_certified_inflation
from reachset_ros.systems.plant import lwa4p_joint_plant

#: Table II axis 1: HG (h1 = 15, h2 = 30) + static feedback, and its identified sets
TABLE_II = Gains(omega=24.40, zeta=0.96, h1=15.0, h2=30.0)
SETS = mdl.JointSets((0.0348, 3.59), (3.49e-5,), (0.0,) * 5, (0.0,), 0, 125)
PLANT = lwa4p_joint_plant()


#: a synthesis record with U_e,ff = 0 (as for Method 1's loop, Appendix B): the tests that use
#: it are about the inflation; U_e,ff has tests of its own below
ZERO_U_E_FF = {"reference_error": {"u_e_ff": [0.0, 0.0]}}


def _model(path, inflation, extra=None, gains=TABLE_II):
    js = mdl.JointSets(SETS.alpha_w, SETS.alpha_v, SETS.c_w, SETS.c_v, 0, 125,
                       gains={**gains.model_dict(), "u_max": 26.0, "u_ff": 2.0},
                       extra=ZERO_U_E_FF if extra is None else extra)
    mdl.save(mdl.ConformanceModel(PLANT, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                                  {"arm_1_joint": js}, inflation), path)
    return path


def test_table_ii_at_inflation_one_is_refused_naming_r_u_and_u_p():
    """HEAD's check_gains used the uninflated alpha (R_u radius 15.68) and accepted. (U_e,ff = 0
    given: the paper's R_u alone.)"""
    ok, why, _ = check_gains(TABLE_II, SETS, u_max=26.0, u_ff=2.0, plant=PLANT, inflation=1.0, u_e_ff=(0.0, 0.0))
    assert not ok
    assert "R*_u = [-29.35, 29.35]" in why and "radius 29.35" in why and "U_p = +-26" in why
    c = certify(TABLE_II, SETS, 1.0, 26.0, 2.0, u_e_ff=(0.0, 0.0), plant=PLANT)
    assert not c.ok and c.ru[1] == pytest.approx(29.35, abs=5e-3)
    # R_u is linear in alpha: the disturbance part doubles
    c0 = certify(TABLE_II, SETS, 0.0, 26.0, 2.0, u_e_ff=(0.0, 0.0), plant=PLANT)
    assert c0.ok and c0.reason == ""
    assert c.ru[1] - 2.0 == pytest.approx(2 * (c0.ru[1] - 2.0), rel=1e-12)


def test_recorded_u_e_ff_counts():
    rec = {"reference_error": {"u_e_ff": [-0.5, 10.5]}}
    js = mdl.JointSets(SETS.alpha_w, SETS.alpha_v, SETS.c_w, SETS.c_v, 0, 125, extra=rec)
    c = certify(TABLE_II, js, 0.0, 26.0, 2.0, plant=PLANT)
    assert not c.ok and c.ru == pytest.approx((-15.6756 - 0.5, 15.6756 + 10.5), abs=1e-3)
    assert "U_e,ff = [-0.5, 10.5]" in c.reason
    assert certify(TABLE_II, js, 0.0, 26.0, 2.0, u_e_ff=(0.0, 0.0), plant=PLANT).ok
    with pytest.raises(ReachsetError, match="u_e_ff"):
        certify(TABLE_II, mdl.JointSets(SETS.alpha_w, SETS.alpha_v, SETS.c_w, SETS.c_v,
                                        extra={"reference_error": {"u_e_ff": [1.0]}}), 0.0, 26.0, 2.0, plant=PLANT)


def test_largest_certified_inflation():
    zero = (0.0, 0.0)
    i = max_certified_inflation(TABLE_II, SETS, 26.0, 2.0, u_e_ff=zero, plant=PLANT)
    assert 0.75 < i < 0.76
    assert certify(TABLE_II, SETS, i, 26.0, 2.0, u_e_ff=zero, plant=PLANT).ok
    assert not certify(TABLE_II, SETS, i * (1 + 1e-5), 26.0, 2.0, u_e_ff=zero, plant=PLANT).ok
    assert max_certified_inflation(TABLE_II, SETS, 10.0, 2.0, u_e_ff=zero, plant=PLANT) is None
    # U_e,ff takes room: a smaller inflation fits
    assert max_certified_inflation(TABLE_II, SETS, 26.0, 2.0, u_e_ff=(-2.0, 2.0), plant=PLANT) < i


def test_largest_certified_inflation_of_a_model(tmp_path):
    """What the demo reports as ``inflation_certified`` (it does not claim R*_u beyond it)."""
    m = mdl.load(_model(tmp_path / "m.yaml", 0.0))
    used, per = certified_inflation(m, 1.0)
    assert used == per["arm_1_joint"] and 0.75 < used < 0.76
    assert certified_inflation(m, 0.5)[0] == 0.5


def test_synthesis_apply_path_certifies_the_model_it_applies(tmp_path):
    data = {"joints": {"arm_1_joint": {"u_max": 26.0, "u_ff": 2.0}}}
    assert certify_synthesis(data, str(_model(tmp_path / "a.yaml", 0.0))) == ""
    why = certify_synthesis(data, str(_model(tmp_path / "b.yaml", 1.0)))
    assert why.startswith("joint arm_1_joint: reachable input R*_u") and "U_p = +-26" in why
    assert "not in the model" in certify_synthesis({"joints": {"arm_9_joint": {"u_max": 26.0}}},
                                                   str(tmp_path / "a.yaml"))


@pytest.mark.dds
@pytest.mark.parametrize("inflation, refused", [(0.0, False), (1.0, True)])
def test_controller_gate_certifies_the_model_inflation(tmp_path, monkeypatch, inflation, refused):
    """The controller node (real rclpy) refuses to start with Table II gains under a model
    whose inflation 1 takes R*_u out of U_p; HEAD started."""
    from reachset_ros.nodes.controller_node import ControllerNode
    monkeypatch.chdir(tmp_path)
    path = _model(tmp_path / "m.yaml", inflation)
    rclpy.init(args=["--ros-args", "-p", f"model_file:={path}", "-p", "joints:=[arm_1_joint]",
                     "-p", "u_max:=[26.0]", "-p", "omega:=[24.4]", "-p", "zeta:=[0.96]",
                     "-p", "h1:=[15.0]", "-p", "h2:=[30.0]"])
    try:
        if refused:
            # U_e,ff bounded over the controller's class (issue 34.4), the sets inflated by 1 + 1
            with pytest.raises(ReachsetError, match=r"arm_1_joint: reachable input R\*_u .* leaves U_p = \+-26 .*inflated by 1 \+ 1"):
                ControllerNode()
        else:
            node = ControllerNode()
            node.destroy_node()
    finally:
        rclpy.shutdown()


def test_recorded_u_e_ff_holds_only_for_the_models_own_gains():
    """U_e,ff (Appendix B) is the reference error of one loop. HEAD certified other gains with
    the model's recorded value (omega 22 here with the number of omega 24.4): now refused,
    unless the caller gives theirs."""
    rec = {"reference_error": {"u_e_ff": [-0.5, 0.5]}}
    js = mdl.JointSets(SETS.alpha_w, SETS.alpha_v, SETS.c_w, SETS.c_v, 0, 125,
                       gains={**TABLE_II.model_dict(), "u_max": 26.0, "u_ff": 2.0}, extra=rec)
    assert certify(TABLE_II, js, 0.0, 26.0, 2.0, plant=PLANT).ok
    other = Gains(omega=22.0, zeta=0.96, h1=15.0, h2=30.0)
    c = certify(other, js, 0.0, 26.0, 2.0, plant=PLANT)
    assert not c.ok and c.ru is None and "recorded for the model's gains (observer=hg" in c.reason
    assert "omega=24.4" in c.reason and "omega=22" in c.reason
    assert certify(other, js, 0.0, 26.0, 2.0, u_e_ff=(-0.7, 0.7), plant=PLANT).ok


def _table_ii_model(extra):
    """A one-joint model (arm_1_joint) synthesised with Table II gains, with the record ``extra``."""
    js = mdl.JointSets(SETS.alpha_w, SETS.alpha_v, SETS.c_w, SETS.c_v, 0, 125,
                       gains={**TABLE_II.model_dict(), "u_max": 26.0, "u_ff": 2.0}, extra=extra)
    return js, mdl.ConformanceModel(PLANT, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                                    {"arm_1_joint": js}, 0.0)


def test_a_reference_class_recomputes_u_e_ff_for_new_gains():
    """With the reference class in the model the gate computes the new loop's U_e,ff (the
    class's sound bound) and certifies with it; the model's own gains keep the recorded one."""
    from reachset_ros.synthesis.reference_error import ReferenceClass, class_reference_error, u_e_ff_for_gains
    from reachset_ros.systems.gains import certify_pair
    rc = ReferenceClass.parse("qdd_max=2")
    own = class_reference_error(PLANT, *TABLE_II.build(0.004), rc)
    rec = {"reference_error": {"u_e_ff": [own.u_lo, own.u_hi], "reference_class": rc.as_dict()}}
    js, model = _table_ii_model(rec)
    other = Gains(omega=20.0, zeta=1.0, h1=15.0, h2=30.0)
    assert u_e_ff_for_gains(TABLE_II, js, PLANT) is None
    want = class_reference_error(PLANT, *other.build(0.004), rc)
    assert u_e_ff_for_gains(other, js, PLANT) == (want.u_lo, want.u_hi) != (own.u_lo, own.u_hi)
    pc = certify_pair({"arm_1_joint": other}, model, [26.0], 2.0, 0.004, u_e_ff_for=u_e_ff_for_gains)
    assert pc.certified["arm_1_joint"].u_e_ff == (want.u_lo, want.u_hi)
    with pytest.raises(ReachsetError, match="recorded for the model's gains"):
        certify_pair({"arm_1_joint": other}, model, [26.0], 2.0, 0.004)


@pytest.mark.dds
def test_controller_gate_bounds_u_e_ff_over_its_class_for_a_model_from_recorded_references(tmp_path, monkeypatch):
    """The controller node (real rclpy) under a synthesised model whose U_e,ff came from
    recorded references (+-0.5 here): that record does not cover the references the controller
    accepts (|qdd_d| <= u_ff_bound 2), so the gate bounds U_e,ff over that class for its own
    gains and for a live omega change alike (issue 34.4; before, its own gains ran on the record
    and omega 22 was refused for want of a bound). The node's verdicts are the pure gate's."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue

    from reachset_ros.nodes.controller_node import ControllerNode
    from reachset_ros.synthesis.reference_error import u_e_ff_for_gains
    monkeypatch.chdir(tmp_path)
    path = _model(tmp_path / "m.yaml", 0.0, extra={"reference_error": {"u_e_ff": [-0.5, 0.5]}})
    js = mdl.load(path).joints["arm_1_joint"]
    other = Gains(omega=22.0, zeta=0.96, h1=15.0, h2=30.0)
    expect = {g.omega: certify(g, js, 0.0, 26.0, 2.0, u_e_ff=u_e_ff_for_gains(g, js, PLANT, 2.0), plant=PLANT)
              for g in (TABLE_II, other)}
    assert all(c.u_e_ff[1] > 5 for c in expect.values())          # the class bound, not the record's 0.5
    rclpy.init(args=["--ros-args", "-p", f"model_file:={path}", "-p", "joints:=[arm_1_joint]",
                     "-p", "u_max:=[26.0]", "-p", "omega:=[24.4]", "-p", "zeta:=[0.96]",
                     "-p", "h1:=[15.0]", "-p", "h2:=[30.0]", "-p", "pair_node:=''"])      # no observer
    try:
        if not expect[24.4].ok:
            with pytest.raises(ReachsetError, match="U_e,ff"):
                ControllerNode()
            return
        node = ControllerNode()
        try:
            p = Parameter(name="omega", value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                                             double_array_value=[22.0]))
            res = node.set_parameters([rclpy.parameter.Parameter.from_parameter_msg(p)])[0]
            assert res.successful == expect[22.0].ok, res.reason
            assert list(node.get_parameter("omega").value) == ([22.0] if expect[22.0].ok else [24.4])
            if not res.successful:
                assert "U_e,ff" in res.reason, res.reason
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


@pytest.mark.dds
def test_a_model_without_u_e_ff_is_not_certified_with_zero(tmp_path, monkeypatch):
    """A model from `reachset identify` records no U_e,ff. HEAD certified gains with U_e,ff = 0:
    omega 20 over these sets has R_u radius 23.66 < 26 and was accepted, although the loop's
    reference error needs up to 6.89 rad/s^2 more for the references U_ff admits. Now certify
    refuses without a bound, and the nodes' gate bounds it over every reference of U_ff
    (qdd_max = u_ff, step_max = 2 u_ff) and refuses these gains; omega 10 fits."""
    from reachset_ros.nodes.controller_node import ControllerNode
    from reachset_ros.synthesis.reference_error import ReferenceClass, class_reference_error, u_e_ff_for_gains
    from reachset_ros.systems.gains import NO_U_E_FF, certify_pair
    js = mdl.JointSets((0.15, 0.0), (4e-4,), (0.0,) * 5, (0.0,), 0, 25)     # no record, no gains
    model = mdl.ConformanceModel(PLANT, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 25,
                                 {"arm_1_joint": js}, 0.0)
    fast, slow = Gains(omega=20.0, zeta=1.0, h1=15.0, h2=30.0), Gains(omega=10.0, zeta=1.0, h1=15.0, h2=30.0)
    c = certify(fast, js, 0.0, 26.0, 2.0, plant=PLANT)
    assert not c.ok and c.reason == NO_U_E_FF and c.u_e_ff is None
    assert certify(fast, js, 0.0, 26.0, 2.0, u_e_ff=(0.0, 0.0), plant=PLANT).ru[1] < 26.0   # HEAD's number
    want = class_reference_error(PLANT, *fast.build(0.004), ReferenceClass(qdd_max=2.0, step_max=4.0))
    assert u_e_ff_for_gains(fast, js, PLANT, 2.0) == (want.u_lo, want.u_hi)
    assert want.u_hi > 6.0
    with pytest.raises(ReachsetError, match=r"arm_1_joint: reachable input R\*_u .*U_e,ff = \[-6\.89, 6\.89\]"):
        certify_pair({"arm_1_joint": fast}, model, [26.0], 2.0, 0.004, u_e_ff_for=u_e_ff_for_gains)
    with pytest.raises(ReachsetError, match="U_e,ff .* is unknown"):
        certify_pair({"arm_1_joint": slow}, model, [26.0], 2.0, 0.004)        # no bound given: refused
    pc = certify_pair({"arm_1_joint": slow}, model, [26.0], 2.0, 0.004, u_e_ff_for=u_e_ff_for_gains)
    ue = pc.certified["arm_1_joint"].u_e_ff
    assert ue[1] > 5.0 and pc.certified["arm_1_joint"].ru[1] < 26.0
    # the controller node (real rclpy) refuses to start with omega 20 under such a model
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "identified.yaml"
    mdl.save(model, path)
    rclpy.init(args=["--ros-args", "-p", f"model_file:={path}", "-p", "joints:=[arm_1_joint]",
                     "-p", "u_max:=[26.0]", "-p", "omega:=[20.0]", "-p", "zeta:=[1.0]",
                     "-p", "h1:=[15.0]", "-p", "h2:=[30.0]"])
    try:
        with pytest.raises(ReachsetError, match=r"U_e,ff = \[-6\.89, 6\.89\]"):
            ControllerNode()
    finally:
        rclpy.shutdown()


@pytest.mark.parametrize("record", ["recorded_references", "narrower_class"])
def test_the_gate_bounds_u_e_ff_over_the_class_the_controller_accepts(record):
    """Issue 34.4: the controller accepts every reference with |qdd_d| <= u_ff_bound. A model's
    U_e,ff over its recorded references (+-0.006 here), or over a reference class narrower than
    that, does not cover them: the gate bounds U_e,ff over the accepted class for the model's
    own gains too (before: the recorded value, R*_u certified for references the controller
    accepts but the record does not cover)."""
    from reachset_ros.synthesis.reference_error import ReferenceClass, class_reference_error, u_e_ff_for_gains
    from reachset_ros.systems.gains import certify_pair
    if record == "recorded_references":
        rec = {"reference_error": {"u_e_ff": [-0.0062, 0.0062]}}
    else:
        narrow = ReferenceClass.parse("qdd_max=1")
        got = class_reference_error(PLANT, *TABLE_II.build(0.004), narrow)
        rec = {"reference_error": {"u_e_ff": [got.u_lo, got.u_hi], "reference_class": narrow.as_dict()}}
    js, model = _table_ii_model(rec)
    want = class_reference_error(PLANT, *TABLE_II.build(0.004), ReferenceClass(qdd_max=2.0))
    assert u_e_ff_for_gains(TABLE_II, js, PLANT, 2.0) == (want.u_lo, want.u_hi)
    assert want.u_hi > 10 * 0.0062
    expected = certify(TABLE_II, js, 0.0, 26.0, 2.0, u_e_ff=(want.u_lo, want.u_hi), plant=PLANT)
    if expected.ok:
        pc = certify_pair({"arm_1_joint": TABLE_II}, model, [26.0], 2.0, 0.004, u_e_ff_for=u_e_ff_for_gains)
        assert pc.certified["arm_1_joint"].u_e_ff == (want.u_lo, want.u_hi)
    else:                                       # R*_u over the accepted class leaves U_p: refused
        with pytest.raises(ReachsetError, match="joint arm_1_joint"):
            certify_pair({"arm_1_joint": TABLE_II}, model, [26.0], 2.0, 0.004, u_e_ff_for=u_e_ff_for_gains)
