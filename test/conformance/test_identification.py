"""Identification beyond the default LP: Corollary 1, quadratic cost, held-out inflation calibration."""
import json

import numpy as np
import pytest
import yaml

from reachset_ros import conformance as cf
from reachset_ros.conformance import model as mdl
from reachset_ros.errors import InfeasibleError
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.systems.plant import LinearPlant, lwa4p_joint_plant

from test_conformance import DT_NS, T0, identify_default_estimator, run_cli, simulate, write_bag

LWA_W, LWA_V = np.array([0.03, 3.0]), np.array([3.5e-5])
DT = 0.01
A2 = np.array([[1.0, DT], [0.0, 0.95]])
B2 = np.array([[0.5 * DT * DT], [DT]])


def simulate_generic(p, T, w_bound, v_bound, seed):
    """Closed loop of a generic plant; w = Gw (w_bound * U[-1,1]), v = v_bound * U[-1,1]."""
    rng = np.random.default_rng(seed)
    x = np.zeros(p.A.shape[0])
    y, u = np.zeros((T, p.C.shape[0])), np.zeros((T, 1))
    for k in range(T):
        u[k] = np.sin(0.02 * k) - 4 * x[0] - 1 * x[1]
        y[k] = p.C @ x + v_bound * rng.uniform(-1, 1, p.C.shape[0])
        x = p.A @ x + p.B @ u[k] + p.Gw @ (w_bound * rng.uniform(-1, 1, p.Gw.shape[1]))
    return y, u


def both(p, est, y, u, K):
    segs = ((0, len(y)),)
    thm = cf.Theorem1.build(p, K)
    dev = cf.deviation_extremes(p, est, y, u, segs, K, thm)
    return thm, dev, cf.identify_sets(p, thm, dev), cf.identify_corollary1(p, est, y, u, segs, horizon=K)


# ------------------------------------------------------------------ Corollary 1
def test_corollary1_full_state_conservative_and_conformant_for_all_k():
    """C = I, G'_W = I, estimator 'output' (x0 = y[m]): Corollary 1 applies."""
    p = LinearPlant(A=A2, B=B2, C=np.eye(2), Gw=np.eye(2), Gv=np.eye(2), dt=DT)
    y, u = simulate_generic(p, 2000, np.array([1e-3, 2e-2]), 5e-4, seed=1)
    est, K, segs = Estimator("output"), 40, ((0, 2000),)
    thm, dev, t1, c1 = both(p, est, y, u, K)
    # the data of the corollary lie in W and V exactly
    sd = cf.state_deviations(p, est, y, u, segs)
    assert np.all(np.abs(sd.xa - c1.c_w[:, None]) <= c1.alpha_w[:, None])
    assert np.all(c1.alpha_v == 0.0) and np.all(sd.v == 0.0)      # y - C pinv(C) y with C = I
    # Remark 2: Theorem 1's feasible set contains Corollary 1's
    assert c1.cost >= t1.cost - 1e-12
    off_t1, off_c1 = thm.offsets(t1.xi)[K], thm.offsets(c1.xi)[K]
    assert np.all(off_c1[0] >= off_t1[0] - 1e-12) and np.any(off_c1[0] > 1.05 * off_t1[0])
    # conformant by check, at the identification horizon and far beyond it (no k* needed)
    assert cf.check(p, thm, est, c1.xi, y, u, segs, K).violations == 0
    K2 = 100
    assert cf.check(p, cf.Theorem1.build(p, K2), est, c1.xi, y, u, segs, K2).violations == 0
    # without a horizon: the same sets (no Theorem-1 clean-up was needed)
    c1n = cf.identify_corollary1(p, est, y, u, segs)
    np.testing.assert_array_equal(c1n.alpha_w, c1.alpha_w)
    # free centers: cost no larger, still conformant
    c1f = cf.identify_corollary1(p, est, y, u, segs, centers="free", horizon=K)
    assert c1f.cost <= c1.cost + 1e-12
    assert cf.check(p, thm, est, c1f.xi, y, u, segs, K).violations == 0


def test_corollary1_position_only_strictly_more_conservative():
    """Remark 2: C not of full column rank -> Corollary 1 constrains the unmeasured state too."""
    p = LinearPlant(A=A2, B=B2, C=[[1.0, 0.0]], Gw=np.eye(2), Gv=[[1.0]], dt=DT)
    y, u = simulate_generic(p, 2000, np.array([1e-3, 2e-2]), 5e-4, seed=2)
    est, K = Estimator("output"), 40
    thm, dev, t1, c1 = both(p, est, y, u, K)
    assert c1.cost > 1.5 * t1.cost
    assert cf.check(p, thm, est, c1.xi, y, u, ((0, 2000),), K).violations == 0


def test_corollary1_rank_deficient_gw_needs_consistent_estimator():
    """G'_W spans one of two directions: feasible iff x_a has no component outside span(G'_W)."""
    gw = np.array([[0.5 * DT * DT], [DT]])
    p = LinearPlant(A=A2, B=B2, C=np.eye(2), Gw=gw, Gv=np.eye(2), dt=DT)
    est, K = Estimator("output"), 30
    y, u = simulate_generic(p, 1500, np.array([3.0]), 0.0, seed=3)       # exact states measured
    thm, dev, t1, c1 = both(p, est, y, u, K)
    assert c1.alpha_w[0] == pytest.approx(3.0, rel=0.02) and c1.alpha_w[0] <= 3.0 * (1 + 1e-6)
    assert cf.check(p, thm, est, c1.xi, y, u, ((0, 1500),), K).violations == 0
    assert c1.cost >= t1.cost - 1e-12
    yn, un = simulate_generic(p, 1500, np.array([3.0]), 1e-4, seed=3)    # noisy states
    with pytest.raises(InfeasibleError, match=r"tick \d+ .*state direction \[.*x0.*x1.*\]"):
        cf.identify_corollary1(p, est, yn, un, ((0, 1500),))


@pytest.mark.parametrize("noise", [3.5e-5, 0.0])
def test_corollary1_lwa4p_fd_is_infeasible_and_says_why(noise):
    """Per-joint LWA-4P: G'_W spans 2 of 5 directions; the causal 'fd' estimate of q[m] is not
    model-consistent (q[m] is measured only at m+1), even on noise-free data."""
    p = lwa4p_joint_plant()
    y, u = simulate(p, 800, LWA_W, np.array([noise]), seed=3)
    with pytest.raises(InfeasibleError) as e:
        cf.identify_corollary1(p, Estimator("fd"), y, u, ((0, 800),))
    msg = str(e.value)
    assert "[+1*q_prev]" in msg and "tick" in msg and "'fd'" in msg and "Theorem 1" in msg
    assert "\n" not in msg


# ------------------------------------------------------------------ quadratic cost
@pytest.fixture(scope="module")
def lwa():
    p = lwa4p_joint_plant()
    y, u = simulate(p, 3000, LWA_W, LWA_V, seed=3)
    K = 60
    thm = cf.Theorem1.build(p, K)
    dev = cf.deviation_extremes(p, Estimator("fd"), y, u, ((0, 3000),), K, thm)
    return p, y, u, K, thm, dev


def test_quadratic_cost_is_sound_and_differs_from_linear(lwa):
    p, y, u, K, thm, dev = lwa
    est, segs = Estimator("fd"), ((0, 3000),)
    lin = cf.identify_sets(p, thm, dev)
    quad = cf.identify_quadratic(p, thm, dev)
    r = cf.check(p, thm, est, quad.xi, y, u, segs, K)
    assert r.violations == 0 and r.worst_margin >= 0.0
    a_lin, a_quad = np.concatenate([lin.alpha_w, lin.alpha_v]), np.concatenate([quad.alpha_w, quad.alpha_v])
    assert np.max(np.abs(a_lin - a_quad) / np.maximum(np.abs(a_lin), 1e-3)) > 0.01
    # each optimum is no worse than the other's solution under its own cost
    fw = cf.frobenius_weights(p)
    assert quad.cost <= fw @ a_lin ** 2 * (1 + 1e-6)
    assert lin.cost <= cf.set_norm_cost(p) @ a_quad * (1 + 1e-9)
    assert quad.cost == pytest.approx(fw @ a_quad ** 2)
    # options: free centers and lower bounds
    qf = cf.identify_quadratic(p, thm, dev, centers="free", alpha_lower=[0.0, 0.5, 1e-4])
    assert qf.alpha_w[1] >= 0.5 and qf.alpha_v[0] >= 1e-4
    assert cf.check(p, thm, est, qf.xi, y, u, segs, K).violations == 0


def test_quadratic_cost_multidimensional_output():
    p = LinearPlant(A=A2, B=B2, C=np.eye(2), Gw=np.eye(2), Gv=np.eye(2), dt=DT)
    y, u = simulate_generic(p, 1500, np.array([1e-3, 2e-2]), 5e-4, seed=4)
    est, K = Estimator("output"), 15
    thm = cf.Theorem1.build(p, K)
    dev = cf.deviation_extremes(p, est, y, u, ((0, 1500),), K, thm)
    quad = cf.identify_quadratic(p, thm, dev)
    assert cf.check(p, thm, est, quad.xi, y, u, ((0, 1500),), K).violations == 0


# ------------------------------------------------------------------ held-out validation
def test_check_many_equals_check(lwa):
    p, y, u, K, thm, dev = lwa
    s = cf.identify_sets(p, thm, dev)
    yf = cf.inject_acceleration_fault(y, ((0, 3000),), 2000, 5.0, p.dt)
    segs = ((0, 1200), (1201, 3000))
    xis = [cf.xi_of(s.c_w, s.c_v, f * s.alpha_w, f * s.alpha_v) for f in (1.0, 0.7, 0.3)]
    many = cf.check_many(p, thm, Estimator("fd"), xis, yf, u, segs, K)
    for xi, r in zip(xis, many):
        ref = cf.check(p, thm, Estimator("fd"), xi, yf, u, segs, K)
        assert (r.violations, r.first_violation_tick, r.test_cases, r.checks, r.worst_margin) == \
            (ref.violations, ref.first_violation_tick, ref.test_cases, ref.checks, ref.worst_margin)
        assert r.violations > 0 and 0 < r.violated_test_cases <= r.test_cases


@pytest.fixture(scope="module")
def held_out():
    """Training: 1500 ticks; validation: 3000 ticks of a 1.3x noisier robot."""
    p = lwa4p_joint_plant()
    yt, ut = simulate(p, 1500, LWA_W, LWA_V, seed=11)
    yv, uv = simulate(p, 3000, 1.3 * LWA_W, 1.3 * LWA_V, seed=12)
    return p, yt, ut, yv, uv


def test_validation_picks_inflation_and_detects_fault(held_out):
    p, yt, ut, yv, uv = held_out
    est, K = Estimator("fd"), 50
    thm = cf.Theorem1.build(p, K)
    s = cf.identify_sets(p, thm, cf.deviation_extremes(p, est, yt, ut, ((0, 1500),), K, thm))
    js = mdl.JointSets(tuple(s.alpha_w), tuple(s.alpha_v), tuple(s.c_w), tuple(s.c_v))
    segs = ((0, 3000),)
    grid = [0.05, 0.1, 0.2, 0.5, 1.0]
    rows, chosen, flagged = cf.validation_grid(p, thm, est, js, yv, uv, segs, K, grid)
    assert [r["inflation"] for r in rows] == [0.0] + grid and not flagged
    assert rows[0]["violating_ticks"] > 0 and rows[0]["violation_rate"] > 0
    assert rows[0]["checked_ticks"] == 3000 - est.history
    assert chosen > 0
    # the chosen inflation makes the held-out data conformant, the grid value below it does not
    assert cf.check(p, thm, est, js.xi(chosen), yv, uv, segs, K).violations == 0
    below = max(g for g in [0.0] + grid if g < chosen)
    assert cf.check(p, thm, est, js.xi(below), yv, uv, segs, K).violations > 0
    # rates are monotone in the inflation
    v = [r["violating_ticks"] for r in rows]
    assert v == sorted(v, reverse=True)
    d = cf.detection_delay(p, thm, est, js.xi(chosen), yv, uv, segs, K, 5.0, p.dt)
    assert d["detected"] and 0 <= d["delay_ticks"] <= 50 and d["alarms_before_onset"] == 0
    assert d["onset_tick"] == est.history + (3000 - est.history) // 2
    # a grid that is too small is flagged
    rows, chosen, flagged = cf.validation_grid(p, thm, est, js, yv, uv, segs, K, [0.01])
    assert flagged and chosen == 0.01


@pytest.mark.slow
def test_cli_cost_method_validate(tmp_path, held_out):
    p, yt, ut, yv, uv = held_out
    names = ["arm_1_joint", "arm_2_joint"]
    y2t, u2t = simulate(p, 1500, LWA_W, LWA_V, seed=21)
    y2v, u2v = simulate(p, 3000, 1.3 * LWA_W, 1.3 * LWA_V, seed=22)
    train, val = tmp_path / "train", tmp_path / "val"
    write_bag(train, np.hstack([yt, y2t]), np.hstack([ut, u2t]), names, T0 + DT_NS * np.arange(1500))
    write_bag(val, np.hstack([yv, y2v]), np.hstack([uv, u2v]), names, T0 + DT_NS * np.arange(3000))
    model = tmp_path / "m.yaml"
    r = run_cli("identify", train, "--horizon", "50", "--validate", val, "--inflation-grid", "0.1", "0.2",
                "0.5", "1", "--inflation-rule", "per-joint", "--out", model, "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert {"joints", "data", "inflation", "cost", "method", "model"} <= set(res)
    infl = res["inflation"]
    for n in names:
        j = res["joints"][n]
        assert set(j) >= {"alpha_w", "alpha_v", "c_w", "c_v", "test_cases", "horizon", "validation"}
        v = j["validation"]
        assert set(v) >= {"at_zero", "grid", "chosen_inflation", "flagged", "model_inflation", "fault",
                          "checked_ticks", "at_model_inflation"}
        est = identify_default_estimator(lwa4p_joint_plant())
        assert v["checked_ticks"] == 3000 - est.history
        # per joint its own smallest conformant inflation (--inflation-rule per-joint, issue 35.1); the
        # model-level is the largest
        assert v["model_inflation"] == v["chosen_inflation"] == j["inflation"] <= infl and not v["flagged"]
        assert v["at_model_inflation"]["violating_ticks"] == 0
        assert v["fault"]["detected"] and v["fault"]["delay_ticks"] >= 0 and v["fault"]["accel"] == 5.0
        assert v["fault"]["onset_ns"] > T0
    assert infl > 0 and max(res["joints"][n]["validation"]["at_zero"]["violating_ticks"] for n in names) > 0
    saved = yaml.safe_load(model.read_text())
    assert saved["inflation"] == infl and len(saved["provenance"]["validation"]["bags"]) == 1
    assert infl == max(res["joints"][n]["inflation"] for n in names)
    assert {n: saved["joints"][n]["inflation"] for n in names} == {n: res["joints"][n]["inflation"] for n in names}
    chk = json.loads(run_cli("check", val, "--model", model, "--json").stdout)
    assert chk["conformant"]

    rq = run_cli("identify", train, "--horizon", "50", "--cost", "quadratic", "--json")
    assert rq.returncode == 0, rq.stderr
    quad = json.loads(rq.stdout)
    assert quad["cost"] == "quadratic" and "validation" not in quad["joints"][names[0]]
    assert quad["joints"][names[0]]["alpha_w"] != res["joints"][names[0]]["alpha_w"]
    assert set(quad["joints"][names[0]]) >= {"alpha_w", "alpha_v", "c_w", "c_v", "test_cases", "horizon"}

    rc = run_cli("identify", train, "--horizon", "50", "--method", "corollary1")
    assert rc.returncode == 2 and "q_prev" in rc.stderr and rc.stderr.count("\n") == 1
    rg = run_cli("identify", train, "--inflation-grid", "0.1")
    assert rg.returncode == 2 and "--validate" in rg.stderr


# ------------------------------------------------------------------ detection cost over the fault window
def test_the_detection_cost_over_the_fault_window_is_sound_and_tighter_where_it_counts(lwa):
    """``--detection-window`` (issue 35: a fault must stop within 100 ms): the detection cost
    summed over the first 25 steps instead of the whole horizon. Same Theorem-1 rows, so just as
    sound on its data; the optimum of each cost is no worse under that cost, and the windowed
    sets are smaller over the window (the steps that decide a stop within it)."""
    from reachset_ros.conformance.identify import detection_cost
    p, y, u, _, _, _ = lwa
    est, segs, K = Estimator("fd"), ((0, 3000),), 125           # the monitor's horizon: 25 steps are a fifth of it
    thm = cf.Theorem1.build(p, K)
    dev = cf.deviation_extremes(p, est, y, u, segs, K, thm)
    full = cf.identify_sets(p, thm, dev, cost_vector=detection_cost(p, thm))
    c25 = detection_cost(p, thm, window=25)
    win = cf.identify_sets(p, thm, dev, cost_vector=c25)
    for sets in (full, win):
        assert cf.check(p, thm, est, sets.xi, y, u, segs, K).violations == 0
    a_full, a_win = (np.concatenate([s.alpha_w, s.alpha_v]) for s in (full, win))
    assert c25 @ a_win <= c25 @ a_full * (1 + 1e-6)
    assert detection_cost(p, thm) @ a_full <= detection_cost(p, thm) @ a_win * (1 + 1e-6)
    assert not np.allclose(a_full, a_win, rtol=0.01)
    radius = lambda sets, k: float(thm.Dp[k][0] @ sets.xi)          # R_a[k]'s half-width
    assert sum(radius(win, k) for k in range(26)) < sum(radius(full, k) for k in range(26))


def test_cli_detection_window_is_recorded_and_checked(tmp_path, lwa):
    """``reachset identify --detection-window S``: the model records the window its sets were
    identified with (the calibration's rule, so a re-calibration identifies its folds alike); the
    default is 0.1 s (``identify.detection_window``); out of range: exit 2, one line, no file."""
    from reachset_ros import defaults
    from reachset_ros.workflows import identify  # noqa: F401  (registers identify's defaults)
    p, y, u, _, _, _ = lwa
    names = ["arm_1_joint"]
    bag = tmp_path / "b"
    write_bag(bag, y[:1500], u[:1500], names, T0 + DT_NS * np.arange(1500))
    write_bag(tmp_path / "b2", y[1500:], u[1500:], names, T0 + DT_NS * np.arange(1500, 3000))
    assert defaults.get("identify.detection_window") == 0.1
    out = {}
    for w in ("0.1", "0"):
        m = tmp_path / f"m{w}.yaml"
        r = run_cli("identify", bag, tmp_path / "b2", "--calibrate", "2", "--detection-window", w,
                    "--out", m, "--json")
        assert r.returncode == 0, r.stderr
        out[w] = yaml.safe_load(m.read_text())
        assert out[w]["calibration"]["rule"]["detection_window_s"] == float(w)
    assert out["0.1"]["joints"]["arm_1_joint"]["alpha_w"] != out["0"]["joints"]["arm_1_joint"]["alpha_w"]
    bad = run_cli("identify", bag, "--detection-window", "-0.5", "--out", tmp_path / "bad.yaml")
    assert bad.returncode == 2 and "--detection-window" in bad.stderr and bad.stderr.count("\n") == 1
    assert not (tmp_path / "bad.yaml").exists()
