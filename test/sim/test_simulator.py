"""The simulated arm: timing of Appendix A, feedback linearization, determinism, faults."""

import numpy as np
import pytest

from reachset_ros import robot as rb
from reachset_ros.sim import simulator as sim
from reachset_ros.errors import ReachsetError

Q0 = np.array([0.3, -0.4, 0.8, 0.2, 0.5, -0.3])
DT = sim.DT


@pytest.fixture(scope="module")
def model():
    return rb.load_model()


@pytest.fixture(scope="module")
def rigid(model):
    """The model without friction (isolates the rigid-body part of the linearization)."""
    return model.replace(friction=rb.Friction.zero())


def u_profile(k, amp=1.5):
    return amp * np.sin(2 * np.pi * 0.5 * k * DT + np.arange(6))


def fl_run(ctrl_model, config, n=300, amp=1.5):
    """Feedback-linearize with ``ctrl_model`` from the true state at which each torque
    starts acting (the oracle the delays otherwise hide); returns commanded u_p and the
    true average acceleration over the interval it acted on."""
    arm = sim.SimulatedArm(config, seed=1)
    data = rb.create_data(ctrl_model)
    arm.reset(Q0)
    us, qds = [], [arm.true_state[2]]
    for k in range(n):
        u = u_profile(k, amp)
        q1, qd1 = arm.preview_state()                  # state at t_{k+1}
        arm.step(rb.feedback_linearization(ctrl_model, data, q1, qd1, u))
        us.append(u)
        qds.append(arm.true_state[2])
    # u_k acts during [t_{k+1}, t_{k+2}): qds[k + 1] -> qds[k + 2]
    acc = np.array([(qds[k + 2] - qds[k + 1]) / config.dt for k in range(n - 1)])
    return np.array(us[:n - 1]), acc


def test_timing_matches_appendix_a(model):
    """y[k] = q[k-1]; the command given after measurement k acts from t_{k+1}."""
    cfg = sim.SimConfig.ideal(model)
    arm = sim.SimulatedArm(cfg)
    m0 = arm.reset(Q0)
    assert m0.stamp_ns == cfg.start_ns
    np.testing.assert_array_equal(m0.q_measured, Q0)
    hold = rb.psi(model, rb.create_data(model), Q0, np.zeros(6))
    truth = [arm.true_state]
    meas = [m0]
    for k in range(6):
        tau = hold + (5.0 if k == 3 else 0.0)   # a torque pulse commanded after measurement 3
        meas.append(arm.step(tau))
        truth.append(arm.true_state)
    for k, m in enumerate(meas):
        assert m.stamp_ns == cfg.start_ns + k * 4_000_000 == truth[k][0]
        if k:
            np.testing.assert_array_equal(m.q_measured, truth[k - 1][1])   # output delay
    # the pulse (commanded at tick 3) acts during [t_4, t_5): the state at t_4 is still at
    # rest, at t_5 it moves; the measurement of tick 5 still shows rest, tick 6 the motion.
    np.testing.assert_allclose(truth[4][2], 0.0, atol=1e-12)
    assert np.all(np.abs(truth[5][2]) > 1e-3)
    np.testing.assert_allclose(meas[5].q_measured, Q0, atol=1e-12)
    assert np.any(np.abs(meas[6].q_measured - Q0) > 1e-6)
    np.testing.assert_allclose(meas[5].tau_applied, hold + 5.0)          # acted [t_4, t_5)
    np.testing.assert_allclose(meas[6].tau_applied, hold)


def test_preview_state_is_the_next_true_state(model):
    arm = sim.SimulatedArm(sim.SimConfig.realistic(model), seed=3)
    arm.reset(Q0)
    data = rb.create_data(model)
    for k in range(5):
        q1, qd1 = arm.preview_state()
        arm.step(rb.feedback_linearization(model, data, q1, qd1, u_profile(k)))
        _, q, qd = arm.true_state
        np.testing.assert_array_equal(q, q1)
        np.testing.assert_array_equal(qd, qd1)


def test_feedback_linearization_with_exact_model_gives_qdd_equal_u(rigid):
    # From rest: only the O(dt^2) motion within the first interval moves M(q) and gravity.
    arm = sim.SimulatedArm(sim.SimConfig.ideal(rigid))
    arm.reset(Q0)
    u = np.array([1.0, -2.0, 0.5, 1.5, -1.0, 2.0])
    tau = rb.feedback_linearization(rigid, rb.create_data(rigid), Q0, np.zeros(6), u)
    arm = sim.SimulatedArm(sim.SimConfig.ideal(rigid))
    arm.reset(Q0, tau0=tau)
    arm.step(tau)
    _, q, qd = arm.true_state
    np.testing.assert_allclose(qd / DT, u, rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(q - Q0, 0.5 * u * DT ** 2, rtol=1e-3, atol=1e-10)
    # In motion: the torque is held for 4 ms while M(q), psi(q, qd) move on, an O(dt)
    # zero-order-hold effect (halving dt halves it), not an integration error (RK4 at
    # 1 kHz agrees with 8 kHz to ~1e-4 of it).
    us, acc = fl_run(rigid, sim.SimConfig.ideal(rigid))
    err = np.abs(acc - us).max(axis=0)
    us_h, acc_h = fl_run(rigid, sim.SimConfig.ideal(rigid, dt=DT / 2), n=600)
    err_h = np.abs(acc_h - us_h).max(axis=0)
    us_f, acc_f = fl_run(rigid, sim.SimConfig.ideal(rigid, substeps=32))
    print("exact model, max |qdd - u_p| per joint [rad/s^2]:", np.round(err, 4),
          " dt/2:", np.round(err_h, 4))
    assert err.max() < 0.05
    assert err_h.max() < 0.6 * err.max()
    assert np.abs(acc_f - acc).max() < 1e-3 * err.max()


def test_model_error_breaks_the_linearization_by_a_documented_amount(rigid, model):
    us, acc = fl_run(rigid, sim.SimConfig.ideal(rigid))
    exact = np.sqrt(np.mean((acc - us) ** 2, axis=0))
    cfg = sim.SimConfig.ideal(rigid, model_error=rb.ModelError.typical(seed=0))
    us_e, acc_e = fl_run(rigid, cfg)
    wrong = np.sqrt(np.mean((acc_e - us_e) ** 2, axis=0))
    # with the shipped friction (Coulomb smoothing 0.02 rad/s) in model and truth
    us_c, acc_c = fl_run(model, sim.SimConfig.ideal(model))
    coul = np.sqrt(np.mean((acc_c - us_c) ** 2, axis=0))
    print("RMS |qdd - u_p| [rad/s^2] exact:", np.round(exact, 4),
          "typical model error:", np.round(wrong, 3), "exact with friction:", np.round(coul, 3))
    assert wrong.max() > 0.5
    assert wrong.max() > 20 * exact.max()


def test_deterministic_from_seed(model):
    def run(seed):
        arm = sim.SimulatedArm(sim.SimConfig.realistic(model), seed=seed)
        data = rb.create_data(model)
        m = arm.reset(Q0)
        out = [m]
        for k in range(100):
            out.append(arm.step(rb.feedback_linearization(model, data, m.q_measured,
                                                          m.qd_measured, u_profile(k))))
            m = out[-1]
        return np.array([o.q_measured for o in out]), np.array([o.qd_measured for o in out])
    a, b, c = run(7), run(7), run(8)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


def test_measurement_quantization_and_bounded_noise(model):
    cfg = sim.SimConfig.ideal(model, quantization=3.5e-5)
    arm = sim.SimulatedArm(cfg)
    m = arm.reset(Q0)
    np.testing.assert_allclose(m.q_measured / 3.5e-5, np.round(m.q_measured / 3.5e-5), atol=1e-6)
    np.testing.assert_allclose(m.q_measured, Q0, atol=3.5e-5 / 2 + 1e-15)
    cfg = sim.SimConfig.ideal(model, position_noise=1e-4)
    arm = sim.SimulatedArm(cfg, seed=2)
    arm.reset(Q0, tau0=np.zeros(6))
    hold = rb.psi(model, rb.create_data(model), Q0, np.zeros(6))
    arm = sim.SimulatedArm(cfg, seed=2)
    arm.reset(Q0)
    errs = []
    for _ in range(300):
        _, q, _ = arm.true_state
        m = arm.step(hold)
        errs.append(m.q_measured - q)
    errs = np.array(errs)
    assert errs.std() == pytest.approx(1e-4, rel=0.15)
    assert np.abs(errs).max() <= 3e-4 + 1e-15


FAULTS = [
    sim.Payload(start_s=0.2, mass=2.0),
    sim.TorqueDisturbance(start_s=0.2, joint=1, torque=5.0),
    sim.AccelerationDisturbance(start_s=0.2, joint="arm_3_joint", acceleration=3.0),
    sim.SensorBias(start_s=0.2, joint=4, bias=2e-3),
    sim.FrozenSensor(start_s=0.2, joint=2),
    sim.NaNSamples(start_s=0.2, joint=None, count=3),
]


@pytest.mark.parametrize("fault", FAULTS, ids=lambda f: type(f).__name__)
def test_each_fault_changes_measurements_from_its_onset_and_not_before(model, fault):
    cfg = sim.SimConfig.realistic(model)

    def run(with_fault):
        arm = sim.SimulatedArm(cfg, seed=11)
        data = rb.create_data(model)
        m = arm.reset(Q0)
        onset = arm.inject(fault) if with_fault else None
        out = [m]
        for k in range(100):                        # open loop: identical commands
            q = Q0 + 0.1 * np.sin(k * DT * np.arange(1, 7))
            out.append(arm.step(rb.feedback_linearization(model, data, q, np.zeros(6),
                                                          u_profile(k, 0.5))))
        return out, onset

    base, _ = run(False)
    faulty, onset = run(True)
    k_on = next(i for i, m in enumerate(base) if m.stamp_ns == onset)
    for a, b in zip(base[:k_on], faulty[:k_on]):                 # not before
        np.testing.assert_array_equal(a.q_measured, b.q_measured)
        np.testing.assert_array_equal(a.qd_measured, b.qd_measured)
    a, b = base[k_on], faulty[k_on]                               # from the onset
    assert not (np.array_equal(a.q_measured, b.q_measured, equal_nan=True)
                and np.array_equal(a.qd_measured, b.qd_measured, equal_nan=True))
    # visibly: beyond the noise and quantization within 25 ticks (0.1 s)
    noise = 3 * cfg.position_noise + cfg.quantization
    dev = [np.nanmax(np.abs(x.q_measured - y.q_measured)) if y.valid else np.inf
           for x, y in zip(base[k_on:k_on + 25], faulty[k_on:k_on + 25])]
    assert max(dev) > 10 * noise
    if isinstance(fault, sim.NaNSamples):
        assert [m.valid for m in faulty[k_on - 1:k_on + 4]] == [True, False, False, False, True]
    if isinstance(fault, sim.FrozenSensor):
        held = {float(m.q_measured[2]) for m in faulty[k_on - 1:]}
        assert len(held) == 1
    if fault.physical:
        assert onset == sim.SimulatedArm(cfg).stamp(round(fault.start_s / DT) + 2)
    else:
        assert onset == sim.SimulatedArm(cfg).stamp(round(fault.start_s / DT))


def test_bad_use_is_reported(model):
    arm = sim.SimulatedArm(sim.SimConfig.ideal(model))
    with pytest.raises(ReachsetError, match="before reset"):
        arm.step(np.zeros(6))
    arm.reset(Q0)
    with pytest.raises(ReachsetError, match="unknown joint"):
        arm.inject(sim.SensorBias(joint="elbow"))
    with pytest.raises(ReachsetError, match="out of range"):
        arm.inject(sim.TorqueDisturbance(joint=6))
    with pytest.raises(ReachsetError):
        sim.SimConfig(dt=0.0)


def test_long_run_with_friction_is_stable(model):
    """Closed loop (PD + feedback linearization on the delayed measurement) for 4 s with
    the realistic configuration stays finite and near the reference. (The cost per step is
    measured by benchmarks/bench_simulator.py, not asserted here.)"""
    cfg = sim.SimConfig.realistic(model)
    arm = sim.SimulatedArm(cfg, seed=0)
    data = rb.create_data(model)
    m = arm.reset(Q0)
    for k in range(1000):
        q_d = Q0 + 0.2 * np.sin(2 * np.pi * 0.25 * k * DT)
        u = 100.0 * (q_d - m.q_measured) - 20.0 * m.qd_measured
        tau = rb.feedback_linearization(model, data, m.q_measured, m.qd_measured, u)
        m = arm.step(tau)
    _, q, qd = arm.true_state
    assert np.all(np.isfinite(q)) and np.abs(q - Q0).max() < 0.5


@pytest.mark.parametrize("fault", [f for f in FAULTS if not f.physical], ids=lambda f: type(f).__name__)
def test_cleared_sensor_fault_gives_the_fault_free_measurements_again(model, fault):
    cfg = sim.SimConfig.realistic(model)

    def run(with_fault, clear_at=60):
        arm = sim.SimulatedArm(cfg, seed=11)
        data = rb.create_data(model)
        out = [arm.reset(Q0)]
        if with_fault:
            arm.inject(fault)
        for k in range(120):
            if with_fault and k == clear_at:
                assert arm.clear_faults() == 1
            q = Q0 + 0.1 * np.sin(k * DT * np.arange(1, 7))
            out.append(arm.step(rb.feedback_linearization(model, data, q, np.zeros(6), u_profile(k, 0.5))))
        return out

    base, faulty = run(False), run(True)
    assert any(not np.array_equal(a.q_measured, b.q_measured, equal_nan=True) for a, b in zip(base[:61], faulty[:61]))
    for a, b in zip(base[61:], faulty[61:]):         # sensor faults never touched the physics
        np.testing.assert_array_equal(a.q_measured, b.q_measured)
        np.testing.assert_array_equal(a.qd_measured, b.qd_measured)


def test_cleared_payload_restores_the_true_robot(model):
    arm = sim.SimulatedArm(sim.SimConfig.realistic(model), seed=1)
    arm.reset(Q0)
    base = arm.true_robot
    arm.inject(sim.Payload(start_s=0.0, mass=2.0))
    for _ in range(5):
        arm.step(np.zeros(6))
    assert arm.true_robot is not base
    assert arm.clear_faults() == 1 and arm.true_robot is base
    arm.step(np.zeros(6))
    assert arm.true_robot is base and arm.state.faults == []


def test_per_joint_measurement_noise(model):
    """Issue 16.2: the calibrated arm has one noise level per joint; a joint with zero noise
    measures the quantized truth, a wrong-length tuple is refused."""
    noise = (0.0, 1e-3, 0.0, 0.0, 0.0, 0.0)
    arm = sim.SimulatedArm(sim.SimConfig(robot=model, position_noise=noise, quantization=0.0), seed=1)
    m0 = arm.reset(np.full(6, 0.1))
    ms = [arm.step(np.zeros(6)) for _ in range(50)]
    truth = [arm.state.q_prev.copy()]
    dev = np.array([m.q_measured for m in ms[-1:]]) - truth[0]
    assert abs(dev[0, 1]) <= 3e-3 and np.all(dev[0, [0, 2, 3, 4, 5]] == 0.0)
    assert np.any(np.array([m.q_measured[1] for m in ms]) != np.array([m.q_measured[1] for m in ms])[0])
    with pytest.raises(ReachsetError, match="one per joint"):
        sim.SimConfig(robot=model, position_noise=(1e-5, 1e-5))
    with pytest.raises(ReachsetError, match=">= 0"):
        sim.SimConfig(robot=model, position_noise=(-1e-5,) * 6)
    assert m0.valid
