"""Conformance: bags -> test cases -> Theorem 1 identification, batch check, online monitor."""
import json

import numpy as np
import pytest

from reachset_ros import defaults
from reachset_ros import bags
from reachset_ros import conformance as cf
from reachset_ros.conformance import model as mdl
from reachset_ros.errors import ReachsetError
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.monitor import JointMonitor, MonitorModel
from reachset_ros.systems.plant import LinearPlant, lwa4p_joint_plant
from cli_helpers import run_cli  # noqa: E402  (re-exported to the conformance tests)

T0 = 1_700_000_000_000_000_000
DT_NS = 4_000_000


def simulate(plant, T, alpha_w, alpha_v, seed, gain=(100.0, 20.0)):
    """Closed loop on the per-joint plant with bounded random disturbances."""
    rng = np.random.default_rng(seed)
    x = np.zeros(plant.A.shape[0])
    y, u = np.zeros((T, plant.C.shape[0])), np.zeros((T, plant.B.shape[1]))
    for k in range(T):
        y[k] = plant.C @ x + plant.Gv @ (alpha_v * rng.uniform(-1, 1, plant.Gv.shape[1]))
        u[k] = 2 * np.sin(0.003 * k) - gain[0] * x[1] - gain[1] * x[2]
        x = plant.A @ x + plant.B @ u[k] + plant.Gw @ (alpha_w * rng.uniform(-1, 1, plant.Gw.shape[1]))
    return y, u


@pytest.fixture(scope="module")
def lwa_data():
    p = lwa4p_joint_plant()
    y, u = simulate(p, 6000, np.array([0.03, 3.0]), np.array([3.5e-5]), seed=3)
    return p, y, u


def identified_model(p, y, u, segs, K=60, est=Estimator("fd")):
    thm = cf.Theorem1.build(p, K)
    dev = cf.deviation_extremes(p, est, y, u, segs, K, thm)
    sets = cf.identify_sets(p, thm, dev)
    return thm, dev, sets


def test_identified_model_has_no_violations_on_its_data(lwa_data):
    p, y, u = lwa_data
    segs = ((0, 2500), (2501, 6000))
    thm, dev, sets = identified_model(p, y, u, segs)
    assert np.all(sets.alpha_w >= 0) and np.all(sets.alpha_v > 0)
    res = cf.check(p, thm, Estimator("fd"), sets.xi, y, u, segs, 60)
    assert res.violations == 0 and res.first_violation_tick == -1
    h = Estimator("fd").history
    assert res.test_cases == dev.test_cases == (2500 - h) + (3499 - h)
    # the LP is tight: some check sits on the boundary, and shrinking the sets breaks it
    assert res.worst_margin == pytest.approx(0.0, abs=1e-9)
    small = cf.xi_of(sets.c_w, sets.c_v, 0.999 * sets.alpha_w, 0.999 * sets.alpha_v)
    assert cf.check(p, thm, Estimator("fd"), small, y, u, segs, 60).violations > 0


def test_noise_free_data_gives_vanishing_sets():
    """Data that follow the nominal model exactly: the identified sets have radius < 1e-8."""
    p = lwa4p_joint_plant()
    rng = np.random.default_rng(2)
    T = 3000
    x = np.array([0.1, 0.1, 0.3, 0.0, 0.0])
    y, u = np.zeros((T, 1)), np.zeros((T, 1))
    for k in range(T):
        y[k] = p.C @ x
        u[k] = 2 * np.sin(0.01 * k) + rng.normal() - 50 * (x[1] - 0.1) - 10 * x[2]
        x = p.A @ x + p.B @ u[k]
    _, _, sets = identified_model(p, y, u, ((0, T),), K=125)
    radius = np.concatenate([np.abs(p.Gw) @ sets.alpha_w,
                             np.abs(p.Gv) @ sets.alpha_v])
    assert np.all(radius < 1e-8)


def test_theorem1_offsets_equal_direct_reachable_set(lwa_data):
    """D_k xi equals the interval of R_a[k] = (+)_{i<k} C A^i W (+) V built with zonotopes."""
    from reachset_ros.sets.zonotope import Zonotope
    p = lwa_data[0]
    K = 30
    thm = cf.Theorem1.build(p, K)
    aw, av = np.array([0.02, 1.5]), np.array([1e-4])
    cw = p.Gw @ np.array([0.001, -0.2])
    cv = np.array([2e-5])
    offs = thm.offsets(cf.xi_of(cw, cv, aw, av))
    W = Zonotope(cw, p.Gw * aw)
    R = Zonotope(cv, p.Gv * av)
    E = p.C.copy()
    for k in range(K + 1):
        lo, hi = R.interval_hull()
        assert offs[k][0][0] == pytest.approx(hi[0], rel=1e-12, abs=1e-15)
        assert offs[k][1][0] == pytest.approx(-lo[0], rel=1e-12, abs=1e-15)
        R = R + E @ W if False else R.minkowski_sum(W.linear_map(E))
        E = E @ p.A


def test_replay_equals_check_exactly_with_violations_and_gaps(lwa_data):
    p, y, u = lwa_data
    y = y.copy()
    y[4000] = np.nan
    # an injected fault: a constant acceleration disturbance of 5 rad/s^2 from tick 5000
    y[5000:, 0] += 0.5 * 5.0 * (0.004 * np.arange(1000)) ** 2
    segs_true = bags.segments_of(np.arange(len(y)) * DT_NS, np.isfinite(y[:, 0]), 0.004)
    thm, dev, sets = identified_model(p, y[:3000], u[:3000], ((0, 3000),))
    est = Estimator("fd")
    for scale in (1.0, 0.8, 0.5):
        m = mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, est, 60,
                                 {"j": mdl.JointSets(tuple(scale * sets.alpha_w), tuple(scale * sets.alpha_v),
                                                     tuple(sets.c_w), tuple(sets.c_v))})
        xi = m.joints["j"].xi()
        ref = cf.check(p, thm, est, xi, y, u, segs_true, 60)
        mon = JointMonitor(MonitorModel.from_model(m, "j"))
        viol, first = 0, -1
        for i in range(len(y)):
            r = mon.tick(T0 + i * DT_NS, y[i], u[i])
            if r.status == "violation":
                viol += 1
                first = i if first < 0 else first
            if i == 4000:
                assert r.status == "invalid"
        assert (viol, first) == (ref.violations, ref.first_violation_tick)
        assert viol > 0


def test_multidimensional_output_plant():
    """A generic plant with a 2-D output: normals from the zonotope H-representation."""
    dt = 0.01
    A = np.array([[1, dt, 0], [0, 0.98, dt], [0, 0, 0.9]])
    B = np.array([[0], [0], [dt]])
    C = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    p = LinearPlant(A=A, B=B, C=C, Gw=np.array([[dt, 0], [0, dt], [0, 0]]), Gv=np.eye(2), dt=dt)
    rng = np.random.default_rng(5)
    T = 1500
    x = np.zeros(3)
    y, u = np.zeros((T, 2)), np.zeros((T, 1))
    for k in range(T):
        y[k] = C @ x + 1e-3 * rng.uniform(-1, 1, 2)
        u[k] = -5 * x[0] - 2 * x[1] + np.sin(0.01 * k)
        x = A @ x + B @ u[k] + p.Gw @ (0.5 * rng.uniform(-1, 1, 2))
    est = Estimator("output")
    K = 8
    thm = cf.Theorem1.build(p, K)
    assert thm.normals[3].shape[1] == 2 and thm.normals[3].shape[0] >= 3
    dev = cf.deviation_extremes(p, est, y, u, ((0, T),), K, thm)
    sets = cf.identify_sets(p, thm, dev)
    assert cf.check(p, thm, est, sets.xi, y, u, ((0, T),), K).violations == 0
    small = cf.xi_of(sets.c_w, sets.c_v, 0.8 * sets.alpha_w, 0.8 * sets.alpha_v)
    ref = cf.check(p, thm, est, small, y, u, ((0, T),), K)
    m = mdl.ConformanceModel(p, {"kind": "matrices", "A": A.tolist(), "B": B.tolist(), "C": C.tolist(),
                                 "Gw": p.Gw.tolist(), "Gv": p.Gv.tolist(), "dt": dt}, est, K,
                             {"j": mdl.JointSets(tuple(0.8 * sets.alpha_w), tuple(0.8 * sets.alpha_v),
                                                 tuple(sets.c_w), tuple(sets.c_v))})
    mon = JointMonitor(MonitorModel.from_model(m, "j"))
    viol = sum(mon.tick(T0 + i * 10_000_000, y[i], u[i]).status == "violation" for i in range(T))
    assert viol == ref.violations > 0


def test_corollary_free_centers_and_lower_bounds(lwa_data):
    p, y, u = lwa_data
    K = 40
    thm = cf.Theorem1.build(p, K)
    dev = cf.deviation_extremes(p, Estimator("fd"), y, u, ((0, 6000),), K, thm)
    zero = cf.identify_sets(p, thm, dev)
    free = cf.identify_sets(p, thm, dev, centers="free")
    assert free.cost <= zero.cost + 1e-12
    lb = cf.identify_sets(p, thm, dev, alpha_lower=[0.0, 0.5, 1e-3])
    assert lb.alpha_w[1] >= 0.5 and lb.alpha_v[0] >= 1e-3
    for s in (free, lb):
        assert cf.check(p, thm, Estimator("fd"), s.xi, y, u, ((0, 6000),), K).violations == 0


def test_model_file_roundtrip_and_errors(tmp_path, lwa_data):
    p = lwa_data[0]
    m = mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                             {"a": mdl.JointSets((0.1, 2.0), (1e-4,), (0,) * 5, (0.0,), 10, 125)}, 0.05,
                             {"bags": []})
    path = tmp_path / "m.yaml"
    mdl.save(m, path)
    back = mdl.load(path)
    assert back.joints == m.joints and back.inflation == 0.05 and back.horizon == 125
    np.testing.assert_array_equal(back.plant.A, p.A)
    bad = {"nope.yaml": None, "garbage.yaml": "{{{", "neg.yaml": path.read_text().replace("- 0.1", "- -0.1")}
    for name, text in bad.items():
        f = tmp_path / name
        if text is not None:
            f.write_text(text)
        with pytest.raises(ReachsetError):
            mdl.load(f)


def write_bag(path, y, u, names, stamps, shuffle_names=False, extra_joint=False):
    """Receive (log) times increase with the message index; header stamps are ``stamps``."""
    with bags.BagWriter(path) as w:
        for i, t in enumerate(stamps):
            recv = T0 + DT_NS * i
            order = list(range(len(names)))
            if shuffle_names and i % 2:
                order = order[::-1]
            nm = [names[j] for j in order]
            yy = [y[i, j] for j in order]
            if extra_joint:
                nm, yy = nm + ["gripper"], yy + [0.0]
            w.write(bags.JOINT_STATES, bags.joint_state(int(t), nm, yy), recv)
            w.write(bags.PLANT_INPUT, bags.plant_input(int(t), [names[j] for j in order],
                                                       [u[i, j] for j in order]), recv + 1000)


def identify_default_estimator(p):
    """``reachset identify``'s default initial-state estimator (``identify.estimator``)."""
    from reachset_ros.workflows import identify  # noqa: F401  (registers the identify.* defaults)
    return Estimator.named(defaults.get("identify.estimator"), p)


def fault_check_equals_replay(tmp_path, y, u, names, model):
    """A constant acceleration from tick 2000 on the first joint: ``reachset check`` (batch)
    and ``reachset replay`` (the monitor's code path) flag exactly the same ticks."""
    yf = y.copy()
    yf[2000:, 0] += 0.5 * 20.0 * (0.004 * np.arange(len(y) - 2000)) ** 2
    faulty = tmp_path / "faulty"
    write_bag(faulty, yf, u, names, T0 + DT_NS * np.arange(len(y)))
    chk = json.loads(run_cli("check", faulty, "--model", model, "--json").stdout)
    rep = json.loads(run_cli("replay", faulty, "--model", model, "--json").stdout)
    assert not chk["conformant"] and chk["joints"][names[0]]["violations"] > 0
    for k in ("violations", "first_violation_ns", "test_cases", "checks"):
        assert chk["joints"][names[0]][k] == rep["joints"][names[0]][k], k


@pytest.mark.slow
def test_cli_identify_check_replay_and_messy_bags(tmp_path, lwa_data):
    p, y1, u1 = lwa_data
    y2, u2 = simulate(p, 6000, np.array([0.03, 3.0]), np.array([3.5e-5]), seed=4)
    Y, U = np.hstack([y1[:2000], y2[:2000]]), np.hstack([u1[:2000], u2[:2000]])
    names = ["arm_1_joint", "arm_2_joint"]
    stamps = T0 + DT_NS * np.arange(2000)
    stamps[1000:] += 2_000_000_000  # a pause between recordings
    clean, messy = tmp_path / "clean", tmp_path / "messy"
    write_bag(clean, Y, U, names, stamps)
    # messy: joint order alternates, an extra joint, a duplicate and out-of-order messages
    idx = np.r_[0:500, 501, 500, 502:2000, 700]
    write_bag(messy, Y[idx], U[idx], names, stamps[idx], shuffle_names=True, extra_joint=True)
    model = tmp_path / "model.yaml"
    r = run_cli("identify", clean, "--horizon", "50", "--out", model, "--json")
    assert r.returncode == 0, r.stderr
    ident = json.loads(r.stdout)
    assert set(ident["joints"]) == set(names)
    for j in ident["joints"].values():
        assert set(j) >= {"alpha_w", "alpha_v", "c_w", "c_v", "test_cases", "horizon"}
        est = identify_default_estimator(p)
        assert j["test_cases"] == 2 * (1000 - est.history) and j["horizon"] == 50
    r2 = run_cli("identify", messy, "--horizon", "50", "--json")
    assert r2.returncode == 0, r2.stderr
    messy_ident = json.loads(r2.stdout)
    for n in names:
        assert messy_ident["joints"][n]["alpha_w"] == ident["joints"][n]["alpha_w"]
        assert messy_ident["joints"][n]["alpha_v"] == ident["joints"][n]["alpha_v"]
    assert messy_ident["data"]["duplicates"]["arm_1_joint"] == 2
    assert messy_ident["data"]["out_of_order"]["/joint_states"] >= 1
    assert messy_ident["data"]["ignored_joints"] == ["gripper"]
    chk = json.loads(run_cli("check", clean, messy, "--model", model, "--json").stdout)
    rep = json.loads(run_cli("replay", clean, messy, "--model", model, "--json").stdout)
    assert chk["conformant"] and rep["conformant"]
    assert rep["ticks"] == 4000
    for n in names:
        assert chk["joints"][n]["violations"] == rep["joints"][n]["violations"] == 0
        assert chk["joints"][n]["test_cases"] == rep["joints"][n]["test_cases"]
    # a bag from a different (noisier) robot is caught by both, identically
    y3, u3 = simulate(p, 2000, np.array([0.3, 30.0]), np.array([3.5e-4]), seed=9)
    other = tmp_path / "other"
    write_bag(other, np.hstack([y3, y3]), np.hstack([u3, u3]), names, T0 + DT_NS * np.arange(2000))
    chk_p, rep_p = (run_cli(c, other, "--model", model, "--json") for c in ("check", "replay"))
    # not conformant: exit 1 from both (a CI gate; before: 0), 2 only for bad input
    assert chk_p.returncode == rep_p.returncode == 1, (chk_p.stderr, rep_p.stderr)
    chk, rep = json.loads(chk_p.stdout), json.loads(rep_p.stdout)
    assert not chk["conformant"]
    for n in names:
        assert chk["joints"][n]["violations"] == rep["joints"][n]["violations"] > 0
        assert chk["joints"][n]["first_violation_ns"] == rep["joints"][n]["first_violation_ns"]


@pytest.mark.parametrize("case", ["missing", "notbag", "no_plant_input", "few_samples", "bad_joint"])
def test_cli_bad_input_exit_2_one_line(tmp_path, case):
    args = ["identify"]
    if case == "missing":
        args.append(tmp_path / "nope")
    elif case == "notbag":
        (tmp_path / "d").mkdir()
        args.append(tmp_path / "d")
    elif case == "no_plant_input":
        with bags.BagWriter(tmp_path / "b") as w:
            w.write(bags.JOINT_STATES, bags.joint_state(T0, ["a"], [0.0]), T0)
        args.append(tmp_path / "b")
    elif case == "few_samples":
        write_bag(tmp_path / "b", np.zeros((1, 1)), np.zeros((1, 1)), ["a"], [T0])
        args.append(tmp_path / "b")
    else:
        write_bag(tmp_path / "b", np.zeros((5, 1)), np.zeros((5, 1)), ["a"], T0 + DT_NS * np.arange(5))
        args += [tmp_path / "b", "--joints", "zzz"]
    out = tmp_path / "out.yaml"
    r = run_cli(*args, "--out", out)
    assert r.returncode == 2
    if case == "no_plant_input":
        assert "/plant_input" in r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("reachset identify: error:")
    assert "Traceback" not in r.stderr
    assert not out.exists()


def test_sweep_results_do_not_depend_on_the_block_size(lwa_data):
    p, y, u = lwa_data
    segs = ((0, 2500), (2501, 6000))

    def collect(block):
        out = {}

        def visit(k, m, t, ya):
            for mm, v in zip(m.tolist(), ya[0].tolist()):
                out[(k, mm)] = v
        cf.sweep(p, Estimator("fd"), y, u, segs, 40, visit, block=block)
        return out

    a, b = collect(16384), collect(97)
    assert a == b and len(a) > 100000


def test_minimum_horizon_from_the_plant():
    """The first k* at which Theorem 1's rows mention every alpha (kernels.minimum_horizon),
    computed from the plant: 2 for the LWA-4P joint (one sample of input and output delay)."""
    p = lwa4p_joint_plant()
    assert cf.minimum_horizon(p) == 2
    thm = cf.Theorem1.build(p, 3)
    n, ny = p.A.shape[0], p.C.shape[0]
    aw = slice(n + ny, n + ny + p.Gw.shape[1])
    assert not np.any(thm.Dp[1][:, aw]) and np.all(thm.Dp[2][:, aw] != 0)   # Theorem 1's own rows agree
    direct = LinearPlant(A=[[1.0]], B=[[1.0]], C=[[1.0]], Gw=[[1.0]], Gv=[[1.0]])     # C G_W != 0
    assert cf.minimum_horizon(direct) == 1
    # a disturbance direction that never reaches the output does not count
    hidden = LinearPlant(A=[[1.0, 0.0], [0.0, 1.0]], B=[[1.0], [0.0]], C=[[1.0, 0.0]],
                         Gw=[[0.0, 0.0], [1.0, 0.0]], Gv=[[1.0]])
    assert cf.minimum_horizon(hidden) == 0
    delayed = LinearPlant(A=np.eye(3, k=1).T, B=[[1.0], [0.0], [0.0]], C=[[0.0, 0.0, 1.0]],
                          Gw=[[1.0], [0.0], [0.0]], Gv=[[1.0]])        # W enters two shifts before y
    assert cf.minimum_horizon(delayed) == 3
    assert cf.require_minimum_horizon(p, 2) == (2, False)
    assert cf.require_minimum_horizon(p, 0, allow_weak=True) == (2, True)
    with pytest.raises(ReachsetError, match=r"^horizon 1 is below the minimum horizon 2 .*--allow-weak-horizon"):
        cf.require_minimum_horizon(p, 1)


def test_model_file_weak_horizon_fields_and_old_files(tmp_path):
    p = lwa4p_joint_plant()
    js = {"a": mdl.JointSets((0.0, 0.0), (1e-4,), (0,) * 5, (0.0,), 10, 1)}
    old = mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 1, js)
    mdl.save(old, tmp_path / "old.yaml")                       # as written before the fields existed
    text = (tmp_path / "old.yaml").read_text()
    assert "minimum_horizon" not in text and "horizon_below_minimum" not in text
    # an old file below the minimum horizon records no flag: refused (issue 34.7); at the minimum it loads
    with pytest.raises(ReachsetError, match="horizon 1 is below the plant's minimum horizon 2"):
        mdl.load(tmp_path / "old.yaml")
    js2 = {"a": mdl.JointSets((1e-3, 1e-3), (1e-4,), (0,) * 5, (0.0,), 10, 2)}
    mdl.save(mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 2, js2),
             tmp_path / "old2.yaml")
    back = mdl.load(tmp_path / "old2.yaml")
    assert back.minimum_horizon is None and back.horizon_below_minimum is False
    weak = mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 1, js, 0.0, {}, 2, True)
    mdl.save(weak, tmp_path / "weak.yaml")
    back = mdl.load(tmp_path / "weak.yaml")
    assert back.minimum_horizon == 2 and back.horizon_below_minimum is True
    (tmp_path / "bad.yaml").write_text((tmp_path / "weak.yaml").read_text().replace(
        "horizon_below_minimum: true", "horizon_below_minimum: maybe"))
    with pytest.raises(ReachsetError, match="horizon_below_minimum must be true or false"):
        mdl.load(tmp_path / "bad.yaml")


def test_cli_identify_inflation_is_recorded_and_checked(tmp_path, lwa_data):
    """``identify --inflation F`` (issue 19.3): the model's inflation without hand-editing the
    YAML; it excludes --validate (which calibrates it); bad values exit 2 with one line."""
    p, y1, u1 = lwa_data
    bag = tmp_path / "b"
    write_bag(bag, np.hstack([y1[:1500], y1[:1500]]), np.hstack([u1[:1500], u1[:1500]]),
              ["arm_1_joint", "arm_2_joint"], T0 + DT_NS * np.arange(1500))
    model = tmp_path / "m.yaml"
    r = run_cli("identify", bag, "--horizon", "50", "--inflation", "0.5", "--out", model, "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["inflation"] == 0.5 and mdl.load(model).inflation == 0.5
    for bad, words in ((["--inflation", "-1"], "--inflation must be finite"),
                       (["--inflation", "0.5", "--validate", str(bag)], "exclude each other")):
        r = run_cli("identify", bag, "--horizon", "50", *bad)
        assert r.returncode == 2 and words in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
