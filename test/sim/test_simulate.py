"""Issue 15.6, the simulation half: any URDF arm through the generic path (a reduced Pinocchio
model, the simulator and the reference from the URDF's limits) and ``reachset simulate``, which
records it as a ros2_control arm is recorded: only ``/joint_states`` with position, velocity
and the effort command of each tick. The robot is the Franka Panda of example-robot-data
(7 arm joints, 2 finger joints locked); nothing here or in the code is Panda-specific.
(The end-to-end route through identify/check/monitor_node: test_panda.py.)
"""
import json

import numpy as np
import pinocchio as pin
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from reachset_ros import bags, cli
from reachset_ros import robot as rb
from reachset_ros.errors import ReachsetError
from reachset_ros.robot.descriptions import resolve_urdf
from reachset_ros.sim import recordings as sr
from reachset_ros.sim import reference as refm
from reachset_ros.sim import simulator as simm

ROBOT = "example-robot-data:panda_description/urdf/panda.urdf"
ARM = [f"panda_joint{i}" for i in range(1, 8)]
FINGERS = ["panda_finger_joint1", "panda_finger_joint2"]
PERIOD_NS = 4_000_000


@pytest.fixture(scope="module")
def urdf():
    return resolve_urdf(ROBOT)


@pytest.fixture(scope="module")
def panda(urdf):
    return rb.load_model(urdf, joints=ARM)


def run_cli(capsys, *args):
    """``reachset simulate ...`` in process: (exit code, JSON result or None, stderr)."""
    capsys.readouterr()
    try:
        rc = cli.main(["simulate", *map(str, args)])
    except SystemExit as e:                       # argparse's usage errors
        rc = e.code
    out, err = capsys.readouterr()
    return rc, (json.loads(out) if rc == 0 and "--json" in args else None), err


def read_joint_states(path):
    """``(topics, stamps, names, P, V, E)`` read with rosbags' own reader (not this package's)."""
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        topics = {c.topic for c in r.connections}
        rows = []
        for conn, t, raw in r.messages([c for c in r.connections if c.topic == "/joint_states"]):
            m = r.deserialize(raw, conn.msgtype)
            rows.append((t, m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, list(m.name),
                         m.position, m.velocity, m.effort))
    t_log = np.array([x[0] for x in rows])
    stamps = np.array([x[1] for x in rows])
    assert np.array_equal(t_log, stamps)                 # recorded at the measurement's stamp
    names = {tuple(x[2]) for x in rows}
    assert len(names) == 1
    return (topics, stamps, list(names.pop()), *(np.array([x[i] for x in rows]) for i in (3, 4, 5)))


# --------------------------------------------------------------------------- the model

def test_reduced_model_is_the_full_model_with_the_locked_joints_rigid_at_neutral(urdf, panda):
    full = rb.load_model(urdf)
    assert full.joint_names == tuple(ARM + FINGERS) and panda.joint_names == tuple(ARM)
    # the order of `joints` does not matter: the URDF's kinematic order is kept
    assert rb.load_model(urdf, joints=ARM[::-1]).joint_names == tuple(ARM)
    neutral = pin.neutral(full.pin_model)[7:]          # the fingers' neutral configuration
    df, dr = rb.create_data(full), rb.create_data(panda)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(panda.lower, panda.upper)
        qd = rng.uniform(-1, 1, 7)
        qf, qdf = np.r_[q, neutral], np.r_[qd, 0.0, 0.0]
        np.testing.assert_allclose(rb.mass_matrix(panda, dr, q), rb.mass_matrix(full, df, qf)[:7, :7],
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(rb.psi(panda, dr, q, qd), rb.psi(full, df, qf, qdf)[:7], rtol=1e-12, atol=1e-12)
        # the fingers locked elsewhere than at neutral would give another model
        assert not np.allclose(rb.psi(full, df, np.r_[q, 0.04, 0.04], qdf)[:7], rb.psi(panda, dr, q, qd),
                               rtol=0, atol=1e-9)
    # limits and friction of the kept joints are the URDF's
    for attr in ("lower", "upper", "velocity_limit", "effort_limit"):
        np.testing.assert_array_equal(getattr(panda, attr), getattr(full, attr)[:7])
    np.testing.assert_array_equal(panda.friction.viscous, full.friction.viscous[:7])
    # the fingers' mass is carried by the last arm link of the reduced model
    mass = lambda m: sum(m.pin_model.inertias[i].mass for i in range(1, m.nv + 1))   # noqa: E731
    assert mass(panda) == pytest.approx(mass(full), rel=1e-12)
    assert panda.pin_model.inertias[7].mass > full.pin_model.inertias[7].mass + 0.01


def test_reduced_model_refuses_unknown_duplicate_or_no_joints(urdf):
    with pytest.raises(ReachsetError, match="no joint elbow_joint"):
        rb.load_model(urdf, joints=["panda_joint1", "elbow_joint"])
    with pytest.raises(ReachsetError, match="distinct"):
        rb.load_model(urdf, joints=["panda_joint1", "panda_joint1"])
    with pytest.raises(ReachsetError, match="not empty"):
        rb.load_model(urdf, joints=[])
    # all joints named: the model is the full one (no reduction)
    assert rb.load_model(joints=rb.JOINT_NAMES).joint_names == rb.load_model().joint_names


def test_reference_for_any_robot_comes_from_its_urdf_limits(panda):
    c = refm.ReferenceConfig.for_robot(panda)
    w = panda.upper - panda.lower
    np.testing.assert_allclose(c.q_min, panda.lower + 0.1 * w)
    np.testing.assert_allclose(c.q_max, panda.upper - 0.1 * w)
    assert np.all(np.asarray(c.qd_max) == 0.7) and np.all(np.asarray(c.qdd_max) == rb.U_REF)   # URDF: 2.2-2.6 rad/s
    # a slow joint: half its URDF velocity limit
    pm = panda.pin_model.copy()
    pm.velocityLimit[2] = 0.5
    slow = refm.ReferenceConfig.for_robot(panda.replace(pin_model=pm))
    assert np.asarray(slow.qd_max)[2] == 0.25 and np.asarray(slow.qd_max)[3] == 0.7
    _, Q, QD, QDD = refm.ReferenceGenerator(c, seed=4).trajectory(20.0)
    assert np.all(Q >= c.q_min - 1e-12) and np.all(Q <= c.q_max + 1e-12)
    assert np.all(np.abs(QD) <= 0.7 + 1e-12) and np.all(np.abs(QDD) <= 2.0 + 1e-12)
    assert np.all(Q[:, 3] < -0.3)      # the Panda's elbow range [-3.07, -0.07]: not a box around 0


# --------------------------------------------------------------------------- the simulator

def test_simulator_runs_the_panda_in_closed_loop_from_the_urdf_alone(panda):
    """Seven joints, the reference box of ReferenceConfig.for_robot (not Table I), torques
    within the URDF's effort limits, no hard stop, small tracking error."""
    log = {}
    cfg = simm.SimConfig.realistic(robot=panda, seed=2)
    recs = sr.simulate_arm_recordings(3.0, seed=2, sim_config=cfg, log=log)
    assert list(recs) == ARM and log["q"].shape == log["qd"].shape == log["effort"].shape == (750, 7)
    box = refm.ReferenceConfig.for_robot(panda)
    Qd = np.column_stack([r.q_d for r in recs.values()])
    assert np.all(Qd >= box.q_min - 1e-12) and np.all(Qd <= box.q_max + 1e-12)
    assert np.all(np.diff(log["stamps"]) == PERIOD_NS)
    assert np.all(np.abs(log["effort"]) <= panda.effort_limit)
    assert log["counters"] == {"hard_stop": 0, "torque_clamped": 0, "invalid_command": 0, "brake_engaged": 0}
    err = np.column_stack([r.y[1:] - r.q_d[:-1] for r in recs.values()])
    assert np.max(np.abs(err)) < 0.1
    # the effort is the nominal model's feedback linearization eq. (6) of the u_p used: with the
    # truth equal to the model (ideal) and no noise, M^-1 (tau - psi) at the estimate gives u_p back
    log2 = {}
    ideal = sr.simulate_arm_recordings(3.0, seed=2, sim_config=simm.SimConfig.ideal(robot=panda), log=log2)
    U = np.column_stack([r.u for r in ideal.values()])
    d = rb.create_data(panda)
    XH = [r.x_hat[:, r.estimate_names.index("q")] for r in ideal.values()]
    XD = [r.x_hat[:, r.estimate_names.index("qd")] for r in ideal.values()]
    ks = np.argsort(-np.abs(U).max(axis=1))[:3]             # the ticks of the largest u_p
    assert np.abs(U[ks]).max() > 0.1
    for k in ks:
        qh, qdh = np.array([x[k] for x in XH]), np.array([x[k] for x in XD])
        np.testing.assert_allclose(rb.inverse_fl(panda, d, qh, qdh, log2["effort"][k]), U[k], atol=1e-9)


def test_a_nan_sample_is_skipped_not_kept_in_the_observer(panda):
    """A NaN measurement does not poison the loop: that joint's observer skips it (as
    observer_node does), the previous command holds, every effort stays finite."""
    log = {}
    recs = sr.simulate_arm_recordings(2.0, seed=3, sim_config=simm.SimConfig.realistic(robot=panda, seed=3),
                                      faults=(simm.NaNSamples(start_s=1.0, joint="panda_joint5", count=3),), log=log)
    k = np.flatnonzero(~np.isfinite(log["q"]).all(axis=1))
    assert k.tolist() == [250, 251, 252] and np.all(~np.isfinite(log["q"][k, 4]))
    assert np.isfinite(np.delete(log["q"], k, axis=0)).all()
    assert np.isfinite(log["effort"]).all() and log["counters"]["brake_engaged"] == 0
    assert log["skipped_samples"].tolist() == [0, 0, 0, 0, 3, 0, 0]
    assert log["fault_onsets"] == [int(log["stamps"][250])]
    u5 = recs["panda_joint5"].u
    assert u5[250] == u5[251] == u5[252] == u5[249]                  # the previous command held
    err = recs["panda_joint5"].y[1:] - recs["panda_joint5"].q_d[:-1]
    assert np.nanmax(np.abs(err[300:])) < 0.05                        # and it tracks again


def test_a_fault_injected_after_reset_starting_earlier_has_its_onset_at_the_next_measurement(panda):
    cfg = simm.SimConfig.ideal(robot=panda)
    arm = simm.SimulatedArm(cfg)
    m0 = arm.reset(0.5 * (panda.lower + panda.upper))
    onset = arm.inject(simm.SensorBias(start_s=0.0, joint="panda_joint2", bias=0.01))
    assert onset == arm.stamp(1) != m0.stamp_ns                       # m0 was measured before
    hold = rb.psi(panda, rb.create_data(panda), arm.true_state[1], np.zeros(7))
    m1 = arm.step(hold)
    assert m1.stamp_ns == onset and m1.q_measured[1] == pytest.approx(m0.q_measured[1] + 0.01, abs=1e-9)
    arm.step(hold)
    assert arm.inject(simm.TorqueDisturbance(start_s=0.0, joint=0, torque=1.0)) == arm.stamp(4)


# --------------------------------------------------------------------------- reachset simulate

def test_simulate_writes_only_joint_states_with_position_velocity_effort(tmp_path, capsys, panda):
    rc, res, err = run_cli(capsys, "--robot", ROBOT, "--joints", ",".join(ARM), "--seconds", 2, "--seed", 7,
                           "--out", tmp_path / "b", "--json")
    assert rc == 0, err
    topics, stamps, names, P, V, E = read_joint_states(tmp_path / "b")
    assert topics == {"/joint_states"} and names == ARM
    assert P.shape == V.shape == E.shape == (500, 7) == (res["ticks"], 7)
    assert np.all(np.diff(stamps) == PERIOD_NS) and res["period_ns"] == PERIOD_NS          # 250 Hz
    assert stamps[0] == res["first_stamp_ns"] and stamps[-1] == res["last_stamp_ns"]
    assert np.isfinite(P).all() and np.isfinite(V).all() and np.isfinite(E).all()
    assert np.all(np.abs(E) <= panda.effort_limit) and np.max(np.abs(E[:, 1])) > 10    # joint 2 holds the arm
    # the same code path as simulate_arm_recordings: the bag is its log, to the bit
    log = {}
    sr.simulate_arm_recordings(2.0, seed=7, sim_config=simm.SimConfig.realistic(robot=panda, seed=7), log=log)
    np.testing.assert_array_equal(P, log["q"])
    np.testing.assert_array_equal(V, log["qd"])
    np.testing.assert_array_equal(E, log["effort"])
    np.testing.assert_array_equal(stamps, log["stamps"])
    # velocity is the measured velocity: close to the differentiated position, not the reference
    fd = np.diff(P, axis=0) / 0.004
    assert np.median(np.abs(fd - V[1:])) < 0.02
    assert res["hard_stops"] == 0 and res["torque_clamped_ticks"] == 0 and res["fault_onset_ns"] is None
    assert res["max_abs_effort"] == {n: float(np.max(np.abs(E[:, j]))) for j, n in enumerate(ARM)}
    assert max(res["max_tracking_error_rad"].values()) < 0.1
    assert not (tmp_path / "b.partial").exists()


def test_simulate_sqlite3_with_plant_input(tmp_path, capsys):
    rc, res, err = run_cli(capsys, "--robot", ROBOT, "--joints", ",".join(ARM), "--seconds", 0.4,
                           "--storage", "sqlite3", "--plant-input", "--out", tmp_path / "b", "--json")
    assert rc == 0, err
    assert [p.suffix for p in (tmp_path / "b").iterdir() if p.suffix != ".yaml"] == [".db3"]
    msgs = list(bags.read_messages([tmp_path / "b"]))
    assert {t for t, _, _ in msgs} == {"/joint_states", "/plant_input"}
    js = [m for t, _, m in msgs if t == "/joint_states"]
    pi = [m for t, _, m in msgs if t == "/plant_input"]
    assert len(js) == len(pi) == res["ticks"] == 100
    assert [bags.header_stamp_ns(m) for m in js] == [bags.header_stamp_ns(m) for m in pi]
    assert list(pi[0].name) == ARM and np.isfinite([m.acceleration for m in pi]).all()


@pytest.mark.parametrize("kind,extra", [("bias", ["--fault-joint", "panda_joint3", "--fault-magnitude", 0.01]),
                                        ("torque", ["--fault-joint", "panda_joint2", "--fault-magnitude", 5])])
def test_simulate_fault_onset_is_the_first_changed_row_of_the_bag(tmp_path, capsys, kind, extra):
    """Against the fault-free run of the same seed: every row before ``fault_onset_ns`` is the
    same (position, velocity, effort), the row stamped ``fault_onset_ns`` is not."""
    base = ["--robot", ROBOT, "--joints", ",".join(ARM), "--seconds", 1.2, "--seed", 5, "--json"]
    rc, clean, err = run_cli(capsys, *base, "--out", tmp_path / "clean")
    assert rc == 0, err
    rc, res, err = run_cli(capsys, *base, "--out", tmp_path / "fault", "--fault", kind, "--fault-at", 0.6, *extra)
    assert rc == 0, err
    onset = res["fault_onset_ns"]
    assert onset == res["fault"]["onset_ns"] and res["first_stamp_ns"] < onset <= res["last_stamp_ns"]
    _, st, _, P0, V0, E0 = read_joint_states(tmp_path / "clean")
    _, st1, _, P1, V1, E1 = read_joint_states(tmp_path / "fault")
    assert np.array_equal(st, st1)
    k = int(np.flatnonzero(st == onset)[0])
    # 0.6 s is tick 150: a sensor fault changes that measurement; a physical one changes the
    # state of tick 151, measured (one sample of output delay) at tick 152
    assert k == (150 if kind == "bias" else 152)
    for a, b in ((P0, P1), (V0, V1), (E0, E1)):
        np.testing.assert_array_equal(a[:k], b[:k])
    assert not (np.array_equal(P0[k], P1[k]) and np.array_equal(V0[k], V1[k]))
    if kind == "bias":
        assert P1[k, 2] - P0[k, 2] == pytest.approx(0.01, abs=1e-4)


def test_simulate_nan_fault_writes_that_many_invalid_samples(tmp_path, capsys):
    rc, res, err = run_cli(capsys, "--robot", ROBOT, "--joints", ",".join(ARM), "--seconds", 1, "--out",
                           tmp_path / "b", "--fault", "nan", "--fault-joint", "panda_joint4", "--fault-magnitude", 2,
                           "--fault-at", 0.5, "--json")
    assert rc == 0, err
    _, st, _, P, V, E = read_joint_states(tmp_path / "b")
    bad = np.flatnonzero(~np.isfinite(P).all(axis=1))
    assert st[bad].tolist() == [res["fault_onset_ns"], res["fault_onset_ns"] + PERIOD_NS]
    assert np.isfinite(E).all() and res["skipped_samples"]["panda_joint4"] == 2


@pytest.mark.parametrize("args,words", [
    (["--seconds", "0.004"], ["--seconds must be > 0 and give two samples"]),
    (["--seconds", "nan"], ["--seconds must be > 0"]),
    (["--joints", "panda_joint1,panda_joint1"], ["distinct"]),
    (["--fault", "torque", "--fault-magnitude", "inf"], ["--fault-magnitude must be finite"]),
    (["--fault", "payload", "--fault-magnitude", "-1"], ["must be > 0 for a payload"]),
    (["--fault", "nan", "--fault-magnitude", "1.5"], ["number of samples"]),
    (["--fault", "payload", "--fault-joint", "panda_joint1"], ["acts on the last link"]),
    (["--fault", "frozen", "--fault-magnitude", "1"], ["has none"]),
    (["--fault", "torque", "--fault-at", "1"], ["--fault-at must be in [0, 1.0)"]),
    (["--fault", "torque", "--fault-at", "0.996"], ["after the recording's last"]),
    (["--fault", "melt"], ["invalid choice"]),
    (["--storage", "rosbag1"], ["invalid choice"]),
    (["--nominal", "/nonexistent/params.yaml"], ["parameter file not found"]),
    (["--robot", "example-robot-data:no_description/urdf/no.urdf"], ["no no_description/urdf/no.urdf"]),
])
def test_simulate_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, args, words):
    opts = {"--robot": ROBOT, "--joints": ",".join(ARM), "--seconds": "1", "--out": str(tmp_path / "b")}
    rest = []
    for flag, value in zip(args[::2], args[1::2]):
        if flag in opts:
            opts[flag] = value
        else:
            rest += [flag, value]
    rc, _, err = run_cli(capsys, *[x for kv in opts.items() for x in kv], *rest)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert all(w in err for w in words), err
    assert not any(tmp_path.iterdir())


def test_simulate_refuses_an_existing_output_and_leaves_it_alone(tmp_path, capsys):
    out = tmp_path / "b"
    out.mkdir()
    (out / "keep").write_text("x")
    rc, _, err = run_cli(capsys, "--robot", ROBOT, "--seconds", 1, "--out", out)
    assert rc == 2 and "already exists" in err
    assert [p.name for p in tmp_path.iterdir()] == ["b"] and (out / "keep").read_text() == "x"
