"""Issue 35.5: the minimum detectable fault, found by bisection on the pure core (no DDS).

A model identified from three short fault-free runs of the simulated LWA-4P (inflation 2: sound
on the other seeds' fault-free running used here); the cases are the nodes' code path in one
loop (simulated arm, certified control law, the monitor node's core)."""
import numpy as np
import pytest

from reachset_ros.errors import ReachsetError
from reachset_ros.sim import detectability as dt
from reachset_ros.sim import simulator as simm

SETUP = dt.Setup(onset_s=2.0)
SEEDS = (101, 102)


@pytest.fixture(scope="module")
def model():
    return dt.identify_model(dt.training_series(SETUP, seeds=(1, 2, 3), seconds=10.0), inflation=2.0)


@pytest.mark.slow
def test_a_fault_far_above_the_minimum_is_stopped_within_100_ms_and_far_below_is_not(model):
    big = [dt.run_case(model, SETUP, fault="acceleration", joint="arm_2_joint", magnitude=60.0, seed=s)
           for s in SEEDS]
    assert all(c.stopped_within(0.1) and c.stop_kind == "violation" for c in big)
    assert all(c.false_stops == 0 for c in big)
    small = [dt.run_case(model, SETUP, fault="acceleration", joint="arm_2_joint", magnitude=0.05, seed=s)
             for s in SEEDS]
    assert not any(c.stopped_within(0.1) for c in small)
    assert dt.detected(model, SETUP, fault="acceleration", joint="arm_2_joint", magnitude=60.0, seeds=SEEDS)[0]
    ok, cases = dt.detected(model, SETUP, fault="acceleration", joint="arm_2_joint", magnitude=0.05, seeds=SEEDS)
    assert not ok and len(cases) == 1          # the first seed decides


def test_fault_free_runs_of_the_same_set_up_do_not_stop(model):
    free = dt.fault_free(model, SETUP, seeds=SEEDS, seconds=6.0)
    assert free["stops"] == [] and free["seconds"] == 12.0
    none = dt.run_case(model, SETUP, fault="acceleration", joint="arm_1_joint", magnitude=0.0, seed=SEEDS[0])
    assert none.stop_ns is None and none.false_stops == 0


@pytest.mark.slow
def test_the_bisection_brackets_the_boundary_and_is_deterministic_for_a_seed(model):
    r = dt.minimum_detectable(model, SETUP, fault="acceleration", joint="arm_2_joint", seeds=SEEDS[:1], hi=60.0,
                              rel_tol=0.1)
    assert 0 < r["lo"] < r["hi"] <= 1.1 * r["lo"]
    below = dt.run_case(model, SETUP, fault="acceleration", joint="arm_2_joint", magnitude=r["lo"], seed=SEEDS[0])
    above = dt.run_case(model, SETUP, fault="acceleration", joint="arm_2_joint", magnitude=r["hi"], seed=SEEDS[0])
    assert not below.stopped_within(0.1) and above.stopped_within(0.1)
    assert r["latency_ms"] == [above.latency_ms] and above.latency_ms <= 100.0
    assert r["false_stops"] == 0 and r["cases"] == len(r["tried"]) - 1       # magnitude 0 runs nothing
    again = dt.minimum_detectable(model, SETUP, fault="acceleration", joint="arm_2_joint", seeds=SEEDS[:1],
                                  hi=60.0, rel_tol=0.1)
    assert again == r


def test_bisect_brackets_a_threshold_and_grows_the_upper_end():
    br = dt.bisect(lambda m: m >= 3.7, lo=0.0, hi=30.0, rel_tol=0.01)
    assert br.lo < 3.7 <= br.hi <= 1.01 * br.lo
    assert all(v == (m >= 3.7) for m, v in br.tried)
    grown = dt.bisect(lambda m: m >= 50.0, lo=0.0, hi=10.0, rel_tol=0.05)
    assert grown.lo < 50.0 <= grown.hi and (10.0, False) in grown.tried and (80.0, True) in grown.tried
    never = dt.bisect(lambda m: False, lo=0.0, hi=1.0, max_grow=2)
    assert never.hi is None and never.lo == 4.0
    with pytest.raises(ReachsetError, match="already holds"):
        dt.bisect(lambda m: True, lo=0.0, hi=1.0)


def test_the_disturbance_trace_recovers_an_injected_acceleration():
    """The limit's yardstick: w2 (the acceleration generator of Appendix A) from the arm's true
    states. An exact model leaves only the estimates' error; a constant acceleration fault of
    5 rad/s^2 on a joint shows as 5 in its w2."""
    su = dt.Setup(sim_config=simm.SimConfig.ideal())
    out = {}
    for m in (0.0, 5.0):
        faults = [simm.AccelerationDisturbance(start_s=0.0, joint=2, acceleration=m)] if m else []
        recs, log = dt.simulate(su, seed=3, faults=faults, seconds=2.0)
        log["u"] = np.column_stack([r.u for r in recs.values()])
        out[m] = dt.disturbance_trace(log)[1]
    assert np.abs(out[0.0]).max() < 0.3
    assert np.median(out[5.0][10:, 2]) == pytest.approx(5.0, abs=0.1)


def test_limits_per_class():
    lim = dt.limits(SETUP, seeds=(101,), seconds=3.0)
    assert set(lim) >= {"acceleration", "torque", "bias"}
    names = list(lim["acceleration"])
    assert len(names) == 6 and all(v > 0 for c in ("acceleration", "torque", "bias") for v in lim[c].values())
    # the bias limit: four times the calibrated noise bound (3 sigma + half the encoder step),
    # and on the quantised sensor 2 q floor(6 sigma / q) (below it: the same encoder steps)
    cfg = simm.SimConfig.calibrated()
    assert lim["bias"][names[0]] == pytest.approx(4 * (3 * cfg.position_noise[0] + 0.5 * cfg.quantization))
    assert lim["bias_quantised"][names[0]] == pytest.approx(2 * 3 * cfg.quantization)     # 6 sigma = 3.4 q
    assert all(lim["bias_quantised"][n] <= lim["bias"][n] for n in names)
    # a torque at the limit accelerates no joint beyond its w2 bound
    assert all(lim["torque"][n] > 0 for n in names)


@pytest.mark.slow
def test_the_sets_own_limit_scales_with_the_inflation(model):
    """Theorem 1's bound over the fault's noise-free effect: zero-centred sets scale with
    (1 + inflation), and the acceleration's first effect is dt^2/2 at step 2 (one sample of
    input and one of output delay)."""
    from dataclasses import replace
    a = dt.sets_limit(model, "arm_2_joint")                        # inflation 2
    b = dt.sets_limit(replace(model, inflation=0.0), "arm_2_joint")
    assert a == pytest.approx(3.0 * b) and b > 0
    assert dt.sets_limit(model, "arm_2_joint", fault="bias") > 0
    assert dt.sets_limit(model, "arm_2_joint", fault="torque") is None
    # a longer window can only lower it
    assert dt.sets_limit(model, "arm_2_joint", within_s=0.2) <= a



def _first_violation(model, joint, fault, magnitude, span):
    """Noise-free data at rest (input 0), then the fault from sample 0 on: a step of the position
    reading (``bias``) or a constant acceleration through the plant's acceleration generator
    (``acceleration``, the simulator's fault as the model sees it). Returns the sample index of
    the first tick the monitor core finds outside the sets, or None up to ``span``. At rest and
    noise-free every deviation before the fault is 0 and after it exactly the fault's effect:
    the event :func:`dt.sets_limit` bounds."""
    from reachset_ros.conformance.monitor_core import MonitorCore
    core = MonitorCore(model, [joint], stuck_ticks=0)
    A, C, g = model.plant.A, model.plant.C, model.plant.Gw[:, -1]
    dt_ns = int(round(model.plant.dt * 1e9))
    before = model.horizon + model.estimator.history + 20
    x = np.zeros(A.shape[0])
    for i in range(-before, span + 1):
        y = float((C @ x)[0]) + (magnitude if fault == "bias" and i >= 0 else 0.0)
        st = (i + before + 1) * dt_ns
        for ev in core.add_y(st, [joint], [y]) + core.add_u(st, [joint], [0.0]):
            assert not hasattr(ev, "kind"), ev                      # no data fault, only the sets
            if "violation" in ev.result["status"]:
                return i
        x = A @ x + (magnitude * g if fault == "acceleration" and i >= 0 else 0.0)
    return None


@pytest.mark.parametrize("fault,joint", [("bias", "arm_2_joint"), ("bias", "arm_5_joint"),
                                         ("acceleration", "arm_3_joint")])
def test_the_sets_own_limit_is_where_the_monitor_stops_the_noise_free_fault(model, fault, joint):
    """The sets' own limit counts every test case the fault reaches within the window, those
    that start on it too (their initial-state estimate mistakes it for motion: for fd a bias
    shows as a velocity of b/dt). Before, only the one started just before the fault counted:
    a bias' limit was min_k d_k, above the step the monitor stops, and an acceleration's about
    8 % high. A fault 2 % above the limit is stopped within 100 ms of its first changed
    measurement (the acceleration's third sample: one sample of input, one of output delay),
    2 % below is not."""
    first = 0 if fault == "bias" else 2
    span = first + int(round(dt.WITHIN_S / model.plant.dt))
    lim = dt.sets_limit(model, joint, fault=fault)
    hit = _first_violation(model, joint, fault, 1.02 * lim, span)
    assert hit is not None and first <= hit <= span
    assert _first_violation(model, joint, fault, 0.98 * lim, span) is None


def test_a_bias_up_to_four_noise_bounds_reads_the_same_as_a_healthy_arm_standing_half_of_it_off():
    """The set-based bias limit (detection-limit note): with every reading's error within n, a
    bias b <= 4 n from sample 0 on and a healthy arm offset by b/2 (same inputs and disturbances)
    give the same readings, before and after the step. The limit before 2026-12-01 was 2 n: a
    bias of 0.999 * 4 n, which this construction hides, lay far above it."""
    from reachset_ros.systems.plant import lwa4p_joint_plant
    plant = lwa4p_joint_plant()
    A, B, C, G = (np.asarray(m, float) for m in (plant.A, plant.B, plant.C, plant.Gw))
    e = np.array([1.0, 1.0, 0.0, 0.0, 0.0])              # a constant position offset
    assert np.array_equal(A @ e, e) and float((C @ e)[0]) == 1.0
    cfg = simm.SimConfig.calibrated()
    set_based, _ = dt.bias_limits(cfg, 6)
    rng = np.random.default_rng(3)
    for j in range(6):
        nb = 3 * cfg.position_noise[j] + 0.5 * cfg.quantization
        b = 0.999 * float(set_based[j])
        assert b > 2 * nb                                   # above the old limit
        x = np.array([0.3, 0.3, 0.1, 0.0, 0.0])
        xt = x + 0.5 * b * e                                # the healthy twin
        for k in range(-200, 200):
            lo, hi = (0.5 * b - nb, nb) if k < 0 else (-nb, nb - 0.5 * b)
            y = float((C @ x)[0]) + rng.uniform(lo, hi) + (b if k >= 0 else 0.0)
            nu_twin = y - float((C @ xt)[0])
            assert abs(nu_twin) <= nb * (1 + 1e-9), (j, k)
            u, w = rng.uniform(-5, 5), rng.uniform(-1, 1, 2) * [0.05, 1.5]
            x = A @ x + B[:, 0] * u + G @ w
            xt = A @ xt + B[:, 0] * u + G @ w


@pytest.mark.parametrize("fraction", [1.0, 0.71, 0.5, 0.13])
def test_the_quantised_bias_limit_hides_a_bias_on_the_simulators_own_sensor(fraction):
    """:func:`dt.bias_twin` on a simulated run's true positions: the biased readings (rounded to
    the encoder step, as the simulator reads them) and a healthy arm's at an offset of M encoder
    steps agree, each with noise inside the simulator's clip of 3 sigma, for every bias up to
    the quantised limit."""
    cfg = simm.SimConfig.calibrated()
    _, quantised = dt.bias_limits(cfg, 6)
    _, log = dt.simulate(SETUP, seed=101, seconds=2.0)
    q_true = np.asarray(log["q_true"], float)
    assert np.ptp(q_true, axis=0).max() > 0.05              # the arm moves: every rounding phase
    for j in range(6):
        sig, step = cfg.position_noise[j], cfg.quantization
        b = fraction * float(quantised[j])
        tw = dt.bias_twin(q_true[:, j], b, sigma=sig, quantization=step, onset=len(q_true) // 2)
        assert tw["offset"] > 0 and tw["offset"] == pytest.approx(0.5 * quantised[j])
        np.testing.assert_allclose(tw["y"], tw["y_twin"], rtol=0, atol=1e-15)
        for nu in (tw["noise"], tw["noise_twin"]):
            assert np.max(np.abs(nu)) <= 3 * sig + 1e-15, (j, np.max(np.abs(nu)), 3 * sig)
        # the biased readings are the simulator's: the rounded biased position plus the noise
        h = np.arange(len(q_true)) >= len(q_true) // 2
        np.testing.assert_allclose(tw["y"] - tw["noise"], simm.quantize(q_true[:, j] + b * h, step),
                                   rtol=0, atol=1e-15)

