"""Observers (HG, ESO, Kalman), controllers (static, compensated, LQR) and the plant model."""
import numpy as np
import pytest
from scipy.signal import cont2discrete

from reachset_ros.errors import ReachsetError
from reachset_ros.synthesis.config import SearchSpace, components_from_gains, load_config
from reachset_ros.systems.closedloop import analyze, close_loop
from reachset_ros.systems.controllers import (LinearController, compensated_feedback, control_input, lqg, lqr,
                                      static_feedback)
from reachset_ros.systems.observers import (LinearObserver, bilinear, extended_state_observer, high_gain_observer,
                                    kalman_filter, paper_lqg_covariances)
from reachset_ros.systems.gains import Gains
from reachset_ros.systems.plant import LinearPlant, lwa4p_joint_plant, lwa4p_robot_model


def test_lwa4p_plant_matches_appendix_a():
    p = lwa4p_joint_plant(dt=0.004)
    h = 0.004
    assert p.state_names == ("q_prev", "q", "qd", "d", "u_prev")
    np.testing.assert_array_equal(p.C, [[1, 0, 0, 0, 0]])
    np.testing.assert_allclose(p.A[1], [0, 1, h, h * h / 2, h * h / 2])
    np.testing.assert_allclose(p.Gw, [[0, 0], [h, h * h / 2], [0, h], [0, 0], [0, 0]])
    # q[k+1] = q + dt qd + dt^2/2 (d + u_prev): a constant acceleration a integrates exactly
    x = np.zeros(5)
    for _ in range(10):
        x = p.step(x, [1.0])
    t = 9 * h  # the input acts one sample late
    assert x[1] == pytest.approx(t * t / 2) and x[2] == pytest.approx(t)
    with pytest.raises(ValueError):
        p.A[0, 0] = 1
    m4 = lwa4p_robot_model()
    assert m4.n_states == 4 and m4.n_outputs == 1


def test_linear_plant_validation_and_any_output_dimension():
    with pytest.raises(ValueError, match="columns"):
        LinearPlant(np.eye(2), [[1], [0]], [[1, 0, 0]])
    with pytest.raises(ValueError, match="square"):
        LinearPlant(np.ones((2, 3)), [[1], [0]], [[1, 0]])
    p = LinearPlant(np.eye(3) * 0.5, [1, 0, 0], np.eye(3), Gw=np.eye(3), Gv=np.eye(3), dt=0.01)
    assert p.B.shape == (3, 1) and p.n_outputs == 3 and p.D.shape == (3, 1)
    assert p.V([1, 2, 3]).radius().tolist() == [1, 2, 3]
    with pytest.raises(ValueError, match="non-negative"):
        p.W([-1, 0, 0])


def test_bilinear_equals_scipy_and_hg_is_steady_state_exact():
    Ac = np.array([[-3.0, 1.0], [-2.0, 0.0]])
    Bc = np.array([[3.0], [2.0]])
    ours = bilinear(Ac, Bc, np.eye(2), np.zeros((2, 1)), 0.01)
    ref = cont2discrete((Ac, Bc, np.eye(2), np.zeros((2, 1))), 0.01, method="bilinear")[:4]
    for a, b in zip(ours, ref):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    obs = high_gain_observer(15, 30, 0.01)
    assert obs.estimate_names == ("q", "qd") and np.all(obs.Do_y != 0)  # current-measurement feedthrough
    st = obs.initial_state()
    for _ in range(300):
        st = st.advance([0.3], [0.0])
    np.testing.assert_allclose(st.estimate([0.3], [0.0]), [0.3, 0.0], atol=1e-9)
    # a ramp y = v t is tracked with the right velocity (trapezoidal rule is exact for ramps in steady state)
    st = obs.initial_state()
    for k in range(600):
        est = st.estimate([0.5 * k * obs.dt], [0.0])
        st = st.advance([0.5 * k * obs.dt], [0.0])
    assert est[1] == pytest.approx(0.5, rel=1e-6)


def test_eso_estimates_a_constant_disturbance_for_both_input_conventions():
    for u_input in ("previous", "current"):
        obs = extended_state_observer(57.1, 103.3, 18.1, 0.01, u_input=u_input)
        assert (np.any(obs.Do_u != 0)) == (u_input == "current")
        # plant qdd = u + d with u = 0 and d = 0.7 (continuous), sampled: y = q
        dt, d = obs.dt, 0.7
        st = obs.initial_state()
        for k in range(6000):
            y = 0.5 * d * (k * dt) ** 2
            est = st.estimate([y], [0.0])
            st = st.advance([y], [0.0])
        assert est[2] == pytest.approx(d, rel=1e-3)
    with pytest.raises(ValueError):
        extended_state_observer(1, 1, 1, u_input="later")
    with pytest.raises(ValueError, match="positive"):
        high_gain_observer(-1, 30)


def test_kalman_forms_and_paper_covariances():
    m4 = lwa4p_robot_model()
    Sw, Sv = paper_lqg_covariances(m4, [0.0348, 3.59], [3.49e-5])
    G = m4.Gw * np.array([0.0348, 3.59])
    np.testing.assert_allclose(Sw, (G @ G.T / 3) @ (G @ G.T / 3))
    for form in ("predictor", "current"):
        kf = kalman_filter(m4, G @ G.T / 9, np.array([[1e-10]]), form=form)
        assert kf.estimate_names == m4.state_names
        # the estimation-error dynamics (A - L C, resp. A (I - M C)) are the filter's Ao: stable
        assert np.max(np.abs(np.linalg.eigvals(kf.Ao))) < 1.0
    with pytest.raises(ValueError):
        kalman_filter(m4, np.eye(3), np.eye(1))


def test_controllers():
    c = static_feedback(24.4, 0.96)
    np.testing.assert_allclose(c.K, [[24.4 ** 2, 2 * 0.96 * 24.4]])
    # u = qdd_d + w^2 (q_d - q_hat) + 2 z w (qd_d - qd_hat)
    u = control_input(c, [0.1, 0.2], x_ref=[0.3, -0.1], u_ff=1.5)
    assert u[0] == pytest.approx(1.5 + 24.4 ** 2 * 0.2 + 2 * 0.96 * 24.4 * (-0.3))
    cc = compensated_feedback(20, 1)
    assert control_input(cc, [0, 0, 0.4])[0] == pytest.approx(-0.4)  # - d_hat, order as in SPEC.md
    np.testing.assert_allclose(c.gain_for(("q", "qd", "d")), [[24.4 ** 2, 2 * 0.96 * 24.4, 0]])
    with pytest.raises(ValueError, match="'d'"):
        cc.gain_for(("q", "qd"))
    with pytest.raises(ValueError):
        static_feedback(0, 1)
    m4 = lwa4p_robot_model()
    K = lqr(m4, np.diag([1000, 1000, 0.01, 1e-4]), 1e-4)
    assert np.max(np.abs(np.linalg.eigvals(m4.A - m4.B @ K.K))) < 1
    obs, ctrl = lqg(m4, 1e-4, [0.0348, 3.59], [3.49e-5])
    assert obs.name == "kalman" and ctrl.estimate_names == m4.state_names
    user = LinearController([[1.0, 2.0]], ("q", "qd"), "user")
    assert user.n_inputs == 1
    with pytest.raises(ValueError):
        LinearController([[1.0, 2.0]], ("q",))
    with pytest.raises(ValueError):
        LinearObserver(np.eye(2), np.ones((2, 1)), np.zeros((2, 1)), np.eye(2), np.zeros((2, 1)),
                       np.zeros((3, 1)), ("q", "qd"))


# ------------------------------------------------------------------ one gains type (issue 14.5)
def test_gains_carry_eso_input_through_synthesis_model_file_and_nodes():
    """One gains type: the synthesis' search space and the model file both become a Gains
    that keeps eso_input, and both paths build the same observer (with eso_input current:
    the ESO fed u_p[k], Do_u != 0). The nodes' parameters: test_nodes.py."""
    g = Gains(observer="eso", controller="compensated", omega=20.0, l1=57.1, l2=103.3, l3=18.1, eso_input="current")
    d = g.model_dict()
    assert d["eso_input"] == "current" and Gains.from_model(d) == g
    assert Gains.from_dict(g.as_dict()) == g
    assert np.any(g.build_observer().Do_u != 0)
    # synthesis: the search space builds through Gains and writes its model_dict
    sp = SearchSpace.from_config(load_config(), "eso", eso_input="current")
    values = sp.values
    assert sp.gains(values)["eso_input"] == "current"
    assert sp.to_gains(values) == Gains.from_model(sp.gains(values))
    assert SearchSpace.from_gains(d).to_gains(SearchSpace.from_gains(d).values) == g
    # the model file's gains give the same loop
    obs_s, _ = sp.build(values)
    obs_m, _ = components_from_gains(sp.gains(values))
    for a in ("Ao", "Bo_y", "Bo_u", "Co", "Do_y", "Do_u"):
        np.testing.assert_array_equal(getattr(obs_s, a), getattr(obs_m, a))
    # an old model file without eso_input means "previous"; an unknown value is refused
    old = {k: v for k, v in d.items() if k != "eso_input"}
    assert Gains.from_model(old).eso_input == "previous"
    with pytest.raises(ReachsetError, match="eso_input"):
        Gains.from_model({**d, "eso_input": "later"})
    with pytest.raises(ReachsetError, match="missing l3"):
        Gains.from_model({k: v for k, v in d.items() if k != "l3"})


def test_certified_norm_is_the_deployed_norm_for_eso_input_current():
    """The issue's numbers: with eso_input current the loop the nodes build from the model's
    gains has the certified ||R_e|| (0.5315 for Table III axis 1), not the 'previous' ESO's."""
    plant = lwa4p_joint_plant()
    aw, av = [0.0234, 3.587], [3.49e-5]
    cur = Gains(observer="eso", controller="compensated", omega=20.0, l1=57.1, l2=103.3, l3=18.1,
                eso_input="current")
    certified = analyze(close_loop(plant, *cur.build()), aw, av, u_ff=2.0).re_norm
    deployed = analyze(close_loop(plant, *components_from_gains(cur.model_dict())), aw, av, u_ff=2.0).re_norm
    prev = analyze(close_loop(plant, *cur.with_(eso_input="previous").build()), aw, av, u_ff=2.0).re_norm
    assert deployed == certified and abs(prev - certified) > 1e-3 * certified
