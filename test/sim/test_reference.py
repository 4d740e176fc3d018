"""Random trapezoidal / quintic point-to-point references inside the limits."""
import numpy as np
import pytest

from reachset_ros import robot as rb
from reachset_ros.errors import ReachsetError
from reachset_ros.sim.reference import ReferenceConfig, ReferenceGenerator

TOL = 1e-9


@pytest.fixture(scope="module")
def traj():
    gen = ReferenceGenerator(ReferenceConfig(), seed=42)
    return gen, gen.trajectory(120.0)


def test_limits_respected(traj):
    gen, (t, Q, QD, QDD) = traj
    c = gen.config
    assert np.all(Q >= c.q_min - TOL) and np.all(Q <= c.q_max + TOL)
    assert np.all(np.abs(QD) <= c.qd_max + TOL)
    assert np.all(np.abs(QDD) <= c.qdd_max + TOL)
    # defaults: Table I box (within the URDF limits), 0.7 rad/s, U_ref = [-2, 2]
    m = rb.load_model()
    np.testing.assert_allclose(c.q_max, np.minimum(rb.TABLE1_Q_MAX, m.upper))
    np.testing.assert_allclose(c.qd_max, 0.7)
    np.testing.assert_allclose(c.qdd_max, rb.U_REF)
    # the references actually use the room they have
    assert np.abs(QD).max() > 0.5 * c.qd_max.max()
    assert np.abs(QDD).max() > 0.5 * rb.U_REF


def test_both_kinds_and_consistent_derivatives(traj):
    gen, (t, Q, QD, QDD) = traj
    kinds = {s.kind for s in gen.segments}
    assert kinds == {"trapezoidal", "quintic"}
    dt = t[1] - t[0]
    # position and velocity are continuous, and integrate the velocity / acceleration
    np.testing.assert_allclose(np.diff(Q, axis=0), 0.5 * (QD[1:] + QD[:-1]) * dt, atol=2e-5)
    np.testing.assert_allclose(np.diff(QD, axis=0), 0.5 * (QDD[1:] + QDD[:-1]) * dt,
                               atol=2 * rb.U_REF * dt)
    for s in gen.segments:                     # every segment ends at rest on its target
        q, qd, qdd = s.evaluate(s.t0 + s.T)
        np.testing.assert_allclose(q, s.q1, atol=1e-12)
        np.testing.assert_allclose(qd, 0.0, atol=1e-12)
        q_end, _, _ = s.evaluate(s.t0 + s.T - 1e-9)
        np.testing.assert_allclose(q_end, s.q1, atol=1e-6)


def test_reproducible_from_seed_and_independent_of_sampling(traj):
    gen, (t, Q, QD, QDD) = traj
    other = ReferenceGenerator(ReferenceConfig(), seed=42)
    ts = t[::-1][:500]                               # sampled backwards, sparsely
    Q2, QD2, QDD2 = other.batch(ts)
    np.testing.assert_array_equal(Q2, Q[::-1][:500])
    np.testing.assert_array_equal(QD2, QD[::-1][:500])
    q, qd, qdd = ReferenceGenerator(ReferenceConfig(), seed=42).sample(t[1234])
    np.testing.assert_array_equal(q, Q[1234])
    different = ReferenceGenerator(ReferenceConfig(), seed=43).batch(t[:2000:50])[0]
    assert not np.allclose(different, Q[:2000:50])


def test_custom_config_and_start():
    cfg = ReferenceConfig(q_min=[-0.5] * 3, q_max=[0.5, 1.0, 0.2], qd_max=[0.3, 0.5, 0.1],
                          qdd_max=1.0, kinds=("quintic",), dwell=(0.1, 0.2))
    gen = ReferenceGenerator(cfg, q0=[0.0, 0.5, -0.2], seed=1)
    t, Q, QD, QDD = gen.trajectory(60.0, dt=0.01)
    np.testing.assert_allclose(Q[0], [0.0, 0.5, -0.2])
    assert np.all(Q >= cfg.q_min - TOL) and np.all(Q <= cfg.q_max + TOL)
    assert np.all(np.abs(QD) <= cfg.qd_max + TOL) and np.all(np.abs(QDD) <= 1.0 + TOL)
    assert {s.kind for s in gen.segments} == {"quintic"}
    assert all(0.1 <= s.dwell <= 0.2 for s in gen.segments)


def test_led_segments_reach_every_joints_limits():
    """The synchronised moves leave the short-range arm_2 far below qd_max (the cause of the
    fault campaign's false stops, docs/reliability.md); led segments reach every joint's
    limits, keep all limits, continuous, and lead=0 draws exactly the plain generator's."""
    plain = ReferenceConfig()
    t, Q, QD, QDD = ReferenceGenerator(plain, seed=1).trajectory(240.0)
    assert np.abs(QD[:, 1]).max() < 0.5 * plain.qd_max[1]
    c = ReferenceConfig(lead=0.5)
    for seed in (1, 2):
        gen = ReferenceGenerator(c, seed=seed)
        t, Q, QD, QDD = gen.trajectory(240.0)
        np.testing.assert_allclose(np.abs(QD).max(axis=0), c.qd_max, rtol=1e-6)
        assert np.all(np.abs(QDD).max(axis=0) >= 0.95 * c.qdd_max)
        assert np.all(Q >= c.q_min - TOL) and np.all(Q <= c.q_max + TOL)
        assert np.all(np.abs(QD) <= c.qd_max + TOL) and np.all(np.abs(QDD) <= c.qdd_max + TOL)
        # the moves join: each segment starts where the one before ended
        segs = gen.segments
        assert all(np.array_equal(a.q1, b.q0) and a.t_end == b.t0 for a, b in zip(segs, segs[1:]))
        # the position is continuous (|dq| <= qd_max dt per tick)
        assert np.all(np.abs(np.diff(Q, axis=0)) <= c.qd_max * 0.004 + TOL)
    a = ReferenceGenerator(ReferenceConfig(lead=0.0), seed=42).trajectory(60.0)[1]
    np.testing.assert_array_equal(a, ReferenceGenerator(ReferenceConfig(), seed=42).trajectory(60.0)[1])
    with pytest.raises(ReachsetError, match="lead"):
        ReferenceConfig(lead=1.5)


def test_bad_configs_are_rejected():
    with pytest.raises(ReachsetError, match="q_max must exceed"):
        ReferenceConfig(q_min=[0.0], q_max=[0.0])
    with pytest.raises(ReachsetError, match="kinds"):
        ReferenceConfig(kinds=("sine",))
    with pytest.raises(ReachsetError, match="outside the position box"):
        ReferenceGenerator(ReferenceConfig(), q0=[3.0, 0, 0, 0, 0, 0])
    with pytest.raises(ReachsetError, match="before the start"):
        ReferenceGenerator(ReferenceConfig()).sample(-1.0)


def test_stream_without_hold_is_the_generator_at_the_stamps():
    from reachset_ros.sim.reference import ReferenceStream
    gen, ref = ReferenceGenerator(seed=5), ReferenceGenerator(seed=5)
    s = ReferenceStream(gen)
    t0 = 1_700_000_000_123_000_000
    for k in range(0, 5000, 7):
        got = s.at(t0 + k * 4_000_000)
        want = ref.sample(k * 4_000_000 * 1e-9)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)


def test_stream_hold_finishes_the_move_rests_and_resumes_continuously():
    """hold: the move under way ends as planned, then rest at its end point; clearing it
    continues with the next move as if no time had passed (continuous reference)."""
    from reachset_ros.sim.reference import ReferenceStream
    ref = ReferenceGenerator(seed=2)
    s = ReferenceStream(ReferenceGenerator(seed=2))
    dt_ns = 4_000_000
    k_hold = 300
    move = ref.current_move(k_hold * 0.004)
    assert move.t0 <= k_hold * 0.004 < move.t_end
    k_end = int(np.ceil(move.t_end / 0.004))
    out = []
    for k in range(k_end + 500):
        out.append(s.at(k * dt_ns, hold=k >= k_hold))
    # until the end of the held move: exactly the generator
    for k in range(k_end):
        for a, b in zip(out[k], ref.sample(k * dt_ns * 1e-9)):
            np.testing.assert_array_equal(a, b)
    # after it: at rest at the move's end point
    for k in range(k_end, k_end + 500):
        np.testing.assert_array_equal(out[k][0], move.q1)
        assert not np.any(out[k][1]) and not np.any(out[k][2])
    # resume 2 s later: continuous, and the generator shifted by the time held
    k_res = k_end + 500
    paused = k_res * dt_ns * 1e-9 - move.t_end
    prev = out[-1][0]
    for k in range(k_res, k_res + 2000):
        q, qd, qdd = s.at(k * dt_ns, hold=False)
        want = ref.sample(k * dt_ns * 1e-9 - paused)
        np.testing.assert_allclose(q, want[0], rtol=0, atol=1e-12)
        assert np.max(np.abs(q - prev)) <= 0.7 * 0.004 + 1e-9    # |qd_d| <= qd_max: no jump
        prev = q
    assert ref.current_move(k_res * 0.004 + 8.0 - paused).t0 > move.t0   # new moves again
