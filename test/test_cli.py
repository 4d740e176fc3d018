"""reachset_ros.cli: the exit status survives a reader that closes the pipe early."""
import os
import subprocess
import sys

import pytest


@pytest.mark.parametrize("args, status", [(["analyze"], 0), (["analyze", "--json"], 0),
                                          (["analyze", "--omega", "-1"], 2), (["analyze", "--omega", "1000"], 1)])
def test_a_closed_pipe_keeps_the_commands_exit_status(args, status):
    """``reachset analyze | true``: the reader is gone before the command writes. HEAD ended with a
    BrokenPipeError traceback and exit status 1 whatever the command's verdict."""
    read, write = os.pipe()
    os.close(read)                                   # the reader has gone before anything is written
    try:
        p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *args], stdout=write,
                           stderr=subprocess.PIPE, text=True, timeout=300)
        # ``2>&1 | true``: stderr (the error line, the reason of an unstable loop) into the closed pipe too
        both = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *args], stdout=write, stderr=write,
                              timeout=300)
    finally:
        os.close(write)
    assert p.returncode == status, p.stderr
    assert "Traceback" not in p.stderr and "BrokenPipe" not in p.stderr
    assert both.returncode == status


@pytest.fixture(scope="module")
def check_case(tmp_path_factory):
    """A simulated bag, the model identify gives for it, and a model with half its sets (the
    bag is not conformant to it)."""
    import yaml

    from reachset_ros.sim import recordings as sr
    d = tmp_path_factory.mktemp("pipe")
    bag, model, tight = d / "bag", d / "m.yaml", d / "tight.yaml"
    sr.write_recordings(bag, sr.simulate_recordings(("arm_1_joint",), 1500, seed=2))
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "identify", str(bag), "--horizon", "5",
                        "--out", str(model)], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    m = yaml.safe_load(model.read_text())
    for j in m["joints"].values():
        j["alpha_w"] = [0.1 * a for a in j["alpha_w"]]
        j["alpha_v"] = [0.1 * a for a in j["alpha_v"]]
    tight.write_text(yaml.safe_dump(m))
    return bag, model, tight


@pytest.mark.parametrize("which, status", [("model", 0), ("tight", 1)])
@pytest.mark.parametrize("reader", ["head -c1", "closed"])
def test_check_into_a_closed_pipe_exits_with_its_verdict(check_case, which, status, reader):
    """``reachset check BAG --model M | head -c1`` (a real pipe whose reader stops early) and a
    pipe closed before anything is written (``| true``): the exit status is check's verdict (0
    conformant, 1 not), no traceback."""
    bag, model, tight = check_case
    argv = [sys.executable, "-m", "reachset_ros.cli", "check", str(bag), "--model",
            str(model if which == "model" else tight)]
    if reader == "head -c1":
        p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        head = subprocess.Popen(["head", "-c1"], stdin=p.stdout, stdout=subprocess.PIPE)
        p.stdout.close()                             # head holds the only read end
        first = head.communicate(timeout=300)[0]
        err = p.stderr.read().decode()
        p.wait(timeout=300)
        assert first in (b"c", b"N"), first          # "conformant" / "NOT conformant"
        code = p.returncode
    else:
        read, write = os.pipe()
        os.close(read)
        try:
            q = subprocess.run(argv, stdout=write, stderr=subprocess.PIPE, text=True, timeout=300)
        finally:
            os.close(write)
        code, err = q.returncode, q.stderr
    assert code == status, err
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_check_gives_seconds_from_the_bags_start_beside_the_stamp(check_case):
    """``check``'s text printed only the raw ns stamp of the first violation; now also the seconds
    from the start of the bag holding it (JSON: ``first_violation_s`` beside
    ``first_violation_ns``, the bags' starts in ``data.start_ns``)."""
    import json
    import re
    bag, _, tight = check_case
    run = [sys.executable, "-m", "reachset_ros.cli", "check", str(bag), "--model", str(tight)]
    text = subprocess.run(run, capture_output=True, text=True, timeout=300)
    assert text.returncode == 1, text.stderr
    m = re.search(r"first at (\d+\.\d{3}) s from the bag's start, stamp (\d+) ns", text.stdout)
    assert m, text.stdout
    d = json.loads(subprocess.run(run + ["--json"], capture_output=True, text=True, timeout=300).stdout)
    j = d["joints"]["arm_1_joint"]
    assert j["first_violation_ns"] == int(m.group(2)) and len(d["data"]["start_ns"]) == 1
    assert j["first_violation_s"] == (j["first_violation_ns"] - d["data"]["start_ns"][0]) * 1e-9
    assert abs(j["first_violation_s"] - float(m.group(1))) < 1e-3


def test_seconds_from_start_counts_from_the_bag_holding_the_stamp():
    from reachset_ros.bags import ReadReport
    rep = ReadReport(start_ns=[5_000_000_000, 1_000_000_000, None])     # bags need not be in time order
    assert rep.seconds_from_start(5_500_000_000) == 0.5
    assert rep.seconds_from_start(1_250_000_000) == 0.25
    assert rep.seconds_from_start(500_000_000) is None and ReadReport().seconds_from_start(1) is None


def _subparsers():
    import argparse

    from reachset_ros.cli import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return parser, sub.choices


def test_help_shows_every_options_default():
    """``reachset CMD --help`` of every subcommand: each option that takes a value shows its
    default (or says it is required); many showed nothing (``--estimator``, ``--dt``, ``--seed``)."""
    import argparse
    parser, commands = _subparsers()
    assert len(commands) >= 14
    missing, shown = [], 0
    for name, sp in commands.items():
        formatter = sp._get_formatter()
        for a in sp._actions:
            if not a.option_strings or a.nargs == 0 or a.default is argparse.SUPPRESS:
                continue
            text = formatter._expand_help(a) if a.help else ""
            if not ("default" in text.lower() or "(required)" in text):
                missing.append(f"{name} {a.option_strings[-1]}: {text!r}")
            elif isinstance(a.default, (int, float, str)) and "(default: " in text:
                shown += 1
                assert f"(default: {a.default})" in text, (name, a.option_strings, text)
    assert not missing, "\n".join(missing)
    assert shown > 10
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "identify", "--help"], capture_output=True,
                       text=True, timeout=300)   # bounds a hang only
    assert p.returncode == 0 and "(default: lsq)" in p.stdout and "(default: 0.004)" in p.stdout, p.stdout


CHATTER = """
import os, sys
from reachset_ros import cli
from reachset_ros.commands import emit, inspect

def run(args):                      # a library below Python writing to descriptor 1
    os.write(1, b"[RTPS_TRANSPORT Warning] native chatter\\n")
    emit(args, {"ok": True})
    return 0

inspect.run = run
sys.argv = ["reachset", "inspect", "x.mcap"] + sys.argv[1:]
sys.exit(cli.main())
"""


@pytest.mark.parametrize("json_flag", [True, False])
def test_json_stdout_holds_the_json_only_whatever_writes_to_descriptor_1(json_flag):
    """With ``--json`` the command's stdout is its JSON object alone: what a library writes to
    file descriptor 1 (the DDS middleware's log) goes to stderr. Before, one such line in front
    of the JSON made ``reachset gains get --json`` unparseable (a loaded test run). Without
    ``--json`` nothing is redirected."""
    import json
    p = subprocess.run([sys.executable, "-c", CHATTER] + (["--json"] if json_flag else []),
                       capture_output=True, text=True, timeout=300)   # bounds a hang only
    assert p.returncode == 0, p.stderr
    if json_flag:
        assert json.loads(p.stdout) == {"ok": True}, p.stdout
        assert "native chatter" in p.stderr
    else:
        assert "native chatter" in p.stdout and "native chatter" not in p.stderr
