"""Per-joint inflation (issue 35.1): each joint's sets are checked scaled by 1 + its own
inflation, in ``check``, ``replay``, the monitor (pure and compiled tick) and the R*_u
certificate. Before, one inflation, the largest over the joints, was applied to every joint:
a fault on a joint with tight sets that stayed inside the largest inflation went unseen."""
from dataclasses import replace

import numpy as np
import pytest
import yaml

from reachset_ros.cli import main
from reachset_ros import conformance as cf
from reachset_ros.conformance import kernels
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.monitor import Monitor, MonitorModel
from reachset_ros.conformance.monitor_core import MonitorCore
from reachset_ros.conformance.watches import TickEvent
from reachset_ros.errors import ReachsetError
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.nodes.synthesis_node import certify_synthesis
from reachset_ros.systems.gains import Gains, certify_pair
from reachset_ros.synthesis.pipeline import SynthesisOptions, plan
from reachset_ros.systems.plant import lwa4p_joint_plant
from reachset_ros.workflows.identify import DEFAULT_GRID, calibrate_margin

from test_reliability_cli import DT_NS, T0, clean_rows, run, run_json, simulate, write_bag

#: Table II axis 1 and its identified sets (as test/systems/test_certify.py), U_e,ff = 0
TABLE_II = Gains(omega=24.40, zeta=0.96, h1=15.0, h2=30.0)
SETS = mdl.JointSets((0.0348, 3.59), (3.49e-5,), (0.0,) * 5, (0.0,), 0, 125)
ZERO_U_E_FF = {"reference_error": {"u_e_ff": [0.0, 0.0]}}
PLANT = lwa4p_joint_plant()

HORIZON = 20
N = 1500
A, B = "arm_1_joint", "arm_2_joint"
SPIKE_AT = 900


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A model identified on clean data of two joints, then joint A at inflation 0 and joint B
    at 0.5; and a faulty copy of the data: one spike on joint A's position, the smallest on a
    10 % grid that joint A's sets at inflation 0 catch (so inside its sets scaled by 1.1)."""
    d = tmp_path_factory.mktemp("pji")
    y, u = np.empty((N, 2)), np.empty((N, 2))
    for j in range(2):
        y[:, j], u[:, j] = simulate(N, seed=300 + j)
    stamps = T0 + DT_NS * np.arange(N)
    clean = write_bag(d / "clean", clean_rows(stamps, y, u))
    ident = d / "ident.yaml"
    assert main(["identify", str(clean), "--horizon", str(HORIZON), "--out", str(ident)]) == 0
    base = mdl.load(ident)
    model = base.with_inflation({A: 0.0, B: 0.5})
    thm = model.theorem1()
    segs = ((0, N),)
    c, yf = 1e-7, None
    while c < 1.0:
        yf = y.copy()
        yf[SPIKE_AT, 0] += c
        if cf.check(model.plant, thm, model.estimator, model.joints[A].xi(0.0), yf[:, 0], u[:, 0], segs,
                    HORIZON).violations:
            break
        c *= 1.1
    assert c < 1.0
    faulty = write_bag(d / "faulty", clean_rows(stamps, yf, u))
    per, old = d / "per_joint.yaml", d / "one_inflation.yaml"
    mdl.save(model, per)
    mdl.save(base.with_inflation(0.5), old)     # what the model file applied before: the largest, to all
    return {"dir": d, "y": y, "u": u, "yf": yf, "stamps": stamps, "clean": clean, "faulty": faulty,
            "per": per, "old": old, "spike": c}


def test_model_file_carries_each_joints_inflation(setup):
    doc = yaml.safe_load(setup["per"].read_text())
    assert doc["joints"][A]["inflation"] == 0.0 and doc["joints"][B]["inflation"] == 0.5
    assert doc["inflation"] == 0.5            # the largest, for readers of one value
    m = mdl.load(setup["per"])
    assert m.inflations() == {A: 0.0, B: 0.5} and m.largest_inflation() == 0.5
    assert m.checked_xi(A).tobytes() == m.joints[A].xi(0.0).tobytes()
    assert m.checked_xi(B).tobytes() == m.joints[B].xi(0.5).tobytes()


@pytest.mark.parametrize("cmd", ["check", "replay"])
def test_a_fault_inside_the_largest_inflation_is_caught_on_the_tight_joint(cmd, setup, capsys):
    """Old code: one inflation, the largest (0.5), for both joints: the spike on joint A stays
    inside its sets scaled by 1.5 and ``check``/``replay`` call the data conformant. Now joint
    A is checked with its own inflation 0: caught, exit 1; joint B stays conformant."""
    r = run_json([cmd, setup["faulty"], "--model", setup["per"]], capsys)
    assert not r["conformant"]
    assert r["joints"][A]["violations"] > 0 and r["joints"][B]["violations"] == 0
    assert run_json([cmd, setup["clean"], "--model", setup["per"]], capsys)["conformant"]
    # the same fault under the largest inflation applied to every joint (the old model): missed
    assert run_json([cmd, setup["faulty"], "--model", setup["old"]], capsys)["conformant"]


def test_monitor_core_stops_on_the_tight_joint(setup):
    """The node's core (MonitorCore: the bounds per joint from ConformanceModel.checked_xi)."""
    def violations(path):
        core = MonitorCore(mdl.load(path))
        ev = []
        for k, t in enumerate(setup["stamps"]):
            ev += core.add_y(int(t), [A, B], list(setup["yf"][k]))
            ev += core.add_u(int(t), [A, B], list(setup["u"][k]))
        st = [e.result["status"] for e in ev if isinstance(e, TickEvent)]
        return [sum(s[j] == "violation" for s in st) for j in range(2)]
    new, old = violations(setup["per"]), violations(setup["old"])
    assert new[0] > 0 and new[1] == 0
    assert old == [0, 0]


@pytest.mark.skipif(kernels.LIB_PATH is None, reason="compiled kernel not built")
def test_compiled_tick_equals_numpy_tick_with_per_joint_inflation(setup):
    model = mdl.load(setup["per"])
    mms = [MonitorModel.from_model(model, n) for n in (A, B)]
    a, b = Monitor(mms, kernel=True), Monitor(mms, kernel=False)
    assert a.kernel and not b.kernel
    seen = set()
    for k, t in enumerate(setup["stamps"]):
        ra, rb = a.tick(int(t), setup["yf"][k], setup["u"][k]), b.tick(int(t), setup["yf"][k], setup["u"][k])
        assert ra["status"] == rb["status"], k
        seen.update(ra["status"])
        for key in ("margin", "checked", "deviation", "bound"):
            assert ra[key].tobytes() == rb[key].tobytes(), (k, key)
    assert "violation" in seen


def test_a_file_with_one_inflation_applies_it_to_every_joint(setup, tmp_path):
    """A model file written before per-joint inflation (no joint carries one) loads with the
    same behaviour: its one inflation for every joint; saved again it stays in that form."""
    doc = yaml.safe_load(setup["old"].read_text())
    for j in doc["joints"].values():
        j.pop("inflation")
    path = tmp_path / "pre35.yaml"
    path.write_text(yaml.safe_dump(doc))
    m = mdl.load(path)
    assert m.inflations() == {A: 0.5, B: 0.5} and all(j.inflation is None for j in m.joints.values())
    for n in (A, B):
        assert m.checked_xi(n).tobytes() == m.joints[n].xi(0.5).tobytes()
    mdl.save(m, tmp_path / "again.yaml")
    again = yaml.safe_load((tmp_path / "again.yaml").read_text())
    assert again["inflation"] == 0.5 and all("inflation" not in j for j in again["joints"].values())


def test_the_model_level_inflation_must_be_the_largest_joints(setup, tmp_path):
    """An edited model-level value that no joint applies is refused (it would say nothing)."""
    doc = yaml.safe_load(setup["per"].read_text())
    doc["inflation"] = 1.0
    path = tmp_path / "edited.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ReachsetError, match="inflation 1 is not the largest of its joints' own inflations"):
        mdl.load(path)
    doc["inflation"], doc["joints"][A]["inflation"] = 0.5, -0.1
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ReachsetError, match=f"joint {A} inflation must be >= 0"):
        mdl.load(path)


def test_the_calibration_record_binds_each_joints_inflation(setup, tmp_path):
    """Row G18 per joint: a record of per-joint values refuses a file whose joint A inflation
    was changed, even when the largest stays the same; an old record (one value) binds it to
    every joint."""
    m = mdl.with_calibration(mdl.load(setup["per"]), method="cross_validation", folds=2)
    assert m.calibration["inflations"] == {A: 0.0, B: 0.5} and m.calibration["inflation"] == 0.5
    mdl.save(m, tmp_path / "cal.yaml")
    assert mdl.load(tmp_path / "cal.yaml").inflations() == {A: 0.0, B: 0.5}
    doc = yaml.safe_load((tmp_path / "cal.yaml").read_text())
    doc["joints"][A]["inflation"] = 0.2
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ReachsetError, match=f"joint {A}: inflation 0.2 is not the calibrated 0 of its calibration"):
        mdl.load(tmp_path / "a.yaml")
    # a record written before per-joint inflation (no 'inflations') on a file of one value
    old = mdl.with_calibration(mdl.load(setup["old"]), method="cross_validation", folds=2)
    doc = mdl.to_dict(old)
    doc["calibration"].pop("inflations")
    for j in doc["joints"].values():
        j.pop("inflation")
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(doc))
    assert mdl.load(tmp_path / "old.yaml").inflations() == {A: 0.5, B: 0.5}
    doc["joints"][A]["inflation"] = 0.0
    doc["inflation"] = 0.5
    (tmp_path / "old_a.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ReachsetError, match=f"joint {A}: inflation 0 is not the calibrated 0.5"):
        mdl.load(tmp_path / "old_a.yaml")


def _gains_model(path, infl_a, infl_b):
    js = mdl.JointSets(SETS.alpha_w, SETS.alpha_v, SETS.c_w, SETS.c_v, 0, 125,
                       gains={**TABLE_II.model_dict(), "u_max": 26.0, "u_ff": 2.0}, extra=ZERO_U_E_FF)
    m = mdl.ConformanceModel(PLANT, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                             {A: js, B: js}).with_inflation({A: infl_a, B: infl_b})
    mdl.save(m, path)
    return mdl.load(path)


def test_the_certificate_of_a_joint_uses_its_own_inflation(tmp_path):
    """Table II's R*_u is certified up to inflation 0.75 (test_certify). Joint A at 0 and joint B
    at 1: A's gains are certified (old code: with the model's one inflation 1, refused), B's
    are refused naming its inflation."""
    m = _gains_model(tmp_path / "m.yaml", 0.0, 1.0)
    pc = certify_pair({A: TABLE_II}, m, [26.0], 2.0, 0.004)
    assert pc.certified[A].ok and pc.certified[A].inflation == 0.0
    with pytest.raises(ReachsetError, match=rf"joint {B}: reachable input R\*_u .* inflated by 1 \+ 1"):
        certify_pair({B: TABLE_II}, m, [26.0], 2.0, 0.004)
    data = {"joints": {A: {"u_max": 26.0, "u_ff": 2.0}}}
    assert certify_synthesis(data, str(tmp_path / "m.yaml")) == ""
    why = certify_synthesis({"joints": {B: {"u_max": 26.0, "u_ff": 2.0}}}, str(tmp_path / "m.yaml"))
    assert why.startswith(f"joint {B}: reachable input R*_u")


@pytest.mark.slow
def test_identify_calibrate_stores_each_joints_own_value(tmp_path, capsys):
    """``identify --calibrate 2 --inflation-rule per-joint``: joint B's second run is disturbed 1.6 times harder than its
    first, joint A's runs alike, so the folds need more on B than on A. Each joint's block
    stores its own cross-validated value (old code: the largest, once, for both), the JSON
    reports it as the joint's ``inflation``, the record binds it; ``--calibrate-margin 1``
    steps each joint's own value; ``--inflation F`` applies F to both."""
    bags = []
    for b in range(2):
        y, u = np.empty((N, 2)), np.empty((N, 2))
        y[:, 0], u[:, 0] = simulate(N, seed=500 + b)
        y[:, 1], u[:, 1] = simulate(N, seed=510 + b, alpha_w=(0.03 * (1 + 0.6 * b), 3.0 * (1 + 0.6 * b)))
        bags.append(write_bag(tmp_path / f"b{b}", clean_rows(T0 + DT_NS * np.arange(N) + b * 10**11, y, u)))
    grid = sorted({0.0, *DEFAULT_GRID})
    for margin in (0, 1):
        out = tmp_path / f"m{margin}.yaml"
        r = run_json(["identify", *bags, "--horizon", HORIZON, "--calibrate", 2, "--calibrate-margin", margin,
                      "--inflation-rule", "per-joint", "--out", out], capsys)
        cv = {n: r["joints"][n]["calibration"]["inflation"] for n in (A, B)}
        want = {n: calibrate_margin(x, grid, margin) if margin else x for n, x in cv.items()}
        assert cv[A] < cv[B]                       # the data make the joints differ
        assert {n: r["joints"][n]["inflation"] for n in (A, B)} == want and r["inflation"] == want[B]
        doc = yaml.safe_load(out.read_text())
        assert {n: doc["joints"][n]["inflation"] for n in (A, B)} == want and doc["inflation"] == want[B]
        assert doc["calibration"]["inflations"] == want and doc["calibration"]["per_joint"] == cv
        assert mdl.load(out).inflations() == want
    # the default rule (identify.inflation_rule, 'largest'): the largest of the joints' values on every joint
    out = tmp_path / "largest.yaml"
    r = run_json(["identify", *bags, "--horizon", HORIZON, "--calibrate", 2, "--out", out], capsys)
    cv = {n: r["joints"][n]["calibration"]["inflation"] for n in (A, B)}
    assert mdl.load(out).inflations() == {A: cv[B], B: cv[B]} and r["inflation"] == cv[B]
    out = tmp_path / "given.yaml"
    run_json(["identify", *bags, "--horizon", HORIZON, "--inflation", 0.3, "--out", out], capsys)
    assert mdl.load(out).inflations() == {A: 0.3, B: 0.3}


def test_reidentify_synthesises_for_each_joints_own_inflation(tmp_path):
    """``synthesize --mode reidentify --model M``: each joint's R*_u is constrained for its own
    inflation in M (old code: the model's one value for all); ``--inflation F`` for all."""
    path = tmp_path / "m.yaml"
    m = _gains_model(path, 0.0, 0.5)
    mdl.save(replace(m, input_source=dict(mdl.PLANT_INPUT)), path)
    pl = plan([tmp_path / "unused"], SynthesisOptions(mode="reidentify", model=str(path)))
    assert pl.inflation == {A: 0.0, B: 0.5}
    assert plan([tmp_path / "unused"], SynthesisOptions(mode="reidentify", model=str(path), inflation=0.3)
                ).inflation == 0.3
