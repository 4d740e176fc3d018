"""The safe stop holds the arm (issue 19.1): stop categories, holding brakes, hard stops.

Pure core (no ROS): :mod:`reachset_ros.systems.stopping` (the controller node's stop law),
the simulated arm's brakes, hard stops and torque limits, and a stop on the simulated arm
for every fault kind of the simulator (:func:`reachset_ros.sim.safe_stop.simulate_safe_stop`).
Before: the controller had only the braking law (category 2), the simulated arm had no
brakes, no joint limits and integrated any torque; a 30 rad/s^2 fault beyond u_max = 26 ran
joint 1 away (486 rad in the demo's bag).
"""
import numpy as np
import pytest

from reachset_ros.errors import ReachsetError
from reachset_ros.sim import simulator as sim
from reachset_ros.sim.safe_stop import REST_WITHIN_S, TRAVEL_WITHIN_RAD, simulate_safe_stop
from reachset_ros.systems.stopping import (AT_REST, TIMEOUT, TRAVEL, StopPolicy, StopState, rest_after_stop,
                                           stop_tick)

MS = 1_000_000


def test_policy_validation():
    for bad in ({"category": 0}, {"category": 3}, {"max_time": 0.0}, {"max_travel": -1.0},
                {"rest_velocity": float("nan")}, {"rest_ticks": 0}):
        with pytest.raises(ReachsetError):
            StopPolicy(**bad)


def test_category_2_never_brakes_category_1_brakes_at_rest_on_time_and_on_travel():
    u_max = np.full(3, 26.0)
    q = np.zeros(3)
    # joint 0 at rest, joint 1 moving slowly for ever, joint 2 moving fast (travel)
    st2, st1 = StopState(3), StopState(3)
    pol1 = StopPolicy(category=1, rest_ticks=3, max_time=0.1, max_travel=0.05)
    for k in range(40):
        qd = np.array([0.0, 0.05, 1.0])
        qk = q + qd * k * 0.004
        u2, e2 = stop_tick(StopPolicy(category=2), st2, k * 4 * MS, qk, qd, u_max)
        u1, e1 = stop_tick(pol1, st1, k * 4 * MS, qk, qd, u_max)
        assert not e2.any() and np.all(np.abs(u2) <= u_max)
        assert np.all(u1[e1] == 0.0) and np.all(np.abs(u1) <= u_max)
    why = {j: (t, r) for t, j, r in st1.reasons}
    assert why[0] == (2 * 4 * MS, AT_REST)              # the third tick at rest
    assert why[2][1] == TRAVEL and why[2][0] == 13 * 4 * MS   # first tick beyond 0.05 rad (13 * 4 ms * 1 rad/s)
    assert why[1] == (25 * 4 * MS, TIMEOUT)             # 0.1 s after the stop began
    assert e1.all()


def test_rest_after_stop_measures_time_travel_and_nan():
    t = np.arange(100) * 4 * MS
    qd = np.zeros((100, 2))
    qd[:30, 0] = 0.5
    q = np.cumsum(qd, axis=0) * 0.004
    r = rest_after_stop(["a", "b"], t, q, qd, 10 * 4 * MS)
    assert r.rest_s == (pytest.approx(0.08), 0.0) and r.travel[0] == pytest.approx((29 - 10) * 0.5 * 0.004)
    assert r.failures(0.5, 0.3) == [] and len(r.failures(0.05, 0.3)) == 1
    qd[-1, 1] = np.nan
    r = rest_after_stop(["a", "b"], t, q, qd, 10 * 4 * MS)
    assert r.finite == (True, False) and "non-finite" in r.failures(0.5, 0.3)[0]


def test_simulated_brake_stops_and_holds_a_joint_against_a_fault():
    arm = sim.SimulatedArm(sim.SimConfig.ideal())
    arm.reset(np.zeros(6))
    arm.inject(sim.AccelerationDisturbance(joint=0, acceleration=30.0))
    tau = np.array(arm.state.tau_pending)
    for _ in range(50):
        arm.step(tau)
    _, q, qd = arm.true_state
    assert qd[0] > 1.0                     # running away under the fault
    arm.set_brakes([True, False, False, False, False, False])
    for _ in range(10):
        arm.step(tau)
    _, q1, qd1 = arm.true_state
    for _ in range(100):
        arm.step(tau)
    _, q2, qd2 = arm.true_state
    assert qd1[0] == 0.0 and qd2[0] == 0.0 and q2[0] == q1[0]    # held against the 30 rad/s^2
    assert arm.counters["brake_engaged"] == 1
    arm.set_brakes(False)                  # released: the fault moves it again
    for _ in range(20):
        arm.step(tau)
    assert arm.true_state[2][0] > 0.5


def test_simulated_hard_stops_torque_limits_and_invalid_commands():
    arm = sim.SimulatedArm(sim.SimConfig.ideal())
    arm.reset(np.zeros(6))
    hi = arm.q_upper.copy()
    arm.inject(sim.AccelerationDisturbance(joint=1, acceleration=200.0))
    tau = np.array(arm.state.tau_pending)
    for _ in range(200):
        arm.step(tau)
    _, q, qd = arm.true_state
    assert q[1] == hi[1] and qd[1] == 0.0 and arm.counters["hard_stop"] == 1   # at the URDF limit 2.07 rad
    # a command beyond the effort limits is clamped, counted, not integrated
    arm.reset(np.zeros(6))
    m = arm.step(np.full(6, 1e9))
    m = arm.step(np.zeros(6))
    assert arm.counters["torque_clamped"] == 1 and np.all(np.abs(m.tau_applied) <= arm.tau_limit)
    # a non-finite command is refused: every brake engages (a drive fault)
    arm.step(np.full(6, np.nan))
    assert arm.counters["invalid_command"] == 1 and arm.brakes.all()
    m = arm.step(np.zeros(6))
    assert np.all(np.isfinite(m.q_measured))


def test_preview_state_has_no_side_effects_with_brakes():
    arm = sim.SimulatedArm(sim.SimConfig.ideal())
    arm.reset(np.zeros(6), qd0=np.full(6, 0.3))
    arm.set_brakes(True)
    before = (arm.state.locked.copy(), dict(arm.counters))
    arm.preview_state()
    assert np.array_equal(arm.state.locked, before[0]) and arm.counters == before[1]


FAULTS = {
    "acceleration beyond u_max": sim.AccelerationDisturbance(joint="arm_1_joint", acceleration=30.0),
    "acceleration beyond u_max, joint 2": sim.AccelerationDisturbance(joint="arm_2_joint", acceleration=30.0),
    "torque": sim.TorqueDisturbance(joint="arm_2_joint", torque=60.0),
    "payload": sim.Payload(mass=5.0),
    "bias": sim.SensorBias(joint="arm_3_joint", bias=0.01),
    "frozen": sim.FrozenSensor(joint="arm_4_joint"),
    "nan": sim.NaNSamples(joint=None, count=3),
    "none": None,
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(FAULTS))
def test_category_1_stop_brings_every_joint_to_rest_for_every_fault_kind(name):
    """After the stop every joint is at rest (|qd| < 0.01 rad/s to the end) within
    REST_WITHIN_S and TRAVEL_WITHIN_RAD of where it was, with no NaN; measured as the bag
    would show it (a frozen sensor cannot show it: its joint is judged on the true state)."""
    run = simulate_safe_stop(FAULTS[name], before=1.0, stop_delay=0.02, after=2.0, seed=1)
    rep = run.rest(true_state=(name == "frozen"))
    assert rep.failures(REST_WITHIN_S, TRAVEL_WITHIN_RAD) == [], (rep.as_dict(), run.reasons)
    true = run.rest(true_state=True)
    assert true.failures(REST_WITHIN_S, TRAVEL_WITHIN_RAD) == [], true.as_dict()
    assert run.brakes[-1].all() and np.all(np.isfinite(run.q[run.stamps >= run.stop_ns]))
    assert run.counters["invalid_command"] == 0


def test_category_2_cannot_hold_a_fault_beyond_the_input_limits():
    """Why category 1 is the default: the braking law alone (what the controller had before)
    cannot decelerate a 30 rad/s^2 disturbance with u_max = 26: joint 1 runs into its hard stop."""
    run = simulate_safe_stop(FAULTS["acceleration beyond u_max"], before=1.0, after=2.0, seed=1,
                             policy=StopPolicy(category=2))
    rep = run.rest(true_state=True)
    assert rep.travel[0] > 1.0 and run.counters["hard_stop"] >= 1 and not run.brakes.any()
