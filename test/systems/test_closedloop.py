"""Closed loops: soundness of R_e / R_u by Monte-Carlo, tick-by-tick code path, paper numbers."""
import numpy as np
import pytest

from types import SimpleNamespace

from reachset_ros.bags.messages import ESTIMATE_TOPIC, REFERENCE_TOPIC
from reachset_ros.plots import controller_transients, demo_tracking
from reachset_ros.systems.closedloop import (SETTLING_TOLERANCE, FeedbackLaw, analyze, center_coefficients,
                                             close_loop, settling_ticks, settling_time, simulate,
                                             simulate_ticks, stability)
from reachset_ros.systems.gains import Gains
from reachset_ros.systems.controllers import compensated_feedback, lqg, lqr, static_feedback
from reachset_ros.systems.observers import extended_state_observer, high_gain_observer, kalman_filter
from reachset_ros.systems.plant import LinearPlant, lwa4p_joint_plant, lwa4p_robot_model
from reachset_ros.sets.reachability import markov_parameters

PLANT = lwa4p_joint_plant()
AW_II, AV_II = [0.0348, 3.59], [3.49e-5]      # Table II axis 1
AW_III, AV_III = [0.0234, 3.587], [3.49e-5]   # Table III axis 1 (ESO)


def _multi_output_case():
    """A user-given plant with two outputs (q[k-1] and qdot[k]) and D != 0, Kalman + LQR."""
    P5 = lwa4p_joint_plant()
    C = np.array([[1.0, 0, 0, 0, 0], [0, 0, 1.0, 0, 0]])
    D = np.array([[0.0], [1e-3]])
    plant = LinearPlant(P5.A, P5.B, C, D, P5.Gw, np.diag([1.0, 1.0]), P5.dt, P5.state_names, "two_outputs")
    m4 = lwa4p_robot_model()
    model = LinearPlant(m4.A, m4.B, np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), D, m4.Gw, np.eye(2),
                        m4.dt, m4.state_names, "model2")
    Gw = model.Gw * np.array(AW_II)
    obs = kalman_filter(model, Gw @ Gw.T / 9 + 1e-14 * np.eye(4), np.diag([1e-10, 1e-4]), form="current")
    ctrl = lqr(model, np.diag([1000.0, 1000.0, 0.01, 1e-4]), 1e-4)
    return plant, obs, ctrl, AW_II, [3.49e-5, 0.01]


def _loops():
    m4 = lwa4p_robot_model()
    yield "hg+static", PLANT, high_gain_observer(15, 30, 0.01), static_feedback(24.40, 0.96), AW_II, AV_II
    yield ("eso+compensated", PLANT, extended_state_observer(57.1, 103.3, 18.1, 0.01),
           compensated_feedback(20, 1), AW_III, AV_III)
    yield ("eso(current u)+compensated", PLANT, extended_state_observer(57.1, 103.3, 18.1, 0.01, u_input="current"),
           compensated_feedback(20, 1), AW_III, AV_III)
    yield ("lqg", PLANT, *lqg(m4, 1e-4, AW_II, AV_II), AW_II, AV_II)
    yield ("lqg(current)", PLANT, *lqg(m4, 1e-2, AW_II, AV_II, form="current"), AW_II, AV_II)
    yield ("two-output plant", *_multi_output_case())


LOOPS = {case[0]: case[1:] for case in _loops()}


def _raw(plant, aw, av, bw, bv):
    """Raw disturbances w = G'_W diag(alpha_W) beta_w, v = G'_V diag(alpha_V) beta_v."""
    return (bw * aw) @ plant.Gw.T, (bv * av) @ plant.Gv.T


@pytest.mark.parametrize("name", list(LOOPS))
def test_monte_carlo_never_leaves_the_outer_sets(name):
    plant, obs, ctrl, aw, av = LOOPS[name]
    aw, av = np.asarray(aw, float), np.asarray(av, float)
    cl = close_loop(plant, obs, ctrl)
    res = analyze(cl, aw, av, u_ff=0.0)
    assert res.stable, res.stability.message
    rad = np.concatenate([res.re_radius, [res.ru[1]]])
    rad_in = np.concatenate([res.re_radius_inner, [res.ru_inner[1]]])
    assert np.all(rad_in <= rad) and res.re_norm_inner <= res.re_norm
    assert res.ru[0] == pytest.approx(-res.ru[1])
    lim = rad * (1 + 1e-9) + 1e-15
    rng = np.random.default_rng(abs(hash(name)) % 2 ** 32)
    gw, gv = len(aw), len(av)

    # random vertices of the disturbance boxes, every step
    T, N = 6000, 200
    w, v = _raw(plant, aw, av, rng.choice([-1.0, 1.0], (T, N, gw)), rng.choice([-1.0, 1.0], (T, N, gv)))
    out = simulate(cl, w, v)
    assert np.all(np.abs(out) <= lim), np.abs(out).max(axis=(0, 1)) / rad

    # adversarial bang-bang: beta = sign of the impulse response, maximising output r at T-1
    T = 1500
    E = np.hstack([cl.Ew * aw, cl.Ev * av])
    M = markov_parameters(cl.A, cl.C, E, T - 1)  # M[j] = C A^j E
    DE = cl.DEv * av
    betas = np.zeros((T, 2 * len(rad), gw + gv))
    for r in range(len(rad)):
        for sgn, col in ((1.0, 2 * r), (-1.0, 2 * r + 1)):
            betas[: T - 1, col] = sgn * np.sign(M[::-1, r, :])
            betas[T - 1, col, gw:] = sgn * np.sign(DE[r])
    w, v = _raw(plant, aw, av, betas[..., :gw], betas[..., gw:])
    out = simulate(cl, w, v)
    assert np.all(np.abs(out) <= lim)
    worst = np.array([out[-1, 2 * r, r] for r in range(len(rad))])
    np.testing.assert_allclose(worst, rad, rtol=1e-4)  # the bound is tight


@pytest.mark.parametrize("name", ["hg+static", "eso+compensated", "eso(current u)+compensated", "lqg"])
def test_tick_by_tick_matches_closed_loop_matrices(name):
    """The nodes' code path (ObserverState + closed_loop_tick) equals the composed matrices."""
    plant, obs, ctrl, aw, av = LOOPS[name]
    cl = close_loop(plant, obs, ctrl)
    rng = np.random.default_rng(7)
    T = 600
    w, v = _raw(plant, np.asarray(aw), np.asarray(av), rng.uniform(-1, 1, (T, 2)), rng.uniform(-1, 1, (T, 1)))
    ref = simulate(cl, w, v)
    got = simulate_ticks(plant, obs, ctrl, w, v)
    # equal up to floating-point re-association (measured: ~1e-14 relative); bitwise equality
    # is impossible because the composed matrices associate the products differently
    scale = np.abs(ref).max(axis=0)
    assert np.all(np.abs(got - ref) <= 1e-12 * scale)


def test_algebraic_loop_is_solved_exactly():
    obs = extended_state_observer(57.1, 103.3, 18.1, 0.01, u_input="current")
    assert np.any(obs.Do_u != 0)
    ctrl = compensated_feedback(20, 1)
    cl = close_loop(PLANT, obs, ctrl)
    # at any state z, u = Fz z must satisfy u = -K x_hat(z, u) with x_hat = Co xo + Do_y y + Do_u u
    z = np.random.default_rng(0).normal(size=cl.n_states)
    xp, xo = z[:5], z[5:]
    u = cl.Fz @ z
    x_hat = obs.Co @ xo + obs.Do_y @ (PLANT.C @ xp) + obs.Do_u @ u
    np.testing.assert_allclose(u, -ctrl.K @ x_hat, rtol=1e-12)


def test_paper_table_ii_static_feedback_hg():
    """Table II (h1 = 15, h2 = 30, eps = 0.01): ||R_e|| in [0.85, 1.02] x the paper's value.

    The paper's numbers include its reference-error set (Appendix B), so ours are smaller.
    """
    table = [(0.62, 24.40, 0.96, 0.0348, 3.59, 3.49e-5), (0.70, 24.39, 0.96, 0.0442, 3.82, 3.49e-5),
             (0.58, 23.06, 0.91, 0.0381, 2.93, 3.49e-5), (0.58, 23.81, 0.96, 0.0363, 3.00, 3.49e-5),
             (0.91, 24.71, 1.00, 0.0142, 7.72, 3.49e-5), (2.39, 25.23, 1.00, 0.0000, 23.28, 2.80e-5)]
    obs = high_gain_observer(15, 30, 0.01)
    for paper, w, z, a1, a2, av in table:
        res = analyze(close_loop(PLANT, obs, static_feedback(w, z)), [a1, a2], [av], u_ff=2.0)
        assert 0.85 <= res.re_norm / paper <= 1.02, (paper, res.re_norm)


def test_paper_table_iii_hg_and_eso_rows():
    """Table III (omega = 20, zeta = 1): HG rows in [0.80, 1.02] x paper; ESO rows with
    eps = 0.01 and the ESO fed u_p[k-1] reproduce the paper to 2 % (found by scanning eps)."""
    hg = [(0.373, 135.0, 416.1, 0.0417, 0.976, 8.73e-6), (0.325, 135.1, 416.4, 0.0397, 0.652, 8.73e-6),
          (0.409, 135.0, 416.1, 0.0539, 0.679, 8.73e-6), (0.428, 135.0, 416.1, 0.0540, 0.881, 8.73e-6),
          (0.542, 103.6, 517.8, 0.0344, 2.780, 8.73e-6), (1.297, 105.5, 602.4, 0.0309, 9.379, 8.73e-6)]
    eso = [(0.535, 57.1, 103.3, 18.1, 0.0234, 3.587, 3.49e-5), (0.662, 93.5, 182.0, 37.9, 0.0362, 4.110, 3.49e-5),
           (0.534, 75.6, 113.7, 16.5, 0.0358, 2.951, 3.49e-5), (0.647, 80.5, 153.4, 30.1, 0.0283, 4.415, 3.49e-5),
           (1.573, 37.6, 490.0, 210.6, 0.0055, 17.936, 8.73e-6), (4.582, 23.1, 638.9, 338.7, 0.0, 55.742, 8.73e-6)]
    ctrl_s, ctrl_c = static_feedback(20, 1), compensated_feedback(20, 1)
    for paper, h1, h2, a1, a2, av in hg:
        res = analyze(close_loop(PLANT, high_gain_observer(h1, h2, 0.01), ctrl_s), [a1, a2], [av], u_ff=2.0)
        assert 0.80 <= res.re_norm / paper <= 1.02, (paper, res.re_norm)
    for paper, l1, l2, l3, a1, a2, av in eso:
        res = analyze(close_loop(PLANT, extended_state_observer(l1, l2, l3, 0.01), ctrl_c), [a1, a2], [av],
                      u_ff=2.0)
        assert 0.98 <= res.re_norm / paper <= 1.02, (paper, res.re_norm)


def test_unstable_loop_is_reported_not_raised():
    cl = close_loop(PLANT, high_gain_observer(15, 30), static_feedback(1000.0, 0.96))
    st = stability(cl)
    assert not st.stable and st.spectral_radius > 1 and "unstable" in st.message
    res = analyze(cl, AW_II, AV_II, u_ff=2.0)
    assert not res.stable and res.re_norm is None and res.ru is None
    assert res.as_dict()["re_norm"] is None and res.as_dict()["stable"] is False
    # the constant-disturbance state (eigenvalue 1) is unreachable and does not count
    ok = stability(close_loop(PLANT, high_gain_observer(15, 30), static_feedback(24.4, 0.96)))
    assert ok.stable and ok.reachable_dim == ok.n_states - 1


def test_bad_compositions_raise():
    with pytest.raises(ValueError, match="'d'"):
        close_loop(PLANT, high_gain_observer(15, 30), compensated_feedback(20, 1))
    with pytest.raises(ValueError, match="alpha_w"):
        analyze(close_loop(PLANT, high_gain_observer(15, 30), static_feedback(20, 1)), [-1, 1], [0])
    with pytest.raises(ValueError, match="measurements"):
        close_loop(_multi_output_case()[0], high_gain_observer(15, 30), static_feedback(20, 1))


def test_u_ff_and_centres():
    cl = close_loop(PLANT, high_gain_observer(15, 30), static_feedback(24.4, 0.96))
    r0, r2 = analyze(cl, AW_II, AV_II, u_ff=0.0), analyze(cl, AW_II, AV_II, u_ff=2.0)
    assert r2.ru[1] == pytest.approx(r0.ru[1] + 2.0) and r2.ru[0] == pytest.approx(r0.ru[0] - 2.0)
    assert r2.re_norm == r0.re_norm
    # a constant measurement offset c_V: the loop settles at Mv c_v
    Mw, Mv = center_coefficients(cl)
    T = 3000
    out = simulate(cl, np.zeros((T, 5)), np.full((T, 1), 1e-3))
    np.testing.assert_allclose(out[-1], Mv[:, 0] * 1e-3, atol=1e-9)
    rc = analyze(cl, AW_II, AV_II, c_v=[1e-3])
    np.testing.assert_allclose(rc.re_center, Mv[:2, 0] * 1e-3)
    # a centre on the constant-disturbance state (eigenvalue 1) has no steady state
    assert np.all(np.isnan(Mw[:, 3]))
    with pytest.raises(ValueError, match="unbounded"):
        analyze(cl, AW_II, AV_II, c_w=[0, 0, 0, 1e-3, 0])
    res = analyze(cl, AW_II, AV_II, u_ff=2.0, sets=True)
    assert res.re_set.norm() == pytest.approx(res.re_norm)
    assert res.ru_set.interval_hull()[1][0] == pytest.approx(res.ru[1])


# ------------------------------------------------------------------ the deployed law; transients (issue 14)
@pytest.mark.parametrize("eso_input", ["previous", "current"])
def test_feedback_law_is_the_certified_algebraic_loop(eso_input):
    """FeedbackLaw (what controller_node calls) solves u = u_ff + K (x_ref - x0 - Do_u u)
    exactly, and at x_ref = u_ff = 0 it is the certified closed loop's u = Fz z."""
    g = Gains(observer="eso", controller="compensated", omega=20.0, eso_input=eso_input)
    obs, ctrl = g.build()
    cl = close_loop(PLANT, obs, ctrl)
    law = FeedbackLaw.of(ctrl, obs)
    rng = np.random.default_rng(3)
    for _ in range(20):
        z = rng.normal(size=cl.n_states)
        xp, xo = z[:5], z[5:]
        x0 = obs.Co @ xo + obs.Do_y @ (PLANT.C @ xp)
        u, x_hat = law(x0)
        np.testing.assert_allclose(u, cl.Fz @ z, rtol=1e-12, atol=1e-12)
        x_ref, u_ff = rng.normal(size=3) * [1, 1, 0], rng.normal()
        u, x_hat = law(x0, x_ref, u_ff)
        np.testing.assert_allclose(x_hat, x0 + obs.Do_u @ u)
        np.testing.assert_allclose(u, u_ff + ctrl.K @ (x_ref - x_hat), rtol=1e-12, atol=1e-12)


def test_settling_ticks_from_the_spectral_radius():
    """R_e holds from zero initial error; the transient after a start or gain change lasts
    settling_ticks: the smallest k with rho^k <= tol (standard ln(tol)/ln(rho))."""
    for rho in (0.5, 0.9, 0.9608459403371857, 0.999):
        k = settling_ticks(rho)
        assert rho ** k <= SETTLING_TOLERANCE < rho ** (k - 1)
        assert k == int(np.ceil(np.log(SETTLING_TOLERANCE) / np.log(rho))) or rho ** (k - 1) > SETTLING_TOLERANCE
    assert settling_ticks(0.9, tol=0.5, initial=0.25) == 0 and settling_ticks(0.0) == 1
    assert settling_ticks(0.9, tol=1e-3, initial=10.0) == settling_ticks(0.9, tol=1e-4)
    with pytest.raises(ValueError, match="does not settle"):
        settling_ticks(1.0)
    with pytest.raises(ValueError):
        settling_ticks(0.9, tol=0.0)
    # the Table II loop (hg, omega 15): its free response from a random initial error has
    # decayed to the order of tol after settling_time ticks (a repeated pole, zeta = 1, adds
    # a factor k to rho^k: the rate is asymptotic, not a bound of the transient's constant)
    cl = close_loop(PLANT, *Gains(omega=15.0).build())
    k = settling_time(cl)
    assert k == settling_ticks(stability(cl).spectral_radius) == 173
    z0 = np.random.default_rng(0).normal(size=cl.n_states)
    z0[3] = 0.0   # the constant disturbance is not a transient (eigenvalue 1)
    out = simulate(cl, np.zeros((3 * k, 5)), np.zeros((3 * k, 1)), z0)
    assert np.all(np.abs(out[k:]).max(axis=0) <= 10 * SETTLING_TOLERANCE * np.abs(out).max(axis=0))
    assert np.any(np.abs(out[: k // 2]).max(axis=0) > 10 * SETTLING_TOLERANCE * np.abs(out).max(axis=0))


def _diag(start, ends, name="reachset_ros: controller"):
    kv = [SimpleNamespace(key="transient_start_ns", value=str(start))]
    kv += [SimpleNamespace(key=f"transient_end_ns/{j}", value=str(e)) for j, e in ends.items()]
    return SimpleNamespace(status=[SimpleNamespace(name=name, values=kv)])


def test_demo_share_inside_excludes_the_transient_after_each_gain_change():
    """The demo's 'inside R*_e' share counts only the ticks outside the transient windows the
    controller reported (after a start, gain change or braking)."""
    dt = 4_000_000
    stamps = [10**18 + k * dt for k in range(200)]
    # a large error for 50 ticks after a gain change at tick 100, small elsewhere
    err = {s: (0.5 if 100 <= k < 150 else 0.001) for k, s in enumerate(stamps)}
    est = {s: SimpleNamespace(name=["a"], position=[err[s]], velocity=[0.0]) for s in stamps}
    ref = {s: SimpleNamespace(name=["a"], position=[0.0], velocity=[0.0]) for s in stamps}
    data = {ESTIMATE_TOPIC: est, REFERENCE_TOPIC: ref}
    syn = {"a": {"re_radius": [0.01, 0.01]}}
    diags = [_diag(stamps[100], {"a": stamps[100] + 60 * dt})] * 3 + [_diag(1, {"b": 2}, "other")]
    windows = controller_transients(diags)
    assert windows == {"a": [(stamps[100], stamps[100] + 60 * dt)]}
    plain, _ = demo_tracking(data, syn, stamps[-1] + 1)
    assert plain["a"]["share_inside"] == pytest.approx(150 / 200)
    st, _ = demo_tracking(data, syn, stamps[-1] + 1, transients=windows)
    assert st["a"]["share_inside"] == 1.0 and st["a"]["ticks"] == 140 and st["a"]["ticks_in_transient"] == 60
    assert st["a"]["transient_s"] == pytest.approx(0.24)
