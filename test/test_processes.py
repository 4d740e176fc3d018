"""reachset_ros.processes: the suite's Fast DDS profile (start-up discovery)."""
import os
import subprocess
import sys
from pathlib import Path

from reachset_ros import processes

PROBE = ("import rclpy; rclpy.init(); n = rclpy.create_node('profile_probe'); "
         "n.destroy_node(); rclpy.shutdown(); print('participant up')")


def _probe(profile_file):
    """A real rclpy participant created with ``profile_file`` as Fast DDS's profile file."""
    env = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(profile_file))
    env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    return subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=300)   # bounds a hang only (make test OVERLAP=1 runs it at the idle priority)


def test_use_dds_profiles_names_the_suites_file_unless_the_user_named_one():
    env = {}
    assert processes.use_dds_profiles(env) is True
    assert env == {"FASTRTPS_DEFAULT_PROFILES_FILE": processes.DDS_PROFILES}
    assert Path(processes.DDS_PROFILES).is_file()
    for var in processes.DDS_PROFILE_VARS:                   # the user's file decides
        env = {var: "/etc/my_fastdds.xml"}
        assert processes.use_dds_profiles(env) is False
        assert env == {var: "/etc/my_fastdds.xml"}
    env = {"FASTRTPS_DEFAULT_PROFILES_FILE": ""}          # set but empty: not a file, ours
    assert processes.use_dds_profiles(env) is True and env["FASTRTPS_DEFAULT_PROFILES_FILE"] == processes.DDS_PROFILES


def test_fast_dds_parses_the_suites_profile(tmp_path):
    """The real Fast DDS loads the file without an XML error (a bad value in the same file is
    reported, so the check can fail) and the participant comes up."""
    ok = _probe(processes.DDS_PROFILES)
    log = ok.stdout + ok.stderr                 # Fast DDS logs to stdout when it is not a terminal
    assert ok.returncode == 0 and "participant up" in ok.stdout, log
    assert "XMLPARSER" not in log, log
    text = Path(processes.DDS_PROFILES).read_text()
    assert "<count>20</count>" in text and 'is_default_profile="true"' in text
    bad = tmp_path / "bad.xml"
    bad.write_text(text.replace("<count>20</count>", "<count>twenty</count>"))
    broken = _probe(bad)
    assert "XMLPARSER" in broken.stdout + broken.stderr, broken
