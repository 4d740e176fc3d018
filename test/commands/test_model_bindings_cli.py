"""Issue 34.10/11 through the real command line: the model records how u_p was computed and the
sets its inflation was calibrated on; ``check`` and ``replay`` refuse a mismatch (exit 2, one
line), and a synthesis' sets get their own calibration (:mod:`reachset_ros.workflows.calibrate`)."""
import json

import numpy as np
import pytest
import yaml

from reachset_ros.cli import main
from reachset_ros.conformance import model as mdl
from reachset_ros.workflows.calibrate import calibrate_model, fold_rule

from test_reliability_cli import (DT_NS, SMALL_SEARCH, T0, assert_one_line_error, clean_rows, run, run_json,
                                  simulate, write_bag)

HORIZON = 20
N = 1500


@pytest.fixture(scope="module")
def two_bags(tmp_path_factory):
    """Two recordings of the simulated closed loop (two runs: two folds)."""
    d = tmp_path_factory.mktemp("bind")
    out = []
    for b in range(2):
        y, u = np.empty((N, 2)), np.empty((N, 2))
        for j in range(2):
            y[:, j], u[:, j] = simulate(N, seed=100 + 10 * b + j)
        out.append(write_bag(d / f"b{b}", clean_rows(T0 + DT_NS * np.arange(N) + b * 10**11, y, u)))
    return d, out


@pytest.fixture(scope="module")
def calibrated(two_bags):
    """``identify --calibrate 2`` of both bags, and ``synthesize --inflation`` with the
    inflation it calibrated (what the demo did): ``(identified, synthesised)`` model paths."""
    d, bags = two_bags
    ident, synth = d / "identified.yaml", d / "synthesised.yaml"
    assert main(["identify", *map(str, bags), "--horizon", str(HORIZON), "--calibrate", "2", "--out", str(ident)]) == 0
    cfg = d / "synthesis.yaml"
    cfg.write_text(yaml.safe_dump({"search": SMALL_SEARCH}))
    inflation = mdl.load(ident).inflation
    assert main(["synthesize", *map(str, bags), "--horizon", str(HORIZON), "--config", str(cfg),
                 "--reference-class", "qdd_max=2", "--inflation", str(inflation), "--out", str(synth)]) == 0
    return ident, synth


@pytest.mark.slow
@pytest.mark.parametrize("cmd", ["check", "replay"])
def test_a_model_without_input_source_is_refused_until_bound(cmd, two_bags, calibrated, tmp_path, capsys):
    """34.10: a model file that does not say how its u_p was computed (written before the
    binding) is refused by check and replay with one line naming the binding; declared, it runs."""
    _, bags = two_bags
    ident, _ = calibrated
    doc = yaml.safe_load(ident.read_text())
    assert doc["input_source"] == {"kind": "topic"}
    doc.pop("input_source")
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump(doc))
    code, so, se = run([cmd, bags[0], "--model", old, "--json"], capsys)
    assert_one_line_error(code, so, se, cmd, [str(old), "records no input_source", "input_source: {kind: topic}"])
    doc["input_source"] = {"kind": "topic"}
    old.write_text(yaml.safe_dump(doc))
    run_json([cmd, bags[0], "--model", old], capsys)


def test_identify_and_synthesize_record_the_source_and_the_calibrated_sets(calibrated):
    """identify records the plant-input topic and the digest of the sets it calibrated; the
    synthesis records the source, and no calibration: its inflation was given, not calibrated
    on its sets (before, neither file recorded either)."""
    ident, synth = calibrated
    m, s = mdl.load(ident), mdl.load(synth)
    assert m.input_source == s.input_source == {"kind": "topic"}
    assert m.calibration["method"] == "cross_validation" and m.calibration["folds"] == 2
    assert m.calibration["sets_sha256"] == mdl.sets_digest(m) and m.calibration["inflation"] == m.inflation
    assert m.calibration["rule"]["sets"] == "identify"
    assert s.calibration is None and s.inflation == m.inflation
    assert mdl.sets_digest(s) != mdl.sets_digest(m)          # the synthesis' sets are other sets


@pytest.mark.parametrize("cmd", ["check", "replay"])
def test_an_inflation_calibrated_on_other_sets_is_refused(cmd, two_bags, calibrated, tmp_path, capsys):
    """34.11: identify's calibration carried over to the synthesis' sets (the monitor checks
    those) is refused with one line; before, check, replay and the monitor took it."""
    _, bags = two_bags
    ident, synth = calibrated
    m, s = mdl.load(ident), mdl.load(synth)
    carried = tmp_path / "carried.yaml"
    mdl.save(m.with_joints(s.joints), carried)       # identify's record over the synthesis' sets
    code, so, se = run([cmd, bags[0], "--model", carried, "--json"], capsys)
    assert_one_line_error(code, so, se, cmd, [str(carried), "calibrated on other sets than the ones it holds"])


def test_calibrate_model_calibrates_the_synthesis_sets_by_their_own_rule(two_bags, calibrated, tmp_path, capsys):
    """The synthesis' sets are calibrated with the rule that made them: per fold, min ||R*_e||
    of the model's gains over the fold's Theorem-1 polytope (the synthesis' sets put nothing on
    alpha_W here, identify's do), checked on the other fold; the record binds these sets, and
    check and replay accept the model. With held-out bags the sets themselves are checked."""
    d, bags = two_bags
    _, synth = calibrated
    s = mdl.load(synth)
    fit, rule = fold_rule(s)
    assert rule["sets"] == "synthesis_min_re_norm"
    from reachset_ros.bags import read_joint_series
    series, _ = read_joint_series(bags[:1], list(s.joints), 0.004)
    fold_sets = fit(series)
    ident_fit, ident_rule = fold_rule(mdl.load(calibrated[0]))
    assert ident_rule["sets"] == "identify"
    ident_sets = ident_fit(series)
    for n, js in s.joints.items():       # each rule reproduces the structure of its own sets
        assert (max(js.alpha_w) == 0) == (max(fold_sets[n].alpha_w) == 0)
        assert fold_sets[n].alpha_w != ident_sets[n].alpha_w
    res = calibrate_model(s, bags=bags, folds=2)
    out = tmp_path / "monitor_model.yaml"
    mdl.save(res.model, out)
    back = mdl.load(out)
    assert back.calibration["sets_sha256"] == mdl.sets_digest(s) and back.inflation == res.model.inflation
    assert back.calibration["rule"]["sets"] == "synthesis_min_re_norm"
    assert {n: j.alpha_w for n, j in back.joints.items()} == {n: j.alpha_w for n, j in s.joints.items()}
    assert all(len(c["folds"]) == 2 for c in res.joints.values())
    for cmd in ("check", "replay"):
        assert run_json([cmd, *bags, "--model", out], capsys)["conformant"]
    held = calibrate_model(s, validate_bags=bags[1:])
    assert held.model.calibration["method"] == "held_out_bags"
    assert held.model.calibration["sets_sha256"] == mdl.sets_digest(s)
    assert json.dumps(held.model.calibration)             # plain values: the YAML file takes it


@pytest.mark.slow
def test_synthesize_calibrate_records_the_inflation_of_its_own_sets(two_bags, calibrated, tmp_path, capsys):
    """``synthesize --calibrate K`` writes the synthesised sets with the inflation calibrated on
    them (the record binds them: check and replay take the model) and says whether R*_u was
    synthesised for it."""
    d, bags = two_bags
    cfg = d / "synthesis.yaml"
    out = tmp_path / "monitor.yaml"
    res = run_json(["synthesize", *bags, "--horizon", HORIZON, "--config", cfg, "--reference-class", "qdd_max=2",
                    "--inflation", 5.0, "--calibrate", 2, "--out", out], capsys)
    cal = res["calibration"]
    m = mdl.load(out)
    assert cal["rule"] == "synthesis_min_re_norm" and cal["folds"] == 2 and cal["inflation"] == m.inflation
    assert cal["certified"] is (m.inflation <= 5.0) and cal["synthesised_for_inflation"] == 5.0
    assert m.calibration["sets_sha256"] == mdl.sets_digest(m) and m.calibration["method"] == "cross_validation"
    assert m.inflation == max(cal["per_joint"].values())
    assert run_json(["check", *bags, "--model", out], capsys)["conformant"]
    code, so, se = run(["synthesize", *bags, "--calibrate", 1, "--reference-class", "qdd_max=2"], capsys)
    assert_one_line_error(code, so, se, "synthesize", ["--calibrate needs K >= 2"])
