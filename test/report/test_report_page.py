"""Issue 36.4: ``reachset report`` through the real command line, its numbers against ``check``'s,
the page self-contained, bad input refused with nothing written; the set use of the core.

The browser's view of the page: test_report_browser.py.
"""
import json
import re

import numpy as np
import pytest

from reachset_ros import bags
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.set_use import set_use
from reachset_ros.conformance.theorem1 import check

from cli_helpers import run_cli
from report_case import FAULT_TICK, JOINTS, STOP_AFTER_TICKS


@pytest.fixture(scope="module")
def page(case, tmp_path_factory):
    """``reachset report train faulty --model M --out report.html --json``: (JSON, page text)."""
    out = tmp_path_factory.mktemp("page") / "report.html"
    p = run_cli("report", case["train"], case["faulty"], "--model", case["model"], "--out", out, "--json")
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout), out.read_text(encoding="utf-8")


def test_the_reports_violations_are_checks_and_its_times_are_seconds_from_the_bags_start(case, page):
    """Per joint the violating ticks of ``check`` on the same bags (count, first one); the first
    violation and the safe stop in seconds from the faulty bag's first /joint_states sample."""
    res, _ = page
    p = run_cli("check", case["train"], case["faulty"], "--model", case["model"], "--json")
    assert p.returncode in (0, 1), p.stderr
    checked = json.loads(p.stdout)["joints"]
    for n in JOINTS:
        assert res["joints"][n]["violations"] == checked[n]["violations"]
        assert res["joints"][n]["test_cases"] == checked[n]["test_cases"]
        first = checked[n]["first_violation_ns"]
        if first is None:
            assert res["joints"][n]["first_violation"] is None
        else:
            fv = res["joints"][n]["first_violation"]
            assert fv["bag"] == str(case["faulty"])
            assert fv["t_s"] == pytest.approx((first - case["start_ns"]) * 1e-9, abs=1e-9)
    # the fault makes arm_2_joint leave its sets; the set use says by how much (0.01 rad bias)
    assert res["joints"]["arm_2_joint"]["violations"] > 0 and res["joints"]["arm_2_joint"]["largest_set_use"] > 1.0
    assert not res["conformant"]
    # one stop, however often the monitor republished it; the fault onset (a bare Header) read too
    [stop] = res["stops"]
    assert stop["bag"] == str(case["faulty"]) and stop["joint"] == "arm_2_joint"
    assert stop["t_s"] == pytest.approx((FAULT_TICK + STOP_AFTER_TICKS) * 0.004, abs=1e-9)
    [onset] = res["fault_onsets"]
    assert onset["t_s"] == pytest.approx(FAULT_TICK * 0.004, abs=1e-9)
    assert res["model_id"] == mdl.file_sha256(case["model"])[:12]


def test_the_page_is_self_contained_and_has_each_joints_section(page):
    """No script, no stylesheet or image fetched from anywhere: figures are data: PNGs."""
    _, text = page
    assert "<script" not in text.lower() and "<link" not in text.lower()
    assert not re.search(r"(src|href)\s*=\s*['\"](?!data:|#)", text), "a reference outside the page"
    assert "http://" not in text and "https://" not in text
    imgs = re.findall(r"<img [^>]*src='data:image/png;base64,", text)
    assert len(imgs) == 2 * len(JOINTS)            # deviations against R_a and set use, per joint
    for n in JOINTS:
        assert f"<section id='joint-{n}'" in text
    for word in ("R*_e", "R*_u", "U_p", "inflation", "model id", "reachset identify"):
        assert word in text


def test_set_use_is_above_one_exactly_at_the_ticks_check_counts(case):
    """The core: on the faulty bag ``set_use`` marks the violating ticks of ``check`` (count and
    first), use > 1 exactly there, <= 1 elsewhere; a NaN sample is a violation of infinite use
    (fail closed), as check counts it."""
    m = mdl.load(case["model"])
    thm = m.theorem1()
    series, _ = bags.read_joint_series([case["faulty"]], None, m.plant.dt)
    for n in JOINTS:
        s = series[n]
        xi = m.checked_xi(n)
        res = check(m.plant, thm, m.estimator, xi, s.y, s.u, s.segments, m.horizon)
        su = set_use(m.plant, thm, m.estimator, xi, s.y, s.u, s.segments, m.horizon)
        assert su.violating.sum() == res.violations and su.test_cases == res.test_cases
        assert (np.flatnonzero(su.violating)[:1].tolist() or [-1])[0] == res.first_violation_tick
        checked = ~np.isnan(su.use)
        assert np.array_equal(su.use[checked] > 1.0, su.violating[checked])
        assert not su.violating[~checked].any()
    s = series["arm_1_joint"]
    xi = m.checked_xi("arm_1_joint")
    u_nan = s.u.copy()
    u_nan[1500] = np.nan                 # kept inside one segment: the deviations after it are NaN
    one = ((0, len(s.y)),)
    res = check(m.plant, thm, m.estimator, xi, s.y, u_nan, one, m.horizon)
    su = set_use(m.plant, thm, m.estimator, xi, s.y, u_nan, one, m.horizon)
    assert res.violations > 0 and su.violating.sum() == res.violations
    assert np.isinf(su.use[su.violating]).any()


@pytest.mark.parametrize("what", ["missing bag", "no such model", "out directory missing", "out is a directory",
                                  "joint not in the model"])
def test_bad_input_is_one_line_exit_2_and_nothing_is_written(case, tmp_path, what):
    """Refused before or during the work: one stderr line naming the problem, exit status 2, the
    page not written and an earlier page untouched (written atomically: no partial file)."""
    out = tmp_path / "report.html"
    out.write_text("earlier page")
    args = {"missing bag": [tmp_path / "nobag", "--model", case["model"], "--out", out],
            "no such model": [case["faulty"], "--model", tmp_path / "none.yaml", "--out", out],
            "out directory missing": [case["faulty"], "--model", case["model"], "--out", tmp_path / "no" / "r.html"],
            "out is a directory": [case["faulty"], "--model", case["model"], "--out", tmp_path],
            "joint not in the model": [case["faulty"], "--model", case["model"], "--out", out,
                                       "--joints", "arm_9_joint"]}[what]
    p = run_cli("report", *args)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("reachset report: error: "), p.stderr
    assert "Traceback" not in p.stderr
    key = {"missing bag": "nobag", "no such model": "none.yaml", "out directory missing": "no",
           "out is a directory": "directory", "joint not in the model": "arm_9_joint"}[what]
    assert key in lines[0]
    assert out.read_text() == "earlier page"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["report.html"]


def test_write_report_is_the_library_call_of_the_command(case, tmp_path):
    """``write_report(bags, model, out)`` (what the demo and the campaign call) writes the page the
    command writes and returns the command's JSON with the page's path."""
    from reachset_ros.report import write_report
    out = tmp_path / "lib.html"
    res = write_report([case["faulty"]], case["model"], out)
    assert res["report"] == str(out) and "<section id='joint-arm_2_joint'" in out.read_text(encoding="utf-8")
    p = run_cli("report", case["faulty"], "--model", case["model"], "--out", tmp_path / "cli.html", "--json")
    assert p.returncode == 0, p.stderr
    cli = json.loads(p.stdout)
    assert {k: v for k, v in cli.items() if k != "report"} == {k: v for k, v in res.items() if k != "report"}
