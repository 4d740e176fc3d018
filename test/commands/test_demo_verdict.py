"""The demo's final line (issue 36.6): PASS or FAIL, naming the summary file."""
from pathlib import Path

from reachset_ros.commands.demo import verdict_line


def test_the_final_line_says_pass_or_fail_and_names_the_summary():
    path = Path("/tmp/w/summary.json")
    line, status = verdict_line({"failures": [], "guarantee_failures": []}, path)
    assert status == 0 and line.startswith("reachset demo: PASS") and str(path) in line
    line, status = verdict_line({"failures": ["a stop before the fault"], "guarantee_failures": ["R*_e left"]}, path)
    assert status == 1 and line.startswith("reachset demo: FAIL") and str(path) in line
    assert "a stop before the fault" in line and "R*_e left" in line
