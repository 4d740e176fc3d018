"""The validated envelope on the command line (issue 37), on real LWA-4P runs: ``identify``
records it, ``check --json`` and ``replay --json`` classify every tick with it (the same counts),
and a model without one says so instead of guessing."""
import json

import pytest
import yaml

from cli_helpers import run_cli

KEYS = ("outside_envelope_ticks", "violations_inside_envelope", "classified_ticks")


def cli(*args, code=0):
    out = run_cli(*args)
    assert out.returncode in ((0, 1) if code is None else (code,)), out.stderr
    return json.loads(out.stdout) if "--json" in args else out.stdout


@pytest.fixture(scope="module")
def bags(lwa4p_dir, tmp_path_factory):
    """Runs 1-3 and 5-7 (one pose, training), run 8 (the same pose, held out) and run 80 (a
    workspace sweep: positions the training never reached)."""
    d = tmp_path_factory.mktemp("envelope")
    for name, runs in (("fit", "1-3,5-7"), ("r8", "8"), ("r80", "80")):
        cli("import-lwa4p", lwa4p_dir, "--runs", runs, "--out", d / name)
    # the whole horizon's detection cost: its sets leave run 80's ticks (the envelope is judged on
    # violations); the 100-ms window's larger late steps contain this sweep
    ident = cli("identify", d / "fit", "--calibrate", 2, "--detection-window", 0, "--out", d / "m.yaml", "--json")
    return d, ident


@pytest.mark.slow
def test_identify_records_the_envelope_in_the_model(bags):
    d, ident = bags
    assert ident["envelope"]["recorded"] is True and ident["envelope"]["hold"] == 125
    text = cli("identify", d / "fit", "--out", d / "m_text.yaml")
    assert "validated envelope recorded: grids q/qd, qd/u, 16 cells per range, dilation 1, hold 125 ticks" in text
    assert set(ident["envelope"]["ticks"]) == set(ident["joints"])
    env = yaml.safe_load((d / "m.yaml").read_text())["envelope"]
    assert env["format"] == "reachset_ros/envelope/1" and env["grids"] == [["q", "qd"], ["qd", "u"]]
    assert set(env["joints"]) == set(ident["joints"])
    assert all(env["joints"][n]["ticks"] == ident["envelope"]["ticks"][n] for n in env["joints"])


def test_check_and_replay_classify_every_tick_alike(bags):
    """Run 80 (a sweep) lies outside on every joint and every one of its violating ticks is
    outside; replay (the monitor's tracker, tick by tick) gives check's counts to the tick."""
    d, _ = bags
    chk = cli("check", d / "r8", d / "r80", "--model", d / "m.yaml", "--json", code=1)
    rep = cli("replay", d / "r8", d / "r80", "--model", d / "m.yaml", "--json", code=1)
    assert chk["envelope"]["recorded"] is True and rep["envelope"] == chk["envelope"]
    for n, j in chk["joints"].items():
        assert all(isinstance(j[k], int) for k in KEYS)
        assert {k: rep["joints"][n][k] for k in KEYS + ("violations",)} == {k: j[k] for k in KEYS + ("violations",)}
        assert j["violations_inside_envelope"] <= j["violations"]
    r80 = cli("check", d / "r80", "--model", d / "m.yaml", "--json", code=1)
    assert any(j["violations"] > 0 for j in r80["joints"].values())
    for j in r80["joints"].values():
        assert j["outside_envelope_ticks"] >= 0.9 * j["classified_ticks"] > 0
        assert j["violations_inside_envelope"] == 0
    r8 = cli("check", d / "r8", "--model", d / "m.yaml", "--json", code=None)
    assert sum(j["outside_envelope_ticks"] for j in r8["joints"].values()) < \
        sum(j["outside_envelope_ticks"] for j in r80["joints"].values()) / 5
    text = cli("check", d / "r80", "--model", d / "m.yaml", code=1)
    assert "ticks outside the validated envelope, 0 violating ticks inside it" in text


def test_a_model_without_an_envelope_says_so(bags, tmp_path):
    d, _ = bags
    doc = yaml.safe_load((d / "m.yaml").read_text())
    del doc["envelope"]
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump(doc, sort_keys=False))
    for cmd in ("check", "replay"):
        res = cli(cmd, d / "r80", "--model", old, "--json", code=1)
        assert res["envelope"]["recorded"] is False and "no validated envelope" in res["envelope"]["note"]
        assert all(j[k] is None for j in res["joints"].values() for k in KEYS)
    assert "no envelope recorded in the model" in cli("check", d / "r80", "--model", old, code=1)
