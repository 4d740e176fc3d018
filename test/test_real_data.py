"""End to end on the real LWA-4P recordings: identify on runs 1-70, check 1-70 and 71-100."""
import json
import subprocess
import sys


def cli(*args):
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, args)],
                         capture_output=True, text=True, timeout=600)
    res = json.loads(out.stdout) if "--json" in args and out.stdout else out.stdout
    # check/replay exit 1 when not conformant (0 when conformant, 2 on bad input)
    want = 0 if not isinstance(res, dict) or res.get("conformant", True) else 1
    assert out.returncode == want, out.stderr
    return res


def test_identify_on_runs_1_70_is_conformant_and_report_71_100(lwa4p_dir, tmp_path):
    cli("import-lwa4p", lwa4p_dir, "--runs", "1-70", "--out", tmp_path / "train")
    cli("import-lwa4p", lwa4p_dir, "--runs", "71-100", "--out", tmp_path / "val")
    ident = cli("identify", tmp_path / "train", "--out", tmp_path / "model.yaml", "--json")
    assert len(ident["joints"]) == 6
    train = cli("check", tmp_path / "train", "--model", tmp_path / "model.yaml", "--json")
    assert train["conformant"]
    for j in train["joints"].values():
        assert j["violations"] == 0 and j["test_cases"] > 40000
    val = cli("check", tmp_path / "val", "--model", tmp_path / "model.yaml", "--json")
    ticks = val["data"]["messages"]["/plant_input"]
    shares = {n: j["violations"] / ticks for n, j in val["joints"].items()}
    print("violation share on runs 71-100:", shares)
    assert all(0.0 <= s <= 1.0 for s in shares.values())
    # the replay (online monitor code path) agrees with the batch check on held-out data
    rep = cli("replay", tmp_path / "val", "--model", tmp_path / "model.yaml", "--json")
    for n in val["joints"]:
        assert rep["joints"][n]["violations"] == val["joints"][n]["violations"]
        assert rep["joints"][n]["first_violation_ns"] == val["joints"][n]["first_violation_ns"]
