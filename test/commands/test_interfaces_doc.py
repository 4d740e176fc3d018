"""docs/interfaces.md is the code's own reference, and the repository stands on its own (issue 39)."""
import os
import subprocess
import sys
from pathlib import Path

import yaml

from reachset_ros.cli import main
from reachset_ros.robot import lwa4p

REPO = Path(__file__).resolve().parents[2]


def test_generated_sections_of_the_interface_reference_match_the_code():
    p = subprocess.run([sys.executable, str(REPO / "tools" / "interfaces_doc.py"), "--check"],
                       env=dict(os.environ), capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr


def _tracked_text_files():
    out = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True, check=True).stdout
    for name in out.splitlines():
        p = REPO / name
        if p.is_file() and p.suffix not in (".csv", ".png", ".mcap", ".db3", ".so"):
            yield p


def test_nothing_in_the_repository_points_outside_it():
    needle = "../" + "shared"      # written in two parts so that this file does not match itself
    hits = [str(p.relative_to(REPO)) for p in _tracked_text_files()
            if needle in p.read_text(errors="replace")]
    assert hits == []


def test_the_shipped_recordings_are_found_without_a_path_and_a_missing_place_is_named(tmp_path):
    assert (lwa4p.recordings_dir() / "LICENSE").is_file()
    assert len(list(lwa4p.recordings_dir().glob("measurement_*"))) == 100
    missing = tmp_path / "nowhere"
    try:
        lwa4p.recordings_dir(missing)
    except Exception as e:          # ReachsetError, one line naming the place
        assert str(missing) in str(e) and "\n" not in str(e)
    else:
        raise AssertionError("a missing data directory was accepted")


def test_import_without_a_directory_reads_the_shipped_recordings(tmp_path, capsys):
    out = tmp_path / "bag"
    assert main(["import-lwa4p", "--runs", "1-2", "--out", str(out), "--json"]) == 0
    runs = lwa4p.read_runs(None, "1-2")
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts["/joint_states"] == sum(r.n_samples for r in runs)
