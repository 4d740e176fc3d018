"""Issue 34.10/11: the model binds how u_p was computed and the sets its inflation was calibrated on.

* ``input_source`` (34.10): ``check``, ``replay`` and the monitor refuse data whose u_p is not
  computed as the model's data's was (the topic instead of the effort, another URDF or
  parameter document, other locked joints), and a model that records no source.
* ``calibration`` (34.11): every reader refuses a model whose calibration record names other
  sets (or another inflation) than the ones it holds.
"""
from pathlib import Path

import pytest
import yaml

from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.errors import ReachsetError
from reachset_ros.systems.plant import lwa4p_joint_plant

REPO = Path(__file__).resolve().parents[2]
NOMINAL = REPO / "config" / "lwa4p_nominal.yaml"


def _model(input_source=mdl.PLANT_INPUT, inflation=0.0, alpha_w=(0.1, 0.0)):
    js = {"arm_1_joint": mdl.JointSets(tuple(alpha_w), (3e-4,), (0.0,) * 5, (0.0,), 10, 20)}
    return mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 20, js,
                                inflation, input_source=input_source)


def test_input_source_round_trips_and_a_model_without_one_is_refused(tmp_path):
    """Before, a model recorded nothing of its u_p: every reader accepted any u_p. Now the
    readers refuse a model without ``input_source`` (one line naming it and the two ways out)
    and accept it once bound."""
    mdl.save(_model(), tmp_path / "m.yaml")
    m = mdl.load(tmp_path / "m.yaml")
    assert m.input_source == {"kind": "topic"}
    assert mdl.require_input_source(m, None, source="m.yaml") == {"kind": "topic"}
    old = yaml.safe_load((tmp_path / "m.yaml").read_text())
    old.pop("input_source")
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(old))
    unbound = mdl.load(tmp_path / "old.yaml")           # the file still loads (observer, controller)
    with pytest.raises(ReachsetError, match=r"records no input_source .*input_source: \{kind: topic\}"):
        mdl.require_input_source(unbound, None, source="old.yaml")
    old["input_source"] = yaml.safe_load("{kind: topic}")
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(old))
    mdl.require_input_source(mdl.load(tmp_path / "old.yaml"), None, source="old.yaml")
    for bad, words in (({"kind": "joint_states"}, "kind topic or effort"),
                       ({"kind": "effort", "urdf_sha256": "ab"}, "has no params_sha256")):
        old["input_source"] = bad
        (tmp_path / "bad.yaml").write_text(yaml.safe_dump(old))
        with pytest.raises(ReachsetError, match=words):
            mdl.load(tmp_path / "bad.yaml")


def test_effort_binding_names_the_field_that_differs(tmp_path):
    """A model identified from effort with the URDF and the nominal parameters is refused for
    u_p from the topic, without the parameters, with other locked joints or another URDF."""
    from reachset_ros.robot.dynamics import DEFAULT_URDF
    from reachset_ros.robot.effort import load_effort_input
    src = load_effort_input(DEFAULT_URDF, NOMINAL)
    b = src.binding()
    assert b["kind"] == "effort" and len(b["urdf_sha256"]) == 64 and len(b["params_sha256"]) == 64
    assert len(b["torque_scale"]) == len(b["joints"]) == 6 and b["locked_joints"] == []
    mdl.save(_model(input_source=b), tmp_path / "m.yaml")
    m = mdl.load(tmp_path / "m.yaml")
    mdl.require_input_source(m, load_effort_input(DEFAULT_URDF, NOMINAL), source="m")
    with pytest.raises(ReachsetError, match="identified with u_p from effort .* comes from the plant-input topic"):
        mdl.require_input_source(m, None, source="m")
    with pytest.raises(ReachsetError, match="params_sha256"):
        mdl.require_input_source(m, load_effort_input(DEFAULT_URDF), source="m")
    plain = _model(input_source=load_effort_input(DEFAULT_URDF).binding())
    with pytest.raises(ReachsetError, match="locked_joints"):
        mdl.require_input_source(plain, load_effort_input(DEFAULT_URDF, lock=["arm_6_joint"]), source="m")
    other = tmp_path / "other.urdf"
    other.write_text(DEFAULT_URDF.read_text().replace('<mass value="', '<mass value="1', 1))
    with pytest.raises(ReachsetError, match="urdf_sha256"):
        mdl.require_input_source(m, load_effort_input(other, NOMINAL), source="m")
    topic = _model()
    with pytest.raises(ReachsetError, match="identified with u_p from the plant-input topic, but this u_p comes "
                                            "from effort"):
        mdl.require_input_source(topic, src, source="m")


def test_a_calibration_record_binds_its_sets_and_inflation(tmp_path):
    """Before, an inflation calibrated on some sets was carried to others (identify's
    calibrated inflation on the synthesis' sets) with nothing to tell. The record's digest
    survives the file; other sets or another inflation under the record are refused by load."""
    m = mdl.with_calibration(_model(inflation=0.5), method="cross_validation", folds=2)
    mdl.save(m, tmp_path / "m.yaml")
    back = mdl.load(tmp_path / "m.yaml")
    assert back.calibration["sets_sha256"] == mdl.sets_digest(back) == mdl.sets_digest(m)
    other = m.with_joints({"arm_1_joint": mdl.JointSets((0.0, 0.0), (2e-4,), (0.0,) * 5, (0.0,), 10, 20)})
    mdl.save(other, tmp_path / "other.yaml")
    with pytest.raises(ReachsetError, match="calibrated on other sets than the ones it holds"):
        mdl.load(tmp_path / "other.yaml")
    doc = yaml.safe_load((tmp_path / "m.yaml").read_text())
    doc["inflation"] = 1.0
    (tmp_path / "infl.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ReachsetError, match="inflation 1 is not the calibrated 0.5"):
        mdl.load(tmp_path / "infl.yaml")
    for key, value in (("horizon", 30), ("initial_state_set", True)):
        doc = yaml.safe_load((tmp_path / "m.yaml").read_text())
        doc[key] = value
        if key == "horizon":
            doc["joints"]["arm_1_joint"]["horizon"] = 30
        (tmp_path / "k.yaml").write_text(yaml.safe_dump(doc))
        with pytest.raises(ReachsetError, match="calibrated on other sets"):
            mdl.load(tmp_path / "k.yaml")
    doc = yaml.safe_load((tmp_path / "m.yaml").read_text())
    doc.pop("calibration")                  # no record: a given inflation, accepted as such
    (tmp_path / "given.yaml").write_text(yaml.safe_dump(doc))
    assert mdl.load(tmp_path / "given.yaml").calibration is None
