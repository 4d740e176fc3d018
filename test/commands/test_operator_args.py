"""The operator commands' input (issue 36.2), without a suite: which domain they reach
(:func:`reachset_ros.domain.suite_domain`), bad input refused with one line and exit status 2
before anything is sent, and the set use read from a real ``/conformance/status`` message."""
import os
import subprocess
import sys

import pytest

from reachset_ros.cli import main
from reachset_ros.domain import STATE_FILE, suite_domain, write_suite_state
from reachset_ros.errors import ReachsetError


def test_the_domain_comes_from_domain_then_workdir_then_the_environment_then_0(tmp_path):
    write_suite_state(tmp_path, domain_id=42, pid=os.getpid(), nodes=[{"name": "monitor_node", "pid": 1, "log": "x"}])
    assert suite_domain(domain=7, workdir=tmp_path, environ={"ROS_DOMAIN_ID": "9"})[:2] == (7, "--domain")
    d, source, state = suite_domain(workdir=tmp_path, environ={"ROS_DOMAIN_ID": "9"})
    assert (d, source) == (42, str(tmp_path / STATE_FILE)) and state["nodes"][0]["name"] == "monitor_node"
    assert suite_domain(environ={"ROS_DOMAIN_ID": " 9 "})[:2] == (9, "ROS_DOMAIN_ID")
    assert suite_domain(environ={})[:2] == (0, "default")


@pytest.mark.parametrize("case, match", [
    ("no up.json", "is not the --workdir of a `reachset up`"),
    ("up ended", "is not running any more"),
    ("unreadable", "unreadable"),
    ("bad domain", "outside 0..232"),
    ("bad environment", "ROS_DOMAIN_ID 'x' is not a domain id"),
])
def test_a_suite_that_is_not_there_is_named(tmp_path, case, match):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True).stdout.strip()
    kw = {"workdir": tmp_path, "environ": {}}
    if case == "up ended":
        write_suite_state(tmp_path, domain_id=5, pid=int(dead))
    elif case == "unreadable":
        (tmp_path / STATE_FILE).write_text("{not json")
    elif case == "bad domain":
        kw = {"domain": 300}
    elif case == "bad environment":
        kw = {"environ": {"ROS_DOMAIN_ID": "x"}}
    with pytest.raises(ReachsetError, match=match):
        suite_domain(**kw)


@pytest.mark.parametrize("argv, match", [
    (["gains", "set", "omega=x"], "omega='x': not a number"),
    (["gains", "set", "omega=0"], "positive finite"),
    (["gains", "set", "omega=1,nan"], "positive finite"),
    (["gains", "set", "gain=1"], "'gain' is not a gain"),
    (["gains", "set", "observer=kalman"], "must be one of hg, eso"),
    (["gains", "set", "omega"], "expected NAME=VALUE"),
    (["gains", "set", "omega=1", "omega=2"], "omega given twice"),
    (["status", "--workdir", "NOWHERE"], "is not the --workdir of a `reachset up`"),
    (["status", "--window", "0"], "--window must be positive"),
    (["reset", "--wait", "-1"], "--wait must not be negative"),
    (["watch", "--period", "0"], "--period and --duration must be positive"),
    (["stop", "--domain", "999"], "--domain 999 is outside"),
    (["stop", "--timeout", "0"], "--timeout must be positive"),
])
def test_bad_input_exits_2_with_one_line_and_sends_nothing(tmp_path, capsys, argv, match):
    argv = [str(tmp_path / "nowhere") if a == "NOWHERE" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err, err


def test_set_use_of_a_status_message():
    from reachset_msgs.msg import ConformanceStatus

    from reachset_ros.workflows.operator import set_use_of
    m = ConformanceStatus(name=["a", "b", "c"], deviation=[0.01, 0.03, 0.0], margin=[0.03, -0.01, 1e300])
    use = set_use_of(m)
    assert use["a"] == pytest.approx(0.25) and use["b"] == pytest.approx(1.5) and use["c"] is None
    if "set_use" in ConformanceStatus.get_fields_and_field_types():       # the monitor's own (issue 36.3)
        m.set_use = [0.5, 1.2, 0.0]
        assert set_use_of(m) == {"a": 0.5, "b": 1.2, "c": 0.0}


def test_the_operator_commands_are_listed_with_their_options():
    import argparse

    from reachset_ros.cli import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert {"status", "watch", "reset", "stop", "gains"} <= set(sub.choices)
    for name in ("status", "watch", "reset", "stop"):
        h = sub.choices[name].format_help()
        assert "--workdir" in h and "--domain" in h and "--json" in h, name
