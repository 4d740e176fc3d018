"""Issue 15.6: a second robot, the Franka Panda of example-robot-data, through the generic URDF
path only: simulate, record /joint_states (with effort) alone, inspect, identify with
``--input effort --robot``, check, monitor over DDS, inject a fault. No Panda-specific code:
the URDF is named by ``example-robot-data:<path>`` and its gripper fingers are locked.
(The long version: ``benchmarks/panda.py``, docs/any-arm.md.)
"""
import json
import shlex
import subprocess
import sys
import time

import numpy as np
import pytest

from reachset_ros import bags

ROBOT = "example-robot-data:panda_description/urdf/panda.urdf"
ARM = ",".join(f"panda_joint{i}" for i in range(1, 8))
LOCK = "panda_finger_joint1,panda_finger_joint2"
EFF = ["--input", "effort", "--robot", ROBOT, "--lock-joints", LOCK]


def cli(*args, code=0):
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, args)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == code, out.stderr
    return json.loads(out.stdout) if "--json" in args else out.stdout


@pytest.fixture(scope="module")
def panda(tmp_path_factory):
    d = tmp_path_factory.mktemp("panda")
    sim = cli("simulate", "--robot", ROBOT, "--joints", ARM, "--seconds", 24, "--seed", 1, "--out", d / "train",
              "--json")
    fault = cli("simulate", "--robot", ROBOT, "--joints", ARM, "--seconds", 8, "--seed", 2, "--out", d / "fault",
                "--fault", "payload", "--fault-at", 5, "--fault-magnitude", 3, "--json")
    return d, sim, fault


@pytest.mark.slow
def test_simulated_panda_is_recorded_as_a_ros2_control_arm(panda):
    d, sim, _ = panda
    topics = {t for t, _, _ in bags.read_messages([d / "train"])}
    assert topics == {"/joint_states"}                      # no /plant_input: only what the arm publishes
    msgs = [m for _, _, m in bags.read_messages([d / "train"], ["/joint_states"])]
    assert len(msgs) == sim["ticks"] == 6000 and list(msgs[0].name) == ARM.split(",")
    assert all(len(m.position) == len(m.velocity) == len(m.effort) == 7 for m in msgs[::100])
    st = np.array([bags.header_stamp_ns(m) for m in msgs])
    assert np.all(np.diff(st) == 4_000_000)
    eff = np.array([m.effort for m in msgs])
    assert np.all(np.abs(eff) <= np.array([87, 87, 87, 87, 12, 12, 12]) + 1e-9)    # URDF effort limits
    assert max(sim["max_tracking_error_rad"].values()) < 0.2                      # it tracks


@pytest.mark.slow
def test_panda_identify_check_and_a_fault_through_the_effort_path(panda):
    d, _, fault = panda
    ins = cli("inspect", d / "train", "--robot", ROBOT, "--json")
    cmd = ins["identify"]["command"]
    assert "--input effort" in cmd and f"--lock-joints {LOCK}" in cmd, ins["identify"]
    ident = cli(*shlex.split(cmd)[1:], "--calibrate", 4, "--out", d / "model.yaml", "--json")
    assert list(ident["joints"]) == ARM.split(",")
    assert ident["data"]["input"]["locked_joints"] == LOCK.split(",")
    train = cli("check", d / "train", "--model", d / "model.yaml", "--json", *EFF)
    assert train["conformant"]
    chk = cli("check", d / "fault", "--model", d / "model.yaml", "--json", *EFF, code=1)
    first = min(j["first_violation_ns"] for j in chk["joints"].values() if j["first_violation_ns"])
    onset = fault["fault"]["onset_ns"]
    print(f"payload 3 kg: first violation {(first - onset) / 1e6:.0f} ms after the onset")
    assert first >= onset                                    # nothing before the fault
    assert first - onset < 2_000_000_000


@pytest.mark.dds
def test_panda_monitor_node_from_joint_states_alone(ros, panda, tmp_path):
    """monitor_node (input_source effort, the URDF by package path, the fingers locked) fed
    the faulted recording's /joint_states over DDS: its first violation is check's and it is
    the safe stop."""
    from sensor_msgs.msg import JointState
    from helpers import Bus
    from reachset_ros import processes
    from reachset_ros.nodes.common import stamp_ns, to_stamp
    d, _, fault = panda
    if not (d / "model.yaml").is_file():
        cli("identify", d / "train", "--calibrate", 4, "--out", d / "model.yaml", *EFF)
    chk = cli("check", d / "fault", "--model", d / "model.yaml", "--json", *EFF, code=1)
    first = min(j["first_violation_ns"] for j in chk["joints"].values() if j["first_violation_ns"])
    msgs = [m for _, _, m in bags.read_messages([d / "fault"], ["/joint_states"])]
    bus = Bus()
    proc = processes.start("monitor_node", {"model_file": str(d / "model.yaml"), "input_source": "effort",
                                         "robot_urdf": ROBOT, "robot_locked_joints": LOCK.split(","),
                                         "max_missing_ticks": 10000, "window_dir": str(tmp_path / "w")}, tmp_path)
    try:
        assert bus.wait(lambda: bus.js.get_subscription_count() > 0, 60), proc.log.read_text()[-2000:]
        for m in msgs:
            out = JointState(name=list(m.name), position=list(m.position), velocity=list(m.velocity),
                             effort=list(m.effort))
            to_stamp(out.header.stamp, bags.header_stamp_ns(m))
            bus.js.publish(out)
            time.sleep(0.002)
            if bus.active_stops():
                break
        assert bus.wait(lambda: bus.active_stops(), 30), proc.log.read_text()[-2000:]
    finally:
        processes.stop([proc])
        bus.close()
    stop = bus.active_stops()[0]
    assert stop.kind == "violation" and stamp_ns(stop.header.stamp) == first
    assert first >= fault["fault"]["onset_ns"]


@pytest.mark.parametrize("args,words", [
    (["--seconds", "-1"], ["--seconds must be > 0"]),
    (["--joints", "panda_joint1,elbow"], ["no joint elbow", "panda.urdf"]),
    (["--fault-at", "2"], ["--fault-at needs --fault"]),
    (["--fault", "bias", "--fault-joint", "panda_joint9"], ["--fault-joint: no joint panda_joint9"]),
])
def test_simulate_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, args, words):
    base = ["--robot", ROBOT, "--seconds", "1", "--out", str(tmp_path / "b")]
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "simulate", *base, *args], capture_output=True,
                       text=True, timeout=300)   # bounds a hang only
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert all(w in p.stderr for w in words), p.stderr
    assert not any(tmp_path.iterdir())
