"""Issue 15.3/15.4: bags of an arm that was not built for reachset_ros.

``--input effort --robot URDF [--nominal PARAMS]`` (u_p = M̂⁻¹(τ − ψ̂) from /joint_states
alone), the sampling period measured from the stamps, ``--joint-names`` for JointState
messages without names, bare .mcap/.db3 files, an unsupported metadata version.
"""
import json
import time
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin

from reachset_ros import bags
from reachset_ros.errors import ReachsetError
from reachset_ros.robot import lwa4p
from reachset_ros.robot.dynamics import DEFAULT_URDF, create_data, inverse_fl
from reachset_ros.robot.effort import load_effort_input, plant_inputs

REPO = Path(__file__).resolve().parents[2]
NOMINAL = REPO / "config" / "lwa4p_nominal.yaml"
TS = bags.typestore()
RUNS = [1, 2, 3, 5]            # training runs (none divisible by 4)
T0 = 1_700_000_000_000_000_000
DT_NS = 4_000_000


def cli(*args, code=0):
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, args)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == code, out.stderr
    if code == 2:
        lines = out.stderr.splitlines()
        assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
        return lines[0]
    return json.loads(out.stdout) if "--json" in args else out.stdout


def write_joint_states_only(path, runs, names, storage="mcap", topic="/joint_states", named=True):
    """The LWA-4P runs as a plain ``/joint_states`` bag (position, velocity, effort = logged
    torque as logged), written by rosbags, as a ros2_control arm records it: no /plant_input."""
    w = Writer(path, version=9, storage_plugin={"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage])
    starts = lwa4p.run_start_stamps(runs)
    with w:
        c = w.add_connection(topic, bags.JOINT_STATE_TYPE, typestore=TS)
        for r, s0 in zip(runs, starts):
            stamps = s0 + np.round((r.t - r.t[0]) * 1e9).astype(np.int64)
            for k, st in enumerate(stamps):
                eff = r.tau[k] if k < len(r.tau) else ()
                msg = bags.joint_state(int(st), names if named else [], r.q[k], r.qd[k], eff)
                w.write(c, int(st), TS.serialize_cdr(msg, bags.JOINT_STATE_TYPE))


def synthetic_bag(path, period_ns=DT_NS, named=True, n=600, storage="mcap"):
    """Two joints, /joint_states and /plant_input, ``n`` ticks every ``period_ns``."""
    rng = np.random.default_rng(3)
    names = ["a", "b"]
    with bags.BagWriter(path, storage=storage) as w:
        for i in range(n):
            st = T0 + period_ns * i
            q = 0.1 * np.sin(0.01 * i + np.arange(2)) + rng.uniform(-1e-5, 1e-5, 2)
            w.write(bags.JOINT_STATES, bags.joint_state(st, names if named else [], q, [], []), st)
            w.write(bags.PLANT_INPUT, bags.plant_input(st, names, -0.001 * np.sin(0.01 * i + np.arange(2))), st)
    return path


@pytest.fixture(scope="module")
def lwa_bags(lwa4p_dir, tmp_path_factory):
    d = tmp_path_factory.mktemp("lwa_effort")
    runs = lwa4p.read_runs(lwa4p_dir, RUNS)
    model = lwa4p.load_nominal(NOMINAL)
    lwa4p.import_runs(lwa4p_dir, RUNS, d / "imported", model)
    write_joint_states_only(d / "plain", runs, list(model.joint_names))
    return d, runs, model


def test_effort_route_equals_import_lwa4p_route(lwa_bags):
    """Issue 15 check: the LWA-4P data as a plain /joint_states bag (position, velocity,
    effort), ``identify --input effort --robot URDF --nominal PARAMS``, gives the same sets
    as the import-lwa4p route (/plant_input computed at import), to the bit."""
    d, runs, model = lwa_bags
    a = cli("identify", d / "imported", "--horizon", 40, "--json")
    b = cli("identify", d / "plain", "--horizon", 40, "--input", "effort", "--robot", DEFAULT_URDF,
            "--nominal", NOMINAL, "--json")
    assert list(a["joints"]) == list(b["joints"]) == list(model.joint_names)
    for n in a["joints"]:
        for k in ("alpha_w", "alpha_v", "c_w", "c_v", "test_cases", "horizon"):
            assert a["joints"][n][k] == b["joints"][n][k], (n, k)
        assert a["joints"][n]["test_cases"] > 1000
    assert b["data"]["input"]["source"] == "effort"
    assert b["data"]["period_s"] == [pytest.approx(0.004)]
    # the series themselves: same stamps, same y, same u_p bits
    sa, _ = bags.read_joint_series([d / "imported"])
    sb, rep = bags.read_joint_series([d / "plain"], effort=load_effort_input(DEFAULT_URDF, NOMINAL))
    for n in sa:
        np.testing.assert_array_equal(sa[n].stamps, sb[n].stamps)
        assert sa[n].y.tobytes() == sb[n].y.tobytes() and sa[n].u.tobytes() == sb[n].u.tobytes()
        assert sa[n].segments == sb[n].segments
    assert len(sa[model.joint_names[0]].segments) == len(RUNS)
    # the last sample of a run has no effort: it is not paired (not an invalid sample)
    assert rep.unpaired[model.joint_names[0]] == len(RUNS) and rep.invalid_samples[model.joint_names[0]] == 0


@pytest.mark.slow
def test_effort_route_on_dask_workers_is_the_same_to_the_bit(lwa_bags, tmp_path):
    """Issue 18 with ``--input effort``: the workers rebuild the robot model from the URDF and
    parameters and compute u_p themselves; the sets are the one-process ones to the bit."""
    d, _, _ = lwa_bags
    other = tmp_path / "plain_copy"
    shutil.copytree(d / "plain", other)            # two bags, so that both workers read one
    argv = ["identify", d / "plain", other, "--horizon", 40, "--input", "effort", "--robot", DEFAULT_URDF,
            "--nominal", NOMINAL, "--json"]
    a, b = cli(*argv), cli(*argv, "--workers", 2)
    assert a["joints"] == b["joints"] and a["data"] == b["data"]
    assert b["data"]["input"]["source"] == "effort"


def test_effort_plant_input_is_eq6_inverted(lwa_bags):
    """u_p = M̂(q)⁻¹ (s τ − ψ̂(q, q̇)): the mass matrix times u_p plus ψ̂ gives back the torque;
    a non-finite input gives a NaN row (never a silently used sample)."""
    _, runs, model = lwa_bags
    from reachset_ros.robot.dynamics import mass_matrix, psi
    r = runs[0]
    Q, QD, TAU = r.q[:50], r.qd[:50], r.tau[:50].copy()
    U = plant_inputs(model, Q, QD, TAU)
    data = create_data(model)
    for k in (0, 17, 49):
        tau = model.torque_scale * TAU[k]
        np.testing.assert_allclose(mass_matrix(model, data, Q[k]) @ U[k] + psi(model, data, Q[k], QD[k]), tau,
                                   rtol=1e-9, atol=1e-9)
        assert U[k].tobytes() == inverse_fl(model, data, Q[k], QD[k], tau).tobytes()
    TAU[5, 2] = np.nan
    U2 = plant_inputs(model, Q, QD, TAU)
    assert np.all(np.isnan(U2[5])) and np.all(np.isfinite(np.delete(U2, 5, axis=0)))


@pytest.mark.slow
def test_effort_route_check_and_replay_agree(lwa_bags, tmp_path):
    d, _, _ = lwa_bags
    eff = ["--input", "effort", "--robot", DEFAULT_URDF, "--nominal", NOMINAL]
    cli("identify", d / "plain", "--horizon", 40, "--out", tmp_path / "m.yaml", *eff)
    prov = yaml.safe_load((tmp_path / "m.yaml").read_text())
    assert "effort" in json.dumps(prov)          # the model records where u_p came from
    c = cli("check", d / "plain", "--model", tmp_path / "m.yaml", "--json", *eff)
    r = cli("replay", d / "plain", "--model", tmp_path / "m.yaml", "--json", *eff)
    assert c["conformant"] and r["conformant"]
    for n, j in c["joints"].items():
        assert j["violations"] == r["joints"][n]["violations"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("cmd", ["check", "replay"])
def test_a_model_identified_from_effort_refuses_u_p_computed_otherwise(cmd, lwa_bags, tmp_path):
    """Issue 34.10: the model records how u_p was computed (from effort with this URDF and
    these parameters); check and replay refuse u_p from the plant-input topic (the imported
    bag), or from effort without the parameters, with one line naming the difference. Before,
    both ran and gave verdicts on a signal the sets do not describe."""
    d, _, _ = lwa_bags
    eff = ["--input", "effort", "--robot", DEFAULT_URDF, "--nominal", NOMINAL]
    m = tmp_path / "m.yaml"
    cli("identify", d / "plain", "--horizon", 10, "--out", m, *eff)
    src = yaml.safe_load(m.read_text())["input_source"]
    assert src == load_effort_input(DEFAULT_URDF, NOMINAL).binding() and src["kind"] == "effort"
    line = cli(cmd, d / "imported", "--model", m, code=2)
    assert str(m) in line and "identified with u_p from effort" in line and "plant-input topic" in line
    line = cli(cmd, d / "plain", "--model", m, "--input", "effort", "--robot", DEFAULT_URDF, code=2)
    assert "params_sha256" in line
    cli(cmd, d / "plain", "--model", m, "--json", *eff)


def test_effort_route_errors(lwa_bags, tmp_path):
    d, _, _ = lwa_bags
    assert "--input effort needs --robot" in cli("identify", d / "plain", "--input", "effort", code=2)
    assert "only used with --input effort" in cli("identify", d / "imported", "--robot", DEFAULT_URDF, code=2)
    assert "topic /plant_input missing" in cli("identify", d / "plain", code=2)
    # a URDF with a joint the bag does not have
    other = tmp_path / "seven.urdf"
    txt = DEFAULT_URDF.read_text()
    extra = ('<link name="extra_link"><inertial><mass value="0.1"/><origin xyz="0 0 0"/>'
             '<inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial></link>'
             '<joint name="extra_joint" type="revolute"><parent link="arm_6_link"/><child link="extra_link"/>'
             '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" velocity="1"/></joint></robot>')
    other.write_text(txt.replace("</robot>", extra))
    line = cli("identify", d / "plain", "--input", "effort", "--robot", other, code=2)
    assert "extra_joint" in line and "/joint_states" in line


@pytest.mark.slow
def test_period_measured_from_stamps_and_mismatch_refused(tmp_path):
    """Issue 15.4: the period is measured, not assumed; a 10 ms bag checked at dt = 4 ms is
    refused naming the measured period; with --dt 0.01 it is read."""
    p = synthetic_bag(tmp_path / "b10", period_ns=10_000_000)
    line = cli("identify", p, "--horizon", 10, code=2)
    assert "10 ms" in line and "4 ms" in line and "/joint_states" in line
    res = cli("identify", p, "--horizon", 10, "--dt", 0.01, "--json")
    assert res["data"]["period_s"] == [pytest.approx(0.01)]
    with pytest.raises(ReachsetError, match="measured sampling period"):
        bags.read_joint_series([p], dt=0.004)


@pytest.mark.slow
def test_joint_names_for_messages_without_names(tmp_path):
    """Issue 15.4: JointState messages with an empty name[] are refused (not dropped) unless
    --joint-names maps them; mapped, they give the same model as the named bag."""
    named = synthetic_bag(tmp_path / "named")
    unnamed = synthetic_bag(tmp_path / "unnamed", named=False)
    line = cli("identify", unnamed, "--horizon", 10, code=2)
    assert "no joint names" in line and "--joint-names" in line
    a = cli("identify", named, "--horizon", 10, "--json")
    b = cli("identify", unnamed, "--horizon", 10, "--joint-names", "a,b", "--json")
    assert a["joints"] == b["joints"]
    assert "--joint-names gives 3 names" in cli("identify", unnamed, "--joint-names", "a,b,c", code=2)


@pytest.mark.slow
@pytest.mark.parametrize("storage,suffix", [("mcap", ".mcap"), ("sqlite3", ".db3")])
def test_bare_storage_file_is_a_bag(tmp_path, storage, suffix):
    """Issue 15.4: a bare .mcap / .db3 file is accepted as `ros2 bag` accepts it, and read
    the same as its bag directory."""
    d = synthetic_bag(tmp_path / "bag", storage=storage)
    f = next(d.glob("*" + suffix))
    bare = tmp_path / ("copy" + suffix)
    shutil.copy(f, bare)
    a = cli("identify", d, "--horizon", 10, "--json")
    b = cli("identify", bare, "--horizon", 10, "--json")
    assert a["joints"] == b["joints"]
    ins = cli("inspect", bare, "--json")
    assert json.dumps(ins).count("/joint_states") >= 1


def test_unsupported_metadata_version_says_so(tmp_path):
    d = synthetic_bag(tmp_path / "bag")
    meta = yaml.safe_load((d / "metadata.yaml").read_text())
    meta["rosbag2_bagfile_information"]["version"] = 42
    (d / "metadata.yaml").write_text(yaml.safe_dump(meta))
    line = cli("identify", d, code=2)
    assert "metadata version 42 is not supported" in line and "1-9" in line


def test_inspect_suggests_the_effort_command_and_it_works(lwa_bags):
    """``reachset inspect --robot URDF`` on a bag with only /joint_states (position, velocity,
    effort) prints the identify command with --input effort; that command runs."""
    import shlex
    d, _, _ = lwa_bags
    res = cli("inspect", d / "plain", "--json")
    assert res["identify"]["command"] is None and "--robot URDF" in res["identify"]["reason"]
    assert res["topics"]["/joint_states"]["filled_share"]["effort"] > 0.99
    res = cli("inspect", d / "plain", "--robot", DEFAULT_URDF, "--nominal", NOMINAL, "--json")
    cmd = res["identify"]["command"]
    assert "--input effort" in cmd and "--dt 0.004" in cmd, res
    out = cli(*shlex.split(cmd)[1:], "--horizon", 20, "--json")
    assert len(out["joints"]) == 6 and out["data"]["input"]["source"] == "effort"


@pytest.mark.dds
def test_monitor_node_with_effort_input_stops_where_check_finds_the_first_violation(ros, lwa_bags, tmp_path):
    """Issue 15.3: ``monitor_node`` with ``input_source: effort`` monitors an arm from
    /joint_states alone (real rclpy, real DDS). A model identified with ``--input effort`` on
    run 2; the same run with a constant acceleration added to the measured position from
    tick 600 on, sent as JointState messages (position, velocity, effort). The monitor's
    first non-conformant tick is the one ``reachset check --input effort`` finds in the bag
    of the same messages, it is after the onset, and it is the safe stop."""
    from helpers import Bus
    from sensor_msgs.msg import JointState
    from reachset_ros import processes
    from reachset_ros.nodes.common import stamp_ns, to_stamp
    d, runs, model = lwa_bags
    names = list(model.joint_names)
    run = runs[1]
    eff = ["--input", "effort", "--robot", DEFAULT_URDF, "--nominal", NOMINAL]
    write_joint_states_only(tmp_path / "clean", [run], names)
    cli("identify", tmp_path / "clean", "--horizon", 40, "--out", tmp_path / "m.yaml", *eff)
    m = len(run.tau)                         # samples with an effort
    onset, accel = 600, 5.0
    q = run.q[:m].copy()
    t = (np.arange(m) - onset).clip(min=0) * 0.004
    q[:, 2] += 0.5 * accel * t ** 2
    stamps = lwa4p.run_start_stamps([run])[0] + np.round((run.t[:m] - run.t[0]) * 1e9).astype(np.int64)
    faulted = tmp_path / "faulted"
    with bags.BagWriter(faulted) as w:
        for k in range(m):
            w.write(bags.JOINT_STATES, bags.joint_state(int(stamps[k]), names, q[k], run.qd[k], run.tau[k]),
                    int(stamps[k]))
    chk = cli("check", faulted, "--model", tmp_path / "m.yaml", "--json", *eff, code=1)
    first_check = min(j["first_violation_ns"] for j in chk["joints"].values() if j["first_violation_ns"])
    assert first_check > stamps[onset]
    bus = Bus()
    proc = processes.start("monitor_node", {"model_file": str(tmp_path / "m.yaml"), "input_source": "effort",
                                         "robot_urdf": str(DEFAULT_URDF), "robot_params": str(NOMINAL),
                                         "max_missing_ticks": 10000, "window_dir": str(tmp_path / "w")}, tmp_path)
    try:
        assert bus.wait(lambda: bus.js.get_subscription_count() > 0, 60), proc.log.read_text()[-2000:]
        for k in range(m):
            msg = JointState(name=names, position=q[k].tolist(), velocity=run.qd[k].tolist(),
                             effort=run.tau[k].tolist())
            to_stamp(msg.header.stamp, int(stamps[k]))
            bus.js.publish(msg)
            time.sleep(0.002)
            if bus.active_stops():
                break
        assert bus.wait(lambda: bus.active_stops(), 30), proc.log.read_text()[-2000:]
        assert bus.wait(lambda: any(stamp_ns(s.header.stamp) >= first_check for s in list(bus.status)), 30)
    finally:
        processes.stop([proc])
        bus.close()
    verdicts = sorted((stamp_ns(s.header.stamp), min(s.margin) >= 0) for s in bus.status if len(s.margin))
    first_monitor = min(st for st, ok in verdicts if not ok and st > stamps[200])     # after the warm-up
    stop = bus.active_stops()[0]
    assert first_monitor == first_check
    assert stop.kind == "violation" and stamp_ns(stop.header.stamp) == first_check


def test_monitor_core_with_effort_input_faults_on_bad_effort(lwa_bags, tmp_path):
    """On the robot side bad data is a fault: a JointState without velocity or effort gives a
    non-finite u_p (``invalid_sample``), one lacking a joint of the robot model a
    ``name_mismatch``; good messages are checked with the u_p of robot.effort.plant_inputs."""
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.watches import FaultEvent, TickEvent
    from reachset_ros.conformance.monitor_core import MonitorCore
    d, runs, model = lwa_bags
    eff = ["--input", "effort", "--robot", DEFAULT_URDF, "--nominal", NOMINAL]
    cli("identify", d / "plain", "--horizon", 10, "--out", tmp_path / "m.yaml", *eff)
    src = load_effort_input(DEFAULT_URDF, NOMINAL)
    names = list(model.joint_names)
    r = runs[0]

    def core():
        return MonitorCore(mdl.load(tmp_path / "m.yaml"), None, 25, src)
    c = core()
    evs = []
    for k in range(30):
        evs += c.add_joint_state(1000 + 4_000_000 * k, names, r.q[k], r.qd[k], r.tau[k])
    assert all(isinstance(e, TickEvent) for e in evs) and len(evs) == 30
    assert np.array_equal(c.window[-1][2], src.plant_inputs(r.q[29:30], r.qd[29:30], r.tau[29:30])[0])
    evs = c.add_joint_state(1000 + 4_000_000 * 30, names, r.q[30], r.qd[30], [])
    assert [e.kind for e in evs if isinstance(e, FaultEvent)] == ["invalid_sample"]
    c = core()
    evs = c.add_joint_state(1000, names[:-1], r.q[0][:-1], r.qd[0][:-1], r.tau[0][:-1])
    assert [(e.kind, e.joint) for e in evs if isinstance(e, FaultEvent)][-1] == ("name_mismatch", names[-1])


def test_one_sample_plant_input_equals_plant_inputs_to_the_bit():
    """Issue 38.4: the monitor node's effort route computes u_p of a message with
    ``EffortInput.plant_input`` (1-D, no 2-D detour); it must be ``plant_inputs``'s row to the
    bit (what ``check``/``replay --input effort`` compute), a non-finite input giving NaN, also
    through ``MonitorCore.add_joint_state`` with the message's joints in another order.
    Fails on the old code: no ``plant_input``."""
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.estimators import Estimator
    from reachset_ros.conformance.monitor_core import MonitorCore
    from reachset_ros.systems.plant import lwa4p_joint_plant
    src = load_effort_input(DEFAULT_URDF)
    n = len(src.joint_names)
    rng = np.random.default_rng(3)
    Q, QD, TAU = rng.uniform(-2, 2, (40, n)), rng.uniform(-1, 1, (40, n)), rng.uniform(-30, 30, (40, n))
    Q[7, 2], QD[11, 0], TAU[13, 5] = np.nan, np.inf, -np.inf
    want = plant_inputs(src.model, Q, QD, TAU)
    data = create_data(src.model)
    got = np.stack([src.plant_input(Q[k], QD[k], TAU[k], data) for k in range(40)])
    assert np.array_equal(got.view(np.int64), want.view(np.int64))      # bits, NaN rows included
    assert np.isnan(got[[7, 11, 13]]).all() and np.isfinite(np.delete(got, [7, 11, 13], axis=0)).all()
    js = {j: mdl.JointSets((0.15, 0.0), (4e-4,), (0.0,) * 5, (0.0,), 0, 10) for j in src.joint_names}
    model = mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 10, js)
    core = MonitorCore(model, None, 10**6, src)
    order = [3, 0, 5, 1, 4, 2]                       # the message's own order of the joints
    names = [src.joint_names[i] for i in order]
    for k in range(6):
        core.add_joint_state(10**9 + 4_000_000 * k, names, Q[k][order].tolist(), QD[k][order].tolist(),
                             TAU[k][order].tolist())
    assert np.array_equal(np.stack([u for _, _, u in core.window]), want[:6])
