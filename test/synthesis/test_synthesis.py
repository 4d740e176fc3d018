"""Combined synthesis and identification (paper eq. 10), its baselines and `reachset synthesize`.

Simulated data: the per-joint plant of Appendix A in closed loop (HG observer + static
feedback) with bounded disturbances and a smooth model error along the reference
(:func:`reachset_ros.sim.recordings.simulate_recordings`); real solvers (HiGHS), small sizes and a
reduced search (``SEARCH``) to keep the module fast.
"""
import json

import numpy as np
import pytest
import yaml

from reachset_ros import cli
from reachset_ros import conformance as cf
from reachset_ros.conformance import model as mdl
from reachset_ros import synthesis as sy
from reachset_ros.bags.references import Reference
from reachset_ros.synthesis.reference_error import _reference_error_system
from reachset_ros.sim import recordings as sr
from reachset_ros.systems.closedloop import analyze, close_loop, simulate
from reachset_ros.errors import InfeasibleError, ReachsetError
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.systems.plant import lwa4p_joint_plant
from reachset_ros.sets.reachability import markov_parameters

PLANT = lwa4p_joint_plant()
JOINTS = ("arm_1_joint", "arm_2_joint", "arm_3_joint")
TICKS = 4000
SEARCH = {"sobol_log2": 4, "local_starts": 2, "local_maxfev": 40}
LQG_R = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)


def run_cli(argv, capsys):
    code = cli.main(list(map(str, argv)))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def recs():
    return sr.simulate_recordings(JOINTS, TICKS, seed=3)


@pytest.fixture(scope="module")
def problems(recs):
    series, refs = sr.recordings_series(recs)
    return sy.problems_from_series(series, PLANT, Estimator("fd"), 125, 26.0, 2.0, refs, 3)


@pytest.fixture(scope="module")
def hg_results(problems):
    space = sy.SearchSpace.from_config(sy.load_config(), "hg")
    return sy.synthesize(problems, space, "combined", SEARCH, seed=0, lqg_r=LQG_R)


@pytest.fixture(scope="module")
def bag(recs, tmp_path_factory):
    path = tmp_path_factory.mktemp("synth") / "sim"
    sr.write_recordings(path, {n: recs[n] for n in JOINTS[:2]})
    return path


@pytest.fixture(scope="module")
def small_config(tmp_path_factory):
    p = tmp_path_factory.mktemp("cfg") / "synthesis.yaml"
    p.write_text(yaml.safe_dump({"search": SEARCH}))
    return p


# ------------------------------------------------------------------ building blocks
def test_lti_simulate_equals_the_tick_loop():
    rng = np.random.default_rng(0)
    A = 0.3 * rng.normal(size=(5, 5))
    B, C, D = rng.normal(size=(5, 2)), rng.normal(size=(3, 5)), rng.normal(size=(3, 2))
    r, z0 = rng.normal(size=(777, 2)), rng.normal(size=5)
    got = sy.lti_simulate(A, B, C, D, r, z0, block=32)
    z, ref = z0.copy(), []
    for k in range(len(r)):
        ref.append(C @ z + D @ r[k])
        z = A @ z + B @ r[k]
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


def test_reference_loop_matches_the_tick_by_tick_nodes_code_path():
    from reachset_ros.systems.closedloop import simulate_ticks
    rng = np.random.default_rng(1)
    for g in (sr.DEFAULT_GAINS, {"observer": "eso", "controller": "compensated", "omega": 20, "zeta": 1,
                                 "l1": 57.1, "l2": 103.3, "l3": 18.1, "eps": 0.01}):
        obs, ctrl = sy.components_from_gains(g)
        T = 2000
        w = (rng.uniform(-1, 1, (T, 2)) * [0.03, 3.0]) @ PLANT.Gw.T
        v = rng.uniform(-1, 1, (T, 1)) * 3.5e-5
        zero = np.zeros(T)
        out = sy.simulate_closed_loop(PLANT, obs, ctrl, zero, zero, zero, w, v, np.zeros(5),
                                      np.zeros(obs.n_states))
        ref = simulate_ticks(PLANT, obs, ctrl, w, v)
        assert np.abs(out["x_hat"][:, :2] - ref[:, :2]).max() <= 1e-12
        assert np.abs(out["u"][:, 0] - ref[:, 2]).max() <= 1e-11


def test_reference_error_vanishes_for_a_constant_reference():
    obs, ctrl = sy.components_from_gains(sr.DEFAULT_GAINS)
    T = 500
    ref = Reference(np.arange(T), np.full(T, 0.7), np.zeros(T), np.zeros(T))
    re = sy.reference_error(PLANT, obs, ctrl, [ref])
    assert re.norm < 1e-9 and abs(re.u_lo) < 1e-6 and abs(re.u_hi) < 1e-6   # rounding only


def test_alpha_polytope_keeps_the_identification_optimum(problems):
    """The reduced Theorem-1 rows give the same min ||W|| + ||V|| as the full LP."""
    pb = problems[0]
    full = cf.identify_sets(pb.plant, pb.thm, pb.devs, horizon=pb.horizon)
    alpha, val = pb.polytope.minimize(cf.set_norm_cost(pb.plant))
    assert len(pb.polytope.h) < pb.polytope.rows_total
    assert val == pytest.approx(full.cost, rel=1e-6)
    aw, av, _ = cf.make_sound(pb.plant, pb.thm, pb.devs, np.zeros(5), np.zeros(1), alpha[:2], alpha[2:])
    assert cf.check(pb.plant, pb.thm, pb.estimator, cf.xi_of(np.zeros(5), np.zeros(1), aw, av),
                    pb.y, pb.u, pb.segments, pb.horizon).violations == 0


def test_shipped_config_equals_the_builtin_defaults():
    path = sy.config_path()
    assert path is not None
    assert yaml.safe_load(path.read_text()) == sy.DEFAULT_CONFIG


# ------------------------------------------------------------------ combined vs separate
@pytest.mark.slow
def test_combined_is_never_worse_than_separate_and_both_are_conformant_and_inside_up(hg_results, problems):
    for pb in problems:
        r = hg_results[pb.name]
        s = r.separate
        assert s is not None
        assert r.re_norm <= s.re_norm + 1e-12
        for res in (r, s):
            assert res.ru_inside and -26.0 <= res.ru[0] and res.ru[1] <= 26.0
            assert res.conformant and res.violations == 0
            xi = cf.xi_of(res.c_w, res.c_v, res.alpha_w, res.alpha_v)
            chk = cf.check(pb.plant, pb.thm, pb.estimator, xi, pb.y, pb.u, pb.segments, pb.horizon)
            assert chk.violations == 0
    # on these data the paper's finding holds: the separate identification puts everything
    # into the velocity disturbance and is far worse for the closed loop
    assert all(hg_results[n].re_norm < 0.7 * hg_results[n].separate.re_norm for n in JOINTS)


def test_returned_gains_in_closed_loop_never_leave_re_or_ru(hg_results, problems, recs):
    """Disturbances at the vertices of the identified W, V (random and adversarial), with the
    recorded reference (method 3): [q_hat - q_d, qd_hat - qd_d] stays in R*_e, u_p in R*_u."""
    rng = np.random.default_rng(11)
    for pb in problems[:2]:
        r = hg_results[pb.name]
        obs, ctrl = sy.components_from_gains(r.gains())
        cl = close_loop(PLANT, obs, ctrl)
        an = analyze(cl, r.alpha_w, r.alpha_v)
        rad = np.concatenate([an.re_radius, [an.ru[1]]])
        # (a) error system: random vertices and the adversarial sign sequence
        T, N = 3000, 64
        bw = rng.choice([-1.0, 1.0], (T, N, 2)) * r.alpha_w
        bv = rng.choice([-1.0, 1.0], (T, N, 1)) * r.alpha_v
        out = simulate(cl, bw @ PLANT.Gw.T, bv @ PLANT.Gv.T)
        assert np.all(np.abs(out) <= rad * (1 + 1e-9) + 1e-15)
        T = 1200
        E = np.hstack([cl.Ew * r.alpha_w, cl.Ev * r.alpha_v])
        M = markov_parameters(cl.A, cl.C, E, T - 1)
        betas = np.zeros((T, 3, 3))
        for o in range(3):
            betas[:T - 1, o] = np.sign(M[::-1, o, :])
            betas[T - 1, o, 2:] = np.sign(cl.DEv[o] * r.alpha_v)
        out = simulate(cl, (betas[..., :2] * r.alpha_w) @ PLANT.Gw.T, (betas[..., 2:] * r.alpha_v) @ PLANT.Gv.T)
        assert np.all(np.abs(out) <= rad * (1 + 1e-9) + 1e-15)
        worst = np.array([out[-1, o, o] for o in range(3)])
        assert np.all(worst >= 0.95 * rad)                        # and the bound is nearly reached
        # (b) the whole loop with the recorded reference: inside R*_e and R*_u
        rec = recs[pb.name]
        T = len(rec.q_d)
        for trial in range(3):
            w = (rng.choice([-1.0, 1.0], (T, 2)) * r.alpha_w) @ PLANT.Gw.T
            v = (rng.choice([-1.0, 1.0], (T, 1)) * r.alpha_v) @ PLANT.Gv.T
            sim = sy.simulate_closed_loop(PLANT, obs, ctrl, rec.q_d, rec.qd_d, rec.qdd_d, w, v)
            e = sim["x_hat"][:, :2] - np.column_stack([rec.q_d, rec.qd_d])
            assert np.all(np.abs(e - r.re_center) <= r.re_radius * (1 + 1e-9))
            assert np.all(sim["u"][:, 0] >= r.ru[0]) and np.all(sim["u"][:, 0] <= r.ru[1])


@pytest.mark.slow
def test_infeasible_input_limit_names_the_binding_constraint(problems):
    space = sy.SearchSpace.from_config(sy.load_config(), "hg")
    pb = problems[0]
    tight = sy.JointProblem.prepare(pb.name, pb.plant, pb.estimator, pb.y, pb.u, pb.segments, pb.horizon,
                                    u_max=2.5, u_ff=2.0, thm=pb.thm, references=pb.references)
    with pytest.raises(InfeasibleError, match=r"no gains keep R_u inside U_p: smallest achievable R_u radius"):
        sy.combined(tight, space, SEARCH)
    with pytest.raises(ReachsetError, match="U_ff"):
        sy.JointProblem.prepare(pb.name, pb.plant, pb.estimator, pb.y, pb.u, pb.segments, pb.horizon,
                                u_max=26, u_ff=0.5, thm=pb.thm, references=pb.references)


# ------------------------------------------------------------------ LQG, ESO, re-identification, iteration
def test_lqg_moves_like_the_papers_table_iv(hg_results):
    for n in JOINTS:
        rows = hg_results[n].extra["lqg"]
        assert [row["r"] for row in rows] == list(LQG_R)
        assert all(row["stable"] for row in rows)
        hi = [row["ru"][1] for row in rows]
        lo = [row["ru"][0] for row in rows]
        assert all(a > b for a, b in zip(hi, hi[1:])) and all(a < b for a, b in zip(lo, lo[1:]))  # R_u shrinks
        re = [row["re_norm"] for row in rows]
        big = [x for row, x in zip(rows, re) if row["r"] >= 1e-3]
        assert all(a < b for a, b in zip(big, big[1:]))            # ||R_e|| grows for large r
        assert rows[0]["ru_inside_up"] is False                    # tiny r violates U_p (paper: r = 1e-7)
        feasible = [row["re_norm"] for row in rows if row["ru_inside_up"]]
        assert hg_results[n].re_norm < min(feasible)               # ours beats every feasible LQG


@pytest.mark.slow
def test_eso_combined_beats_separate(problems):
    space = sy.SearchSpace.from_config(sy.load_config(), "eso")
    assert space.free == ("l1", "l2", "l3") and space.controller == "compensated"
    res = sy.synthesize(problems[:1], space, "combined", SEARCH)[JOINTS[0]]
    assert res.observer == "eso" and set(res.gains()) >= {"l1", "l2", "l3", "omega", "zeta", "eps"}
    assert res.re_norm <= res.separate.re_norm and res.conformant and res.ru_inside


def test_reidentify_keeps_the_controller(hg_results, problems):
    pb = problems[1]
    g = hg_results[pb.name].gains()
    res = sy.reidentify(pb, g)
    assert res.mode == "reidentify" and res.conformant
    assert {k: res.gains()[k] for k in ("omega", "zeta", "h1", "h2")} == {k: g[k] for k in ("omega", "zeta", "h1", "h2")}
    assert res.re_norm == pytest.approx(hg_results[pb.name].re_norm, rel=1e-6)


def test_iterative_procedure_with_a_simulated_robot():
    """Sec. III-D on the linear plant: synthesise, record with the new gains, synthesise again,
    re-identify (records without references: a reference class bounds the reference error)."""
    calls = []

    def record(gains):
        calls.append(gains)
        recs = sr.simulate_recordings(["j"], 2500, seed=10 + len(calls), gains=gains)
        return sr.recordings_series(recs)[0]

    series = sr.recordings_series(sr.simulate_recordings(["j"], 2500, seed=10))[0]
    space = sy.SearchSpace.from_config(sy.load_config(), "hg")
    hist = sy.iterate(record, series, space, iterations=2, search=SEARCH,
                      reference_class=sy.ReferenceClass(2.0, 0.05))
    assert [h["step"] for h in hist] == ["synthesis 1", "synthesis 2", "re-identification"]
    assert len(calls) == 2 and calls[0]["j"]["omega"] == hist[0]["results"]["j"].params["omega"]
    final = hist[-1]["results"]["j"]
    assert final.conformant and final.ru_inside and final.mode == "reidentify"
    kept = hist[int(hist[-1]["kept"]["j"].split()[-1]) - 1]["results"]["j"]      # the better synthesis
    assert kept.re_norm == min(h["results"]["j"].re_norm for h in hist[:2])
    assert final.params["omega"] == kept.params["omega"]


def test_iterative_procedure_keeps_the_better_iteration():
    """Issue 16.4: when the second iteration's data are worse (larger disturbances), its
    guaranteed ||R*_e|| is larger; the first synthesis is kept, the re-identification runs with
    its gains, and the history says so (before: the last synthesis's gains were used)."""
    calls = []

    def record(gains):
        calls.append(gains)
        sc = sr.Scenario(a1=0.01, a2=3.0) if len(calls) == 1 else sr.Scenario()
        return sr.recordings_series(sr.simulate_recordings(["j"], 2500, seed=30 + len(calls), gains=gains,
                                                           scenarios={"j": sc}))[0]

    series = sr.recordings_series(sr.simulate_recordings(["j"], 2500, seed=30))[0]
    space = sy.SearchSpace.from_config(sy.load_config(), "hg")
    hist = sy.iterate(record, series, space, iterations=2, search=SEARCH,
                      reference_class=sy.ReferenceClass(2.0, 0.05))
    first, second = hist[0]["results"]["j"], hist[1]["results"]["j"]
    assert second.re_norm > first.re_norm                       # the worse data give a worse guarantee
    assert hist[-1]["kept"] == {"j": "synthesis 1"}
    assert calls[1]["j"]["omega"] == first.params["omega"]      # recorded again with the kept gains
    assert hist[-1]["results"]["j"].params["omega"] == first.params["omega"]


@pytest.mark.slow
def test_iterative_procedure_with_the_projects_simulated_arm():
    """One iteration with the nonlinear simulated LWA-4P (model error, friction, delays) driven
    by the nodes' control law; references recorded, so method 3 is active."""
    joint = "arm_3_joint"

    def record(gains, seed=[20]):
        seed[0] += 1
        recs = sr.simulate_arm_recordings(6.0, gains, seed=seed[0])
        series, refs = sr.recordings_series({joint: recs[joint]})
        return series, refs

    space = sy.SearchSpace.from_config(sy.load_config(), "hg")
    hist = sy.iterate(record, record(None), space, iterations=1, search=SEARCH, u_max=26.0)
    first, final = hist[0]["results"][joint], hist[-1]["results"][joint]
    assert first.reference["ticks"] > 0 and first.conformant and first.ru_inside
    assert final.mode == "reidentify" and final.conformant and final.ru_inside


# ------------------------------------------------------------------ command line
@pytest.mark.slow
def test_cli_synthesize_json_out_plots_and_check(bag, small_config, tmp_path, capsys):
    out = tmp_path / "gains.yaml"
    plots = tmp_path / "plots"
    code, so, se = run_cli(["synthesize", bag, "--json", "--out", out, "--config", small_config,
                            "--lqg-r", "1e-4", "1e-2", "--plot", plots], capsys)
    assert code == 0, se
    d = json.loads(so)
    assert set(d["joints"]) == set(JOINTS[:2]) and d["mode"] == "combined" and d["observer"] == "hg"
    for n, j in d["joints"].items():
        for key in ("re_norm", "ru", "gains", "alpha_w", "alpha_v", "c_w", "c_v", "test_cases", "horizon",
                    "separate", "lqg", "reference_error"):
            assert key in j, key
        assert j["re_norm"] <= j["separate"]["re_norm"] + 1e-12
        assert j["gains"]["observer"] == "hg" and j["gains"]["u_max"] == 26.0
        assert j["reference_error"]["ticks"] > 0          # the bag's /reference was used
        assert len(j["lqg"]) == 2
    assert {p.rsplit("/", 1)[-1] for p in d["plots"]} >= {f"{JOINTS[0]}_re.png", f"{JOINTS[0]}_ru.png",
                                                            f"{JOINTS[0]}_conformance.png"}
    m = mdl.load(out)
    assert m.joints[JOINTS[0]].gains["omega"] == d["joints"][JOINTS[0]]["gains"]["omega"]
    code, so, se = run_cli(["check", bag, "--model", out, "--json"], capsys)
    assert code == 0, se
    chk = json.loads(so)
    assert chk["conformant"] and all(j["violations"] == 0 for j in chk["joints"].values())
    # reidentify from the written model: same controller, conformant sets
    out2 = tmp_path / "reid.yaml"
    code, so, se = run_cli(["synthesize", bag, "--mode", "reidentify", "--model", out, "--json", "--out", out2],
                           capsys)
    assert code == 0, se
    d2 = json.loads(so)
    for n in JOINTS[:2]:
        assert d2["joints"][n]["gains"]["omega"] == d["joints"][n]["gains"]["omega"]
        assert d2["joints"][n]["conformant"]


def test_cli_infeasible_u_max_exits_2_with_one_line_and_no_file(bag, small_config, tmp_path, capsys):
    out = tmp_path / "never.yaml"
    code, so, se = run_cli(["synthesize", bag, "--joints", JOINTS[0], "--u-max", "2.03", "--out", out,
                            "--config", small_config], capsys)
    assert code == 2
    assert len(se.strip().splitlines()) == 1
    assert "R_u inside U_p" in se and "u_max 2.03" in se
    assert not out.exists() and not list(tmp_path.glob("never.yaml*"))


@pytest.mark.parametrize("argv, msg", [
    (["--mode", "reidentify"], "--model"),
    (["--controller", "compensated"], "eso"),
    (["--free", "h9"], "h9"),
    (["--u-max", "26", "26", "26"], "3 values for 2 joints"),
    (["--fix", "omega"], "NAME=VALUE"),
    (["--fix", "l1=3"], "'l1' is not a parameter of the hg loop"),
    (["--seed", "-1"], "seed"),
    (["--joints", "nope"], "nope"),
])
def test_cli_bad_input(bag, argv, msg, capsys):
    code, so, se = run_cli(["synthesize", bag, *argv], capsys)
    assert code == 2 and msg in se and len(se.strip().splitlines()) == 1


# ------------------------------------------------------------------ reference error without /reference (issue 14.4)
def _integrate(qdd, av, ap, q0=0.0, qd0=0.0):
    """Samples q_d, qd_d of a reference whose tick means of qdd_d(t) are ``av`` (velocity) and
    ``ap`` (position weights 2 (dt - t) / dt^2): exact for piecewise-constant qdd_d(t)."""
    dt = PLANT.dt
    q, qd = np.full(len(qdd), float(q0)), np.full(len(qdd), float(qd0))
    for k in range(len(qdd) - 1):
        qd[k + 1] = qd[k] + dt * av[k]
        q[k + 1] = q[k] + dt * qd[k] + 0.5 * dt * dt * ap[k]
    return q, qd


def _piecewise(rng, T, a, s):
    """A random reference of the class: piecewise-constant qdd_d(t), at most one switch inside
    each tick (at a random instant, often to the extreme), jumps <= s, |qdd_d| <= a."""
    qdd, av, ap = np.zeros(T), np.zeros(T), np.zeros(T)
    cur = rng.uniform(-a, a)
    for k in range(T):
        qdd[k] = av[k] = ap[k] = cur
        if rng.random() < 0.5:
            f = rng.random()                       # fraction of the tick before the switch
            lo, hi = max(-a, cur - s), min(a, cur + s)
            new = rng.choice([lo, hi, rng.uniform(lo, hi)])
            av[k] = f * cur + (1 - f) * new
            ap[k] = (1 - (1 - f) ** 2) * cur + (1 - f) ** 2 * new
            cur = new
    return qdd, av, ap


def _loop_errors(obs, ctrl, qdd, av, ap, rng):
    q, qd = _integrate(qdd, av, ap, rng.uniform(-2, 2), rng.uniform(-1, 1))
    out = sy.simulate_closed_loop(PLANT, obs, ctrl, q, qd, qdd)
    return np.column_stack([out["x_hat"][:, :2] - np.column_stack([q, qd]), out["u"][:, 0] - qdd])


@pytest.mark.parametrize("gains", [sr.DEFAULT_GAINS,
                                   {"observer": "eso", "controller": "compensated", "omega": 20, "zeta": 1,
                                    "l1": 57.1, "l2": 103.3, "l3": 18.1, "eps": 0.01}], ids=["hg", "eso"])
def test_reference_class_bound_is_sound_and_not_loose(gains):
    """Y_e,ref and U_e,ff of a reference class contain the reference error of the simulated closed
    loop for random references of the class (switches inside ticks, random start position and
    velocity) and for worst-case sign patterns, and are within 3x of the worst one found."""
    obs, ctrl = sy.components_from_gains(gains)
    Ae, Be, Ce, De = _reference_error_system(PLANT, obs, ctrl)
    H = np.concatenate([De[None], markov_parameters(Ae, Ce, Be, 699)])     # (lag, output, channel)
    rng = np.random.default_rng(7)
    for a, s in ((2.0, 4.0), (2.0, 0.5), (2.0, 0.02)):
        b = sy.class_reference_error(PLANT, obs, ctrl, sy.ReferenceClass(a, s))
        bound = np.concatenate([b.e_hi, [b.u_hi]])
        assert np.allclose(-bound, np.concatenate([b.e_lo, [b.u_lo]])) and np.all(bound > 0)
        worst = np.zeros(3)
        for _ in range(4):
            e = _loop_errors(obs, ctrl, *_piecewise(rng, 1000, a, s), rng)
            assert np.all(np.abs(e) <= bound), (a, s)
            worst = np.maximum(worst, np.abs(e).max(axis=0))
        for r in range(3):                         # bang-bang aligned with the impulse response
            if s >= 2 * a:                         # samples -sigma a, tick means +sigma a
                sig = np.sign(2 * H[:, r, 1] + 2 * H[:, r, 2] - H[:, r, 0])[::-1]
                qdd, av = -sig * a, sig * a
                e = _loop_errors(obs, ctrl, qdd, av, av, rng)
            else:                                  # zero-order hold slewing at step_max
                sig, qdd, cur = np.sign(H[:, r, 0])[::-1], np.zeros(len(H)), 0.0
                for k in range(len(H)):
                    cur = float(np.clip(sig[k] * a, cur - s, cur + s))
                    qdd[k] = cur
                e = _loop_errors(obs, ctrl, qdd, qdd, qdd, rng)
            assert np.all(np.abs(e) <= bound), (a, s, r)
            worst = np.maximum(worst, np.abs(e).max(axis=0))
        assert np.all(bound <= 3.0 * worst), (a, s, bound, worst)


def test_problem_needs_references_or_a_reference_class_and_checks_the_class(problems):
    pb = problems[0]
    args = (pb.name, pb.plant, pb.estimator, pb.y, pb.u, pb.segments, pb.horizon)
    with pytest.raises(ReachsetError, match="no references and no reference class"):
        sy.JointProblem.prepare(*args, thm=pb.thm)
    with pytest.raises(ReachsetError, match=r"not in the reference class qdd_max=2,step_max=0.0001: the step"):
        sy.JointProblem.prepare(*args, thm=pb.thm, references=pb.references,
                                reference_class=sy.ReferenceClass(2.0, 1e-4))
    with pytest.raises(ReachsetError, match="outside U_ff"):
        sy.JointProblem.prepare(*args, thm=pb.thm, reference_class=sy.ReferenceClass(2.5))
    ok = sy.JointProblem.prepare(*args, thm=pb.thm, references=pb.references,
                                 reference_class=sy.ReferenceClass(2.0, 0.05))
    obs, ctrl = sy.components_from_gains(sr.DEFAULT_GAINS)
    rec, cls = sy.reference_error(PLANT, obs, ctrl, pb.references), ok.reference_sets(obs, ctrl)
    assert np.all(cls.e_lo <= rec.e_lo) and np.all(rec.e_hi <= cls.e_hi)    # the class covers the recording
    assert cls.u_lo <= rec.u_lo and rec.u_hi <= cls.u_hi


@pytest.fixture(scope="module")
def bag_without_reference(recs, tmp_path_factory):
    path = tmp_path_factory.mktemp("synth_noref") / "sim"
    sr.write_recordings(path, {JOINTS[0]: recs[JOINTS[0]]}, reference=False, estimate=False)
    return path


def test_cli_synthesize_without_reference_exits_2_naming_the_missing_input(bag_without_reference, small_config,
                                                                          tmp_path, capsys):
    """On 555f6a7 this succeeded with the reference error taken as zero."""
    out = tmp_path / "never.yaml"
    code, so, se = run_cli(["synthesize", bag_without_reference, "--config", small_config, "--out", out], capsys)
    assert code == 2 and len(se.strip().splitlines()) == 1, se
    assert str(bag_without_reference) in se and "no /reference topic" in se and "--reference-class" in se
    assert not out.exists()
    code, so, se = run_cli(["synthesize", bag_without_reference, "--reference-class", "step_max=1"], capsys)
    assert code == 2 and "qdd_max is required" in se and len(se.strip().splitlines()) == 1


def test_cli_synthesize_with_a_reference_class(bag_without_reference, small_config, tmp_path, capsys):
    out = tmp_path / "gains.yaml"
    code, so, se = run_cli(["synthesize", bag_without_reference, "--config", small_config, "--json", "--out", out,
                            "--reference-class", "qdd_max=2,step_max=0.05"], capsys)
    assert code == 0, se
    d = json.loads(so)
    assert d["reference_class"] == {"qdd_max": 2.0, "step_max": 0.05}
    ref = d["joints"][JOINTS[0]]["reference_error"]
    assert ref["source"].startswith("reference class qdd_max=2,step_max=0.05") and ref["ticks"] == 0
    assert ref["reference_class"] == {"qdd_max": 2.0, "step_max": 0.05} and ref["u_e_ff"][1] > 0
    assert ref["y_e_ref"][1][1] > 0 and ref["norm"] > 0
    m = mdl.load(out)
    assert m.joints[JOINTS[0]].extra["reference_error"]["reference_class"] == {"qdd_max": 2.0, "step_max": 0.05}
    # reidentify takes the class recorded in the model
    code, so, se = run_cli(["synthesize", bag_without_reference, "--mode", "reidentify", "--model", out, "--json"],
                           capsys)
    assert code == 0, se
    assert json.loads(so)["joints"][JOINTS[0]]["reference_error"]["source"].startswith("reference class")


@pytest.mark.slow
def test_cli_synthesize_with_inflation_certifies_the_monitored_sets(bag, small_config, tmp_path, capsys):
    """``synthesize --inflation F``: gains whose R*_u stays inside U_p for the sets the monitor
    checks (W, V scaled by 1 + F), recorded in the model; the synthesis without it is certified
    only far below F when U_p binds (U_p = +-6 here; the demo's old NOT CERTIFIED: its monitor
    checked inflation 1.0 with gains synthesised for 0)."""
    from reachset_ros.systems.gains import Gains, certified_inflation, certify
    joint = JOINTS[0]
    models = {}
    for f in (0.0, 1.0):
        out = tmp_path / f"m{f:g}.yaml"
        code, so, se = run_cli(["synthesize", bag, "--json", "--out", out, "--config", small_config,
                                "--joints", joint, "--inflation", f, "--u-max", 6], capsys)
        assert code == 0, se
        d = json.loads(so)
        j = d["joints"][joint]
        assert d["inflation"] == f and j["inflation"] == f and j["ru_inside_up"] and j["conformant"]
        m = models[f] = mdl.load(out)
        assert m.inflation == f
        js = m.joints[joint]
        c = certify(Gains.from_model(js.gains), js, f, js.gains["u_max"], js.gains["u_ff"], plant=PLANT)
        assert c.ok, c.reason
        # the reported R_u is that of the inflated sets, as certify computes it (to rounding)
        assert abs(max(-c.ru[0], c.ru[1]) - max(-j["ru"][0], j["ru"][1])) <= 1e-6 * j["u_max"]
    used, per_joint = certified_inflation(models[0.0], 1.0)
    assert used < 1.0 and per_joint[joint] < 1.0          # the uninflated synthesis does not cover it
    used, per_joint = certified_inflation(models[1.0], 1.0)
    assert used == 1.0 and per_joint[joint] >= 1.0
    # more room is needed for the doubled sets: a slower loop, a larger guaranteed error
    g0, g1 = models[0.0].joints[joint].gains, models[1.0].joints[joint].gains
    assert models[1.0].joints[joint].gains["re_norm"] > g0["re_norm"]
    assert g1["omega"] <= g0["omega"] + 1e-9


def test_synthesize_refuses_a_negative_inflation(bag, capsys):
    code, so, se = run_cli(["synthesize", bag, "--inflation", "-0.5"], capsys)
    assert code == 2 and "inflation" in se and len(se.strip().splitlines()) == 1
