"""``reachset analyze`` as a user runs it (a real subprocess), docs/interfaces.md."""
import json
import subprocess
import sys

import pytest


def _run(*args):
    return subprocess.run([sys.executable, "-m", "reachset_ros.cli", "analyze", *args],
                          capture_output=True, text=True, timeout=120)


def test_analyze_json_defaults_hg_static():
    out = _run("--json")
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert {"re_norm", "re_radius", "ru", "stable"} <= set(res)
    assert res["stable"] is True
    assert len(res["re_radius"]) == 2 and len(res["ru"]) == 2
    assert res["re_norm"] == pytest.approx(2 * sum(res["re_radius"]))
    assert res["ru"][0] < -2 < 2 < res["ru"][1]  # contains U_ff = [-2, 2]
    assert res["re_norm_inner"] <= res["re_norm"]
    assert res["params"]["observer"] == "hg" and res["params"]["omega"] == 24.4


@pytest.mark.slow
def test_analyze_eso_and_options_change_the_result():
    a = json.loads(_run("--json", "--observer", "eso").stdout)
    b = json.loads(_run("--json", "--observer", "eso", "--l1", "57.1", "--l2", "103.3", "--l3", "18.1",
                        "--eps", "0.01", "--controller", "compensated", "--omega", "20", "--zeta", "1",
                        "--alpha-w", "0.0234", "3.587", "--alpha-v", "3.49e-5", "--u-ff", "0").stdout)
    assert a["stable"] and b["stable"]
    assert a["re_norm"] == pytest.approx(b["re_norm"])
    assert a["ru"][1] == pytest.approx(b["ru"][1] + 2.0)
    c = json.loads(_run("--json", "--alpha-w", "0.0696", "7.18", "--alpha-v", "6.98e-5").stdout)
    d = json.loads(_run("--json").stdout)
    assert c["re_norm"] == pytest.approx(2 * d["re_norm"], rel=1e-9)  # linear in alpha


@pytest.mark.slow
def test_analyze_unstable_exits_1_with_a_one_line_reason():
    """Issue 36.6: an unstable loop exited 0 (a script could not tell it from a stable one).
    Now exit 1, the result still printed, one line on stderr saying why."""
    out = _run("--json", "--omega", "1000")
    assert out.returncode == 1, out.stderr
    res = json.loads(out.stdout)
    assert res["stable"] is False and res["re_norm"] is None and res["ru"] is None
    assert out.stderr.count("\n") == 1 and out.stderr.startswith("reachset analyze: closed loop unstable"), out.stderr
    text = _run("--omega", "1000")
    assert text.returncode == 1 and "unstable" in text.stdout and "Traceback" not in text.stderr


def test_analyze_human_output():
    out = _run("--observer", "hg", "--h1", "135", "--h2", "416.1")
    assert out.returncode == 0 and "R_e (outer)" in out.stdout and "R_u" in out.stdout


@pytest.mark.parametrize("args, word", [
    (("--alpha-w", "-1", "3"), "alpha-w"),
    (("--alpha-v=-1e-5",), "alpha-v"),
    (("--omega", "0"), "omega"),
    (("--controller", "compensated"), "eso"),
    (("--observer", "eso", "--l3", "nan"), "l3"),
    (("--dt", "-0.004"), "dt"),
])
@pytest.mark.slow
def test_analyze_bad_input_exits_2_with_one_line(args, word):
    out = _run("--json", *args)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and word in lines[0] and "Traceback" not in out.stderr
    assert out.stdout == ""
